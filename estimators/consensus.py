"""Consensus + innovation estimators for one agent (pure update rules, no kernel).

An estimator object is agent i's update rule. The host (the event kernel, a test,
a vectorised engine) calls :meth:`message_arrived` for every delivered message and
:meth:`step` once per sampling step with the agent's own measurement, and reads
:attr:`estimate`, :meth:`outgoing` and :attr:`last_delays`. The time the data
refers to (the message's time-stamp ``sent_step``) is kept apart from the time it
arrived (the order of :meth:`message_arrived` calls).

Implemented update rules (agent i, step k >= 1; step 0 is innovation-only from the
prior x-hat_{0|-1} = x0_mean):

* :class:`CompensatingEstimator` -- LCSYS2022 eqs. (4)-(5), with A^(k - s_j)
  compensation of a neighbour's estimate time-stamped s_j (the augmented form (9):
  a fixed delay r gives A^(r+1)).
* :class:`UncompensatedEstimator` -- delay-tolerant paper eqs. (6)-(7): the same with
  A in place of A^(k - s_j), using the most recently *arrived* message.
* :class:`BlockUpdateEstimator` -- LCSYS2022 eqs. (15)-(16): update and communicate
  every tau+1 steps with A^(tau+1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "NO_MESSAGE",
    "ConsensusParameters",
    "CompensatingEstimator",
    "UncompensatedEstimator",
    "BlockUpdateEstimator",
]

#: Effective delay recorded when nothing has arrived from a neighbour yet (agent i
#: then substitutes its own estimate, DESIGN.md).
NO_MESSAGE = -1


@dataclass(frozen=True)
class ConsensusParameters:
    """What agent i knows: its weights, the plant model, its output and gain.

    Parameters
    ----------
    agent : int
        Index i of this agent.
    weights : numpy.ndarray, shape (N,)
        Row i of the consensus matrix P (p_ii > 0, row-stochastic).
    A : numpy.ndarray, shape (n, n)
        System matrix (known to every agent, Assumption 1).
    C : numpy.ndarray, shape (m_i, n)
        Agent i's output matrix.
    L : numpy.ndarray, shape (n, m_i)
        Innovation gain L_i = K_i C_i^T of eq. (5).
    prior : numpy.ndarray, shape (n,)
        Initial prior x-hat_{0|-1}.
    """

    agent: int
    weights: np.ndarray
    A: np.ndarray
    C: np.ndarray
    L: np.ndarray
    prior: np.ndarray

    @property
    def neighbours(self) -> tuple[int, ...]:
        """In-neighbours j != i with p_ij > 0, sorted."""
        return tuple(int(j) for j in np.flatnonzero(self.weights) if j != self.agent)


class _ConsensusBase:
    """Shared state and innovation step (eq. 5) of the consensus estimators."""

    #: Whether the rule uses time-stamps (freshest = largest time-stamp).
    uses_timestamps = True
    #: Whether a neighbour estimate stamped s is propagated with A^(k - s) (else A).
    compensates = True

    def __init__(self, params: ConsensusParameters) -> None:
        self.params = params
        self.agent = params.agent
        self.neighbours = params.neighbours
        self._weights = params.weights
        # the same float64 weights as plain Python floats (identical products, no
        # numpy scalar indexing in the update loop)
        self._own_weight = float(params.weights[params.agent])
        self._neighbour_weights = tuple((j, float(params.weights[j])) for j in self.neighbours)
        # per neighbour j: p_ij A^r for r = 0, 1, ... (filled on demand), so a neighbour
        # term costs one matrix-vector product
        self._weighted: dict[int, list[np.ndarray]] = {j: [] for j in self.neighbours}
        self._A = params.A
        self._C = params.C
        self._L = params.L
        self._powers: list[np.ndarray] = [np.eye(params.A.shape[0]), params.A]
        self._estimate = np.asarray(params.prior, dtype=float).copy()
        self._stored: dict[int, tuple[int, np.ndarray]] = {}
        self._started = False
        self.last_step: int | None = None
        self._last_delays: dict[int, int] = {}
        # (k, copy of the stored messages) of the last update: last_delays is built
        # from it only when someone reads it
        self._used: tuple[int, dict[int, tuple[int, np.ndarray]]] | None = None
        #: Messages discarded on arrival by the freshest rule.
        self.discarded = 0

    @property
    def last_delays(self) -> dict[int, int]:
        """Effective delay r_ij[k] = k - 1 - s_j used by the last update, per
        in-neighbour j (NO_MESSAGE when i substituted its own estimate)."""
        if self._used is not None:
            k, stored = self._used
            self._used = None
            self._last_delays = {
                j: NO_MESSAGE if j not in stored else k - 1 - stored[j][0]
                for j in self.neighbours
            }
        return self._last_delays

    @last_delays.setter
    def last_delays(self, delays: dict[int, int]) -> None:
        self._used = None
        self._last_delays = delays

    # -- messages -------------------------------------------------------------
    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        """Store a delivered estimate x-hat^j_{s|s}; return False if discarded.

        Freshest rule: with time-stamps, a message older than (or as old as) the
        stored one from the same sender is discarded.
        """
        if self.uses_timestamps:
            current = self._stored.get(sender)
            if current is not None and sent_step <= current[0]:
                self.discarded += 1
                return False
        self._stored[sender] = (sent_step, payload)
        return True

    def outgoing(self, step: int) -> np.ndarray | None:
        """Return the payload to send after the update at ``step`` (None: send nothing)."""
        return self._estimate

    @property
    def estimate(self) -> np.ndarray:
        """Agent i's current estimate x-hat^i_{k|k}, shape (n,)."""
        return self._estimate

    def power(self, exponent: int) -> np.ndarray:
        """Return A^exponent, cached."""
        while len(self._powers) <= exponent:
            self._powers.append(self._A @ self._powers[-1])
        return self._powers[exponent]

    # -- update ---------------------------------------------------------------
    # Matrix-vector products use ndarray.dot: the same BLAS gemv as ``@`` (bit for
    # bit), at well under half of the matmul ufunc's call overhead on tiny arrays.
    def _innovate(self, prior: np.ndarray, y: np.ndarray) -> np.ndarray:
        # eq. (5): x_{k|k} = x_{k|k-1} + K_i C_i^T (y - C_i x_{k|k-1}), K_i C_i^T = L_i
        return prior + self._L.dot(y - self._C.dot(prior))

    def _compensate(self, k: int, sent_step: int, payload: np.ndarray) -> np.ndarray:
        """The neighbour term A^(k - s) x-hat^j_{s|s} (A x-hat^j without compensation)."""
        if not self.compensates:
            return self._A.dot(payload)
        return self.power(k - sent_step).dot(payload)

    def _own_prediction(self) -> np.ndarray:
        """Agent i's own term A x-hat^i_{k-1|k-1} (also substituted for silent neighbours)."""
        return self._A.dot(self._estimate)

    def _prior(self, k: int) -> np.ndarray:
        # p_ii own + sum_j p_ij (compensated neighbour term, or own if j is silent),
        # accumulated in place in neighbour order. A neighbour term is one product with
        # the cached p_ij A^r: (p_ij A^r) x rather than p_ij (A^r x), the same value up
        # to round-off (about one unit in the last place).
        own = self._own_prediction()
        prior = self._own_weight * own
        stored = self._stored
        compensates = self.compensates
        weighted = self._weighted
        for j, w in self._neighbour_weights:
            entry = stored.get(j)
            if entry is None:
                prior += w * own
                continue
            sent_step, payload = entry
            if sent_step >= k:
                raise RuntimeError(
                    f"agent {self.agent}: message from {j} stamped {sent_step} used at step {k}"
                )
            lag = k - sent_step if compensates else 1
            matrices = weighted[j]
            while len(matrices) <= lag:
                matrices.append(w * self.power(len(matrices)))
            prior += matrices[lag].dot(payload)
        self._used = (k, stored.copy())
        return prior

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Run the update of step ``k`` with the measurement y^i_k (shape (m_i,)).

        Returns
        -------
        numpy.ndarray, shape (n,)
            The new estimate x-hat^i_{k|k}.
        """
        if not self._started:
            prior = self._estimate
            self._started = True
            self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
        else:
            prior = self._prior(k)
        self._estimate = self._innovate(prior, y)
        self.last_step = k
        return self._estimate


class CompensatingEstimator(_ConsensusBase):
    """LCSYS2022 eqs. (4)-(5): known, time-stamped delays, A^(k - s) compensation.

    x-hat^i_{k|k-1} = p_ii A x-hat^i_{k-1|k-1} + sum_j p_ij A^(k - s_j) x-hat^j_{s_j|s_j}
    where s_j is the largest time-stamp received from j (freshest rule).
    """

    family = "compensated"
    uses_timestamps = True
    compensates = True


class UncompensatedEstimator(_ConsensusBase):
    """Delay-tolerant paper eqs. (6)-(7): unknown delays, no time-stamps, A only.

    x-hat^i_{k|k-1} = p_ii A x-hat^i_{k-1|k-1} + sum_j p_ij A x-hat^j (most recently
    arrived estimate from j, whatever step it refers to).
    """

    family = "uncompensated"
    uses_timestamps = False
    compensates = False


class BlockUpdateEstimator(_ConsensusBase):
    """LCSYS2022 eqs. (15)-(16): update and communicate every tau+1 steps.

    At steps k = m (tau+1), m >= 1:
    x-hat^i_{k|k-1} = sum_{j in N_i + {i}} p_ij A^(tau+1) x-hat^j_{k-tau-1}, then the
    innovation (16) with y^i_k. Between block steps the estimator makes no update
    and reports its open-loop prediction A^(k - k_m) x-hat^i_{k_m|k_m} (so the MSE
    is comparable step by step). A neighbour estimate that has not arrived by the
    block step (a delay above the bound) is replaced by the freshest one available,
    compensated with A^(k - s), or by i's own estimate if none arrived.

    Parameters
    ----------
    params : ConsensusParameters
    tau : int
        The delay bound tau-bar; the block length is tau + 1.
    """

    family = "block"
    uses_timestamps = True
    compensates = True

    def __init__(self, params: ConsensusParameters, tau: int) -> None:
        super().__init__(params)
        self.tau = int(tau)
        self.period = self.tau + 1
        self._block_estimate = self._estimate
        self._block_step = 0

    def _own_prediction(self) -> np.ndarray:
        """Agent i's own term A^(tau+1) x-hat^i at the previous block step (eq. 15)."""
        return self.power(self.period).dot(self._block_estimate)

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Run step ``k``: a full update at block steps, a prediction otherwise."""
        if not self._started or k % self.period == 0:
            if not self._started:
                prior = self._estimate
                self._started = True
                self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
            else:
                prior = self._prior(k)
            self._block_estimate = self._innovate(prior, y)
            self._block_step = k
            self._estimate = self._block_estimate
        else:
            self.last_delays = {}
            self._estimate = self.power(k - self._block_step).dot(self._block_estimate)
        self.last_step = k
        return self._estimate

    def outgoing(self, step: int) -> np.ndarray | None:
        """Send only at block steps (the estimate x-hat^i at that block step)."""
        return self._block_estimate if step % self.period == 0 else None
