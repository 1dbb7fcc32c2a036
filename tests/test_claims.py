"""The claim registry and ``netsim claims``: each check against an independent computation."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest

from netsim.claims import CLAIM_IDS, PROVED, REFUTED, REGISTRY, UNDECIDED, VERDICTS, Context, select
from netsim.claims.checks import eq14_on, theorem1_on
from netsim.claims.search import ScalarInstance
from netsim.cli import main
from netsim.papers.lcsys2022 import search_theorem1


def scalar_augmented(a: float, P: np.ndarray, g: np.ndarray, tau: int) -> np.ndarray:
    """By hand: the compensated closed loop of a scalar plant, every link delayed by tau,
    self-loops undelayed. e_k = G (P_0 a e_{k-1} + P_off a^(tau+1) e_{k-1-tau})."""
    N = len(g)
    G = np.diag(g)
    P0 = np.diag(np.diag(P))
    Poff = P - P0
    M = np.zeros((N * (tau + 1), N * (tau + 1)))
    M[:N, :N] += G @ P0 * a
    M[:N, tau * N:] += G @ Poff * a ** (tau + 1)
    for r in range(tau):
        M[(r + 1) * N:(r + 2) * N, r * N:(r + 1) * N] = np.eye(N)
    return M


def rho(M: np.ndarray) -> float:
    return float(max(abs(np.linalg.eigvals(M))))


def scalar_tau_star(a: float, P: np.ndarray, g: np.ndarray) -> int | None:
    """Closed form of Theorem 1's condition for n = 1: |a|^(tau+1) rho(G P) < 1."""
    base = rho(np.diag(g) @ P)
    if abs(a) * base >= 1:
        return None
    if abs(a) <= 1:
        return 20
    return min(20, math.ceil(-math.log(base) / math.log(abs(a))) - 2)


def test_registry_entries_are_complete():
    assert len(CLAIM_IDS) >= 15
    papers = {c.paper for c in REGISTRY.values()}
    assert papers == {"LCSYS2022", "delay-tolerant", "aoi", "dkfe"}
    for c in REGISTRY.values():
        assert c.statement and c.where and c.kind in ("theorem", "printed", "figure")
    assert [c.id for c in select(["aoi"])] == ["A-theorem1", "A-lemma2", "A-lemma3",
                                            "A-lemma4", "A-lemma5", "A-corollary1",
                                            "A-naive-growth"]
    with pytest.raises(ValueError):
        select(["no-such-claim"])


def test_theorem1_check_against_hand_built_matrix():
    """theorem1_on on a scalar instance equals the hand-built augmented matrix."""
    a, P, c, k = -1.5, np.array([[0.66, 0.34], [0.6, 0.4]]), (1.0, 0.0), (2.0, 0.0)
    inst = ScalarInstance(a, tuple(map(tuple, P)), c, k)
    g = np.array([1 - ki * ci * ci for ki, ci in zip(k, c, strict=True)])
    res = theorem1_on(*inst.matrices())
    assert res["tau_star"] == scalar_tau_star(a, P, g) == 1
    for tau, r in res["exact"].items():
        assert r == pytest.approx(rho(scalar_augmented(a, P, g, tau)), rel=1e-9)
    assert res["violations"] == [1]
    assert rho(scalar_augmented(a, P, g, 1)) > 1  # the counterexample, by hand


def test_theorem1_check_holds_on_an_undelayed_stable_instance():
    # |a| < 1, contraction: every tau is stable (closed form: rho <= |a| max|g| < 1)
    a, P, g_k = 0.5, np.array([[0.5, 0.5], [0.5, 0.5]]), (0.5, 0.5)
    inst = ScalarInstance(a, tuple(map(tuple, P)), (1.0, 1.0), g_k)
    res = theorem1_on(*inst.matrices(), tau_max=5)
    assert res["violations"] == [] and res["tau_star"] == 5


def test_eq14_check_against_hand_built_matrix():
    a, P = -1.5, np.array([[0.66, 0.34], [0.6, 0.4]])
    inst = ScalarInstance(a, tuple(map(tuple, P)), (1.0, 0.0), (2.0, 0.0))
    g = np.array([-1.0, 1.0])
    res = eq14_on(*inst.matrices(), range(4))
    hand = {t: rho(scalar_augmented(a, P, g, t)) for t in range(4)}
    assert res["exact"] == pytest.approx(hand, rel=1e-9)
    drops = [(s, t) for s, t in zip(range(3), range(1, 4), strict=True) if hand[t] < hand[s] - 1e-9]
    assert res["decreases"] == drops


def test_eq14_detects_a_non_monotone_case():
    # a = -1: G P a with alternating sign; search a small scalar case where rho drops
    rng = np.random.default_rng(3)
    for _ in range(400):
        a = float(rng.uniform(-2, 2))
        w = rng.uniform(0.05, 1, 2)
        P = np.array([[w[0], 1 - w[0]], [1 - w[1], w[1]]])
        g = np.array([float(rng.uniform(-1, 1)), 1.0])
        hand = [rho(scalar_augmented(a, P, g, t)) for t in range(3)]
        if hand[2] < hand[1] - 1e-6:
            inst = ScalarInstance(a, tuple(map(tuple, P)), (1.0, 0.0), (1 - g[0], 0.0))
            assert (1, 2) in eq14_on(*inst.matrices(), range(3))["decreases"]
            return
    pytest.fail("no non-monotone scalar case found")


def test_naive_growth_factors_are_the_closed_forms():
    """Uniform weights: sqrt(rho([[2, 1], [1, 1]])) = golden ratio; tree weights: a = 2."""
    from netsim.papers.aoi import naive_growth

    g = naive_growth()
    golden = (1 + 5 ** 0.5) / 2
    assert math.sqrt(max(abs(np.linalg.eigvals(np.array([[2.0, 1.0], [1.0, 1.0]]))))) \
        == pytest.approx(golden)
    assert g["naive-uniform"] == pytest.approx(golden, rel=1e-3)
    assert g["naive-tree"] == pytest.approx(2.0, rel=1e-6)
    assert REGISTRY["A-naive-growth"].run(Context()).verdict == PROVED


def test_search_finds_shrunk_counterexamples_satisfying_the_hypotheses():
    res = search_theorem1(seed=1, instances=40)
    assert res.instance is not None and res.hits >= 1 and res.complete
    inst, d = res.instance, res.details
    assert inst.hypotheses() is None and d["tau"] <= d["tau_star"]
    P = np.array(inst.P)
    g = np.array([1 - k * c * c for k, c in zip(inst.k, inst.c, strict=True)])
    assert np.allclose(P.sum(axis=1), 1) and np.all(np.diag(P) > 0)
    assert rho(np.diag(g) @ P * inst.a) < 1
    assert scalar_tau_star(inst.a, P, g) == d["tau_star"]
    assert rho(scalar_augmented(inst.a, P, g, d["tau"])) == pytest.approx(d["exact_rho"])
    assert d["exact_rho"] > 1


def test_netsim_claims_finds_and_writes_a_theorem1_counterexample(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["claims", "L-theorem1", "L-decay", "A-naive-growth", "--instances", "40",
                 "--seed", "1", "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in text.splitlines() if ln.split()
             and ln.split()[0] in CLAIM_IDS}
    assert "REFUTED" in lines["L-theorem1"] and "REFUTED" in lines["L-decay"]
    assert (out / "claims.md").is_file()
    path = out / "L-theorem1-counterexample.toml"
    sc = tomllib.loads(path.read_text())
    a = sc["plant"]["A"][0][0]
    P = np.array(sc["network"]["P"])
    c = np.array([ci[0][0] for ci in sc["plant"]["C"]])
    k = np.array([ki[0][0] for ki in sc["gains"]["K"]])
    tau = sc["delays"]["tau"]
    assert sc["delays"]["model"] == "homogeneous"
    g = 1 - k * c * c
    star = scalar_tau_star(a, P, g)
    hand = rho(scalar_augmented(a, P, g, tau))
    assert rho(np.diag(g) @ P * a) < 1 and tau <= star and hand > 1
    # netsim analyze reproduces it
    assert main(["analyze", str(path), "--tau-max", str(tau), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["tau_star"] == star
    row = data["homogeneous"][tau]
    assert row["tau"] == tau and row["rho_compensated"] == pytest.approx(hand, rel=1e-9)
    # netsim run: the error grows
    assert main(["run", str(path), "--json", "--steps", "120", "--trials", "2"]) == 0
    run = json.loads(capsys.readouterr().out)
    mse_at = run["estimators"]["compensated"]["mse_at"]
    steps = sorted(mse_at, key=int)
    assert mse_at[steps[-1]] > 1e3 * mse_at[steps[0]]


def test_json_equals_text_verdicts(tmp_path, capsys):
    args = ["claims", "D-table1", "D-cond75", "D-eq94", "A-naive-growth", "L-rho", "L-hom-19",
            "--instances", "8", "--out", str(tmp_path), "--no-progress"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert main(args + ["--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    verdicts = {c["id"]: c["verdict"] for c in data["claims"]}
    for cid, v in verdicts.items():
        line = next(ln for ln in text.splitlines() if ln.startswith(cid + " "))
        assert line.split(None, 1)[1].startswith(v.upper())
        assert v in VERDICTS
    # L-rho: attained on the calibrated instance; L-hom-19's rho = 1 by none of them
    assert verdicts["L-rho"] == PROVED and verdicts["L-hom-19"] == UNDECIDED
    assert verdicts["D-table1"] == PROVED


def test_bad_input_is_one_line_exit_2(capsys):
    assert main(["claims", "nope"]) == 2
    assert main(["claims", "--budget", "-1"]) == 2
    assert main(["claims", "--instances", "0"]) == 2
    assert main(["claims", "--instances", "10000000000"]) == 2  # refused with an estimate
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(e.startswith("netsim claims: error:") for e in err)
    assert "would take about" in err[-1]


def test_bench_statements_come_from_the_registry():
    from netsim.bench.claims import CLAIMS

    assert set(CLAIMS) <= set(REGISTRY)
    assert CLAIMS["L-eq26"] is REGISTRY["L-eq26"].bench
    assert REFUTED in VERDICTS


def test_progress_counts_every_search_then_every_claim():
    """The progress callbacks tick once per search the checks read, then once per claim
    (so the bar moves during the search phase); the counts are known before the run."""
    from netsim.claims.report import run_claims, search_names

    chosen = select(["L-theorem1", "L-decay"])
    names = search_names(chosen)
    assert names and len(names) == len(set(names))
    order: list[tuple[str, str]] = []
    run_claims(chosen, seed=1, instances=10, workers=1,
               search_progress=lambda n: order.append(("search", n)),
               progress=lambda c: order.append(("claim", c)))
    assert order == [("search", n) for n in names] + [("claim", c.id) for c in chosen]
