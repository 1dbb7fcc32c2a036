"""Bad input through the real ``netsim`` command line.

Every broken scenario is the valid built-in ``lcsys2022-heterogeneous`` file with one
small edit. Each case asserts exit code 2, exactly one line on stderr of the form
``netsim run: error: ...`` naming the offending key, nothing on stdout, and no traceback.
A few cases run in a real subprocess (``python -m netsim.cli``) to prove the same from
the outside; the rest call :func:`netsim.cli.main` in-process.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from netsim.models.scenario import builtin_scenarios, load_scenario

from netsim.cli import main

BUILTIN = "lcsys2022-heterogeneous"
BASE = builtin_scenarios()[BUILTIN].read_text(encoding="utf-8")
SMALL = ["--steps", "10", "--trials", "1", "--no-progress"]
PREFIX = "netsim run: error: "

NETWORK = 'topology = "cycle"\nagents = 4\nweights = "random"\nseed = 2022\n'
# A valid explicit P for the cycle 0->1->2->3->0 (P[i][j] > 0: i receives from j).
P_VALID = [
    [0.5, 0.0, 0.0, 0.5],
    [0.5, 0.5, 0.0, 0.0],
    [0.0, 0.5, 0.5, 0.0],
    [0.0, 0.0, 0.5, 0.5],
]
A_BLOCK = re.compile(r"^A = \[\n(?:    \[.*\],\n)+\]\n", re.MULTILINE)
A_ROW_3 = "[0.00, 0.00, -0.20, 0.95, 0.00, 0.00],"
A_ROW_5 = "    [0.00, 0.00, 0.00, 0.00, 0.00, 1.04],\n"
C_SENSOR_2 = "[[0.0, 0.0, 0.0, 0.0, 1.0, 0.0]],"
DELAYS = 'model = "heterogeneous"\ntau = 3\n'
FIXED_DELAYS = 'model = "fixed"\nlinks = [{from = 0, to = 1, delay = 2}]\n'


def edit(old: str, new: str, text: str = BASE) -> str:
    """Replace the single occurrence of ``old`` (fail loudly if the base file changed)."""
    assert text.count(old) == 1, f"expected exactly one {old!r} in the base scenario"
    return text.replace(old, new)


def with_p(rows: list[list[float]]) -> str:
    """The base scenario with ``network.P`` given explicitly instead of a topology."""
    body = ",\n".join("    [" + ", ".join(repr(float(v)) for v in row) + "]" for row in rows)
    return edit(NETWORK, f"P = [\n{body},\n]\n")


def write(tmp_path: Path, text: str, name: str = "broken.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def run_main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["run", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def run_process(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "netsim.cli", "run", *args],
        capture_output=True, text=True, timeout=120, check=False,
    )


def assert_bad_input(code: int, out: str, err: str, *fragments: str) -> None:
    """Exit 2, nothing on stdout, one ``netsim run: error:`` line containing ``fragments``."""
    assert "Traceback" not in err, err
    assert code == 2, err
    assert out == ""
    assert err.endswith("\n") and err.count("\n") == 1, f"not exactly one line: {err!r}"
    assert err.startswith(PREFIX), err
    for fragment in fragments:
        assert fragment in err, f"{fragment!r} not in {err!r}"


# -- control: the edits below break only what they mean to break ---------------


@pytest.mark.parametrize(
    "text",
    [
        pytest.param(BASE, id="base"),
        pytest.param(with_p(P_VALID), id="explicit-P"),
        pytest.param(
            edit(NETWORK, 'topology = "edges"\nagents = 4\nedges = [[0, 1], [1, 2], [2, 3], '
                 '[3, 0]]\nseed = 2022\n'),
            id="edges",
        ),
        pytest.param(edit(DELAYS, FIXED_DELAYS), id="fixed-links"),
    ],
)
def test_unbroken_variants_load(tmp_path: Path, text: str) -> None:
    scenario = load_scenario(write(tmp_path, text))
    assert scenario.n_agents == 4


# -- broken scenario files -----------------------------------------------------

CASES = [
    # 1. P not row-stochastic: row 2 sums to 0.9
    pytest.param(
        with_p([P_VALID[0], P_VALID[1], [0.0, 0.4, 0.5, 0.0], P_VALID[3]]),
        ["network.P", "row-stochastic", "row 2", "0.9"],
        id="P-not-row-stochastic",
    ),
    # 2. zero self-weight (row still sums to 1)
    pytest.param(
        with_p([P_VALID[0], [1.0, 0.0, 0.0, 0.0], P_VALID[2], P_VALID[3]]),
        ["network.P[1][1]", "self-weights"],
        id="P-zero-self-weight",
    ),
    # 3. missing matrix
    pytest.param(A_BLOCK.sub("", BASE, count=1), ["plant.A", "missing"], id="A-missing"),
    # 4. mis-shaped matrices
    pytest.param(
        edit(C_SENSOR_2, "[[0.0, 0.0, 0.0, 0.0, 1.0]],"),
        ["plant.C[2]", "shape", "(1, 5)", "6"],
        id="C2-five-columns",
    ),
    pytest.param(edit(A_ROW_5, ""), ["plant.A", "square", "(5, 6)"], id="A-not-square"),
    pytest.param(
        edit(A_ROW_3, "[0.00, 0.00, -0.20, 0.95, 0.00],"),
        ["plant.A", "row 3", "5 entries"],
        id="A-ragged",
    ),
    # 5. negative delays
    pytest.param(edit("tau = 3", "tau = -1"), ["delays.tau", ">= 0", "-1"], id="tau-negative"),
    pytest.param(
        edit(DELAYS, 'model = "fixed"\nlinks = [{from = 0, to = 1, delay = -2}]\n'),
        ["delays.links[0].delay", ">= 0", "-2"],
        id="fixed-link-delay-negative",
    ),
    # 6. unknown keys
    pytest.param(
        edit('weights = "random"', 'weigths = "random"'),
        ["network.weigths", "unknown", "did you mean 'weights'"],
        id="unknown-network-key",
    ),
    pytest.param(BASE + "\n[extras]\nfoo = 1\n", ["extras: unknown"], id="unknown-section"),
    # 7. non-finite matrix entries
    pytest.param(
        edit(A_ROW_3, "[0.00, 0.00, -0.20, nan, 0.00, 0.00],"),
        ["plant.A[3][3]", "NaN"],
        id="A-nan",
    ),
    pytest.param(
        edit(A_ROW_3, "[0.00, 0.00, -0.20, 0.95, inf, 0.00],"),
        ["plant.A[3][4]", "infinite"],
        id="A-inf",
    ),
    # 8. graphs that are not strongly connected
    pytest.param(
        with_p([
            [0.5, 0.5, 0.0, 0.0],
            [0.5, 0.5, 0.0, 0.0],
            [0.0, 0.0, 0.5, 0.5],
            [0.0, 0.0, 0.5, 0.5],
        ]),
        ["network.P", "not strongly connected"],
        id="P-block-diagonal",
    ),
    pytest.param(
        edit(NETWORK, 'topology = "edges"\nagents = 4\nedges = [[0, 1], [1, 0], [2, 3], '
             '[3, 2]]\nseed = 2022\n'),
        ["network", "not strongly connected"],
        id="edges-disconnected",
    ),
]


@pytest.mark.parametrize(("text", "fragments"), CASES)
def test_broken_scenario_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, fragments: list[str]
) -> None:
    path = write(tmp_path, text)
    code, out, err = run_main(capsys, str(path), *SMALL)
    assert_bad_input(code, out, err, f"scenario {path}: ", *fragments)


def test_nan_matrix_in_real_process(tmp_path: Path) -> None:
    path = write(tmp_path, edit(A_ROW_3, "[0.00, 0.00, -0.20, nan, 0.00, 0.00],"))
    proc = run_process(str(path), *SMALL)
    assert_bad_input(proc.returncode, proc.stdout, proc.stderr, "plant.A[3][3]: is NaN")


def test_not_row_stochastic_in_real_process(tmp_path: Path) -> None:
    path = write(tmp_path, with_p([P_VALID[0], P_VALID[1], [0.0, 0.4, 0.5, 0.0], P_VALID[3]]))
    proc = run_process(str(path), *SMALL)
    assert_bad_input(proc.returncode, proc.stdout, proc.stderr, "row-stochastic", "row 2")


# -- bad scenario names, files and options -------------------------------------


def test_missing_scenario_file_in_real_process(tmp_path: Path) -> None:
    path = tmp_path / "does-not-exist.toml"
    proc = run_process(str(path), *SMALL)
    assert_bad_input(
        proc.returncode, proc.stdout, proc.stderr, "cannot read scenario file", str(path),
        "No such file",
    )


def test_unknown_builtin_name(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, "lcsys2022-heterogenous", *SMALL)
    assert_bad_input(
        code, out, err, "no built-in scenario or file named 'lcsys2022-heterogenous'",
        "did you mean 'lcsys2022-heterogeneous'",
    )


def test_invalid_toml_in_real_process(tmp_path: Path) -> None:
    path = write(tmp_path, edit("tau = 3", "tau = = 3"))
    proc = run_process(str(path), *SMALL)
    assert_bad_input(proc.returncode, proc.stdout, proc.stderr, "not valid TOML", "line")


@pytest.mark.parametrize(
    ("option", "value"),
    [("--trials", "0"), ("--steps", "0"), ("--trials", "-3"), ("--seed", "-1")],
)
def test_non_positive_run_option(
    capsys: pytest.CaptureFixture[str], option: str, value: str
) -> None:
    args = [BUILTIN, "--steps", "10", "--trials", "1", "--no-progress", option, value]
    code, out, err = run_main(capsys, *args)
    assert_bad_input(code, out, err, option, value)


def test_negative_tau_override_on_builtin(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, BUILTIN, "--tau", "-1", *SMALL)
    assert_bad_input(code, out, err, "delays.tau", "-1")


def test_tau_override_on_fixed_delays(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write(tmp_path, edit(DELAYS, FIXED_DELAYS))
    code, out, err = run_main(capsys, str(path), "--tau", "1", *SMALL)
    assert_bad_input(code, out, err, "delays.tau", "fixed")


def test_unknown_estimator_option(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, BUILTIN, "--estimators", "block,kalman", *SMALL)
    assert_bad_input(code, out, err, "--estimators", "kalman")


def test_non_integer_option_is_an_argparse_error(capsys: pytest.CaptureFixture[str]) -> None:
    # one line, like every other bad input (the usage is left to --help)
    with pytest.raises(SystemExit) as exit_info:
        main(["run", BUILTIN, "--trials", "abc"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "Traceback" not in err
    assert err == ("netsim run: error: argument --trials: invalid int value: 'abc' "
                   "(see netsim run --help)\n")


# -- bugs found by these tests, now fixed -----------------------------------------


def test_non_utf8_scenario_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes(BASE.replace("LCSYS2022 Section IV", "LCSYS2022 \xa7 IV").encode("latin-1"))
    code, out, err = run_main(capsys, str(path), *SMALL)
    assert_bad_input(code, out, err, str(path))


def test_empty_estimator_list(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, BUILTIN, "--estimators", ",", *SMALL)
    assert_bad_input(code, out, err, "--estimators")


# -- a valid run ---------------------------------------------------------------


def test_valid_tiny_run_prints_json() -> None:
    proc = run_process(BUILTIN, "--steps", "20", "--trials", "2", "--json")
    assert "Traceback" not in proc.stderr
    assert proc.returncode == 0, proc.stderr
    data = json.loads(proc.stdout)
    assert data["steps"] == 20 and data["trials"] == 2
    estimators = data["estimators"]
    assert set(estimators) == {"compensated", "uncompensated", "block", "centralized-kf"}
    for name, result in estimators.items():
        assert "verdict" in result and isinstance(result["last_trusted_mse"], float), name
        # a steady MSE belongs to stable runs only
        assert ("steady_state_mse" in result) == (result["verdict"] == "stable"), name
        assert result["verdict"] in ("stable", "diverging", "unbounded", "undecided",
                                     "diverged"), name


@pytest.mark.parametrize("radius", ["0.0", "-1.0"])
def test_non_positive_geometric_radius_is_rejected(tmp_path: Path, capsys, radius) -> None:
    text = BASE.replace('topology = "cycle"', f'topology = "geometric"\nradius = {radius}')
    path = tmp_path / "geo.toml"
    path.write_text(text)
    code, out, err = run_main(capsys, str(path), *SMALL)
    assert_bad_input(code, out, err, "network.radius")


def test_vectorised_engine_refuses_the_aoi_observer(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, "aoi-example", "--engine", "vectorised",
                              "--no-progress")
    assert_bad_input(code, out, err, "--engine vectorised", "aoi-example", "event kernel")


def test_divergence_threshold_beyond_float_range_is_no_threshold(tmp_path: Path) -> None:
    """run.divergence_threshold = 1e300 (its square overflows) runs on both engines."""
    path = write(tmp_path, BASE.replace("[run]", "[run]\ndivergence_threshold = 1e300", 1))
    scenario = load_scenario(path)
    from netsim.runner import run_monte_carlo

    for engine in ("events", "vectorised"):
        result = run_monte_carlo(scenario, steps=20, trials=2, engine=engine,
                                 families=["centralized-kf"])
        s = result.estimators["centralized-kf"]
        # no trial blew up; 10 fitted steps x 2 trials may not establish "stable"
        assert s.diverged == [] and s.verdict in ("stable", "undecided")
        assert s.judgement.growth.rate < 1  # the transient decays


@pytest.mark.parametrize("engine", ["events", "vectorised"])
def test_trace_replay_past_its_end_is_one_clear_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], engine: str) -> None:
    short = tmp_path / "short.mcap"
    code, _, err = run_main(capsys, "lcsys2022-time-varying", "--trials", "1", "--steps", "20",
                            "--estimators", "compensated", "--trace", str(short),
                            "--no-progress")
    assert code == 0, err
    replay = write(tmp_path, BASE + f'\n[links]\ndelay = {{distribution = "trace", '
                   f'file = "{short}"}}\n', "replay.toml")
    code, out, err = run_main(capsys, str(replay), "--steps", "40", "--trials", "1",
                              "--estimators", "compensated", "--engine", engine,
                              "--no-progress")
    assert_bad_input(code, out, err, "replay.toml", "recorded 21 messages on link",
                     "no recorded delay")
