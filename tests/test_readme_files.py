"""Every file the README shows or links, or the tests read from the repository, is
committed.

A fresh clone has only what git tracks, and ``.gitignore`` ignores ``*.png`` and
``*.mcap``: a figure or fixture that exists only in a working tree would pass locally and
fail in CI (or show a broken image on the project page).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

__all__: list[str] = []

ROOT = Path(__file__).resolve().parent.parent


def _tracked() -> set[str] | None:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return set(out.splitlines())


#: The project's address; the README's links into the repository start with these (so
#: they work on PyPI too), and are mapped back to repository paths here.
PROJECT = "https://github.com/netsim-dev/netsim"
_REPO_URL = re.compile(r"^(?:https://raw\.githubusercontent\.com/netsim-dev/netsim/main/"
                       r"|https://github\.com/netsim-dev/netsim/(?:blob|tree)/main/)(.*)$")


def repo_path(url: str) -> str | None:
    """The repository path an absolute README link points at, or None for another site."""
    m = _REPO_URL.match(url)
    return m[1].rstrip("/") if m else None


def test_repo_path_maps_the_project_urls():
    assert repo_path("https://raw.githubusercontent.com/netsim-dev/netsim/main/docs/a.png") == (
        "docs/a.png")
    assert repo_path(f"{PROJECT}/blob/main/docs/cli.rst") == "docs/cli.rst"
    assert repo_path(f"{PROJECT}/tree/main/docs/gallery/") == "docs/gallery"
    assert repo_path("https://example.org/docs/a.png") is None


def test_readme_images_exist_and_are_tracked():
    text = (ROOT / "README.md").read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text)
    assert images, "the README shows figures"
    tracked = _tracked()
    for url in images:
        # absolute, so that the picture shows on PyPI as well as on GitHub
        path = repo_path(url)
        assert path is not None, f"{url}: not an absolute link into {PROJECT}"
        assert (ROOT / path).is_file(), path
        if tracked is not None:
            assert path in tracked, f"{path} exists but is not committed"


def test_readme_links_into_the_repository_exist():
    text = (ROOT / "README.md").read_text()
    links = re.findall(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)", text)
    tracked = _tracked()
    for url in links:
        assert "://" in url or url.startswith("#"), f"{url}: relative links break on PyPI"
        path = repo_path(url)
        if path is None:
            continue
        assert (ROOT / path).exists(), path
        if tracked is not None and (ROOT / path).is_file():
            assert path in tracked, f"{path} exists but is not committed"


def test_fixture_files_are_tracked():
    tracked = _tracked()
    if tracked is None:
        pytest.skip("not a git checkout")
    for path in sorted((ROOT / "tests" / "fixtures").glob("*")):
        if path.is_file() and path.suffix != ".pyc":
            rel = path.relative_to(ROOT).as_posix()
            assert rel in tracked, f"{rel} exists but is not committed"


def test_every_package_is_listed_in_pyproject():
    """A non-editable install (``pip install .``) ships only the listed packages: every
    folder with an ``__init__.py`` under the package roots must be one of them."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    roots = {name: ROOT / folder for name, folder in config["package-dir"].items()}
    found = set()
    for name, folder in roots.items():
        for init in folder.rglob("__init__.py"):
            rel = init.parent.relative_to(folder).parts
            if "scenarios" in rel or any(p.startswith((".", "_")) for p in rel):
                continue
            found.add(".".join((name, *rel)))
    assert found <= listed, f"not in pyproject's packages: {sorted(found - listed)}"
