"""The public Python API: the documented example (docs/getting-started.rst) runs, the
surface is what it documents, and the installed packages cannot collide with other
distributions."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


GETTING_STARTED = ROOT / "docs" / "getting-started.rst"


def _docs_block(section: str) -> str:
    """The one ``.. code-block:: python`` under ``section`` of docs/getting-started.rst."""
    text = GETTING_STARTED.read_text()
    underline = "-" * len(section)
    part = text.split(f"\n{section}\n{underline}\n", 1)[1]
    part = re.split(r"\n[^\n]+\n-{3,}\n", part, maxsplit=1)[0]  # up to the next section
    blocks = re.findall(r"\.\. code-block:: python\n\n((?:(?:   .*)?\n)+)", part)
    assert len(blocks) == 1, f"expected one python block under {section!r}"
    return textwrap.dedent(blocks[0])


def test_docs_python_api_example_runs(capsys, tmp_path, monkeypatch):
    code = _docs_block("Python API")
    monkeypatch.chdir(tmp_path)  # the example writes run.mcap
    namespace: dict = {}
    exec(compile(code, "docs/getting-started.rst (Python API)", "exec"), namespace)  # noqa: S102
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "(4, 101, 4)"
    assert out[1] == "(4, 101, 4, 4)"
    # the example's own numbers, checked against what they must be
    held = namespace["held"]["hold"]
    # an estimator that keeps its prior (0) has error ||x_k||^2 at every agent
    np.testing.assert_allclose(held.squared_errors,
                               np.repeat((held.states ** 2).sum(axis=-1)[..., None], 4,
                                         axis=-1))
    assert namespace["gains"].method == namespace["result"].monte_carlo.gains.method


def test_version_after_install():
    done = subprocess.run([sys.executable, "-c", "import netsim; print(netsim.__version__)"],
                          capture_output=True, text=True, timeout=60, cwd="/")
    assert done.returncode == 0, done.stderr
    from importlib.metadata import version

    assert done.stdout.strip() == version("netsim")


def test_the_documented_surface_exists():
    import netsim

    for name in netsim.__all__:
        assert getattr(netsim, name) is not None, name
    assert isinstance(netsim.__version__, str)
    with pytest.raises(AttributeError):
        netsim.no_such_thing  # noqa: B018


def test_importing_a_subpackage_does_not_load_the_kernel():
    code = ("import sys, netsim.models.scenario; "
            "print(sorted(m for m in sys.modules if m in ('simpy', 'netsim.api', "
            "'netsim.kernel')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd="/")
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_installed_packages_all_live_under_netsim():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert all(p == "netsim" or p.startswith("netsim.") for p in config["packages"])
    # from outside the source tree, the folders are not importable as top-level names
    code = ("import importlib.util as u; "
            "print([n for n in ('models', 'estimators') if u.find_spec(n)])")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd="/", env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_load_scenario_from_a_dict_and_bad_estimator_name():
    from netsim.models.scenario import resolve_scenario

    import netsim

    source = tomllib.loads((ROOT / "models" / "scenarios" /
                            "lcsys2022-homogeneous.toml").read_text())
    scenario = netsim.load_scenario(source)
    builtin = resolve_scenario("lcsys2022-homogeneous")
    assert np.array_equal(scenario.weights, builtin.weights)
    source["run"]["estimators"] = ["compensated", "no-such-estimator"]
    with pytest.raises(netsim.ScenarioError, match=r"run\.estimators\[1\]"):
        netsim.load_scenario(source)


def test_to_dataframe_rows():
    pd = pytest.importorskip("pandas")
    import netsim

    result = netsim.run("lcsys2022-heterogeneous", steps=10, trials=2,
                        estimators=["compensated", "centralized-kf"])
    frame = result.to_dataframe()
    assert isinstance(frame, pd.DataFrame)
    assert len(frame) == 2 * 11 * 4 + 2 * 11 * 1
    sub = frame[(frame.family == "compensated") & (frame.trial == 1) & (frame.step == 5)]
    np.testing.assert_array_equal(sub.squared_error.to_numpy(),
                                  result["compensated"].squared_errors[1, 5])


@pytest.mark.slow
def test_fresh_venv_install_beside_pypi_traces(tmp_path):
    """pip install netsim, then the PyPI package `traces`: netsim's traces still work."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, str(ROOT)], check=True, timeout=1200)
    subprocess.run([*pip, "traces"], check=True, timeout=600)
    netsim_cli = str(venv / "bin" / "netsim")
    trace = tmp_path / "t.mcap"
    subprocess.run([netsim_cli, "run", "lcsys2022-heterogeneous", "--trials", "1", "--steps",
                    "20", "--estimators", "compensated", "--trace", str(trace),
                    "--no-progress"], check=True, timeout=300, cwd=tmp_path)
    done = subprocess.run([netsim_cli, "inspect", str(trace), "--json"], capture_output=True,
                          text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert '"family": "compensated"' in done.stdout
