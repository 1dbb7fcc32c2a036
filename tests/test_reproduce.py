"""``netsim reproduce``: every listed item written, and its data checked independently.

The independent computations (never values copied from the output):

- Table I's column (75): condition (75) of Theorem 2 asks for D > 0 with f(D) < D,
  f(D) = E{A_1(t)^T D A_1(t)} (Lemma 7), which for the positive map f holds exactly when
  rho(E{A_1(t) kron A_1(t)}) < 1. Here A_1(t) is written from the paper's model: the
  local Kalman filter error x~(t) = Phi_K x~(t-1) + ..., and the compensating estimate
  x^c(t) = H(t) x-hat_1(t) + (I - H(t)) A x^c(t-1) (eq. 15, d_1 = 0), so
  [x~; xi](t) = [[Phi_K, 0], [H Phi_K, (I - H) A]] [x~; xi](t-1) + noise, with
  Phi_K from scipy's Riccati solver.
- Tr Xi_11 at gamma_11 = 0.5 (Figs. 3-4): the stationary second moment of the same
  chain with its noise, solved as one linear system.
- The aoi naive growth factors: golden ratio (uniform weights: rho([[2, 1], [1, 1]])^(1/2)
  per step over the two-step period) and a = 2 (tree weights).
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla

from netsim.cli import main
from netsim.papers._dkfe_readings import EQ94_EVALUATIONS, EQ94_QUICK_MIN
from netsim.reproduce import ITEMS, PAPERS, items_for

ROOT = Path(__file__).resolve().parents[1]
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def reproduced(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    code = main(["reproduce", "--out", str(out), "--trials", "4", "--workers", "1",
                 "--claim-budget", "0.5", "--json", "--no-progress"])
    assert code == 0
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_every_item_is_listed_for_the_four_papers():
    assert {it.paper for it in ITEMS} == set(PAPERS)
    labels = {(it.paper, it.label) for it in ITEMS}
    assert labels == {("LCSYS2022", "Fig. 1"), ("delay-tolerant", "Fig. 1"),
                      ("LCSYS2022", "Experiment: MSE and decay vs delay bound"),
                      ("LCSYS2022", "Experiment: packet loss"),
                      ("delay-tolerant", "Fig. 2"), ("aoi", "Fig. 2"),
                      ("aoi", "Corollary 1 (experiment)"), ("dkfe", "Table I"),
                      ("dkfe", "Example 2"), *(("dkfe", f"Fig. {k}") for k in range(3, 9)),
                      ("LCSYS2022", "Section IV (calibrated)"),
                      ("LCSYS2022", "Fig. 1 (calibrated)"),
                      ("delay-tolerant", "Figs. 1-2 (calibrated)"),
                      ("dkfe", "eq. (94), readings"), ("dkfe", "(71)-(72) against d"),
                      ("dkfe", "r_i sweep"), ("dkfe", "Theorem 4"), ("dkfe", "Remark 1")}
    assert [it.id for it in items_for(["DKFE"])] == [it.id for it in ITEMS
                                                     if it.paper == "dkfe"]


def test_every_item_has_png_data_and_report_entry(reproduced):
    report = (reproduced / "report.md").read_text()
    for it in ITEMS:
        png = reproduced / f"{it.id}.png"
        assert png.read_bytes()[:8] == PNG, it.id
        data = [p for p in reproduced.glob(f"{it.id}.*") if p.suffix in (".csv", ".json")]
        assert data, it.id
        for p in data:
            assert p.stat().st_size > 100, p
            if p.suffix == ".json":
                json.loads(p.read_text())
        assert f"### {it.paper} {it.label}" in report
        assert f"![{it.paper} {it.label}]({it.id}.png)" in report
    # the report says where we differ, and gives claim verdicts
    assert "does not print A, C, P or K" in report
    assert "| L-theorem1 |" in report and "| D-table1 |" in report
    assert "| A-naive-growth |" in report


def _phi_and_gain(A, C, Q, R):
    """Steady-state Kalman filter (paper eq. 7): prior P*, K, G = I - K C, Phi = G A."""
    Pp = sla.solve_discrete_are(A.T, C.T, Q, R)
    K = Pp @ C.T @ np.linalg.inv(C @ Pp @ C.T + R)
    G = np.eye(A.shape[0]) - K @ C
    return G @ A, G, K


EX1_A = np.array([[1.25, 0.0], [1.0, 1.1]])
EX1_Q = 20.0 * np.eye(2)
EX1_C = np.array([[0.0, 1.0]])
EX1_R = np.array([[2.5]])


def _chain(gamma):
    """(probabilities, M_h, B_h) of [x~; xi](t) = M_h [x~; xi](t-1) + B_h [w; v]."""
    Phi, G, K = _phi_and_gain(EX1_A, EX1_C, EX1_Q, EX1_R)
    out = []
    for p, h in ((gamma, np.diag([1.0, 0.0])), (1 - gamma, np.diag([0.0, 1.0]))):
        eye = np.eye(2)
        M = np.block([[Phi, np.zeros((2, 2))], [h @ Phi, (eye - h) @ EX1_A]])
        B = np.block([[G, -K], [h @ G + (eye - h), -h @ K]])
        out.append((p, M, B))
    return out


def test_table1_column_75_against_the_mean_square_test(reproduced):
    rows = _rows(reproduced / "dkfe-table1.csv")
    assert len(rows) == 11
    for r in rows:
        g = float(r["gamma11"])
        second = sum(p * np.kron(M, M) for p, M, _ in _chain(g))
        expected = max(abs(np.linalg.eigvals(second))) < 1
        assert (r["c75_ours"] == "True") == expected, g
        assert r["c75_ours"] == r["c75_paper"], g


def test_trace_xi11_at_gamma_half_from_the_stationary_second_moment(reproduced):
    chain = _chain(0.5)
    noise = sla.block_diag(EX1_Q, EX1_R)
    T = sum(p * np.kron(M, M) for p, M, _ in chain)
    N = sum(p * B @ noise @ B.T for p, _, B in chain)
    S = np.linalg.solve(np.eye(16) - T, N.reshape(-1)).reshape(4, 4)
    expected = float(np.trace(S[2:, 2:]))
    assert expected == pytest.approx(362.7, abs=0.05)
    rows = [r for r in _rows(reproduced / "dkfe-fig3.csv") if float(r["gamma11"]) == 0.5]
    last = max(rows, key=lambda r: int(r["t"]))
    assert float(last["trace_Xi11_exact"]) == pytest.approx(expected, rel=1e-4)
    # and gamma 0.3 (fails (75)) grows without bound in the same data
    grow = [float(r["trace_Xi11_exact"]) for r in _rows(reproduced / "dkfe-fig3.csv")
            if float(r["gamma11"]) == 0.3]
    assert grow[-1] > 100 * expected


def test_aoi_naive_growth_factors_golden_ratio_and_two(reproduced):
    errs: dict[str, dict[int, float]] = defaultdict(dict)
    for r in _rows(reproduced / "aoi-fig2.csv"):
        if r["trial"] == "0" and r["error"]:
            k = int(r["step"])
            errs[r["observer"]][k] = max(errs[r["observer"]].get(k, 0.0), float(r["error"]))
    for name, expected in (("naive-uniform", (1 + math.sqrt(5)) / 2), ("naive-tree", 2.0)):
        e = errs[name]
        k = max(k for k, v in e.items() if math.isfinite(v) and v > 0)
        two_step = math.sqrt(e[k] / e[k - 2])
        assert two_step == pytest.approx(expected, rel=1e-3), name
    assert max(v for k, v in errs["aoi"].items() if k >= 5) == 0.0


def test_fig7_limits_do_not_depend_on_the_initial_value(reproduced):
    rows = _rows(reproduced / "dkfe-fig7.csv")
    last = max(int(r["t"]) for r in rows)
    end = [r for r in rows if int(r["t"]) == last]
    assert len(end) == 2
    for key in ("norm2_P", "norm2_Omega_1", "norm2_Omega_2"):
        a, b = (float(r[key]) for r in end)
        assert a == pytest.approx(b, rel=1e-3), key
    first = [r for r in rows if int(r["t"]) == 0]
    assert float(first[1]["norm2_P"]) > 5 * float(first[0]["norm2_P"])


def test_fig8_dkfe_minus_sdkfe_vanishes(reproduced):
    rows = _rows(reproduced / "dkfe-fig8.csv")
    early = max(abs(float(v)) for r in rows[:20] for k, v in r.items() if k != "t")
    late = max(abs(float(v)) for r in rows[-20:] for k, v in r.items() if k != "t")
    assert late < 1e-3 * early


@pytest.mark.parametrize("argv, needle", [
    (["reproduce", "nosuchpaper"], "unknown paper"),
    (["reproduce", "--trials", "0"], "--trials"),
    (["reproduce", "--seed", "-1"], "--seed"),
    (["reproduce", "--workers", "0"], "--workers"),
    (["reproduce", "--claim-budget", "nan"], "--claim-budget"),
])
def test_bad_input_is_one_line_and_exit_2(argv, needle, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err


def test_plot_modules_leave_the_matplotlib_backend_alone(tmp_path):
    code = ("import matplotlib; before = matplotlib.get_backend(); "
            "import netsim.traces.plot, netsim.bench.plots, netsim.reproduce; "
            "print(before, matplotlib.get_backend())")
    env = {**os.environ, "MPLBACKEND": "svg"}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    before, after = res.stdout.split()
    assert before == after == "svg"


def test_aoi_trace_plot_has_no_empty_panel(tmp_path):
    from netsim.traces.plot import traces_figure
    from netsim.traces.reader import read_trace

    base = tmp_path / "aoi.mcap"
    assert main(["run", "aoi-example", "--trials", "1", "--steps", "12", "--estimators",
                 "aoi", "--trace", str(base), "--no-progress", "--json"]) == 0
    traces = [read_trace(p) for p in sorted(tmp_path.glob("*.mcap"))]
    fig = traces_figure(traces)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert not any("no P, A" in t or "no delays" in t for t in texts)
    titles = [ax.get_title() for ax in fig.axes]
    assert not any(t.startswith("Spectral radius") for t in titles)
    assert any("Age of information" in t for t in titles)


def test_delay_histogram_ticks_are_thinned_at_large_delays():
    from matplotlib.figure import Figure
    from netsim.traces.plot import _delay_panel

    fig = Figure()
    ax = fig.subplots()
    _delay_panel(ax, [("link delays", np.arange(44), "0.4")])
    ticks = [t for t in ax.get_xticks() if -0.5 <= t <= 43.5]
    assert len(ticks) <= 12
    assert all(float(t).is_integer() for t in ticks)


@pytest.mark.slow
def test_dkfe_monte_carlo_agrees_with_the_exact_traces(tmp_path):
    """Fig. 6 and Fig. 3 at 400 trials: the Monte Carlo MSE over the steady part agrees
    with the exact covariance traces within a few standard errors (stable cases)."""
    assert main(["reproduce", "dkfe", "--out", str(tmp_path), "--trials", "400",
                 "--claim-budget", "0.5", "--no-progress"]) == 0
    rows = _rows(tmp_path / "dkfe-fig6.csv")
    for name in ("CSE 1", "CSE 2", "DKFE", "ODKFE"):
        steady = [r for r in rows if int(r["t"]) >= 100]
        mc = np.mean([float(r[f"mse_{name}_monte_carlo"]) for r in steady])
        exact = np.mean([float(r[f"trace_{name}_exact"]) for r in steady])
        assert mc == pytest.approx(exact, rel=0.1), name
    fig3 = [r for r in _rows(tmp_path / "dkfe-fig3.csv")
            if float(r["gamma11"]) == 0.5 and int(r["t"]) >= 50]
    mc = np.mean([float(r["mse_cse_monte_carlo"]) for r in fig3])
    exact = np.mean([float(r["trace_Xi11_exact"]) for r in fig3])
    assert mc == pytest.approx(exact, rel=0.1)


def test_gamma11_option_of_the_fusion_runs():
    from netsim.fusion import example_setup, mse_curves

    assert example_setup("dkfe-example1", 0.3).selections[0].H[0, 0] == pytest.approx(0.3)
    for bad in (("dkfe-example2", 0.5), ("dkfe-example1", 1.5), ("dkfe-example1", math.nan)):
        with pytest.raises(ValueError):
            example_setup(*bad)
    curves = mse_curves("dkfe-example1", 3, 2, gamma11=0.0)
    assert len(curves["CSE 1 (d=0)"]) == 4


# -- the experiments LCSYS2022 leaves out (quick run: 4 trials x 100 steps) ----------------


def _centralised_kf_trace():
    """tr P of the steady centralised Kalman filter (posterior), from scipy's Riccati
    solver on the scenario's own matrices: the MSE the optimal filter reaches."""
    from netsim.models.scenario import resolve_scenario

    p = resolve_scenario("lcsys2022-heterogeneous").plant
    A, Q = np.asarray(p.A, float), np.asarray(p.Q, float)
    C = np.vstack([np.atleast_2d(c) for c in p.C])
    R = sla.block_diag(*[np.atleast_2d(r) for r in p.R])
    prior = sla.solve_discrete_are(A.T, C.T, Q, R)
    K = prior @ C.T @ np.linalg.inv(C @ prior @ C.T + R)
    return float(np.trace((np.eye(A.shape[0]) - K @ C) @ prior))


def test_loss_experiment_loses_messages_at_the_asked_rate(reproduced):
    rows = json.loads((reproduced / "lcsys2022-loss.json").read_text())["rows"]
    by = defaultdict(dict)
    for r in rows:
        by[r["family"]][r["loss"]] = r
    for family, runs in by.items():
        if not runs[0.0]["sent"]:
            continue  # no network: nothing sent
        base = runs[0.0]["delivered"]  # p = 0: every message but those still in flight
        for p, r in runs.items():
            assert r["sent"] == runs[0.0]["sent"], family
            # Bernoulli(p) on each message: delivered / delivered at p = 0 ~ 1 - p
            sd = math.sqrt(max(p * (1 - p), 1e-12) / base)
            assert abs(r["delivered"] / base - (1 - p)) < 5 * sd + 1e-9, (family, p)


def test_loss_experiment_centralised_kf_is_the_riccati_optimum_whatever_the_loss(reproduced):
    rows = json.loads((reproduced / "lcsys2022-loss.json").read_text())["rows"]
    ckf = [r for r in rows if r["family"] == "centralized-kf"]
    assert len({r["last_trusted_mse"] for r in ckf}) == 1  # no network, nothing lost
    # 4 trials x the last quarter of 100 steps: well within 25 % of tr P
    assert ckf[0]["last_trusted_mse"] == pytest.approx(_centralised_kf_trace(), rel=0.25)


def test_baselines_experiment_has_every_family_and_the_optimum(reproduced):
    rows = _rows(reproduced / "lcsys2022-baselines.csv")
    families = {r["family"] for r in rows}
    assert families == {"compensated", "uncompensated", "centralized-kf", "local-kf", "kcf",
                        "ci", "diffkf"}
    for r in rows:
        if r["family"] == "centralized-kf":
            assert float(r["last_trusted_mse"]) == pytest.approx(_centralised_kf_trace(),
                                                                 rel=0.25)


# -- a quick run (--trials below the default) does a share of the dkfe issue-31 work -------


def test_quick_share_and_the_full_computation_at_the_default_trials(monkeypatch):
    """The arguments the computations get: the full ones (as ``netsim claims``) at the
    default trials and above, a share below; recorded, not run."""
    from types import SimpleNamespace

    import netsim.models.dkfe as dk

    from netsim.papers import _dkfe_readings as rd
    from netsim.reproduce.report import DEFAULT_TRIALS

    assert rd.quick_fraction(None) == rd.quick_fraction(DEFAULT_TRIALS) == 1.0
    assert rd.quick_fraction(10 * DEFAULT_TRIALS) == 1.0
    assert rd.quick_fraction(DEFAULT_TRIALS // 4) == 0.25
    seen = []
    stub = SimpleNamespace(to_dict=lambda: {"rows": []})
    monkeypatch.setattr(dk, "eq94_readings", lambda **kw: seen.append(kw) or stub)
    monkeypatch.setattr("netsim.fusion.eq94_transient", lambda: [])
    rd._computed.cache_clear()
    try:
        for trials in (None, DEFAULT_TRIALS, 4 * DEFAULT_TRIALS, DEFAULT_TRIALS // 2, 1):
            data = rd.compute("eq94", 0, trials)
            assert ("quick" in data) == (trials is not None and trials < DEFAULT_TRIALS)
    finally:
        rd._computed.cache_clear()
    # None, the default and 4x share one full computation; half and one trial: a share
    assert seen == [{"search_evaluations": rd.EQ94_EVALUATIONS},
                    {"search_evaluations": rd.EQ94_EVALUATIONS // 2},
                    {"search_evaluations": rd.EQ94_QUICK_MIN}]


def test_quick_run_solves_the_lmis_next_to_the_boundary_and_says_so(reproduced):
    """At 4 trials: every cell keeps its exact radius; (71)-(72) are solved on both sides
    of radius 1 and agree with it; the report names the quick share."""
    data = json.loads((reproduced / "dkfe-gamma-delay.json").read_text())
    g, s = data["example1"], data["example2"]
    assert "quick" in g and "quick" in s
    assert len(g["cells"]) == len(g["gammas"]) * len(g["delays"])
    solved = [c for c in g["cells"] if c["lmi71_72"] is not None]
    assert {c["radius"] < 1 for c in solved} == {True, False}
    assert all(c["lmi71_72"] == (c["radius"] < 1) for c in solved)
    for sink, largest in enumerate(s["largest_feasible_delay"], start=1):
        rows = {r["d"]: r for r in s["rows"] if r["sink"] == sink}
        assert len(rows) == len(s["delays"])
        assert rows[largest]["lmi71_72"] is True and rows[largest + 1]["lmi71_72"] is False
    eq94 = json.loads((reproduced / "dkfe-eq94-readings.json").read_text())
    assert f"ran {EQ94_QUICK_MIN} of {EQ94_EVALUATIONS} evaluations" in eq94["quick"]
    assert (reproduced / "report.md").read_text().count("Quick run (4 trials)") == 3
