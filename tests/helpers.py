"""Shared builders for the tests (not a test module)."""

from __future__ import annotations

import os
import signal
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
from netsim.models.scenario import DelaySpec, Scenario, resolve_scenario

__all__ = ["lcsys", "with_delays", "lockstep_compensated", "rho", "augmented_by_hand",
           "example", "mse_level", "N_AGENTS", "N_STATES"]

N_AGENTS, N_STATES = 4, 6


def lcsys(**changes) -> Scenario:
    """The built-in LCSYS2022 scenario, optionally with fields replaced."""
    scenario = resolve_scenario("lcsys2022-heterogeneous")
    return replace(scenario, **changes) if changes else scenario


def with_delays(scenario: Scenario, **spec) -> Scenario:
    """Replace the scenario's delay specification."""
    return replace(scenario, delays=DelaySpec(**spec))


def lockstep_compensated(P, A, C, L, prior, ys, delays, steps):
    """Agent-by-agent recursion of LCSYS2022 eqs. (4)-(5) with fixed delays.

    Written from the paper independently of the estimator classes: at step k >= 1,
    x^i_{k|k-1} = p_ii A x^i_{k-1} + sum_j p_ij A^(d_ij + 1) x^j_{k-1-d_ij}, where a
    neighbour estimate not yet available (k - 1 - d_ij < 0) is replaced by agent
    i's own A x^i_{k-1}; then x^i_k = x^i_{k|k-1} + L_i (y^i_k - C_i x^i_{k|k-1}).
    ``ys[i]`` has shape (K+1, m_i); ``delays[(j, i)]`` is d_ij. Returns (K+1, N, n).
    """
    N, n = len(C), A.shape[0]
    xs = np.zeros((steps + 1, N, n))
    for i in range(N):
        xs[0, i] = prior + L[i] @ (ys[i][0] - C[i] @ prior)
    for k in range(1, steps + 1):
        for i in range(N):
            prior_i = P[i, i] * A @ xs[k - 1, i]
            for j in range(N):
                if j == i or P[i, j] == 0:
                    continue
                d = delays[(j, i)]
                if k - 1 - d >= 0:
                    Ad = np.linalg.matrix_power(A, d + 1)
                    prior_i = prior_i + P[i, j] * Ad @ xs[k - 1 - d, j]
                else:
                    prior_i = prior_i + P[i, j] * A @ xs[k - 1, i]
            xs[k, i] = prior_i + L[i] @ (ys[i][k] - C[i] @ prior_i)
    return xs


def rho(M: np.ndarray) -> float:
    """Spectral radius by dense eigenvalues."""
    return float(max(abs(np.linalg.eigvals(M))))


def augmented_by_hand(P, A, C, L, d, compensated=True) -> np.ndarray:
    """The augmented closed loop of LCSYS2022 eqs. (9)-(10) (compensated) or the
    delay-tolerant eq. (11), built by hand with numpy kron (not netsim.models.augmented):
    first block row (I - blockdiag(L_i C_i)) [P_0 kron B_0, ..., P_tau kron B_tau],
    B_r = A^(r+1) or A, identities below; P_r keeps the entries of P whose delay
    ``d[i, j]`` is r."""
    P, A = np.asarray(P, float), np.atleast_2d(np.asarray(A, float))
    N, n = P.shape[0], A.shape[0]
    d = np.asarray(d)
    tau = int(d[P != 0].max())
    G = np.zeros((N * n, N * n))
    for i in range(N):
        G[i * n:(i + 1) * n, i * n:(i + 1) * n] = np.eye(n) - np.atleast_2d(L[i]) @ \
            np.atleast_2d(C[i])
    m = N * n
    M = np.zeros((m * (tau + 1), m * (tau + 1)))
    for r in range(tau + 1):
        Pr = np.where((d == r) & (P != 0), P, 0.0)
        B = np.linalg.matrix_power(A, r + 1) if compensated else A
        M[:m, r * m:(r + 1) * m] = G @ np.kron(Pr, B)
    M[m:, :-m] = np.eye(m * tau)
    return M


def example(seed: int = 0):
    """n=6 unstable structurally-cyclic A (4 irreducible blocks), N=4 sensors on
    a directed self-looped cycle 1->2->3->4->1, one output per sensor."""
    rng = np.random.default_rng(seed)
    n, N = N_STATES, N_AGENTS
    sizes = [2, 2, 1, 1]
    starts = np.cumsum([0, *sizes])
    A = np.zeros((n, n))
    for b, (s, e) in enumerate(zip(starts[:-1], starts[1:], strict=True)):
        A[s:e, s:e] = rng.uniform(0.5, 1.0, (e - s, e - s))
        if b:
            A[s:e, :s] = rng.uniform(-0.3, 0.3, (e - s, s)) * (rng.random((e - s, s)) < 0.5)
    A *= 1.04 / np.max(np.abs(np.linalg.eigvals(A)))
    C = [np.eye(n)[[s]] for s in starts[:-1]]
    W = (np.eye(N) + np.roll(np.eye(N), -1, axis=1)) * rng.uniform(0.2, 1.0, (N, N))
    P = W / W.sum(axis=1, keepdims=True)
    return P, A, C


def mse_level(estimator: dict) -> float:
    """An estimator's MSE level from ``netsim run --json``: its steady MSE when the run
    is stable, else the mean of its trusted MSE@ values from step K/2 on (a run that is
    not judged stable has no steady MSE, netsim.verdicts.has_steady_state)."""
    if "steady_state_mse" in estimator:
        return float(estimator["steady_state_mse"])
    trusted = estimator["mse_at_trusted"]
    last = max(int(k) for k in trusted)
    values = [v for k, v in trusted.items() if int(k) >= last // 2 and v is not None]
    return float(np.mean(values))


def start_process(argv: list[str], log: Path, cwd: Path | None = None,
                  env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
    """Start ``argv`` in its own session (so :func:`kill_process` ends its whole group),
    its output into ``log``."""
    with open(log, "wb") as out:
        return subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, cwd=cwd, env=env,
                                start_new_session=True, stdin=subprocess.DEVNULL)


def kill_process(proc: subprocess.Popen[bytes], timeout: float) -> None:
    """Kill a process started by :func:`start_process` with its whole group."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=timeout)
