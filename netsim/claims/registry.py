"""The registry: every checkable statement of the four papers, one :class:`Claim` each."""

from __future__ import annotations

from netsim import papers as _p
from netsim.bench.claims import CLAIMS as _B
from netsim.claims import checks as _c
from netsim.claims.core import Claim

__all__ = ["REGISTRY", "CLAIM_IDS", "get_claim", "select"]

_L_HYP = ("Lemma 1: P row-stochastic and irreducible on a self-looped graph, "
          "(P kron A, D_C) observable",
          "K block-diagonal with rho(A-hat) = rho((I - K D_C)(P kron A)) < 1",
          "Assumption 2: fixed (time-invariant) delays bounded by tau-bar; here one common "
          "tau on every link, self-loops undelayed")
_T_HYP = ("Lemma 1 (as in LCSYS2022)", "rho(A-hat) < 1",
          "Assumption 2: arbitrary (time-varying) delays bounded by tau-bar, no time-stamps")
_NOT_PRINTED = "the paper's own unprinted system"
_AOI_HYP = ("Assumption 1: the graph sequence is jointly strongly connected over windows of "
            "T steps", "(A, C) jointly observable", "noise-free")

_CLAIMS = [
    # -- LCSYS2022 ------------------------------------------------------------------
    Claim("L-theorem1", _p.LCSYS, "Theorem 1",
          "the compensating estimator (4)-(5) tracks the system with stable error for any "
          "tau-bar <= tau*, tau* the largest tau with rho((I-KD_C)(P kron A^(tau+1))) < 1",
          _L_HYP, "theorem", _c.check_theorem1, bench=_B["L-theorem1"],
          searches=("L-theorem1",)),
    Claim("L-eq26-bound", _p.LCSYS, "eq. (26), Lemma 5",
          "the exact spectral radius of the delayed closed loop (10) is at most "
          "rho((I-KD_C)(P kron A^(tau+1)))^(1/(tau+1))",
          _L_HYP + ("here also heterogeneous fixed delays with one link at tau",), "theorem",
          _c.check_eq26_bound, searches=("L-eq26-bound",)),
    Claim("L-decay", _p.LCSYS, "eq. (14), Section III-C",
          "longer delays give a slower decay of the error (10): for tau1 < tau2 <= tau* the "
          "decay rate at tau2 is lower", _L_HYP, "theorem", _c.check_eq14,
          bench=_B["L-decay"]),
    Claim("L-lemma2", _p.LCSYS, "Lemma 2",
          "the convergence time of the error dynamics (10) is of order "
          "Theta(1/(1 - rho)) (and of (12), printed with rho(A))", _L_HYP, "theorem",
          _c.check_lemma2),
    Claim("L-lemma4", _p.LCSYS, "Lemmas 4-5 (proof), eq. (2)",
          "with every delay equal to tau (tau_ij = tau-bar for all i, j) the augmented "
          "matrix has rho = rho(A-hat_tau)^(1/(tau+1)) (q(lambda) = p(lambda^(tau+1)))",
          ("every link and self-loop delayed by tau",), "theorem", _c.check_lemma4,
          searches=("L-theorem1",)),
    Claim("L-lemma1", _p.LCSYS, "Lemma 1 (and delay-tolerant Lemma 1)",
          "(P kron A, D_C-bar) is structurally observable if P is irreducible (self-loops "
          "on) and (A, C) is observable", ("Assumption 1, self-damped strongly connected "
                                           "graph",), "theorem", _c.check_lemma1),
    Claim("L-lemma3", _p.LCSYS, "Lemma 3, Discussion 2 (and delay-tolerant Lemma 3)",
          "the eigenvalues of P kron A are the products lambda_i mu_j; hence rho(P kron A) = "
          "rho(A) for row-stochastic P", (), "theorem", _c.check_lemma3),
    Claim("L-corollary1", _p.LCSYS, "Corollary 1, Section III-A",
          "for observable (P kron A, D_C-bar) a block-diagonal K with rho(A-hat) < 1 can be "
          "designed (LMI)", ("Lemma 1",), "theorem", _c.check_corollary1),
    Claim("L-rho", _p.LCSYS, "Section IV",
          f"the LMI gains give rho(A-hat) = {_p.LCSYS_RHO:g}", (_NOT_PRINTED,), "printed",
          _c.check_printed_rho, {"rho_delay_free": _p.LCSYS_RHO},
          bench=_B["L-rho"]),
    Claim("L-tau-star", _p.LCSYS, "Section IV",
          f"tau* = {_p.LCSYS_TAU_STAR} (Theorem 1)", (_NOT_PRINTED,), "printed",
          _c.check_printed_rho, {"tau_star": _p.LCSYS_TAU_STAR}, bench=_B["L-tau-star"]),
    Claim("L-eq26", _p.LCSYS, "Section IV",
          "eq. (26) bounds " + ", ".join(f"{v:g}" for v in _p.LCSYS_EQ26.values())
          + " at tau = " + ", ".join(str(t) for t in _p.LCSYS_EQ26),
          (_NOT_PRINTED,), "printed", _c.check_printed_eq26,
          {str(t): v for t, v in _p.LCSYS_EQ26.items()}, bench=_B["L-eq26"]),
    Claim("L-stable-0-3-8", _p.LCSYS, "Fig. 1",
          "compensated MSE bounded, steady-state stable for tau = 0, 3, 8 (homogeneous and "
          "heterogeneous)", (_NOT_PRINTED,), "figure", _c.check_stable_038_bench,
          {"taus": list(_p.LCSYS_FIG1_TAUS)}, bench=_B["L-stable-0-3-8"],
          searches=("bench:lcsys2022-fig1",)),
    Claim("L-hom-19", _p.LCSYS, "Fig. 1, Section IV",
          "homogeneous tau = 19: the MSE is marginally unstable, rho(A-bar) = 1",
          (_NOT_PRINTED,), "printed", _c.check_hom19, {"rho_19": _p.LCSYS_HOM19_RHO},
          bench=_B["L-hom-19"]),
    Claim("L-het-19", _p.LCSYS, "Fig. 1", "heterogeneous tau = 19: the MSE is stable",
          (_NOT_PRINTED,), "figure", _c.check_het19_bench, bench=_B["L-het-19"],
          searches=("bench:lcsys2022-fig1",)),
    # -- delay-tolerant paper -----------------------------------------------------------
    Claim("T-theorem1", _p.TOLERANT, "Theorem 1",
          "with rho(A-hat) < 1 the uncompensated estimator (6)-(7) tracks the system with "
          "bounded steady-state error for any delay satisfying Assumption 2", _T_HYP,
          "theorem", _c.check_tolerant_theorem1, bench=_B["T-theorem1"],
          searches=("T-theorem1",)),
    Claim("T-lemma5-bound", _p.TOLERANT, "Theorem 1 proof, Lemma 5",
          "rho of the augmented closed loop (11) is at most rho(A-hat)^(1/(tau+1)) < 1",
          _T_HYP, "theorem", _c.check_tolerant_bound, searches=("T-lemma5-bound",)),
    Claim("T-lemma2", _p.TOLERANT, "Lemma 2",
          "the convergence time of the error dynamics (13) is of order Theta(1/(1 - rho))",
          _T_HYP, "theorem", _c.check_tolerant_lemma2),
    Claim("T-decay", _p.TOLERANT, "eq. (17)",
          "longer delays result in a lower decay rate of the error (13)", _T_HYP, "theorem",
          _c.check_tolerant_decay, bench=_B["T-decay"]),
    Claim("T-rho", _p.TOLERANT, "Section V",
          f"the LMI gains give rho(A-hat) = {_p.TOLERANT_RHO:g}", (_NOT_PRINTED,), "printed",
          _c.check_tolerant_printed, {"rho_delay_free": _p.TOLERANT_RHO},
          bench=_B["T-rho"]),
    Claim("T-bounds", _p.TOLERANT, "Section V",
          "bounds " + ", ".join(f"rho(A-hat)^(1/{t + 1}) = {v:g}"
                                for t, v in _p.TOLERANT_BOUNDS.items()),
          (_NOT_PRINTED,), "printed", _c.check_tolerant_printed,
          {str(t): v for t, v in _p.TOLERANT_BOUNDS.items()}, bench=_B["T-bounds"]),
    Claim("T-fig1-stable", _p.TOLERANT, "Fig. 1",
          "uncompensated MSE bounded, steady-state stable without delay and with tau-bar = "
          "10 and 25 (random delays)", (_NOT_PRINTED,), "figure", _c.check_tolerant_fig1,
          bench=_B["T-fig1-stable"], searches=("bench:delay-tolerant-fig1",)),
    Claim("T-fig2-stable", _p.TOLERANT, "Fig. 2",
          "uncompensated MSE bounded for asynchronous varying, synchronous varying and "
          "asynchronous fixed delays, tau-bar = 15", (_NOT_PRINTED,), "figure",
          _c.check_tolerant_fig2, bench=_B["T-fig2-stable"],
          searches=("bench:delay-tolerant-fig2",)),
    # -- aoi paper ---------------------------------------------------------------------------
    Claim("A-theorem1", _p.AOI, "Theorem 1",
          "the gains can be designed so that every node's error converges to zero "
          "exponentially at any desired rate rho",
          _AOI_HYP[:2] + ("rate design: A_jj - L_j C_jj with distinct real eigenvalues, "
                          "rho_1 < ... < rho_N < rho",), "theorem", _c.check_aoi_theorem1),
    Claim("A-lemma3", _p.AOI, "Lemma 3",
          "every freshness index is triggered (finite) by step (N-1)T", _AOI_HYP[:1],
          "theorem", _c.check_aoi_lemma3, searches=("A-corollary1",)),
    Claim("A-lemma5", _p.AOI, "Lemma 5",
          "from step (N-1)T on every freshness index is at most 2(N-1)T", _AOI_HYP[:1],
          "theorem", _c.check_aoi_lemma5, searches=("A-corollary1",)),
    Claim("A-corollary1", _p.AOI, "Corollary 1",
          "with deadbeat gains the freshness-index observer's error is zero after at most "
          "n + 2N(N-1)T steps",
          _AOI_HYP, "theorem", _c.check_aoi_corollary1, searches=("A-corollary1",)),
    Claim("A-naive-growth", _p.AOI, "Section 3, Fig. 2",
          "naive consensus with uniform weights or with weights along the tree rooted at "
          "node 1 has unstable errors on the Section 3 example (x[k+1] = 2 x[k])",
          ("the Section 3 example",), "theorem", _c.check_aoi_naive),
    # -- dkfe paper --------------------------------------------------------------------------
    Claim("D-table1", _p.DKFE, "Table I, Example 1",
          "conditions (75), (76), (74) over gamma_11 = 0, 0.1, ..., 1 are as printed "
          "((75) true for 0.4..0.8, (76) and (74) never)",
          ("Example 1, d_1 = 0",), "printed", _c.check_dkfe_table1),
    Claim("D-cond75", _p.DKFE, "Theorem 2, eq. (75)-(76)",
          "(75) feasible implies Tr Xi_11(t) converges, and (75) is less conservative than "
          "(76)", ("Example 1, d_1 = 0; the search: one sink, (58), any d_i",), "theorem",
          _c.check_dkfe_75_search, searches=("D-cond75",)),
    Claim("D-cond77", _p.DKFE, "Theorem 3, eq. (77), Example 2",
          "condition (77) holds for Example 2 (so the SDKFE exists)",
          ("Example 2",), "printed", _c.check_dkfe_77),
    Claim("D-eq83", _p.DKFE, "eq. (83), Example 1",
          "the steady-state G_K1 = [[0.4760, -0.8573], [0.0314, 0.0376]]", ("Example 1",),
          "printed", _c.check_dkfe_eq83),
    Claim("D-ex1-numbers", _p.DKFE, "Example 1, after (84)",
          "at gamma_11 = 0.5: lambda_max(A^T (I - H_1) A) = 1.5887, xi_inf,1 = 2.3625, and "
          "the printed D_1 solves (75)", ("Example 1, gamma_11 = 0.5",), "printed",
          _c.check_dkfe_ex1_numbers),
    Claim("D-eq88", _p.DKFE, "eq. (88), Example 2", "the printed Phi_K1, Phi_K2",
          ("Example 2",), "printed", _c.check_dkfe_eq88),
    Claim("D-eq93", _p.DKFE, "eq. (93), Example 2",
          "rho(A (I - H_1) A) = 0.5759 and rho(A^2 (I - H_2) A) = 0.6631",
          ("Example 2, d = (1, 2)",), "printed", _c.check_dkfe_eq93),
    Claim("D-eq94", _p.DKFE, "eq. (94), Example 2",
          "the steady-state weighting matrices Omega_1, Omega_2 of Algorithm 1 are as printed",
          ("Example 2, d = (1, 2)",), "printed", _c.check_dkfe_eq94),
    Claim("D-eq95", _p.DKFE, "eq. (95), Example 2",
          "zeta_inf,1 = 0.8657 < 1 and zeta_inf,2 = 1.3554 > 1 ((74) fails for sink 2)",
          ("Example 2, d = (1, 2)",), "printed", _c.check_dkfe_eq95),
    Claim("D-fig6", _p.DKFE, "Fig. 6, eq. (57)",
          "at every step the DKFE's error covariance trace is below each CSE's, and the "
          "ODKFE's (no delays) below the DKFE's; all converge", ("Example 2, d = (1, 2)",),
          "figure", _c.check_dkfe_fig6_run, searches=("fusion:1:20",)),
    Claim("D-fig7", _p.DKFE, "Fig. 7, Theorem 3",
          "the fusion covariance P(t) converges to a unique steady-state matrix under "
          "different initial values", ("Example 2, d = (1, 2)",), "figure",
          _c.check_dkfe_fig7),
    Claim("D-fig8", _p.DKFE, "Fig. 8",
          "the difference between the DKFE and the SDKFE estimates converges to zero",
          ("Example 2, d = (1, 2)",), "figure", _c.check_dkfe_fig8,
          searches=("fusion:1:20",)),
]

#: Every claim by id, in the order above.
REGISTRY: dict[str, Claim] = {c.id: c for c in _CLAIMS}
#: The ids in order.
CLAIM_IDS: tuple[str, ...] = tuple(REGISTRY)


def get_claim(claim_id: str) -> Claim:
    """Return the claim ``claim_id`` (KeyError with the known ids otherwise)."""
    try:
        return REGISTRY[claim_id]
    except KeyError:
        raise KeyError(f"unknown claim {claim_id!r}; known: {', '.join(CLAIM_IDS)}") from None


def select(names: list[str] | tuple[str, ...] | None) -> list[Claim]:
    """Claims named by id or by paper (``LCSYS2022``, ``delay-tolerant``, ``aoi``, ``dkfe``);
    all for an empty selection. ValueError names an unknown one."""
    if not names:
        return list(_CLAIMS)
    papers = {c.paper.lower() for c in _CLAIMS}
    out: list[Claim] = []
    for name in names:
        if name.lower() in papers:
            picked = [c for c in _CLAIMS if c.paper.lower() == name.lower()]
        elif name in REGISTRY:
            picked = [REGISTRY[name]]
        else:
            raise ValueError(f"unknown paper or claim {name!r} (papers: "
                             f"{', '.join(sorted(papers))}; claims: {', '.join(CLAIM_IDS)})")
        out += [c for c in picked if c not in out]
    return out
