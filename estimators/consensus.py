"""Consensus + innovation estimators for one agent (pure update rules, no kernel).

An estimator object is agent i's update rule. The host (the event kernel, a test,
a vectorised engine) calls :meth:`message_arrived` for every delivered message and
:meth:`step` once per sampling step with the agent's own measurement (optionally
with an array to put the new estimate in, which spares the host a copy), and reads
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

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

__all__ = [
    "NO_MESSAGE",
    "OPERATOR_CACHE_BYTES",
    "ConsensusParameters",
    "CompensatingEstimator",
    "UncompensatedEstimator",
    "BlockUpdateEstimator",
]

#: Bytes of update operators an estimator caches (one operator per pattern of lags
#: seen); once full, an operator is assembled afresh from cached blocks per update.
OPERATOR_CACHE_BYTES = 256 * 1024

#: Effective delay recorded when nothing has arrived from a neighbour yet (agent i
#: then substitutes its own estimate, DESIGN.md).
NO_MESSAGE = -1

_FLOAT64 = np.dtype(np.float64)
# The update's input vector [v_i; x-hat^j...; y] as one byte string of the float64
# vectors, read back as an array: the same values as numpy.concatenate at well under
# half its call overhead on short vectors (a non-contiguous vector raises TypeError
# and takes numpy.concatenate).
_join_bytes = b"".join
_from_bytes = np.frombuffer


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
        self._A = params.A
        self._C = params.C
        self._L = params.L
        # I - L_i C_i, and per neighbour j the blocks (I - L_i C_i) p_ij A^r for
        # r = 0, 1, ... (filled on demand) of the update operators (see _update)
        self._closed_loop = np.eye(params.A.shape[0]) - params.L @ params.C
        # (by neighbour position; every list as long as _lag_blocks)
        self._weighted: list[list[np.ndarray]] = [[] for _ in self.neighbours]
        self._lag_blocks = 0
        # own blocks (I - L_i C_i) (p_ii + silent weights) A^e per (e, silent set;
        # () when every neighbour has been heard from)
        self._own_blocks: dict[tuple[int, tuple[bool, ...]], np.ndarray] = {}
        self._operators: dict[tuple[int, ...], np.ndarray] = {}
        self._operator_room = OPERATOR_CACHE_BYTES
        self._powers: list[np.ndarray] = [np.eye(params.A.shape[0]), params.A]
        self._estimate = np.asarray(params.prior, dtype=float).copy()
        #: Whether every vector of an update is float64 (then read as bytes, see
        #: _join_bytes): estimates are, with real matrices; payloads are converted on
        #: arrival; the measurement is checked per update.
        self._float_inputs = all(np.asarray(M).dtype.kind in "biuf"
                                 for M in (params.A, params.C, params.L))
        # the stored message of each in-neighbour, by its position in neighbours:
        # time-stamp s_j (None: nothing arrived yet) and payload x-hat^j_{s_j|s_j}
        self._position = {j: p for p, j in enumerate(self.neighbours)}
        self._stamps: list[int | None] = [None] * len(self.neighbours)
        self._payloads: list[np.ndarray | None] = [None] * len(self.neighbours)
        self._silent = len(self.neighbours)
        self._started = False
        self.last_step: int | None = None
        self._last_delays: dict[int, int] = {}
        # (exponent, lag k - s_j or NO_MESSAGE per neighbour) of the last update:
        # last_delays is built from it only when someone reads it
        self._used: tuple[int, ...] | None = None
        #: Messages discarded on arrival by the freshest rule.
        self.discarded = 0

    @property
    def last_delays(self) -> dict[int, int]:
        """Effective delay r_ij[k] = k - 1 - s_j used by the last update, per
        in-neighbour j (NO_MESSAGE when i substituted its own estimate)."""
        if self._used is not None:
            lags = self._used[1:]
            self._used = None
            self._last_delays = {
                j: NO_MESSAGE if lag == NO_MESSAGE else lag - 1
                for j, lag in zip(self.neighbours, lags, strict=True)
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
        stored one from the same sender is discarded. A message from an agent that
        is not an in-neighbour (p_ij = 0) is accepted and has no effect.
        """
        position = self._position.get(sender)
        if position is None:
            return True
        current = self._stamps[position]
        if current is None:
            self._silent -= 1
        elif sent_step <= current and self.uses_timestamps:
            self.discarded += 1
            return False
        self._stamps[position] = sent_step
        if getattr(payload, "dtype", None) is not _FLOAT64:
            # the update reads the payloads' bytes as float64: real numbers are
            # converted (as numpy.concatenate would), anything else turns that off
            payload = np.asarray(payload)
            if payload.dtype.kind in "biuf":
                payload = payload.astype(_FLOAT64)
            else:
                self._float_inputs = False
        self._payloads[position] = payload
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

    @staticmethod
    def _written(value: np.ndarray, out: np.ndarray | None) -> np.ndarray:
        """``value`` copied into ``out`` and ``out`` returned, if it is float64 (see step)."""
        if out is None or value.dtype is not _FLOAT64:
            return value
        out[...] = value
        return out

    def _update(self, k: int, y: np.ndarray, exponent: int, own: np.ndarray,
                out: np.ndarray | None = None) -> np.ndarray:
        """Eqs. (4)-(5) of step k >= 1 as one product with a cached operator.

        Agent i's own term is A^e v (``exponent`` e, ``own`` v): A x-hat^i_{k-1|k-1}
        here, A^(tau+1) x-hat^i at the last block step for the block update; the same
        term stands in for a silent neighbour.

        Eq. (4) is x_{k|k-1} = (p_ii + sum of silent p_ij) A^e v_i
        + sum_j p_ij A^(r_j) x-hat^j_{s_j|s_j} (r_j = k - s_j, or 1 without
        compensation), and eq. (5) is x_{k|k} = (I - L_i C_i) x_{k|k-1} + L_i y. So
        x_{k|k} = [G_i, G_j1, ..., L_i] [v_i; x-hat^j1; ...; y] with
        G_j = (I - L_i C_i) p_ij A^(r_j), a linear map fixed by the pattern of lags.
        The operator is cached per pattern, so an update costs one concatenation and
        one matrix-vector product. The value equals the two-stage form (prior, then
        innovation) up to round-off; the vectorised engine computes the two-stage
        form and the differential tests compare them. The product is written into
        ``out`` when given and the inputs are float64 (see :meth:`step`).
        """
        stamps = self._stamps
        if self._silent or not self.compensates:
            lags = [NO_MESSAGE if s is None else k - s for s in stamps]
            used = key = (exponent, *lags)
            if not self.compensates:
                # the lags k - s_j are recorded and checked, but eq. (6) uses A
                self._check_lags(k, lags)
                key = (exponent, *[lag if lag == NO_MESSAGE else 1 for lag in lags])
            vectors = [own, *(v for v in self._payloads if v is not None), y]
        else:
            # every neighbour heard from: the lags k - s_j, straight into the key
            heard = cast("list[int]", stamps)  # no None left (no silent neighbour)
            used = key = (exponent, *[k - s for s in heard])
            vectors = [own, *cast("list[np.ndarray]", self._payloads), y]
        operator = self._operators.get(key)
        if operator is None:
            key_lags = key[1:]
            # a lag k - s_j < 1 is never cached, so checking here catches it (the
            # full check only when some lag is below 1: a silent neighbour's is -1)
            if min(key_lags, default=1) < 1:
                self._check_lags(k, key_lags)
            operator = self._operator(exponent, key_lags)
            if self._operator_room >= operator.nbytes:
                self._operator_room -= operator.nbytes
                self._operators[key] = operator
        self._used = used
        if self._float_inputs and getattr(y, "dtype", None) is _FLOAT64:
            try:
                # numpy's stubs give ndarray the buffer protocol (__buffer__) only for
                # Python >= 3.12; b"".join takes arrays on 3.11 too.
                return operator.dot(_from_bytes(_join_bytes(vectors)),  # type: ignore[arg-type]
                                    out)
            except TypeError:  # a vector that is not contiguous
                pass
        return self._written(operator.dot(np.concatenate(vectors)), out)

    def _check_lags(self, k: int, lags: Sequence[int]) -> None:
        """Fail loudly if a message would be used at or before the step it was sent."""
        if any(lag < 1 for lag in lags if lag != NO_MESSAGE):
            late = max(s for s in self._stamps if s is not None)
            raise RuntimeError(f"agent {self.agent}: a message stamped {late} used at step {k}")

    def _operator(self, exponent: int, lags: Sequence[int]) -> np.ndarray:
        """The stacked operator [G_i, G_j..., L_i] of :meth:`_update`, shape
        (n, n (1 + number of neighbours heard from) + m_i)."""
        deepest = max(lags, default=0)
        weighted = self._weighted
        while self._lag_blocks <= deepest:  # every neighbour's block for one more lag
            r = self._lag_blocks
            power = self._closed_loop.dot(self.power(r))
            for matrices, (_, w) in zip(weighted, self._neighbour_weights, strict=True):
                matrices.append(w * power)
            self._lag_blocks += 1
        if NO_MESSAGE in lags:
            silent = tuple(lag == NO_MESSAGE for lag in lags)
            blocks = [matrices[lag] for matrices, lag in zip(weighted, lags, strict=True)
                      if lag != NO_MESSAGE]
        else:  # every neighbour heard from (the usual case): one C-level map
            silent = ()
            blocks = list(map(list.__getitem__, weighted, lags))
        own = self._own_blocks.get((exponent, silent))
        if own is None:
            # silent weights join p_ii (silent is () when no neighbour is silent)
            own_weight = self._own_weight + sum(
                w for (_, w), quiet in zip(self._neighbour_weights, silent, strict=False)
                if quiet)
            own = self._own_blocks[(exponent, silent)] = self._closed_loop.dot(
                own_weight * self.power(exponent))
        return np.concatenate([own, *blocks, self._L], axis=1)

    def step(self, k: int, y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Run the update of step ``k`` with the measurement y^i_k (shape (m_i,)).

        Parameters
        ----------
        k : int
            The step.
        y : numpy.ndarray, shape (m_i,)
            Agent i's measurement y^i_k.
        out : numpy.ndarray, shape (n,), float64, optional
            Where to put the new estimate (a host's record of it, e.g. the event
            kernel's row of estimates): the same numbers, bit for bit, as without it.
            The estimate returned is then ``out`` itself, which the estimator keeps as
            its estimate and sends, so the host must not write to it again. When the
            numbers are not float64 (complex inputs) a new array is returned and
            ``out`` is left alone.

        Returns
        -------
        numpy.ndarray, shape (n,)
            The new estimate x-hat^i_{k|k}.
        """
        if not self._started:
            self._started = True
            self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
            self._estimate = self._written(self._innovate(self._estimate, y), out)
        else:
            self._estimate = self._update(k, y, 1, self._estimate, out)
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

    def step(self, k: int, y: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Run step ``k``: a full update at block steps, a prediction otherwise.

        ``y`` and ``out`` as in :meth:`_ConsensusBase.step`.
        """
        if not self._started or k % self.period == 0:
            if not self._started:
                self._started = True
                self.last_delays = {j: NO_MESSAGE for j in self.neighbours}
                self._block_estimate = self._written(self._innovate(self._estimate, y), out)
            else:
                # eq. (15): own term A^(tau+1) x-hat^i at the previous block step
                self._block_estimate = self._update(
                    k, y, self.period, self._block_estimate, out)
            self._block_step = k
            self._estimate = self._block_estimate
        else:
            self.last_delays = {}
            self._estimate = self._written(
                self.power(k - self._block_step).dot(self._block_estimate), out)
        self.last_step = k
        return self._estimate

    def outgoing(self, step: int) -> np.ndarray | None:
        """Send only at block steps (the estimate x-hat^i at that block step)."""
        return self._block_estimate if step % self.period == 0 else None


# -- the families this module declares (netsim.estimators.registry) --------------------

from netsim.estimators.registry import (  # noqa: E402  (declared after the classes)
    RECURSION_BLOCK,
    RECURSION_COMPENSATED,
    RECURSION_UNCOMPENSATED,
    AgentPlan,
    EstimatorFamily,
    FamilyContext,
    register,
)


def _consensus_agents(make: type[_ConsensusBase] | None, block: bool = False):
    def build(context: FamilyContext) -> list[AgentPlan]:
        scenario, gains = context.scenario, context.gains
        if gains is None:
            raise ValueError(f"estimator family {context.family!r} needs gains")
        plant, P, graph = scenario.plant, scenario.weights, scenario.graph
        plans = []
        for i in range(scenario.n_agents):
            params = ConsensusParameters(agent=i, weights=P[i], A=plant.A, C=plant.C[i],
                                         L=gains.L[i], prior=plant.x0_mean)
            estimator = (BlockUpdateEstimator(params, scenario.delay_bound)
                         if block or make is None else make(params))
            plans.append(AgentPlan(estimator, (i,), tuple(sorted(graph.successors(i)))))
        return plans

    return build


#: The batched form: the vectorised engine's consensus lockstep (netsim.vectorised).
_LOCKSTEP = "netsim.vectorised:run_vectorised"

for _name, _make, _block, _recursion, _compensate, _stamps, _text, _paper in (
    ("compensated", CompensatingEstimator, False, RECURSION_COMPENSATED, True, True,
     "consensus + innovation with A^(k - s_j) delay compensation",
     "LCSYS2022 eqs. (4)-(5); augmented error recursion eq. (9)"),
    ("uncompensated", UncompensatedEstimator, False, RECURSION_UNCOMPENSATED, False, False,
     "consensus + innovation with A, no time-stamps (most recently arrived)",
     "delay-tolerant paper eqs. (6)-(7); augmented recursion eq. (11)"),
    ("block", None, True, RECURSION_BLOCK, True, True,
     "block update: update and communicate every tau+1 steps with A^(tau+1)",
     "LCSYS2022 eqs. (15)-(16)"),
):
    register(EstimatorFamily(
        name=_name, build=_consensus_agents(_make, block=_block), description=_text,
        paper=_paper, needs_gains=True, timestamps=_stamps, error_recursion=_recursion,
        batched=_LOCKSTEP,
        batched_options={"rule": "consensus", "compensate": _compensate,
                         "timestamps": _stamps, "block": _block},
        source="builtin",
    ))
