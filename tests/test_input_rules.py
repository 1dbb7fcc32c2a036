"""Inputs that used to give an unnamed error or were silently accepted.

Each case runs the real ``netsim`` command line in-process and asserts the exit code and
the message: exit 2 with one ``error:`` line naming the key, or, where the input is
reasonable, exit 0 with one ``warning:`` line on stderr (the rule is in the README).
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest
from netsim.models.scenario import ScenarioWarning, builtin_scenarios, load_scenario

from netsim.cli import main
from tests.test_bad_input import (
    BASE,
    DELAYS,
    NETWORK,
    SMALL,
    assert_bad_input,
    edit,
    run_main,
    write,
)

EDGES = ('topology = "edges"\nagents = 4\nedges = [[0, 1], [1, 2], [2, 3], [3, 0]{extra}]\n'
         'seed = 2022\n')


def assert_warned(code: int, out: str, err: str, command: str, *fragments: str) -> None:
    """Exit 0, output on stdout, exactly one ``netsim <command>: warning:`` line."""
    assert "Traceback" not in err, err
    assert code == 0, err
    assert out
    lines = [line for line in err.splitlines() if line.strip()]
    warned = [line for line in lines if line.startswith(f"netsim {command}: warning: ")]
    assert len(warned) == 1, err
    for fragment in fragments:
        assert fragment in warned[0], f"{fragment!r} not in {warned[0]!r}"


def test_utf8_bom_is_skipped_with_a_warning(tmp_path, capsys) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BASE.encode("utf-8"))
    code, out, err = run_main(capsys, str(path), *SMALL, "--json")
    assert_warned(code, out, err, "run", str(path), "UTF-8 BOM")
    path.write_text(BASE, encoding="utf-8")  # the same file without its BOM
    assert main(["run", str(path), *SMALL, "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.out == out and "warning" not in captured.err


def test_utf8_bom_from_python_is_a_scenario_warning(tmp_path) -> None:
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BASE.encode("utf-8"))
    with pytest.warns(ScenarioWarning, match="UTF-8 BOM"):
        assert load_scenario(path).n_agents == 4


# -- silently accepted: now errors ----------------------------------------------------


CASES = [
    pytest.param(edit(NETWORK, NETWORK + "P = [[0.5, 0, 0, 0.5], [0.5, 0.5, 0, 0], "
                      "[0, 0.5, 0.5, 0], [0, 0, 0.5, 0.5]]\n"),
                 ["network.weights", "network.P", "not both"], id="P-and-weights"),
    pytest.param(edit(NETWORK, EDGES.format(extra=", [0, 1]")),
                 ["network.edges[4]", "0 -> 1", "listed twice", "network.edges[0]"],
                 id="duplicate-edge"),
    pytest.param(edit(NETWORK, EDGES.format(extra=", [2, 2]")),
                 ["network.edges[4]", "self-loop"], id="self-loop-edge"),
    pytest.param(edit(DELAYS, 'model = "fixed"\nlinks = [{from = 0, to = 1, delay = 2}, '
                      '{from = 0, to = 1, delay = 1}]\n'),
                 ["delays.links[1]", "0 -> 1", "listed twice", "delays.links[0]"],
                 id="duplicate-delay-link"),
    pytest.param(edit(DELAYS, 'model = "none"\ntau = 3\n'),
                 ["delays.tau", "'none'", "homogeneous"], id="tau-with-model-none"),
    pytest.param(edit(DELAYS, 'model = "none"\n') + '\n[links]\ndelay = { distribution = '
                 '"constant", value = 5 }\nbound = 2\n',
                 ["links.bound", "is 2", "up to 5", "links.delay", ">= 5"],
                 id="bound-below-constant-delay"),
    pytest.param(edit(DELAYS, 'model = "homogeneous"\ntau = 4\n') + '\n[links]\nbound = 3\n',
                 ["links.bound", "is 3", "up to 4", "[delays]"],
                 id="bound-below-homogeneous-tau"),
]


@pytest.mark.parametrize("text, fragments", CASES)
def test_silent_acceptance_is_now_an_error(tmp_path, capsys, text, fragments) -> None:
    path = write(tmp_path, text)
    code, out, err = run_main(capsys, str(path), *SMALL)
    assert_bad_input(code, out, err, *fragments)


def test_explicit_tau_zero_with_model_none_is_fine(tmp_path) -> None:
    scenario = load_scenario(write(tmp_path, edit(DELAYS, 'model = "none"\ntau = 0\n')))
    assert scenario.delay_bound == 0


def test_bound_above_an_unbounded_distribution_is_a_choice(tmp_path) -> None:
    text = edit(DELAYS, 'model = "none"\n') + (
        '\n[links]\ndelay = { distribution = "geometric", p = 0.2 }\nbound = 3\n')
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)
        assert load_scenario(write(tmp_path, text)).delay_bound == 3


# -- silently accepted: now a documented rule with a warning ---------------------------


def test_links_bound_over_delays_tau_warns(tmp_path, capsys) -> None:
    text = edit(DELAYS, 'model = "homogeneous"\ntau = 4\n') + "\n[links]\nbound = 6\n"
    code, out, err = run_main(capsys, str(write(tmp_path, text)), *SMALL, "--json")
    assert_warned(code, out, err, "run", "links.bound: 6 replaces delays.tau = 4",
                  "tau-bar = 6")
    assert '"bound": 6' in out


def test_edge_probability_zero_warns(tmp_path, capsys) -> None:
    text = edit(NETWORK, 'topology = "random"\nagents = 4\nweights = "random"\nseed = 2022\n'
                'edge_probability = 0\n')
    code, out, err = run_main(capsys, str(write(tmp_path, text)), *SMALL, "--json")
    assert_warned(code, out, err, "run", "network.edge_probability", "Hamiltonian cycle")
    assert re.search(r'"links": \[\s*\[', out)


def test_a_warning_is_said_once_per_command(tmp_path, capsys) -> None:
    """A sweep parses its scenario once per variant; the warning is one line."""
    text = edit(NETWORK, 'topology = "random"\nagents = 4\nweights = "random"\nseed = 2022\n'
                'edge_probability = 0\n')
    path = write(tmp_path, text)
    code = main(["bench", "sweep", str(path), "--taus", "0,1", "--trials", "1", "--steps",
                 "5", "--estimators", "compensated", "--workers", "1", "--no-progress",
                 "--out", str(tmp_path / "rows.jsonl")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert err.count("warning: network.edge_probability") == 1, err


def test_builtin_scenarios_and_examples_warn_nothing() -> None:
    import warnings

    examples = sorted((Path(__file__).parent.parent / "examples").glob("*.toml"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)
        for path in [*builtin_scenarios().values(), *examples]:
            load_scenario(path)
            tomllib.loads(path.read_text(encoding="utf-8"))


# -- a singular innovation covariance names plant.R ----------------------------------

DKFE = builtin_scenarios()["dkfe-example2"].read_text(encoding="utf-8")


def _dkfe_with_R(R: str) -> str:
    start, stop = DKFE.index("R = ["), DKFE.index("x0_cov")
    return DKFE[:start] + f"R = {R}\n" + DKFE[stop:]


@pytest.mark.parametrize("R", ["0", "[0.0, 0.0, 0.0]"])
def test_singular_R_of_a_kalman_filter_names_plant_R(tmp_path, capsys, R) -> None:
    """Sink 0 of dkfe-example2 measures x0 + x2 twice: with R_0 = 0 its innovation
    covariance is singular (was: "Singular matrix")."""
    path = write(tmp_path, _dkfe_with_R(R))
    code, out, err = run_main(capsys, str(path), *SMALL)
    assert_bad_input(code, out, err, "plant.R[0]", "innovation covariance", "singular",
                     "step 0")


@pytest.mark.parametrize("engine", ["vectorised", "events"])
def test_singular_R_of_the_centralised_filter(tmp_path, capsys, engine) -> None:
    text = edit("R = 0.004", "R = 0")
    text = edit("[[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]],", "[[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]],", text)
    path = write(tmp_path, text)
    code, out, err = run_main(capsys, str(path), *SMALL, "--estimators", "centralized-kf",
                              "--engine", engine)
    assert_bad_input(code, out, err, "plant.R:", "innovation covariance", "singular")


def test_R_zero_with_independent_outputs_still_runs(tmp_path, capsys) -> None:
    path = write(tmp_path, edit("R = 0.004", "R = 0"))
    code, out, err = run_main(capsys, str(path), *SMALL, "--estimators",
                              "local-kf,centralized-kf")
    assert code == 0, err


# -- bench: the results file and the Dask scheduler ------------------------------------


def assert_bench_error(code: int, err: str, *fragments: str) -> None:
    assert "Traceback" not in err, err
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("netsim bench: error: "), err
    for fragment in fragments:
        assert fragment in last, f"{fragment!r} not in {last!r}"


def _bench(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["bench", "delay-tolerance", "lcsys2022-heterogeneous", "--taus", "0",
                 "--delays", "homogeneous", "--trials", "1", "--steps", "5",
                 "--estimators", "compensated", "--no-progress", *args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_garbage_resume_file_is_named(tmp_path, capsys) -> None:
    import os

    bad = tmp_path / "bad.jsonl"
    bad.write_bytes(os.urandom(64).replace(b"\n", b"") + b"\xff\n")
    code, _, err = _bench(capsys, "--resume", str(bad), "--workers", "1")
    assert_bench_error(code, err, f"results file {bad}", "line 1", "not UTF-8")


def test_unreachable_dask_scheduler(capsys) -> None:
    code, _, err = _bench(capsys, "--dask", "tcp://127.0.0.1:9")
    assert_bench_error(code, err, "could not connect to the Dask scheduler at "
                       "tcp://127.0.0.1:9")
    assert "cannot write results" not in err


# -- AoI options without an AoI family -----------------------------------------------


@pytest.mark.parametrize("option", [["--rho", "0.3"], ["--gains", "rate"],
                                    ["--ties", "random"], ["--delayed", "age"]])
def test_aoi_option_without_an_aoi_family(capsys, option) -> None:
    code, out, err = run_main(capsys, "lcsys2022-heterogeneous", *SMALL, *option)
    assert_bad_input(code, out, err, option[0], "[options.aoi]",
                     "compensated, uncompensated, block, centralized-kf", "aoi")


def test_aoi_option_with_an_aoi_family_runs(capsys) -> None:
    code, out, err = run_main(capsys, "lcsys2022-heterogeneous", *SMALL, "--gains", "rate",
                              "--rho", "0.3", "--estimators", "aoi,compensated")
    assert code == 0, err
