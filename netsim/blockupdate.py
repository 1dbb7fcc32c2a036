"""Stability of the block update of LCSYS2022 eqs. (15)-(16), predicted and measured.

With unknown delays bounded by ``tau``, LCSYS2022 Discussion 1 lets every sensor update
and communicate only every ``tau + 1`` steps:

    x-hat^i_{m|m-1} = sum_{j in N_i u {i}} p_ij A^(tau+1) x-hat^j_{m-1|m-1},   (15)
    x-hat^i_{m|m}   = x-hat^i_{m|m-1} + K_i C_i^T (y^i_m - C_i x-hat^i_{m|m-1}),  (16)

"a non-delayed LTI distributed estimator as in [17] with system matrix A^(tau+1), where
the stability analysis follows similar to Theorem 1". Every message sent at a block step
arrives (delay ``<= tau``) before the next one, so on the block time scale the
noise-free error is ``e_m = (I - K D_C-bar)(P kron A^(tau+1)) e_(m-1)``: stable iff
``rho(A-hat_tau) = rho((I - K D_C-bar)(P kron A^(tau+1))) < 1``, at the per-step rate
``rho(A-hat_tau)^(1/(tau+1))`` -- which is what netsim's analytics say
(:func:`netsim.models.augmented.delay_bound_lcsys`, used by
:func:`netsim.models.jointsystem.block_joint_analysis`).

:func:`block_prediction` gives the prediction for one instance, :func:`block_growth`
measures netsim's ``block`` estimator (:class:`netsim.estimators.consensus.
BlockUpdateEstimator`) in a noise-free run with time-varying delays, and
:func:`search_block` compares the two over seeded random instances: a counterexample
is an instance the prediction calls stable (rate per block ``<= 1 - 0.05``) whose
measured error grows (``>= 1 + 0.05`` per block), or the reverse.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from netsim.models.augmented import delay_bound_lcsys, tau_star_report

__all__ = ["BlockPrediction", "block_prediction", "block_scenario", "block_growth",
           "BlockInstance", "search_block", "BLOCK_FAMILY", "BLOCK_SHARE", "BLOCKS",
           "BLOCK_MARGIN"]

#: Instances of :func:`search_block` per requested instance (a netsim run each).
BLOCK_SHARE = 1 / 8
#: Blocks (of tau + 1 steps) each run of the search lasts.
BLOCKS = 40
#: Distance from 1 (per block) that makes a prediction, and a measurement, decisive.
BLOCK_MARGIN = 0.05

BLOCK_FAMILY = ("random systems N 2..4, n 1..3, one output per agent, rho(A) in "
                "[0.8, 1.1], random gains, time-varying delays uniform in 0..tau per "
                "message (tau 1..5), noise-free, 40 blocks; |rho(A-hat_tau) - 1| >= 0.05")


@dataclass(frozen=True)
class BlockPrediction:
    """What the analysis predicts for the block update at delay bound ``tau``.

    Attributes
    ----------
    tau : int
    rho_block : float
        ``rho((I - K D_C-bar)(P kron A^(tau+1)))``, the growth per block.
    rate_per_step : float
        ``rho_block^(1/(tau+1))`` (:func:`netsim.models.augmented.delay_bound_lcsys`).
    """

    tau: int
    rho_block: float
    rate_per_step: float

    @property
    def stable(self) -> bool:
        """``rho_block < 1``."""
        return self.rho_block < 1.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"tau": self.tau, "rho_block": self.rho_block,
                "rate_per_step": self.rate_per_step, "stable": self.stable}


def block_prediction(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                     L: Sequence[ArrayLike], tau: int) -> BlockPrediction:
    """The block update's predicted growth at delay bound ``tau``.

    Parameters
    ----------
    P : array_like, shape (N, N)
    A : array_like, shape (n, n)
    C : sequence of array_like, ``C[i]`` of shape (m_i, n)
    L : sequence of array_like, ``L[i] = K_i C_i^T``, shape (n, m_i)
    tau : int
        The delay bound; the block length is ``tau + 1``.

    Returns
    -------
    BlockPrediction
    """
    tau = int(tau)
    rho_block = float(tau_star_report(P, A, C, L, tau_max=tau).values[tau])
    return BlockPrediction(tau, rho_block, float(delay_bound_lcsys(P, A, C, L, tau)))


def _given_gains(C: Sequence[np.ndarray], L: Sequence[ArrayLike]) -> list[list[list[float]]]:
    """Per-agent ``K_i`` (n x n) with ``K_i C_i^T = L_i`` (one output per agent)."""
    out = []
    for Ci, Li in zip(C, L, strict=True):
        c = np.asarray(Ci, dtype=float).reshape(1, -1)
        out.append((np.asarray(Li, dtype=float).reshape(-1, 1) @ c / float(np.sum(c * c))).tolist())
    return out


def block_scenario(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                   L: Sequence[ArrayLike], tau: int, *, steps: int, seed: int = 0,
                   delays: str = "asynchronous") -> dict[str, Any]:
    """A noise-free scenario (as parsed TOML) running the ``block`` family with the given
    gains and ``delays`` (``asynchronous``: every message delayed uniformly in
    ``0..tau``; ``homogeneous``: every link ``tau``); one output per agent."""
    P_arr = np.asarray(P, dtype=float)
    A_arr = np.atleast_2d(np.asarray(A, dtype=float))
    Cs = [np.asarray(c, dtype=float).reshape(1, -1) for c in C]
    return {
        "name": "block-update-check",
        "description": "LCSYS2022 eqs. (15)-(16) noise-free, netsim.blockupdate",
        "run": {"steps": int(steps), "trials": 1, "seed": int(seed), "estimators": ["block"]},
        "plant": {"A": A_arr.tolist(), "C": [c.tolist() for c in Cs], "Q": 0.0, "R": 0.0,
                  "x0_cov": 1.0},
        "network": {"P": P_arr.tolist()},
        "delays": {"model": delays, "tau": int(tau), "seed": int(seed)},
        "gains": {"method": "given", "K": _given_gains(Cs, L)},
    }


def block_growth(P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike],
                 L: Sequence[ArrayLike], tau: int, *, blocks: int = BLOCKS, seed: int = 0,
                 delays: str = "asynchronous") -> float | None:
    """Measured growth per block of netsim's ``block`` estimator (noise-free run).

    The largest agent error at the block steps ``m (tau + 1)``; a log-linear fit over
    the second half of those whose error is finite and above ``1e-11 ||x||`` (round-off)
    and whose run had not diverged. None when fewer than 4 such blocks remain (the error
    reached round-off at once).
    """
    from netsim.api import load_scenario
    from netsim.runner import run_monte_carlo

    tau = int(tau)
    period = tau + 1
    sc = load_scenario(block_scenario(P, A, C, L, tau, steps=blocks * period, seed=seed,
                                      delays=delays))
    with np.errstate(over="ignore", invalid="ignore"):
        res = run_monte_carlo(sc, families=["block"], keep_trials=True)
        trial = res.runs["block"][0]
        err = np.sqrt(np.asarray(trial.squared_errors, dtype=float)).max(axis=1)
        scale = np.linalg.norm(np.asarray(trial.states, dtype=float), axis=1)
    ks = np.arange(period, len(err), period)
    ok = np.isfinite(err[ks]) & (err[ks] > 1e-11 * np.maximum(scale[ks], 1e-300))
    good = ks[ok]
    if trial.diverged_at is not None:
        good = good[good < trial.diverged_at]
    if len(good) < 4:
        return None
    good = good[len(good) // 2 - (1 if len(good) % 2 else 0):] if len(good) >= 8 else good
    slope = np.polyfit(good / period, np.log(err[good]), 1)[0]
    return float(math.exp(slope))


@dataclass(frozen=True)
class BlockInstance:
    """A random system with given gains, a delay bound and a delay seed."""

    P: tuple[tuple[float, ...], ...]
    A: tuple[tuple[float, ...], ...]
    C: tuple[tuple[float, ...], ...]
    L: tuple[tuple[float, ...], ...]
    tau: int
    seed: int

    def matrices(self) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], list[np.ndarray]]:
        """``(P, A, C, L)``."""
        return (np.array(self.P), np.array(self.A), [np.array([c]) for c in self.C],
                [np.array(v)[:, None] for v in self.L])

    def prediction(self) -> BlockPrediction:
        """:func:`block_prediction`."""
        return block_prediction(*self.matrices(), self.tau)

    def measured(self) -> float | None:
        """:func:`block_growth` (time-varying delays)."""
        return block_growth(*self.matrices(), self.tau, seed=self.seed)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form."""
        return {"P": [list(r) for r in self.P], "A": [list(r) for r in self.A],
                "C": [list(r) for r in self.C], "L": [list(r) for r in self.L],
                "tau": self.tau, "seed": self.seed}


def _block_draw(rng: np.random.Generator) -> BlockInstance | None:
    """A random instance whose prediction is decisive and measurable (else None)."""
    N, n = int(rng.integers(2, 5)), int(rng.integers(1, 4))
    adj = np.eye(N, dtype=bool)
    for i in range(N):
        adj[(i + 1) % N, i] = True
    adj |= rng.random((N, N)) < 0.3
    W = np.where(adj, rng.random((N, N)) + 0.05, 0.0)
    P = np.round(W / W.sum(axis=1, keepdims=True), 12)
    P[np.diag_indices(N)] += 1.0 - P.sum(axis=1)
    A = rng.standard_normal((n, n))
    A *= float(rng.uniform(0.8, 1.1)) / max(abs(np.linalg.eigvals(A)))
    C = rng.standard_normal((N, n))
    # gains L_i = g_i C_i^T / |C_i|^2 with g_i ~ U(0, 1.6) plus a random perturbation
    L = [(float(rng.uniform(0.0, 1.6)) * c / float(c @ c) + 0.3 * rng.standard_normal(n))
         for c in C]
    x = BlockInstance(tuple(map(tuple, P.tolist())), tuple(map(tuple, A.tolist())),
                      tuple(map(tuple, C.tolist())), tuple(tuple(v.tolist()) for v in L),
                      int(rng.integers(1, 6)), int(rng.integers(0, 2 ** 31)))
    rho = x.prediction().rho_block
    if not math.isfinite(rho) or abs(rho - 1.0) < BLOCK_MARGIN or rho < 0.3:
        return None
    return x


def _block_judge(x: BlockInstance, seen: list[float] | None = None) -> dict[str, Any] | None:
    pred = x.prediction()
    meas = x.measured()
    if meas is None:
        return None
    if seen is not None and meas > 0:
        seen.append(abs(math.log(meas / pred.rho_block)))
    wrong = ((pred.rho_block <= 1.0 - BLOCK_MARGIN and meas >= 1.0 + BLOCK_MARGIN)
             or (pred.rho_block >= 1.0 + BLOCK_MARGIN and meas <= 1.0 - BLOCK_MARGIN))
    if not wrong:
        return None
    return {**pred.to_dict(), "measured_per_block": meas}


def search_block(seed: Any = 0, instances: int = 400, deadline: float = math.inf) -> Any:
    """Counted search for an instance where netsim's block estimator contradicts the
    prediction ``stable iff rho(A-hat_tau) < 1`` (:data:`BLOCK_FAMILY`,
    ``max(1, instances * BLOCK_SHARE)`` instances, a noise-free run each).

    The family's row of ``Found.families`` also gives ``measured`` (instances whose growth
    was measurable) and ``max_log_rate_ratio``, the largest ``|ln(measured / rho(A-hat_tau))|``
    per block over them (how closely the rate, not only the stability, agrees).

    Returns
    -------
    netsim.claims.search.Found
    """
    from netsim.claims.search import random_search

    seen: list[float] = []
    found = random_search("L-block", _block_draw, lambda x: _block_judge(x, seen), None,
                          seed=seed, instances=max(1, int(instances * BLOCK_SHARE)),
                          family=BLOCK_FAMILY, deadline=deadline)
    if found.families:
        found.families[0]["measured"] = len(seen)
        found.families[0]["max_log_rate_ratio"] = max(seen) if seen else None
    return found
