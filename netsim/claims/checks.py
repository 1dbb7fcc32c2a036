"""Helpers the papers' claim checks share (what ``netsim claims`` runs is declared by
the paper modules, :mod:`netsim.papers`).

A check takes a :class:`~netsim.claims.core.Context` and returns an
:class:`~netsim.claims.core.Outcome`. The instance-level helpers
(:func:`theorem1_on`, :func:`eq14_on`, :func:`lemma2_on`) take explicit matrices so that
the tests can put the same question to an independent computation; the others turn a
counted search (:func:`searched`) or a bench report (:func:`from_bench`) into a verdict.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from netsim.claims.core import (
    NO_COUNTEREXAMPLE,
    UNDECIDED,
    Context,
    Evidence,
    Outcome,
)
from netsim.models.augmented import augmented_spectral_radius, tau_star_report

__all__ = ["homogeneous_delays", "exact_rho", "theorem1_on", "eq14_on", "searched",
           "confirm_run", "search_undecided", "unconfirmed", "run_words", "search_words",
           "rounded", "bench", "from_bench", "convergence_time", "lemma2_on",
           "kron_observable", "BOUND_SLACK_FIXED"]

#: Margin by which a fixed instance's exact rho must exceed a bound to refute it.
BOUND_SLACK_FIXED = 1e-9


def rounded(x: float | None, digits: int = 4) -> float | None:
    """``x`` rounded to ``digits`` (None stays None)."""
    return None if x is None else round(float(x), digits)


def homogeneous_delays(P: np.ndarray, tau: int) -> np.ndarray:
    """Delay ``tau`` on every link of ``P``, 0 on the self-loops (the papers' setting)."""
    P = np.asarray(P)
    return np.where((P != 0) & ~np.eye(P.shape[0], dtype=bool), tau, 0)


def exact_rho(P: Any, A: Any, C: Any, L: Any, tau: int, compensated: bool = True) -> float:
    """Exact spectral radius of the augmented closed loop at homogeneous ``tau``."""
    return augmented_spectral_radius(P, A, C, L, homogeneous_delays(P, tau), tau,
                                     compensated=compensated)


def theorem1_on(P: Any, A: Any, C: Any, L: Any, tau_max: int = 30) -> dict[str, Any]:
    """Theorem 1 on one instance: exact rho at every homogeneous ``tau <= tau*``.

    Returns ``{"tau_star", "exact": {tau: rho}, "violations": [tau, ...]}``; a violation
    is a ``tau <= tau*`` with exact rho ``>= 1``.
    """
    star = tau_star_report(P, A, C, L, tau_max=tau_max).contiguous
    exact = {} if star is None else {t: exact_rho(P, A, C, L, t) for t in range(star + 1)}
    return {"tau_star": star, "exact": exact,
            "violations": [t for t, r in exact.items() if r >= 1.0]}


def eq14_on(P: Any, A: Any, C: Any, L: Any, taus: Sequence[int]) -> dict[str, Any]:
    """Eq. (14)'s "longer delays, slower decay": is the exact rho non-decreasing in tau?

    Returns ``{"exact": {tau: rho}, "decreases": [(tau1, tau2), ...]}``, consecutive
    pairs of ``taus`` where the exact rho decreases (beyond 1e-9).
    """
    exact = {int(t): exact_rho(P, A, C, L, int(t)) for t in taus}
    ts = sorted(exact)
    drops = [(a, b) for a, b in zip(ts, ts[1:], strict=False)
             if exact[b] < exact[a] - 1e-9]
    return {"exact": exact, "decreases": drops}


def search_undecided(found: Any, what: str, numbers: dict[str, Any],
                     tail: str = "") -> Outcome:
    """``undecided`` for a search that did not run all its instances and found nothing."""
    why = found.incomplete_reason()
    return Outcome(UNDECIDED, f"{what}: no counterexample, but {why}" + tail, numbers,
                   reason=why, headline=f"{what}: {why}" + tail)


def unconfirmed(what: str, verification: dict[str, Any], numbers: dict[str, Any],
                cx: dict[str, Any]) -> Outcome:
    """``undecided``: the exact analysis found a counterexample the simulation did not
    confirm."""
    why = ("the exact analysis finds a counterexample that the simulation does not "
           f"confirm (simulated error growth {verification['simulated_error_growth']:.4f}"
           + (f", netsim run: {run_words(verification['netsim_run'])}"
              if verification.get("netsim_run") else "") + ")")
    return Outcome(UNDECIDED, f"{what}: {why}", numbers, cx, reason=why)


def searched(context: Context, claim_id: str) -> Any:
    """The result of ``claim_id``'s counterexample search (run now unless
    :func:`netsim.claims.run_claims` ran it already, in a worker)."""
    from netsim.claims.searches import run_search, searches

    found = searches().get(claim_id)
    key = found.key if found is not None else f"search:{claim_id}"
    return context.cached(key, lambda: run_search(claim_id, context.seed, context.budget,
                                                  context.instances))


def confirm_run(path: Any, family: str) -> dict[str, Any]:
    """``netsim run`` on a written counterexample (see :mod:`netsim.claims.searches`)."""
    from netsim.claims.searches import confirm_run as run_it

    return run_it(path, family)


def _g(v: Any) -> str:
    return "-" if v is None else f"{v:.3g}"


def run_words(r: dict[str, Any]) -> str:
    """A :func:`confirm_run` result in words."""
    growth = r.get("mse_growth")
    return (f"{r['verdict']} (measured {r['measured']}"
            + (f", MSE growth {growth:.4f}/step" if growth is not None else "")
            + f"), MSE {_g(r['mse_first'])} -> {_g(r['mse_last'])} over {r['steps']} steps")


def search_words(found: Any) -> str:
    """``H of M instances of <family> (seed s)``."""
    return f"{found.hits} of {found.tried} instances of {found.family} (seed {found.seed})"


def bench(context: Context, preset: str) -> dict[str, Any]:
    """:func:`netsim.claims.searches.bench_report` for the context's seed, cached per
    preset."""
    from netsim.claims.searches import bench_report

    return context.cached(f"bench:{preset}", lambda: bench_report(preset, context.seed))


def from_bench(context: Context, claim_id: str, preset: str) -> Outcome:
    """A figure's Monte Carlo observation of the paper's unprinted system, on our
    instance (a bench report): agreement is no counterexample in the trials run; a
    disagreement cannot refute a figure of another system, so it is undecided with the
    difference stated."""
    from netsim.bench.claims import bench_rows

    data = bench(context, preset)
    row = bench_rows()[claim_id](data)
    numbers = {"bench": preset, "trials": data["trials"], "steps": data["steps"],
               "ours": row["ours"], "status": row["status"]}
    where = (f"netsim bench delay-tolerance {preset} ({data['trials']} trials x "
             f"{data['steps']} steps) on our instance of the unprinted system: ")
    if row["agrees"] is None:
        return Outcome(UNDECIDED, where + row["ours"], numbers,
                       reason="the bench report has no cell for it")
    if row["agrees"]:
        evidence = Evidence(int(data["trials"]), f"Monte Carlo trials of {data['steps']} "
                            f"steps of netsim bench {preset} on our instance", context.seed)
        return Outcome(NO_COUNTEREXAMPLE, where + row["ours"], numbers, evidence=evidence)
    why = ("the figure is of the paper's unprinted system; on our instance it does not "
           "show (" + row["ours"] + ")")
    return Outcome(UNDECIDED, where + row["ours"], numbers,
                   {"bench": preset, "cells": row["ours"]}, reason=why)


def convergence_time(M: np.ndarray, factor: float = 1e-3, seed: int = 0,
                     max_steps: int = 100_000) -> int | None:
    """Steps until ``||M^k e_0|| <= factor ||e_0||`` for a random ``e_0`` (noise-free error
    recursion e_k = M e_{k-1}); None if not within ``max_steps``."""
    e = np.random.default_rng(seed).standard_normal(int(M.shape[0]))
    e0 = float(np.linalg.norm(e))
    for k in range(1, max_steps + 1):
        e = cast("np.ndarray", M @ e)  # numpy's stubs type this product as float
        if np.linalg.norm(e) <= factor * e0:
            return k
    return None


def lemma2_on(P: Any, A: Any, C: Any, L: Any, taus: Sequence[int],
              compensated: bool = True) -> dict[int, dict[str, float | None]]:
    """Per homogeneous tau: exact rho of (10) (or (11)), the measured convergence time
    (error down by 1e3) and ``time (1 - rho) / ln(1e3)`` (about 1 for a Theta match)."""
    from netsim.models.augmented import augmented_closed_loop

    out: dict[int, dict[str, float | None]] = {}
    for t in taus:
        M = augmented_closed_loop(P, A, C, L, homogeneous_delays(P, t), t,
                                  compensated=compensated)
        r = float(max(abs(np.linalg.eigvals(M))))
        k = convergence_time(M) if r < 1 else None
        out[int(t)] = {"rho": r, "time": k,
                       "ratio": None if k is None else k * (1 - r) / math.log(1e3)}
    return out


def kron_observable(P: Any, A: Any, C: Sequence[Any]) -> bool:
    """Is ``(P kron A, D_C-bar)`` observable (rank of the observability matrix)?"""
    from netsim.models.augmented import output_gain_matrix

    F = np.kron(np.asarray(P, float), np.asarray(A, float))
    D = output_gain_matrix(C)
    m = F.shape[0]
    blocks, M = [], np.eye(m)
    for _ in range(m):
        blocks.append(D @ M)
        M = M @ F
    return bool(np.linalg.matrix_rank(np.vstack(blocks)) == m)


