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
