"""mypy at default strictness gives 0 errors on netsim, models, estimators and traces.

The folders ``models/``, ``estimators/`` and ``traces/`` install as ``netsim.models``,
``netsim.estimators`` and ``netsim.traces`` (pyproject's package-dir). The editable
install maps them with an import hook, which mypy does not run, so ``mypy -p netsim``
alone would not find them. Instead mypy checks a tree of symbolic links laid out as the
installed package: ``netsim/`` holding links to each entry of the repository's
``netsim/`` folder plus ``models``, ``estimators`` and ``traces``. The tree is kept in
``.mypy_cache/`` (which mypy keeps out of git). Every file is checked exactly once, under
the module name the code imports it by, with the settings of ``mypy.ini`` at the
repository root. Paths in the report are given back as repository paths.

By hand (extra arguments go to mypy)::

    .venv/bin/python tests/test_types.py
"""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SUBPACKAGES = ("models", "estimators", "traces")


def _link_tree(base: Path) -> Path:
    """Lay the four folders out under ``base`` as the installed ``netsim`` package.

    The tree stays in place between runs (mypy's cache records each module's path) and is
    brought up to date link by link, each link replaced atomically, so that two runs at
    once do not disturb each other.
    """
    pkg = base / "netsim"
    pkg.mkdir(parents=True, exist_ok=True)
    want = {}
    for entry in (ROOT / "netsim").iterdir():
        if entry.name in SUBPACKAGES:
            raise RuntimeError(f"netsim/{entry.name} would shadow the top-level {entry.name}/")
        if entry.name != "__pycache__" and (entry.is_dir() or entry.suffix in (".py", ".pyi")):
            want[entry.name] = entry
    for name in SUBPACKAGES:
        want[name] = ROOT / name
    for name, target in want.items():
        link = pkg / name
        if link.is_symlink() and os.readlink(link) == str(target):
            continue
        tmp = pkg / f".{name}.{os.getpid()}"
        tmp.symlink_to(target)
        os.replace(tmp, link)
    for stale in pkg.iterdir():
        if stale.name not in want and not stale.name.startswith("."):
            stale.unlink(missing_ok=True)
    return pkg


def run_mypy(*extra: str) -> subprocess.CompletedProcess[str]:
    """Run mypy on the installed layout; the report's paths are repository paths."""
    tree = ROOT / ".mypy_cache" / "installed-layout"
    pkg = _link_tree(tree)
    env = dict(os.environ, MYPYPATH=str(tree))
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(ROOT / "mypy.ini"),
         "--cache-dir", str(ROOT / ".mypy_cache"), "-p", "netsim", *extra],
        cwd=ROOT, env=env, capture_output=True, text=True,
    )
    out = proc.stdout + proc.stderr
    for shown in (str(pkg), str(pkg.relative_to(ROOT))):
        for name in SUBPACKAGES:
            out = out.replace(f"{shown}/{name}/", f"{name}/")
        out = out.replace(f"{shown}/", "netsim/")
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, "")


def _error_count(report: str) -> int:
    return sum(1 for line in report.splitlines() if ": error:" in line)


def test_mypy_clean() -> None:
    proc = run_mypy()
    assert "Success" in proc.stdout or "Found" in proc.stdout, proc.stdout  # mypy ran
    errors = _error_count(proc.stdout)
    assert proc.returncode == 0 and errors == 0 and "Success: no issues found" in proc.stdout, (
        f"mypy: {errors} errors (issue 30: none allowed):\n{proc.stdout}")


if __name__ == "__main__":
    result = run_mypy(*sys.argv[1:])
    sys.stdout.write(result.stdout)
    sys.exit(result.returncode)
