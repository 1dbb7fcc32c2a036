"""The distributions: ``python -m build`` (sdist and wheel) and ``twine check`` on both.

The build runs without isolation (``--no-isolation``: the test extra installs setuptools,
wheel, build and twine), on a copy of the repository in a temporary folder, so no
network is needed and the checkout's ``build/`` folder (which can hold files of removed
modules) never reaches the wheel.

The sdist ships no tests: the suite reads the repository's examples, benchmarks, docs
and fixtures, so it runs from a clone (MANIFEST.in prunes tests, docs, benchmarks and
examples).
"""

from __future__ import annotations

import email
import shutil
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = sorted(p.name for p in (ROOT / "models" / "scenarios").glob("*.toml"))
PROTOS = sorted(p.name for p in (ROOT / "traces").glob("*.proto"))
#: Folders of the repository that the sdist leaves out (MANIFEST.in).
NOT_SHIPPED = ("tests", "docs", "benchmarks", "examples")

pytest.importorskip("build")
pytest.importorskip("twine")


def _source_files() -> list[str]:
    """The repository's files (tracked, and untracked ones git does not ignore)."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [f for f in out.splitlines() if (ROOT / f).is_file()]


@pytest.fixture(scope="module")
def dists(tmp_path_factory):
    """Build the sdist and the wheel once: ``{"sdist": path, "wheel": path}``."""
    base = tmp_path_factory.mktemp("packaging")
    src, out = base / "src", base / "dist"
    for name in _source_files():
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, src / name)
    build = subprocess.run([sys.executable, "-m", "build", "--no-isolation", "--sdist",
                            "--wheel", "--outdir", str(out), str(src)],
                           capture_output=True, text=True, timeout=300)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    log = build.stdout + build.stderr
    # setuptools' "Package 'x' is absent from the `packages` configuration" and the like
    assert "absent from" not in log and "SetuptoolsDeprecationWarning" not in log, log
    (sdist,) = out.glob("*.tar.gz")
    (wheel,) = out.glob("*.whl")
    return {"sdist": sdist, "wheel": wheel}


def test_twine_check_passes_on_both(dists):
    check = subprocess.run([sys.executable, "-m", "twine", "check", "--strict",
                            str(dists["sdist"]), str(dists["wheel"])],
                           capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stdout + check.stderr
    assert check.stdout.count("PASSED") == 2, check.stdout


def test_wheel_contents(dists):
    names = zipfile.ZipFile(dists["wheel"]).namelist()
    assert "netsim/py.typed" in names
    for scenario in SCENARIOS:
        assert f"netsim/models/scenarios/{scenario}" in names
    for proto in PROTOS:
        assert f"netsim/traces/{proto}" in names
    for package in ("netsim", "netsim/models", "netsim/estimators", "netsim/traces",
                    "netsim/bench", "netsim/claims", "netsim/papers", "netsim/reproduce"):
        assert f"{package}/__init__.py" in names
    licences = [n for n in names if n.endswith(".dist-info/licenses/LICENSE")]
    assert licences, names
    tops = {n.split("/")[0] for n in names}
    assert {t for t in tops if not t.endswith(".dist-info")} == {"netsim"}
    assert not [n for n in names if "test" in n.split("/")[-1] or n.startswith("tests/")]
    assert not [n for n in names if n.endswith((".pyc", ".mcap", ".png"))]


def test_wheel_metadata(dists):
    with zipfile.ZipFile(dists["wheel"]) as wheel:
        (meta_name,) = [n for n in wheel.namelist() if n.endswith(".dist-info/METADATA")]
        meta = email.message_from_bytes(wheel.read(meta_name))
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert meta["Name"] == "netsim" and meta["Version"] == project["version"]
    assert meta["License-Expression"] == "MIT"
    assert meta.get_all("License-File") == ["LICENSE"]
    assert "License ::" not in " ".join(meta.get_all("Classifier"))  # SPDX string instead
    assert "Typing :: Typed" in meta.get_all("Classifier")
    urls = dict(u.split(", ", 1) for u in meta.get_all("Project-URL"))
    assert urls["Source"] == "https://github.com/netsim-dev/netsim"
    assert urls["Documentation"] == "https://netsim-dev.github.io/netsim"
    requires = meta.get_all("Requires-Dist")
    core = [r for r in requires if "extra ==" not in r]
    # the optional pieces are extras, not core dependencies
    for optional in ("dask", "distributed", "matplotlib", "pandas", "foxglove"):
        assert not [r for r in core if r.lower().startswith(optional)], core
    extras = set(meta.get_all("Provides-Extra"))
    assert {"plot", "dask", "notebook", "live", "docs", "types", "test"} <= extras


def test_sdist_ships_no_tests(dists):
    with tarfile.open(dists["sdist"]) as tar:
        names = [n.split("/", 1)[1] for n in tar.getnames() if "/" in n]
    for folder in NOT_SHIPPED:
        assert not [n for n in names if n == folder or n.startswith(f"{folder}/")], folder
    for name in ("pyproject.toml", "README.md", "LICENSE", "CITATION.cff", "netsim/py.typed",
                 "netsim/__init__.py", "models/__init__.py", "estimators/__init__.py",
                 "traces/__init__.py",
                 *(f"models/scenarios/{s}" for s in SCENARIOS),
                 *(f"traces/{p}" for p in PROTOS)):
        assert name in names, name


def test_citation_cff_is_valid():
    """CITATION.cff: the keys CFF 1.2.0 requires, and the same version and licence as the
    package (the schema check itself runs where cffconvert is installed)."""
    yaml = pytest.importorskip("yaml")
    data = yaml.safe_load((ROOT / "CITATION.cff").read_text(encoding="utf-8"))
    assert data["cff-version"] == "1.2.0"
    for key in ("message", "title", "authors"):
        assert data[key], key
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert str(data["version"]) == project["version"]
    assert data["license"] == project["license"] == "MIT"
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License") and "Copyright (c) 2026 the netsim authors" in text


# -- optional dependencies: one line naming the extra ----------------------------------


@pytest.fixture
def without(monkeypatch):
    """Make ``import NAME`` fail as if NAME were not installed."""
    def hide(*names):
        for name in names:
            for loaded in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
                monkeypatch.delitem(sys.modules, loaded)
            monkeypatch.setitem(sys.modules, name, None)
    return hide


def _one_line(capsys, argv, extra):
    from netsim.cli import main

    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 2 and out == "", (code, out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"pip install 'netsim[{extra}]'" in err, err
    return err


def test_require_names_the_extra(without):
    from netsim.models.extras import MissingExtra, require

    without("matplotlib")
    with pytest.raises(MissingExtra, match=r"netsim plot needs matplotlib, which is not "
                       r"installed: pip install 'netsim\[plot\]'"):
        require("matplotlib.figure", "plot", "netsim plot")
    assert issubclass(MissingExtra, ImportError)


def test_plot_commands_without_matplotlib(capsys, without, tmp_path):
    without("matplotlib")
    sys.modules.pop("netsim.traces.plot", None)
    png = tmp_path / "x.png"
    trace = ROOT / "tests" / "fixtures" / "format1-consensus.mcap"
    assert "matplotlib" in _one_line(capsys, ["plot", str(trace), "-o", str(png)], "plot")
    _one_line(capsys, ["layout", str(trace), "-o", str(tmp_path / "l.json"),
                       "--figure", str(png)], "plot")
    assert not (tmp_path / "l.json").exists()  # refused before writing anything
    _one_line(capsys, ["bench", "delay-tolerance", "lcsys2022-fig1", "--plot", str(png),
                       "--no-progress"], "plot")
    _one_line(capsys, ["reproduce", "--out", str(tmp_path / "r")], "plot")
    assert not png.exists()


def test_dask_executor_without_dask(capsys, without):
    without("distributed", "dask")
    err = _one_line(capsys, ["bench", "delay-tolerance", "lcsys2022-fig1", "--dask",
                             "tcp://127.0.0.1:1", "--no-progress"], "dask")
    assert "dask[distributed]" in err
    from netsim.models.extras import MissingExtra

    from netsim.sweep import _Dask

    with pytest.raises(MissingExtra, match=r"pip install 'netsim\[dask\]'"):
        _Dask("tcp://127.0.0.1:1")
