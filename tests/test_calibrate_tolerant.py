"""netsim calibrate delay-tolerant and the calibrated-scenario API (issue 31).

The bundled instances are checked against independent computations: dense eigenvalues
of matrices built here from the papers' equations, an observability matrix rank, a
noise-free simulation of the estimator (6)-(7) written here, and Monte Carlo runs.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from netsim.models import augmented as aug

from netsim import calibrate as cal

N, n = 4, 6


def _parts(sc) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
    from netsim.runner import scenario_gains

    return sc.plant.A, sc.weights, list(sc.plant.C), list(scenario_gains(sc).L)


@pytest.fixture(scope="module")
def tolerant():
    return _parts(cal.calibrated_scenario("delay-tolerant"))


def _ahat(P, A, C, L) -> np.ndarray:
    """(I - blockdiag(L_i C_i)) (P kron A), the delay-free global matrix (eq. 15)."""
    G = np.zeros((N * n, N * n))
    for i in range(N):
        G[i * n:(i + 1) * n, i * n:(i + 1) * n] = L[i] @ C[i]
    return (np.eye(N * n) - G) @ np.kron(P, A)


def _companion(P, A, C, L, d, tau) -> np.ndarray:
    """The uncompensated augmented loop (eq. 11): first block row (I - KD)(P_r kron A)."""
    G = np.eye(N * n) - (np.eye(N * n) - _ahat(np.eye(N), np.eye(n), C, L))
    m = N * n
    M = np.zeros((m * (tau + 1), m * (tau + 1)))
    for r in range(tau + 1):
        Pr = np.where((d == r) & (P != 0), P, 0.0)
        M[:m, r * m:(r + 1) * m] = G @ np.kron(Pr, A)
    M[m:, :-m] = np.eye(m * tau)
    return M


def _rho(M: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def _obs_rank(A, C) -> int:
    C = np.vstack(C)
    return int(np.linalg.matrix_rank(np.vstack([C @ np.linalg.matrix_power(A, k)
                                                for k in range(n)]), tol=1e-9))


def test_bundled_tolerant_instance_has_the_papers_properties(tolerant) -> None:
    A, P, C, L = tolerant
    eig = np.linalg.eigvals(A)
    assert math.isclose(max(abs(eig)), 1.04, rel_tol=1e-9)  # unstable, rho(A) = 1.04
    assert abs(np.linalg.det(A)) > 1e-6 and np.all(np.diag(A) != 0)  # full rank, self-damped
    assert _obs_rank(A, C) == n  # observable together ...
    for i in range(N):  # ... but in no closed in-neighbourhood {i-1, i} of the cycle
        assert _obs_rank(A, [C[(i - 1) % N], C[i]]) < n
    assert np.allclose(P.sum(axis=1), 1) and np.all(P >= 0)
    cycle = np.eye(N, dtype=bool) | np.roll(np.eye(N, dtype=bool), -1, axis=1)
    assert np.array_equal(P > 0, cycle)
    rho = _rho(_ahat(P, A, C, L))
    assert round(rho, 2) == 0.64  # printed rho(A-hat)
    assert round(rho ** (1 / 11), 2) == 0.96 and round(rho ** (1 / 26), 3) == 0.983
    # the bound claims hold on the exact loop built here (hom. tau = 10)
    d = np.where(cycle & ~np.eye(N, dtype=bool), 10, 0)
    exact = _rho(_companion(P, A, C, L, d, 10))
    assert exact <= rho ** (1 / 11)
    assert math.isclose(exact, aug.augmented_spectral_radius(P, A, C, L, d, 10,
                                                             compensated=False),
                        rel_tol=1e-8)


def test_bundled_tolerant_gains_track_the_unstable_mode(tolerant) -> None:
    A, P, C, L = tolerant
    w, V = np.linalg.eig(A)
    k = int(np.argmax(abs(w)))
    v = V[:, k].real / np.linalg.norm(V[:, k].real)
    for Li, Ci in zip(L, C, strict=True):
        assert np.linalg.norm(v - Li @ (Ci @ v)) < 1e-9
    # then rho(A-hat) is A's second eigenvalue modulus (closed form of the notes)
    assert math.isclose(_rho(_ahat(P, A, C, L)), sorted(abs(w))[-2], rel_tol=1e-9)


def _noise_free(A, P, C, L, delays, steps, rng, x0=None):
    """Eqs. (6)-(7) without noise, written here: the estimate of j that agent i uses at
    step k is j's estimate of step k - 1 - delays(k)[i, j]. Returns (errors, states)."""
    x = rng.normal(size=n) if x0 is None else x0
    hist = [np.zeros((N, n))]  # estimates start at the prior mean 0
    xs, errs = [x], [np.linalg.norm(x)]
    for k in range(1, steps + 1):
        x = A @ x
        d = delays(k)
        new = np.zeros((N, n))
        for i in range(N):
            prior = sum(P[i, j] * A @ hist[max(0, len(hist) - 1 - int(d[i, j]))][j]
                        for j in range(N) if P[i, j] != 0)
            new[i] = prior + L[i][:, 0] * (C[i] @ x - C[i] @ prior)[0]
        hist.append(new)
        xs.append(x)
        errs.append(float(np.max(np.linalg.norm(x - new, axis=1))))
    return np.array(errs), np.array(xs)


def test_noise_free_error_bounded_and_perturbed_gains_diverge(tolerant) -> None:
    A, P, C, L = tolerant
    off = (P != 0) & ~np.eye(N, dtype=bool)
    rng_d = np.random.default_rng(5)

    def varying(k):  # asynchronous time-varying delays in 0..10
        return np.where(off, rng_d.integers(0, 11, size=(N, N)), 0)

    errs, xs = _noise_free(A, P, C, L, varying, 150, np.random.default_rng(1))
    assert errs[-1] < 1e-3 * np.linalg.norm(xs[-1])  # tracks the growing state
    assert errs[-1] < 10 * errs[0]
    Lp = [Li * 1.001 for Li in L]
    errs_p, _ = _noise_free(A, P, C, Lp, varying, 150, np.random.default_rng(1))
    growth = (errs_p[-1] / errs_p[100]) ** (1 / 50)
    assert abs(growth - 1.04) < 0.01  # grows like rho(A)^k


def test_forced_response_gap_is_the_simulated_one(tolerant) -> None:
    A, P, C, L = tolerant
    Lp = [Li * 1.001 for Li in L]
    inst = cal.Instance(A, tuple(C), P, tuple(Li @ Ci for Li, Ci in zip(Lp, C, strict=True)),
                        tuple(Lp))
    off = (P != 0) & ~np.eye(N, dtype=bool)
    d = np.where(off, 3, 0)
    gap = cal.forced_response_gap(inst, d)
    w, V = np.linalg.eig(A)
    k = int(np.argmax(abs(w)))
    v = V[:, k].real
    v = v / np.linalg.norm(v) * np.sign(v[np.argmax(abs(v))])
    lam = w[k].real
    steps = 300
    errs, xs = _noise_free(A, P, C, Lp, lambda k: d, steps, np.random.default_rng(0), x0=v)
    # the estimate divided by lambda^k settles to w_i: its error / lambda^k to w_i - v
    assert math.isclose(errs[-1] / lam ** steps, gap, rel_tol=1e-3)
    assert gap > 1e-5


def test_memoryless_mse_matches_monte_carlo_for_every_delay() -> None:
    from netsim.api import run

    data = cal.calibrated_scenario("delay-tolerant", as_dict=True)
    tails = []
    for model, tau in (("none", 0), ("asynchronous", 10), ("heterogeneous", 15)):
        data["delays"] = {"model": model, "tau": tau, "seed": 2022} if tau else {
            "model": "none"}
        res = run(data, steps=200, trials=10, estimators=["uncompensated"], seed=3)
        mse = res["uncompensated"].mse
        tails.append(mse)
        assert np.all(np.isfinite(mse)) and not res.summary["uncompensated"].diverged
    # with estimates started at the prior mean the curve does not depend on the delays
    np.testing.assert_allclose(tails[1], tails[0], rtol=1e-6)
    np.testing.assert_allclose(tails[2], tails[0], rtol=1e-6)
    sc = cal.calibrated_scenario("delay-tolerant")
    A, P, C, L = _parts(sc)
    inst = cal.Instance(A, tuple(C), P, (), tuple(L))
    closed = cal.memoryless_mse(inst)
    # 10 trials x 100 correlated steps: 15% covers the Monte Carlo error
    assert abs(float(np.mean(tails[0][100:])) / closed - 1) < 0.15


def test_coupling_patterns_are_the_structurally_admissible_ones() -> None:
    from itertools import combinations

    rng = np.random.default_rng(0)
    listed = set(cal.coupling_patterns())
    C = [np.zeros((1, n)) for _ in range(N)]
    for Ci, (lo, _) in zip(C, cal.BLOCKS, strict=True):
        Ci[0, lo] = 1.0
    for k in range(len(cal.COUPLINGS) + 1):
        for pattern in combinations(cal.COUPLINGS, k):
            # a generic numeric instance of the pattern (random entries)
            A = np.zeros((n, n))
            for lo, hi in cal.BLOCKS:
                A[lo:hi, lo:hi] = rng.uniform(0.3, 1.0, (hi - lo, hi - lo))
            for a, b in pattern:
                (la, ha), (lb, hb) = cal.BLOCKS[a], cal.BLOCKS[b]
                A[lb:hb, la:ha] = rng.uniform(0.3, 1.0, (hb - lb, ha - la))
            local = [_obs_rank(A, [C[(i - 1) % N], C[i]]) == n for i in range(N)]
            assert (pattern in listed) == (not any(local)), pattern
            # a driving block: A's top eigenvector, if in that block, touches every block
            root = cal.universal_block(pattern)
            if root is not None:
                lo, hi = cal.BLOCKS[root]
                B = A.copy()
                B[lo:hi, lo:hi] *= 3  # make the root block's eigenvalue the largest
                w, V = np.linalg.eig(B)
                v = V[:, int(np.argmax(abs(w)))]
                assert all(abs(v[l0:h0]).max() > 1e-9 for l0, h0 in cal.BLOCKS)


def test_project_gains_zero_defect_and_rho_is_second_eigenvalue() -> None:
    rng = np.random.default_rng(3)
    pattern = ((0, 1), (0, 2), (0, 3))
    x = cal._tolerant_start(rng)
    x[0:4] = [3.0, 0.4, 0.5, 1.0]  # the root block holds the only unstable eigenvalue
    x[4:10] = [0.5, 0.2, -0.2, 0.4, 0.3, -0.4]
    inst = cal.unpack_tolerant(x, pattern)
    proj = cal.project_gains(inst)
    assert proj is not None
    assert cal.tracking_defect(proj)["max"] < 1e-12
    moduli = sorted(abs(np.linalg.eigvals(inst.A)))
    rho = _rho(_ahat(proj.P, proj.A, list(proj.C), list(proj.L)))
    assert math.isclose(rho, moduli[-2], rel_tol=1e-8)
    # a pattern without a driving block: no rank-one gain tracks the top mode
    lone = cal.unpack_tolerant(x, ())
    assert cal.project_gains(lone) is None
    assert cal.tracking_defect(lone)["max"] >= 1 - 1e-12  # C_i v = 0: defect |v| = 1


def test_search_tolerant_counts_and_is_deterministic() -> None:
    res = cal.search_tolerant(evaluations=5, starts=1, seed=1, exact=False)
    assert res.verdict == "undecided" and 1 <= res.evaluations <= 5
    a = cal.search_tolerant(evaluations=120, starts=2, seed=4, exact=False)
    b = cal.search_tolerant(evaluations=120, starts=2, seed=4, exact=False)
    assert a.parameters == b.parameters and a.evaluations == b.evaluations <= 120
    assert a.verdict in ("undecided", "not matched")
    # its rows are the analytics recomputed
    assert a.instance is not None
    rows = {r["name"]: r for r in a.targets}
    assert rows["rho(A-hat)"]["achieved"] == aug.delay_free_spectral_radius(
        a.instance.P, a.instance.A, list(a.instance.C), list(a.instance.L))
    assert all(p["holds"] for p in a.properties.values()), a.properties


def test_printed_numbers_agree_with_the_papers_module() -> None:
    got = cal.tolerant_printed()
    assert got == cal.TOLERANT_PRINTED
    from netsim import papers

    if hasattr(papers, "TOLERANT_RHO"):
        assert got["rho_delay_free"] == papers.TOLERANT_RHO
        assert got["bound_tau10"] == papers.TOLERANT_BOUNDS[10]


def _lcsys_theorem1(P, A, C, L, tau) -> float:
    G = np.eye(N * n) - (np.eye(N * n) - _ahat(np.eye(N), np.eye(n), C, L))
    return _rho(G @ np.kron(P, np.linalg.matrix_power(A, tau + 1)))


def test_bundled_lcsys_instance_states_its_numbers_truthfully() -> None:
    text = cal.calibrated_toml("LCSYS2022")
    A, P, C, L = _parts(cal.calibrated_scenario("lcsys2022"))
    assert math.isclose(max(abs(np.linalg.eigvals(A))), 1.04, rel_tol=1e-9)
    rho = _rho(_ahat(P, A, C, L))
    values = [_lcsys_theorem1(P, A, C, L, t) for t in range(cal.TAU_MAX + 1)]
    star = next((t - 1 for t, v in enumerate(values) if v >= 1), cal.TAU_MAX)
    desc = re.sub(r"\s+", " ", text)
    stated_rho = float(re.search(r"rho\(A-hat\) 0\.64 -> ([0-9.]+)", desc).group(1))
    stated_star = int(re.search(r"tau\* 10 -> (\d+)", desc).group(1))
    assert abs(stated_rho - rho) < 6e-5 and stated_star == star
    for t in (3, 8, 19):  # the no-root reading's eq. (26) values
        got = float(re.search(rf"eq\. \(26\) at tau = {t} [0-9.]+ -> ([0-9.]+)",
                              desc).group(1))
        assert abs(got - values[t]) < 6e-5
    assert "does NOT match" in desc and "reading no-root" in desc


def test_calibrated_scenario_api() -> None:
    sc = cal.calibrated_scenario("Delay-Tolerant")
    assert sc.name == "delay-tolerant-calibrated" and sc.delays.model == "asynchronous"
    data = cal.calibrated_scenario("delay-tolerant", as_dict=True)
    assert data["gains"]["method"] == "given" and len(data["gains"]["K"]) == N
    with pytest.raises(ValueError, match="unknown paper"):
        cal.calibrated_scenario("nope")
    # explicit settings search (tiny budget) and are cached for the process
    t1 = cal.calibrated_toml("delay-tolerant", evaluations=3, starts=1, seed=9)
    t2 = cal.calibrated_toml("delay-tolerant", evaluations=3, starts=1, seed=9)
    assert t1 is t2 and "does NOT match" in t1


def test_cli_delay_tolerant_json_and_errors(tmp_path, capsys) -> None:
    from netsim.cli import main

    out = tmp_path / "t.toml"
    args = ["calibrate", "delay-tolerant", "--evaluations", "20", "--starts", "1",
            "--no-progress", "--no-simulate", "--out", str(out)]
    assert main([*args, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["paper"] == "delay-tolerant" and data["simulation"] is None
    assert data["results"][0]["verdict"] in ("undecided", "not matched")
    assert data["written"] == str(out) and out.read_text().startswith("# Written by")
    assert main([*args, "--force", "--reading", "no-root"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--reading" in err[0]
    assert main(["calibrate", "delay-tolerant", "--trials", "0"]) != 0
    assert "--trials" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("paper", ["delay-tolerant", "lcsys2022"])
def test_bundled_file_is_what_the_command_writes(paper) -> None:
    """Re-derive the bundled TOML with the settings that wrote it (slow: the search)."""
    b = cal.BUNDLED[paper]
    again = cal.calibrated_toml(paper, seed=b["seed"], evaluations=b["evaluations"],
                                starts=b["starts"])
    assert again == cal.calibrated_toml(paper)
