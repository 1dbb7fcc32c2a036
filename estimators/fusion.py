"""Distributed Kalman fusion with dimensionality reduction and delays (dkfe paper).

Pure numpy update rules, usable by the event kernel (one trial: vectors of shape (n,))
and by the lock-step Monte Carlo engine :func:`run_lockstep` (many trials at once:
arrays of shape (B, n)); the same objects do both.

- :class:`LocalGains`: the time-varying Kalman gains of a sink, eq. (7) (deterministic).
- :class:`SinkNode`: the sink's local Kalman filter (5)-(7) and its random choice of the
  r_i components to send (13), drawn from the categorical distribution (21)-(22).
  The message carries the pattern index h_i and the r_i selected values only.
- :class:`FusionCentre`: the compensating estimates (15) from the received selections,
  the optimal weights and fused estimate (28), (31)-(32) (DKFE), and the fused
  estimate with steady-state weights (80) (SDKFE). With all delays 0 it is the
  paper's ODKFE.
- :class:`FusionCovariance`: the exact error covariances Xi(t) (33) of the compensating
  estimates, cross-covariances included, P(t) (32) and the weights (31). Computed by
  propagating the second moment of a stacked error state (local errors, compensating
  errors and process noises over the delay window) with the selection moments
  E{h} and E{h h^T} (54); mathematically equivalent to Theorem 1's (55)-(56). The
  paper's own recursion (45), (55) for Xi_ii is transcribed in
  :func:`paper_xi_ii_steady_state` and checked against it in the tests.

Initialisation (not in the paper): x(0) ~ N(x0_mean, x0_cov); step 0 is the local
filters' measurement update of that prior (the same as the centralised filter). A
compensating estimate for a time t < d_i (nothing received yet) is the prior
prediction A^t x0_mean, and the prediction of x(0) used by (15) at t = d_i is
x0_mean; this satisfies the paper's unbiasedness assumption below (27).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast, overload

import numpy as np
import scipy.linalg as sla
from netsim.estimators.kalman import kalman_gain
from netsim.models.dkfe import DkfeSetup, SelectionScheme

__all__ = [
    "LocalGains",
    "SelectedComponents",
    "SinkNode",
    "FusionCentre",
    "MissingSelection",
    "FusionCovariance",
    "CovarianceSnapshot",
    "SteadyState",
    "optimal_weights",
    "weights_as_printed_79",
    "paper_xi_ii_steady_state",
    "BatchedKalmanFilter",
    "LockstepRun",
    "run_lockstep",
    "covariances_for",
]


# ---------------------------------------------------------------------------
# local filter gains and sinks
# ---------------------------------------------------------------------------


class LocalGains:
    """K_i(t), G_Ki(t) = I - K_i(t) C_i and P_ii(t) of eq. (7), computed lazily.

    Step 0 updates the prior: P*(0) = x0_cov; for t >= 1, P*(t) = A P(t-1) A^T + Q.
    """

    def __init__(self, A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray,
                 P0: np.ndarray, key: str = "plant.R") -> None:
        self.A, self.C, self.Q, self.R = A, C, Q, R
        self.key = key  # what a singular innovation covariance names
        self._P0 = np.asarray(P0, dtype=float)
        self._K: list[np.ndarray] = []
        self._G: list[np.ndarray] = []
        self._P: list[np.ndarray] = []

    def _extend(self) -> None:
        A, C, Q, R = self.A, self.C, self.Q, self.R
        t = len(self._K)
        P_pred = self._P0 if t == 0 else A @ self._P[-1] @ A.T + Q
        S = C @ P_pred @ C.T + R
        K = kalman_gain(S, C @ P_pred, self.key, t)
        G = np.eye(A.shape[0]) - K @ C
        P = G @ P_pred @ G.T + K @ R @ K.T  # Joseph form of P = G P* (eq. 7)
        self._K.append(K)
        self._G.append(G)
        self._P.append(0.5 * (P + P.T))

    def at(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (K_i(t), G_Ki(t), P_ii(t))."""
        while len(self._K) <= t:
            self._extend()
        return self._K[t], self._G[t], self._P[t]


@dataclass(frozen=True)
class SelectedComponents:
    """What a sink sends at step ``step``: the pattern index and the r_i values.

    ``index`` has shape (B,) and ``values`` (B, r_i) (B = 1 in the kernel).
    ``numpy.asarray(message)`` gives what crosses the link as numbers, [index, values]
    (shape (1 + r_i,) in the kernel), so a trace recorder stores the transmitted
    selection.
    """

    step: int
    index: np.ndarray
    values: np.ndarray

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        flat = np.concatenate([np.asarray(self.index, dtype=float).reshape(-1, 1),
                               np.asarray(self.values, dtype=float).reshape(
                                   np.size(self.index), -1)], axis=1)
        out = flat[0] if flat.shape[0] == 1 else flat
        return out if dtype is None else out.astype(dtype)


class _Batch:
    """Shape helpers: internal arrays are (B, n); a 1-D input means one trial."""

    @staticmethod
    def rows(y: np.ndarray) -> tuple[np.ndarray, bool]:
        y = np.asarray(y, dtype=float)
        return (y[None, :], True) if y.ndim == 1 else (y, False)


class SinkNode:
    """Sink node i: local Kalman filter (5)-(7) and random selection (13).

    Parameters
    ----------
    index : int
        Sink number i (0-based).
    A, C : numpy.ndarray
    gains : LocalGains
    selection : SelectionScheme
    prior_mean : numpy.ndarray, shape (n,)
    rng : numpy.random.Generator, optional
        Stream of the categorical draws (independent over time and sinks, eq. 21).
    selector : callable(step, batch) -> numpy.ndarray of int, optional
        Forced pattern indices (replays); overrides ``rng``.
    """

    family = "dkfe-sink"

    def __init__(self, index: int, A: np.ndarray, C: np.ndarray, gains: LocalGains,
                 selection: SelectionScheme, prior_mean: np.ndarray,
                 rng: np.random.Generator | None = None, selector: Any = None) -> None:
        if rng is None and selector is None:
            raise ValueError("a sink needs an rng or a selector")
        self.index = int(index)
        self.A, self.C, self.gains, self.selection = A, C, gains, selection
        self._prior = np.asarray(prior_mean, dtype=float)
        self._rng, self._selector = rng, selector
        self._components = np.array([np.flatnonzero(p) for p in selection.patterns])
        self._x: np.ndarray = self._prior[None, :].copy()
        self._scalar = True
        self.last_step: int | None = None
        self.last_payload: SelectedComponents | None = None
        #: Pattern index chosen at each step (list of arrays of shape (B,)).
        self.selections: list[np.ndarray] = []

    def message_arrived(self, sender: int, sent_step: int, payload: Any) -> bool:
        """Sinks receive nothing."""
        return False

    @property
    def estimate(self) -> np.ndarray:
        """Local optimal estimate x-hat_i(t), shape (n,) or (B, n)."""
        return self._x[0] if self._scalar else self._x

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Filter y_i(k) (eq. 5) and choose the components to send (eq. 13)."""
        Y, self._scalar = _Batch.rows(y)
        K, G, _ = self.gains.at(k)
        if k == 0:
            x = (G @ self._prior)[None, :] + Y @ K.T
        else:
            x = self._x @ (G @ self.A).T + Y @ K.T
        batch = x.shape[0]
        if self._selector is not None:
            idx = np.asarray(self._selector(k, batch), dtype=np.int64).reshape(batch)
        else:
            rng = cast(np.random.Generator, self._rng)  # given when there is no selector
            idx = np.asarray(self.selection.draw(rng, size=batch), dtype=np.int64)
        values = np.take_along_axis(x, self._components[idx], axis=1)
        self._x = x
        self.last_step = k
        self.last_payload = SelectedComponents(k, idx, values)
        self.selections.append(idx)
        return self.estimate

    def outgoing(self, k: int) -> SelectedComponents | None:
        """The selection made at step k (the kernel sends it on the sink's link)."""
        if self.last_payload is None or self.last_payload.step != k:
            return None
        return self.last_payload


# ---------------------------------------------------------------------------
# fusion centre
# ---------------------------------------------------------------------------


class MissingSelection(RuntimeError, ValueError):
    """The centre needs a selection that has not arrived (delay above its bound, loss).

    Also a ValueError: with ``on_missing="fail"`` the scenario's links break what the
    paper's centre assumes, which the command line reports as bad input (exit 2)."""


class FusionCentre:
    """Fusion centre: compensating estimates (15), DKFE (28)/(31) and SDKFE (80).

    At step t, for sink i with (padded) delay d_i and t >= d_i, it uses the selection
    the sink made at t - d_i (a buffered message, or for d_i = 0 the sink's current
    payload read directly, see ``direct``):
    x-hat^c_i(t) = A^{d_i} [H_i(t-d_i) x-hat_i(t-d_i) + (I - H_i(t-d_i)) A x-hat^c_i(t-d_i-1)].

    Parameters
    ----------
    A : numpy.ndarray
    delays : sequence of int
        d_i of each sink (the paper's; a padded bound for time-varying delays).
    selections : sequence of SelectionScheme
    prior_mean : numpy.ndarray
    covariance : FusionCovariance
        Gives the weights Omega_i(t) (31); must be built for the same delays.
    senders : sequence of int, optional
        Kernel agent id of each sink (default 0..L-1).
    direct : mapping sink index -> SinkNode, optional
        Sinks read at the same step (every d_i = 0 sink must be here): the kernel
        cannot deliver within a step, so the centre reads the sink's payload of the
        current step; the sink must update before the centre.
    steady_weights : sequence of numpy.ndarray, optional
        Omega_i of (79); enables the SDKFE.
    output : "dkfe" or "sdkfe"
        Which fused estimate is the agent's ``estimate``.
    record : bool
        Keep every step's compensating and fused estimates (``history``).
    batch : int, optional
        Number of lock-step trials B (estimates of shape (B, n)); None for one trial
        in the kernel (estimates of shape (n,)).
    on_missing : "fail" or "predict"
        What to do when the selection of step t - d_i has not arrived (a delay above
        the bound d_i - 1, or a message lost): ``fail`` raises
        :class:`MissingSelection` (the paper's setting has neither); ``predict`` is an
        extension outside the paper: every component is predicted, as if nothing had
        been sent (H_i(t - d_i) = 0 in eq. (15)), and ``missed`` counts it. The weights
        (31) still come from the loss-free covariances, so they are then not optimal.
    """

    family = "dkfe-centre"

    def __init__(self, A: np.ndarray, delays: Sequence[int],
                 selections: Sequence[SelectionScheme], prior_mean: np.ndarray,
                 covariance: FusionCovariance, *, senders: Sequence[int] | None = None,
                 direct: Mapping[int, SinkNode] | None = None,
                 steady_weights: Sequence[np.ndarray] | None = None,
                 output: str = "dkfe", record: bool = True,
                 batch: int | None = None, on_missing: str = "fail") -> None:
        if on_missing not in ("fail", "predict"):
            raise ValueError(f"on_missing must be 'fail' or 'predict', got {on_missing!r}")
        self.on_missing = on_missing
        #: Selections that had not arrived when needed (``on_missing="predict"``).
        self.missed = 0
        self.A = np.asarray(A, dtype=float)
        self.n = self.A.shape[0]
        self.delays = tuple(int(d) for d in delays)
        self.L = len(self.delays)
        if tuple(covariance.delays) != self.delays:
            raise ValueError(f"covariance built for delays {covariance.delays}, "
                             f"centre has {self.delays}")
        self.selections = tuple(selections)
        self._patterns = [s.patterns for s in self.selections]
        self._components = [np.array([np.flatnonzero(p) for p in s.patterns])
                            for s in self.selections]
        self._Ad = [np.linalg.matrix_power(self.A, d) for d in self.delays]
        self._prior = np.asarray(prior_mean, dtype=float)[None, :]
        self.covariance = covariance
        senders = list(range(self.L)) if senders is None else [int(s) for s in senders]
        self._sink_of = {s: i for i, s in enumerate(senders)}
        self._sender = senders
        self.direct = dict(direct or {})
        for i, d in enumerate(self.delays):
            if d == 0 and i not in self.direct:
                raise ValueError(f"sink {i} has d_i = 0: it must be read directly "
                                 "(a kernel link always delays by at least one step)")
        self.steady_weights = None if steady_weights is None else [
            np.asarray(w, dtype=float) for w in steady_weights]
        if output not in ("dkfe", "sdkfe"):
            raise ValueError(f"output must be 'dkfe' or 'sdkfe', got {output!r}")
        if output == "sdkfe" and self.steady_weights is None:
            raise ValueError("output 'sdkfe' needs steady_weights")
        self.output = output
        self.record = record
        self._buffer: list[dict[int, SelectedComponents]] = [{} for _ in range(self.L)]
        self._cse_hist: list[dict[int, np.ndarray]] = [{} for _ in range(self.L)]
        self._dkfe: np.ndarray = self._prior.copy()
        self._sdkfe: np.ndarray | None = None
        self.batch = batch
        self._scalar = batch is None
        self.last_step: int | None = None
        self.last_delays: dict[int, int] = {}
        #: (sink, sent_step) -> first step at which the selection was usable.
        self.arrivals: dict[tuple[int, int], int] = {}
        self.history: dict[str, list[np.ndarray]] = {"cse": [], "dkfe": [], "sdkfe": []}

    # -- kernel interface -------------------------------------------------

    def message_arrived(self, sender: int, sent_step: int, payload: Any) -> bool:
        """Buffer a selection (Remark 1); refuse one that is too old to be used."""
        i = self._sink_of.get(int(sender))
        if i is None or not isinstance(payload, SelectedComponents):
            return False
        usable = 0 if self.last_step is None else self.last_step + 1
        if sent_step + self.delays[i] < usable:
            return False  # its slot has passed (cannot happen with delays <= the bound)
        self._buffer[i][int(sent_step)] = payload
        self.arrivals[(i, int(sent_step))] = usable
        return True

    @overload
    def _shape(self, x: np.ndarray) -> np.ndarray: ...

    @overload
    def _shape(self, x: None) -> None: ...

    def _shape(self, x: np.ndarray | None) -> np.ndarray | None:
        if x is None:
            return None
        if self._scalar:
            return x[0]
        return np.broadcast_to(x, (cast(int, self.batch), self.n))  # batched: batch given

    @property
    def estimate(self) -> np.ndarray:
        """The DKFE (``output="dkfe"``) or the SDKFE, shape (n,) or (B, n)."""
        # the SDKFE is None only before the first step
        return self._shape(self._dkfe if self.output == "dkfe"
                           else cast(np.ndarray, self._sdkfe))

    @property
    def dkfe(self) -> np.ndarray:
        """The DKFE x-hat(t) (28) with the optimal weights (31)."""
        return self._shape(self._dkfe)

    @property
    def sdkfe(self) -> np.ndarray | None:
        """The SDKFE x-hat_s(t) (80) with the steady-state weights (79)."""
        return self._shape(self._sdkfe)

    def step(self, k: int, y: Any = None) -> np.ndarray:
        """Form the compensating estimates (15) and fuse them (28)."""
        A = self.A
        cses = []
        used: dict[int, int] = {}
        for i, d in enumerate(self.delays):
            if k < d:
                cse = self._prior @ np.linalg.matrix_power(A, k).T  # nothing received yet
            else:
                u = k - d
                pred = self._prior if u == 0 else self._cse_hist[i][u - 1] @ A.T
                try:
                    payload = self._take(i, u)
                except MissingSelection:
                    if self.on_missing == "fail":
                        raise
                    payload = None
                    self.missed += 1
                if payload is None:  # nothing arrived: every component predicted
                    x_r = np.broadcast_to(pred, (pred.shape[0], self.n)).copy()
                else:
                    if payload.step != u:
                        raise MissingSelection(f"sink {i}: need the selection of step "
                                               f"{u}, have step {payload.step}")
                    batch = payload.values.shape[0]
                    mask = self._patterns[i][payload.index]  # (B, n)
                    sent = np.zeros((batch, self.n))
                    np.put_along_axis(sent, self._components[i][payload.index],
                                      payload.values, axis=1)
                    x_r = sent + (1.0 - mask) * pred  # x-hat^r_i(t - d_i)
                cse = x_r @ self._Ad[i].T
                if d > 0:
                    used[self._sender[i]] = d - 1  # kernel's r = k - 1 - s
            self._cse_hist[i][k] = cse
            self._cse_hist[i].pop(k - d - 1, None)
            cses.append(cse)
        weights = self.covariance.weights(k)
        self._dkfe = sum(c @ w.T for c, w in zip(cses, weights, strict=True))
        if self.steady_weights is not None:
            self._sdkfe = sum(c @ w.T for c, w in zip(cses, self.steady_weights, strict=True))
        if self.record:
            batch = 1 if self.batch is None else self.batch
            self.history["cse"].append(np.stack([np.broadcast_to(c, (batch, self.n))
                                                 for c in cses]))
            self.history["dkfe"].append(np.broadcast_to(self._dkfe, (batch, self.n)).copy())
            if self._sdkfe is not None:
                self.history["sdkfe"].append(
                    np.broadcast_to(self._sdkfe, (batch, self.n)).copy())
        self.last_step = k
        self.last_delays = used
        return self.estimate

    def _take(self, i: int, u: int) -> SelectedComponents:
        if i in self.direct:
            payload = self.direct[i].last_payload
            if payload is None or payload.step != u:
                raise MissingSelection(
                    f"sink {i} (read directly) has no payload of step {u}: the sink must "
                    "update before the centre at every step")
            return payload
        buf = self._buffer[i]
        for s in [s for s in buf if s < u]:
            del buf[s]
        try:
            return buf.pop(u)
        except KeyError:
            raise MissingSelection(
                f"sink {i}: the selection sent at step {u} had not arrived by step "
                f"{u + self.delays[i]} (a delay above the bound d_i - 1 = "
                f"{self.delays[i] - 1}, or a lost message)") from None


# ---------------------------------------------------------------------------
# covariances and weights
# ---------------------------------------------------------------------------


def optimal_weights(Xi: np.ndarray, L: int, n: int) -> tuple[list[np.ndarray], np.ndarray, str]:
    """Optimal weights (31) and fused covariance (32).

    [Omega_1..Omega_L] = (I_a^T Xi^-1 I_a)^-1 I_a^T Xi^-1, P = (I_a^T Xi^-1 I_a)^-1.
    When Xi is singular (e.g. at t = 0, when several compensating estimates are the
    same prior prediction) the minimiser of tr(Omega Xi Omega^T) subject to
    sum Omega_i = I is taken from the KKT system (minimum-norm least squares) and
    P = Omega Xi Omega^T. Returns (weights, P, method).
    """
    Ia = np.tile(np.eye(n), (L, 1))
    Xs = 0.5 * (Xi + Xi.T)
    w = np.linalg.eigvalsh(Xs)
    if w[0] > 1e-11 * max(w[-1], 1e-300):
        c = sla.cho_factor(Xs)
        XiIa = sla.cho_solve(c, Ia)  # Xi^-1 I_a
        P = np.linalg.inv(Ia.T @ XiIa)
        P = 0.5 * (P + P.T)
        row = P @ XiIa.T
        method = "eq31"
    else:
        kkt = np.block([[Xs, Ia], [Ia.T, np.zeros((n, n))]])
        rhs = np.vstack([np.zeros((L * n, n)), np.eye(n)])
        sol = np.linalg.lstsq(kkt, rhs, rcond=None)[0]
        row = sol[: L * n].T
        P = row @ Xs @ row.T
        P = 0.5 * (P + P.T)
        method = "kkt"
    return [row[:, i * n:(i + 1) * n] for i in range(L)], P, method


def weights_as_printed_79(Xi: np.ndarray, P: np.ndarray, L: int, n: int) -> list[np.ndarray]:
    """Eq. (79) exactly as printed, P^{-1} I_a^T Xi^{-1} (for the typo check only)."""
    Ia = np.tile(np.eye(n), (L, 1))
    row = np.linalg.inv(P) @ np.linalg.solve(Xi, Ia).T
    return [row[:, i * n:(i + 1) * n] for i in range(L)]


@dataclass(frozen=True)
class CovarianceSnapshot:
    """Exact second moments at one step t.

    Xi : (L n, L n), Xi_ij(t) = E{x~^c_i(t) x~^c_j(t)^T} (33)
    P : (n, n) fused error covariance (32)
    weights : list of (n, n), Omega_i(t) (31)
    P_local : (L n, L n), P_ij(t) = E{x~_i(t) x~_j(t)^T} (7)-(8)
    Gamma : (L n, L n), Gamma_ij(t) = E{x~_i(t) x~^c_j(t)^T} (44)
    method : "eq31" or "kkt" (see :func:`optimal_weights`)
    """

    t: int
    Xi: np.ndarray
    P: np.ndarray
    weights: list[np.ndarray]
    P_local: np.ndarray
    Gamma: np.ndarray
    method: str

    def Xi_block(self, i: int, j: int) -> np.ndarray:
        n = self.P.shape[0]
        return self.Xi[i * n:(i + 1) * n, j * n:(j + 1) * n]


@dataclass(frozen=True)
class SteadyState:
    """Limits of Xi(t), P(t), Omega_i(t) (Theorem 3), or the last iterate."""

    Xi: np.ndarray
    P: np.ndarray
    weights: list[np.ndarray]
    steps: int
    converged: bool
    change: float


class _StackedRecursion:
    """Second moment of the stacked error state e(t) (see FusionCovariance)."""

    def __init__(self, A, Q, C, R, delays, selections, P0, gains) -> None:
        self.A, self.Q, self.C, self.R = A, Q, C, R
        self.delays, self.selections, self.P0, self.gains = delays, selections, P0, gains
        n, L = A.shape[0], len(C)
        self.n, self.L = n, L
        Dmax = max(delays)
        self.Dmax, self.Lw = Dmax, max(Dmax, 1)
        off = 0
        self.loc: list[list[int]] = []
        for _ in range(L):
            self.loc.append([off + m * n for m in range(self.Lw)])
            off += self.Lw * n
        self.cse: list[list[int]] = []
        for d in delays:
            self.cse.append([off + m * n for m in range(d + 1)])
            off += (d + 1) * n
        self.w = [off + m * n for m in range(Dmax)]
        off += Dmax * n
        self.N = off
        self.wnew = off
        self.v: list[int] = []
        off += n
        for Ci in C:
            self.v.append(off)
            off += Ci.shape[0]
        self.Next = off
        self.Ad = [np.linalg.matrix_power(A, d) for d in delays]
        self.Apow = [np.linalg.matrix_power(A, k) for k in range(Dmax + 1)]
        self.S: np.ndarray | None = None
        self.t = -1

    def _put(self, M: np.ndarray, r: int, c: int, block: np.ndarray) -> None:
        M[r:r + block.shape[0], c:c + block.shape[1]] += block

    def _ext_cov(self, S: np.ndarray) -> np.ndarray:
        blocks = [S, self.Q] + list(self.R)
        return sla.block_diag(*blocks)

    def _apply(self, T: np.ndarray, random_rows: list[tuple[int, np.ndarray]],
               Sext: np.ndarray) -> np.ndarray:
        """S' = E{(T e + sum_i E_i A^d_i H_i Delta_i e)(...)^T} over e and the H_i."""
        n = self.n
        Tbar = T.copy()
        for i, Delta in random_rows:
            row = self.cse[i][0]
            Tbar[row:row + n] += self.Ad[i] @ (self.selections[i].mean[:, None] * Delta)
        S = Tbar @ Sext @ Tbar.T
        for i, Delta in random_rows:
            sel = self.selections[i]
            h = sel.mean
            cov_h = sel.Lambda - np.outer(h, h)
            X = Delta @ Sext @ Delta.T
            row = self.cse[i][0]
            S[row:row + n, row:row + n] += self.Ad[i] @ (cov_h * X) @ self.Ad[i].T
        return 0.5 * (S + S.T)

    def initial(self) -> np.ndarray:
        """e(0) from z0 = [x(0) - x0_mean; v_1(0); ...; v_L(0)]."""
        n, L = self.n, self.L
        # reuse the extended layout: e0 sits in the w_new slot, v_i(0) in the v slots
        T = np.zeros((self.N, self.Next))
        eye = np.eye(n)
        rand = []
        for i in range(L):
            K, G, _ = self.gains[i].at(0)
            r = self.loc[i][0]
            self._put(T, r, self.wnew, G)
            self._put(T, r, self.v[i], -K)
            c = self.cse[i][0]
            if self.delays[i] >= 1:
                self._put(T, c, self.wnew, eye)  # x-hat^c_i(0) = x0_mean
            else:
                a = np.zeros((n, self.Next))
                self._put(a, 0, self.wnew, G)
                self._put(a, 0, self.v[i], -K)
                b = np.zeros((n, self.Next))
                self._put(b, 0, self.wnew, eye)
                T[c:c + n] += b  # A^0 b
                rand.append((i, a - b))
        Sext = sla.block_diag(np.zeros((self.N, self.N)), self.P0, *self.R)
        return self._apply(T, rand, Sext)

    def transition(self, s: int) -> tuple[np.ndarray, list[tuple[int, np.ndarray]]]:
        """Linear maps from [e(s-1); w(s-1); v(s)] to e(s)."""
        n, A = self.n, self.A
        eye = np.eye(n)
        T = np.zeros((self.N, self.Next))
        rand = []
        for m in range(1, self.Dmax):
            self._put(T, self.w[m], self.w[m - 1], eye)
        if self.Dmax:
            self._put(T, self.w[0], self.wnew, eye)
        for i in range(self.L):
            K, G, _ = self.gains[i].at(s)
            loc, cse, d = self.loc[i], self.cse[i], self.delays[i]
            new_loc = np.zeros((n, self.Next))
            self._put(new_loc, 0, loc[0], G @ A)
            self._put(new_loc, 0, self.wnew, G)
            self._put(new_loc, 0, self.v[i], -K)
            T[loc[0]:loc[0] + n] += new_loc
            for m in range(1, self.Lw):
                self._put(T, loc[m], loc[m - 1], eye)
            for m in range(1, d + 1):
                self._put(T, cse[m], cse[m - 1], eye)
            c = cse[0]
            if s < d:  # prior prediction: x~^c(s) = A x~^c(s-1) + w(s-1)
                self._put(T, c, cse[0], A)
                self._put(T, c, self.wnew, eye)
                continue
            # x~^c(s) = A^d [b + H (a - b)] + F_w(d, s)   (eq. 25)
            if d == 0:
                a = new_loc
            else:
                a = np.zeros((n, self.Next))
                self._put(a, 0, loc[d - 1], eye)  # x~_i(s - d)
            b = np.zeros((n, self.Next))
            if s == d:
                self._put(b, 0, cse[d - 1], eye)  # x~^c_i(0) = x(0) - x0_mean
            else:
                self._put(b, 0, cse[d], A)  # A x~^c_i(s - d - 1)
                self._put(b, 0, self.wnew if d == 0 else self.w[d - 1], eye)  # w(s - d - 1)
            F = np.zeros((n, self.Next))
            for theta in range(1, d + 1):  # sum A^(theta-1) w(s - theta)
                col = self.wnew if theta == 1 else self.w[theta - 2]
                self._put(F, 0, col, self.Apow[theta - 1])
            T[c:c + n] += self.Ad[i] @ b + F
            rand.append((i, a - b))
        return T, rand

    def advance(self) -> np.ndarray:
        if self.S is None:
            self.S = self.initial()
            self.t = 0
        else:
            self.t += 1
            T, rand = self.transition(self.t)
            self.S = self._apply(T, rand, self._ext_cov(self.S))
        return self.S

    def blocks(self, S: np.ndarray, rows: list[int], cols: list[int]) -> np.ndarray:
        n = self.n
        return np.block([[S[r:r + n, c:c + n] for c in cols] for r in rows])


class FusionCovariance:
    """Exact Xi(t), P(t), Omega_i(t) of the DKFE, computed lazily step by step.

    The stacked error state at step t holds, per sink, the local errors
    x~_i(t), ..., x~_i(t - D + 1) (D = max d_i, at least one), the compensating errors
    x~^c_i(t), ..., x~^c_i(t - d_i), and the process noises w(t-1), ..., w(t-D). Each
    step maps it linearly (with the new w(t), v_i(t+1)) except for the selection H_i
    drawn at t + 1 - d_i, which is independent of the state; so
    E{e' e'^T} = T-bar S T-bar^T + sum_i E_i A^{d_i} [(Lambda_i - h_i h_i^T) o
    (Delta_i S Delta_i^T)] A^{d_i T} E_i^T, with T-bar the map at H_i = E{H_i}, h_i its
    diagonal and Delta_i the difference of the transmitted and the predicted
    error (Lemma 1). Deterministic: one object serves every trial.

    Parameters
    ----------
    setup : DkfeSetup
        Plant, sinks, selections, delays and x(0) statistics.
    gains : list of LocalGains, optional
        Shared with the sinks (otherwise made here).
    """

    def __init__(self, setup: DkfeSetup, gains: Sequence[LocalGains] | None = None) -> None:
        self.setup = setup
        self.delays = setup.delays
        self.n, self.L = setup.n, setup.n_sinks
        self.gains = list(gains) if gains is not None else [
            LocalGains(setup.A, C, setup.Q, R, setup.x0_cov, f"plant.R[{i}]")
            for i, (C, R) in enumerate(zip(setup.C, setup.R, strict=True))]
        self._rec = self._recursion()
        self._snaps: list[CovarianceSnapshot] = []

    def _recursion(self) -> _StackedRecursion:
        s = self.setup
        return _StackedRecursion(s.A, s.Q, s.C, s.R, s.delays, s.selections, s.x0_cov,
                                 self.gains)

    def _snapshot(self, rec: _StackedRecursion, S: np.ndarray) -> CovarianceSnapshot:
        cse = [c[0] for c in rec.cse]
        loc = [lo[0] for lo in rec.loc]
        Xi = rec.blocks(S, cse, cse)
        weights, P, method = optimal_weights(Xi, self.L, self.n)
        return CovarianceSnapshot(rec.t, Xi, P, weights, rec.blocks(S, loc, loc),
                                  rec.blocks(S, loc, cse), method)

    def at(self, t: int) -> CovarianceSnapshot:
        """The snapshot of step t (computing the steps up to t once)."""
        while len(self._snaps) <= t:
            S = self._rec.advance()
            self._snaps.append(self._snapshot(self._rec, S))
        return self._snaps[t]

    def weights(self, t: int) -> list[np.ndarray]:
        return self.at(t).weights

    def Xi(self, t: int) -> np.ndarray:
        return self.at(t).Xi

    def P(self, t: int) -> np.ndarray:
        return self.at(t).P

    def fused_covariance(self, t: int, weights: Sequence[np.ndarray]) -> np.ndarray:
        """E{(x - sum Omega_i x-hat^c_i)(...)^T} for given weights summing to I."""
        row = np.hstack(list(weights))
        return row @ self.at(t).Xi @ row.T

    def steady_state(self, tol: float = 1e-12, max_steps: int = 20000,
                     patience: int = 10) -> SteadyState:
        """Iterate until Xi(t) stops changing (relative max-entry change < tol).

        Uses its own copy of the recursion; the stored snapshots are not extended.
        """
        with np.errstate(over="ignore", invalid="ignore"):
            return self._iterate(tol, max_steps, patience)

    def _iterate(self, tol: float, max_steps: int, patience: int) -> SteadyState:
        rec = self._recursion()
        prev = None
        calm = 0
        change = np.inf
        Xi = None
        for t in range(max_steps + 1):
            S = rec.advance()
            Xi = rec.blocks(S, [c[0] for c in rec.cse], [c[0] for c in rec.cse])
            if not np.all(np.isfinite(Xi)):
                break
            if prev is not None:
                change = float(np.max(np.abs(Xi - prev)) / max(np.max(np.abs(Xi)), 1e-300))
                calm = calm + 1 if change < tol else 0
                if calm >= patience:
                    weights, P, _ = optimal_weights(Xi, self.L, self.n)
                    return SteadyState(Xi, P, weights, t, True, change)
            prev = Xi
        weights, P, _ = optimal_weights(Xi, self.L, self.n) if Xi is not None and np.all(
            np.isfinite(Xi)) else ([np.full((self.n, self.n), np.nan)] * self.L,
                                   np.full((self.n, self.n), np.nan), "")
        # Xi is None only when max_steps < 0 (no step taken)
        return SteadyState(cast(np.ndarray, Xi), P, weights, rec.t, False, change)


def paper_xi_ii_steady_state(A: np.ndarray, Q: np.ndarray, Phi: np.ndarray, G: np.ndarray,
                             P: np.ndarray, selection: SelectionScheme, d: int,
                             iterations: int = 5000) -> tuple[np.ndarray, np.ndarray]:
    """Fixed point of the paper's (45) (i = j) and (55) with steady-state gains.

    Gamma = Phi^(d+1) Gamma H_Ad^T + Phi^d P H_d^T + sum_theta Phi^(theta-1) G Q
    (A^(theta-1))^T + Phi^d G Q Hbar_Ad^T (eqs. 36-38, 45), then Xi_ii from (55). For the
    cross-check of :class:`FusionCovariance`; returns (Xi_ii, Gamma_ii).
    """
    n = A.shape[0]
    eye = np.eye(n)
    Ad = np.linalg.matrix_power(A, d)
    H = selection.H
    H_d, H_Ad = Ad @ H, Ad @ (eye - H) @ A
    Hbar_Ad = Ad - H_d
    Phid = np.linalg.matrix_power(Phi, d)
    Phid1 = Phid @ Phi
    const = Phid @ P @ H_d.T + Phid @ G @ Q @ Hbar_Ad.T
    for theta in range(1, d + 1):
        At = np.linalg.matrix_power(A, theta - 1)
        const = const + np.linalg.matrix_power(Phi, theta - 1) @ G @ Q @ At.T
    Gamma = np.zeros((n, n))
    for _ in range(iterations):
        Gamma = Phid1 @ Gamma @ H_Ad.T + const
    Lam, V, W = selection.Lambda, selection.V, selection.W
    tail = sum((np.linalg.matrix_power(A, th - 1) @ Q @ np.linalg.matrix_power(A, th - 1).T
                for th in range(1, d + 1)), np.zeros((n, n)))
    Xi = np.zeros((n, n))
    for _ in range(iterations):
        inner = (W * (A @ Xi @ A.T) + Lam * P + W * Q
                 + V * (Phi @ Gamma @ A.T + G @ Q) + V.T * (A @ Gamma.T @ Phi.T + Q @ G.T))
        Xi = Ad @ inner @ Ad.T + tail
    return Xi, Gamma


def covariances_for(setup: DkfeSetup) -> tuple[FusionCovariance, FusionCovariance,
                                               list[LocalGains]]:
    """Covariances of the DKFE (the setup's delays) and of the ODKFE (all delays 0)."""
    gains = [LocalGains(setup.A, C, setup.Q, R, setup.x0_cov, f"plant.R[{i}]")
             for i, (C, R) in enumerate(zip(setup.C, setup.R, strict=True))]
    dkfe = FusionCovariance(setup, gains)
    odkfe = FusionCovariance(setup.with_delays([0] * setup.n_sinks), gains)
    return dkfe, odkfe, gains


# ---------------------------------------------------------------------------
# lock-step Monte Carlo (many trials at once, the same objects)
# ---------------------------------------------------------------------------


class BatchedKalmanFilter:
    """Centralised Kalman filter on all sinks' measurements, for (B, m) batches.

    The same recursion as :class:`netsim.estimators.kalman.CentralizedKalmanFilter`; the
    covariance sequence ``covariances`` is deterministic.
    """

    def __init__(self, A, C, Q, R, prior_mean, prior_cov) -> None:
        self.gains = LocalGains(A, C, Q, R, prior_cov)
        self.A = A
        self._prior = np.asarray(prior_mean, dtype=float)
        self._x = self._prior[None, :]

    def step(self, k: int, Y: np.ndarray) -> np.ndarray:
        K, G, _ = self.gains.at(k)
        if k == 0:
            self._x = (G @ self._prior)[None, :] + Y @ K.T
        else:
            self._x = self._x @ (G @ self.A).T + Y @ K.T
        return self._x

    def covariance(self, k: int) -> np.ndarray:
        return self.gains.at(k)[2]


def _factor(cov: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(cov)
        return v * np.sqrt(np.clip(w, 0.0, None))


@dataclass
class LockstepRun:
    """Arrays of a lock-step run: axis 0 is the step, axis -1 the state.

    states (K+1, B, n); local (K+1, L, B, n); cse (K+1, L, B, n); dkfe, sdkfe, odkfe,
    ckf (K+1, B, n); selections (K+1, L, B) pattern indices.
    """

    states: np.ndarray
    local: np.ndarray
    cse: np.ndarray
    dkfe: np.ndarray
    sdkfe: np.ndarray | None
    odkfe: np.ndarray
    ckf: np.ndarray
    selections: np.ndarray
    covariance: FusionCovariance
    odkfe_covariance: FusionCovariance
    extra: dict[str, Any] = field(default_factory=dict)


def run_lockstep(setup: DkfeSetup, steps: int, trials: int, seed: Any, *,
                 steady_weights: Sequence[np.ndarray] | None = None,
                 covariances: tuple[FusionCovariance, FusionCovariance,
                                    list[LocalGains]] | None = None) -> LockstepRun:
    """Run ``trials`` independent trials in lock-step (vectorised), no event kernel.

    Messages follow the paper's timing (a selection made at s is used at s + d_i);
    randomness from :func:`netsim.models.seeding.stream` of ``seed``: ``"lockstep/plant"`` and
    ``"lockstep/sink/<i>/selection"``.
    """
    from netsim.models.seeding import stream

    A, n, L = setup.A, setup.n, setup.n_sinks
    cov, ocov, gains = covariances if covariances is not None else covariances_for(setup)
    sinks = [SinkNode(i, A, setup.C[i], gains[i], setup.selections[i], setup.x0_mean,
                      rng=stream(seed, "lockstep", "sink", i, "selection"))
             for i in range(L)]
    direct = {i: sinks[i] for i in range(L) if setup.delays[i] == 0}
    B = int(trials)
    centre = FusionCentre(A, setup.delays, setup.selections, setup.x0_mean, cov,
                          direct=direct, steady_weights=steady_weights, batch=B)
    ocentre = FusionCentre(A, [0] * L, setup.selections, setup.x0_mean, ocov,
                           direct=dict(enumerate(sinks)), batch=B)
    ckf = BatchedKalmanFilter(A, np.vstack(setup.C), setup.Q, sla.block_diag(*setup.R),
                              setup.x0_mean, setup.x0_cov)
    rng = stream(seed, "lockstep", "plant")
    F0, FQ = _factor(setup.x0_cov), _factor(setup.Q)
    FR = [_factor(R) for R in setup.R]
    states = np.empty((steps + 1, B, n))
    local = np.empty((steps + 1, L, B, n))
    sel = np.empty((steps + 1, L, B), dtype=np.int64)
    ckf_x = np.empty((steps + 1, B, n))
    pending: list[tuple[int, int, SelectedComponents]] = []  # (usable step, sink, payload)
    x = setup.x0_mean[None, :] + rng.standard_normal((B, n)) @ F0.T
    for k in range(steps + 1):
        if k > 0:
            x = x @ A.T + rng.standard_normal((B, n)) @ FQ.T
        ys = [x @ C.T + rng.standard_normal((B, C.shape[0])) @ F.T
              for C, F in zip(setup.C, FR, strict=True)]
        states[k] = x
        for i, sink in enumerate(sinks):
            local[k, i] = sink.step(k, ys[i])
            payload = cast(SelectedComponents, sink.last_payload)  # set by the step
            sel[k, i] = payload.index
            if setup.delays[i] > 0:
                pending.append((k + setup.delays[i], i, payload))
        ready = [p for p in pending if p[0] == k + 1]
        pending = [p for p in pending if p[0] != k + 1]
        centre.step(k)
        ocentre.step(k)
        ckf_x[k] = ckf.step(k, np.hstack(ys))
        for _, i, payload in ready:  # usable from step k + 1 on
            centre.message_arrived(i, payload.step, payload)
    return LockstepRun(
        states=states,
        local=local,
        cse=np.stack(centre.history["cse"]),
        dkfe=np.stack(centre.history["dkfe"]),
        sdkfe=np.stack(centre.history["sdkfe"]) if steady_weights is not None else None,
        odkfe=np.stack(ocentre.history["dkfe"]),
        ckf=ckf_x,
        selections=sel,
        covariance=cov,
        odkfe_covariance=ocov,
        extra={"ckf": ckf},
    )


# ---------------------------------------------------------------------------
# the families this module declares (netsim.estimators.registry)
# ---------------------------------------------------------------------------
#
# ``dkfe``, ``sdkfe`` and ``odkfe`` run on a scenario whose last agent is the fusion
# centre (a sensor with no output, ``C = []``) and whose other agents are the sink
# nodes, each linked to the centre; ``[options.fusion]`` gives what the paper's
# centre knows: ``delays`` (d_i), ``components`` (r_i) with ``probabilities`` (over
# the r_i-subsets of the n components in lexicographic order, eq. 89) or explicit
# ``patterns``, and ``on_missing`` (predict | fail). A link from sink i delivers its
# selection for the centre's update d_i steps later when its step delay is d_i - 1;
# a sink with d_i = 0 has no link (the centre reads it at the same step).

import math  # noqa: E402

from netsim.estimators.registry import (  # noqa: E402  (declared after the classes)
    AgentPlan,
    EstimatorFamily,
    FamilyContext,
    FamilyError,
    ObserverTap,
    register,
)
from netsim.models.dkfe import sink_conditions, steady_state_local_filter  # noqa: E402
from netsim.models.seeding import stream  # noqa: E402

#: Keys of ``[options.fusion]`` (``on_missing`` defaults to ``predict``).
FUSION_OPTIONS = ("delays", "components", "probabilities", "patterns", "on_missing")


def _fusion_error(key: str, message: str) -> FamilyError:
    return FamilyError(f"options.fusion.{key}", message)


def fusion_setup(scenario: Any) -> DkfeSetup:
    """The dkfe problem of a scenario: sinks = agents 0..N-2, the centre = agent N-1."""
    cached = _SETUPS.get(id(scenario))
    if cached is not None and cached[0] is scenario:
        return cached[1]
    table = dict(scenario.options.get("fusion", {}))
    unknown = sorted(set(table) - set(FUSION_OPTIONS))
    if unknown:
        raise _fusion_error(unknown[0], f"unknown key; allowed: {', '.join(FUSION_OPTIONS)}")
    p = scenario.plant
    L = p.n_sensors - 1
    if L < 1 or p.C[-1].shape[0] != 0:
        raise FamilyError("plant.C", "a fusion scenario's last agent is the centre: give it "
                          "no output (C = []) and at least one sink before it")
    n = p.n_states
    delays = table.get("delays")
    if not (isinstance(delays, list) and len(delays) == L
            and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0
                    for d in delays)):
        raise _fusion_error("delays", f"expected {L} non-negative integers d_i (one per "
                            f"sink), got {delays!r}")
    selections = []
    if "patterns" in table:
        pats = table["patterns"]
        probs = table.get("probabilities")
        if not (isinstance(pats, list) and len(pats) == L and isinstance(probs, list)
                and len(probs) == L):
            raise _fusion_error("patterns", f"expected {L} pattern lists with "
                                f"{L} probability lists")
        for i in range(L):
            try:
                selections.append(SelectionScheme(np.asarray(pats[i], dtype=float),
                                                  np.asarray(probs[i], dtype=float)))
            except (ValueError, TypeError) as exc:
                raise _fusion_error(f"patterns[{i}]", str(exc)) from None
    else:
        comps = table.get("components")
        probs = table.get("probabilities")
        if not (isinstance(comps, list) and len(comps) == L):
            raise _fusion_error("components", f"expected {L} integers r_i, got {comps!r}")
        if not (isinstance(probs, list) and len(probs) == L):
            raise _fusion_error("probabilities", f"expected {L} lists (one per sink)")
        for i in range(L):
            r = comps[i]
            if not (isinstance(r, int) and 1 <= r <= n):
                raise _fusion_error(f"components[{i}]", f"expected 1..{n}, got {r!r}")
            count = math.comb(n, r)
            if not (isinstance(probs[i], list) and len(probs[i]) == count):
                raise _fusion_error(f"probabilities[{i}]", f"expected {count} probabilities "
                                    f"(one per {r}-subset of {n} components)")
            try:
                selections.append(SelectionScheme.all_subsets(n, r, probs[i]))
            except (ValueError, TypeError) as exc:
                raise _fusion_error(f"probabilities[{i}]", str(exc)) from None
    on_missing = table.get("on_missing", "predict")
    if on_missing not in ("predict", "fail"):
        raise _fusion_error("on_missing", f"expected predict or fail, got {on_missing!r}")
    centre = L
    links = set(scenario.links)
    for i, d in enumerate(delays):
        if d >= 1 and (i, centre) not in links:
            raise _fusion_error("delays", f"sink {i} has d_i = {d} but no link {i} -> "
                                f"{centre} (the centre)")
        if d == 0 and (i, centre) in links:
            raise _fusion_error("delays", f"sink {i} has d_i = 0 (read at the same step): "
                                f"remove its link {i} -> {centre}")
    model = scenario.delay_model(0)
    if model.time_invariant and scenario.link_spec is None:
        for i, d in enumerate(delays):
            if d >= 1 and int(model.draw(i, centre, 0)) != d - 1:
                raise _fusion_error("delays", f"sink {i}: d_i = {d} needs the link "
                                    f"{i} -> {centre} to delay by d_i - 1 = {d - 1} steps, "
                                    f"it delays by {int(model.draw(i, centre, 0))}")
    setup = DkfeSetup(
        name=scenario.name, description=scenario.description, A=p.A, Q=p.Q,
        C=tuple(p.C[:L]), R=tuple(p.R[:L]), delays=tuple(delays),
        selections=tuple(selections), x0_mean=p.x0_mean, x0_cov=p.x0_cov)
    covs = covariances_for(setup)
    if len(_SETUPS) > 8:
        _SETUPS.clear()
    _SETUPS[id(scenario)] = (scenario, setup)
    _COVARIANCES[id(setup)] = (setup, covs, on_missing)
    return setup


_SETUPS: dict[int, tuple[Any, DkfeSetup]] = {}
_COVARIANCES: dict[int, tuple[DkfeSetup, Any, str]] = {}
_STEADY: dict[int, tuple[Any, SteadyState, SteadyState]] = {}


def _covariances(setup: DkfeSetup) -> tuple[FusionCovariance, FusionCovariance,
                                            list[LocalGains], str]:
    _, (cov, ocov, gains), on_missing = _COVARIANCES[id(setup)]
    return cov, ocov, gains, on_missing


def _steady(setup: DkfeSetup) -> tuple[SteadyState, SteadyState]:
    cached = _STEADY.get(id(setup))
    if cached is None or cached[0] is not setup:
        cov, ocov, _, _ = _covariances(setup)
        cached = (setup, cov.steady_state(), ocov.steady_state())
        _STEADY[id(setup)] = cached
    return cached[1], cached[2]


def _fusion_agents(output: str) -> Any:
    def build(context: FamilyContext) -> list[AgentPlan]:
        scenario = context.scenario
        setup = fusion_setup(scenario)
        cov, ocov, gains, on_missing = _covariances(setup)
        L = setup.n_sinks
        sinks = [SinkNode(i, setup.A, setup.C[i], gains[i], setup.selections[i],
                          setup.x0_mean, rng=stream(context.trial_seed, "sink", i, "selection"))
                 for i in range(L)]
        if output == "odkfe":  # the paper's benchmark: every selection used at once
            centre = FusionCentre(setup.A, [0] * L, setup.selections, setup.x0_mean, ocov,
                                  direct=dict(enumerate(sinks)), on_missing=on_missing)
            links: list[tuple[int, ...]] = [() for _ in range(L)]
        else:
            steady = _steady(setup)[0].weights if output == "sdkfe" else None
            direct = {i: sinks[i] for i in range(L) if setup.delays[i] == 0}
            centre = FusionCentre(setup.A, setup.delays, setup.selections, setup.x0_mean,
                                  cov, direct=direct, steady_weights=steady, output=output,
                                  on_missing=on_missing)
            links = [(L,) if setup.delays[i] >= 1 else () for i in range(L)]
        plans = [AgentPlan(s, (i,), links[i]) for i, s in enumerate(sinks)]
        plans.append(AgentPlan(centre, (L,), ()))
        return plans

    return build


class _CentreTap(ObserverTap):
    """Forwards the kernel's hooks to ``inner``; collects the centre's compensating
    estimates (K+1, L, n) and its count of missing selections."""

    def __init__(self, centre: FusionCentre, inner: Any) -> None:
        super().__init__(inner)
        self.centre = centre

    def collect(self) -> dict[str, Any]:
        history = self.centre.history["cse"]
        cse = np.stack(history)[:, :, 0] if history else np.zeros((0, self.centre.L,
                                                                   self.centre.n))
        return {"cse": cse, "missed": int(self.centre.missed)}


def _fusion_tap(context: FamilyContext, plans: Sequence[AgentPlan], steps: int,
                inner: Any) -> _CentreTap:
    return _CentreTap(plans[-1].estimator, inner)


def _marks(steps: int) -> list[int]:
    return sorted({0, 1, 2, steps // 10, steps // 4, steps // 2, steps})


def fusion_report(context: FamilyContext, trials: Sequence[Any]) -> dict[str, Any]:
    """Monte Carlo MSE E||x - x-hat||^2 at the paper's marks beside the trace of the exact
    error covariance, for the family's fused estimate, each sink's local filter and
    compensating estimate; the selections that had not arrived when needed."""
    setup = fusion_setup(context.scenario)
    cov, ocov, gains, _ = _covariances(setup)
    L, n = setup.n_sinks, setup.n
    good = [t for t in trials if t.diverged_at is None]
    steps = len(trials[0].states) - 1
    marks = _marks(steps)
    out: dict[str, Any] = {"marks": marks, "diverged_trials": len(trials) - len(good),
                           "missing_selections": sum(t.extras.get("missed", 0)
                                                     for t in trials)}
    if not good:
        return out
    states = np.stack([t.states for t in good])                  # (M, K+1, n)
    estimates = np.stack([t.estimates for t in good])            # (M, K+1, L+1, n)
    family = context.family
    series = {family: estimates[:, :, L]}
    if family != "odkfe":
        for i in range(L):
            series[f"sink {i + 1} local KF"] = estimates[:, :, i]
        if all("cse" in t.extras and len(t.extras["cse"]) for t in good):
            cse = np.stack([t.extras["cse"] for t in good])     # (M, K+1, L, n)
            for i in range(L):
                series[f"CSE {i + 1} (d={setup.delays[i]})"] = cse[:, :, i]
    mse, se = {}, {}
    for name, est in series.items():
        sq = np.sum((states - est) ** 2, axis=-1)                # (M, K+1)
        mse[name] = [float(sq[:, m].mean()) for m in marks]
        se[name] = [float(sq[:, m].std(ddof=1) / math.sqrt(sq.shape[0]))
                    if sq.shape[0] > 1 else None for m in marks]
    exact: dict[str, list[float | None]] = {}
    if family == "dkfe":
        exact[family] = [float(np.trace(cov.at(t).P)) for t in marks]
    elif family == "sdkfe":
        steady = _steady(setup)[0]
        exact[family] = [float(np.trace(cov.fused_covariance(t, steady.weights)))
                         for t in marks]
    else:
        exact[family] = [float(np.trace(ocov.at(t).P)) for t in marks]
    if family != "odkfe":
        for i in range(L):
            exact[f"sink {i + 1} local KF"] = [
                float(np.trace(cov.at(t).P_local[i * n:(i + 1) * n, i * n:(i + 1) * n]))
                for t in marks]
            exact[f"CSE {i + 1} (d={setup.delays[i]})"] = [
                float(np.trace(cov.at(t).Xi_block(i, i))) for t in marks]
    out.update(mse=mse, mse_standard_error=se, exact_trace=exact)
    missed = out["missing_selections"]
    out["summary_lines"] = [
        f"{family}: MSE at t = {marks[-1]}: {mse[family][-1]:.4g} (exact trace "
        f"{exact[family][-1]:.4g})" + (f"; {missed} selections had not arrived when "
                                       "needed (predicted, outside the paper)"
                                       if missed else "")]
    return out


def fusion_analytics(scenario: Any, gains: Any = None) -> dict[str, Any]:
    """The example's stability conditions per sink and the steady state (Theorem 3)."""
    setup = fusion_setup(scenario)
    for i in range(setup.n_sinks):  # each sink's local filter needs a steady state (58)
        C, R = setup.C[i], setup.R[i]
        S = C @ setup.x0_cov @ C.T + R
        if np.linalg.matrix_rank(S) < S.shape[0]:
            raise FamilyError(f"plant.R[{i}]", f"sink {i}'s Kalman filter: the innovation "
                              "covariance C P C^T + R is singular at step 0; give R "
                              "positive definite")
        try:
            with np.errstate(all="ignore"):
                steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i])
        except (ValueError, np.linalg.LinAlgError) as exc:
            R = setup.R[i]
            key = (f"plant.R[{i}]" if np.linalg.matrix_rank(R) < R.shape[0]
                   else f"plant.C[{i}]")
            raise FamilyError(key, f"sink {i}'s local Kalman filter has no steady state "
                              f"(discrete Riccati equation: {exc}); it needs R_{i} "
                              "positive definite and (A, C_i) detectable") from None
    steady, osteady = _steady(setup)
    conds = sink_conditions(setup)
    lines = [f"fusion: L = {setup.n_sinks} sinks, delays d = {list(setup.delays)}, "
             f"components sent r = {[s.r for s in setup.selections]}; steady state "
             f"(Theorem 3) {'converged' if steady.converged else 'NOT converged'} after "
             f"{steady.steps} steps, tr P = {np.trace(steady.P):.4f}, ODKFE tr P_o = "
             f"{np.trace(osteady.P):.4f}"]
    for c in conds:
        lines.append(f"  sink {c['sink']} (d = {c['delay']}): (77) rho = {c['c77_rho']:.4f}; "
                     f"exact mean-square radius {c['second_moment_radius']:.4f}")
    return {
        "summary_lines": lines,
        "example": setup.summary(),
        "steady_state": {
            "converged": steady.converged, "steps": steady.steps,
            "trace_P": float(np.trace(steady.P)), "trace_P_odkfe": float(np.trace(osteady.P)),
            "weights": [np.asarray(w).tolist() for w in steady.weights],
        },
        "conditions": conds,
    }


def _centre(scenario: Any) -> list[int]:
    return [scenario.n_agents - 1]


_DKFE_PAPER = "dkfe paper: compensating estimates (15), fusion (28)/(31)"
for _name, _text in (
    ("dkfe", "fusion centre with the optimal time-varying weights (31)"),
    ("sdkfe", "fusion centre with the steady-state weights (79)-(80)"),
    ("odkfe", "fusion centre without delays (every selection at once), the benchmark"),
):
    register(EstimatorFamily(
        name=_name, build=_fusion_agents(_name), description=_text, paper=_DKFE_PAPER,
        timestamps=True, observer=_fusion_tap, report=fusion_report,
        analytics=fusion_analytics, analytics_key="fusion", reported=_centre,
        source="builtin"))
