"""Every file the README shows or the tests read from the repository is committed.

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


def test_readme_images_exist_and_are_tracked():
    text = (ROOT / "README.md").read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text)
    assert images, "the README shows figures"
    tracked = _tracked()
    for path in images:
        assert (ROOT / path).is_file(), path
        if tracked is not None:
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
