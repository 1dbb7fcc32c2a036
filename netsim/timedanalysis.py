"""Exact growth of the timed consensus recursions for fixed offsets and commensurate periods.

Under a ``[time]`` table whose clocks have fixed offsets, no drift and no jitter,
whose sampling periods are commensurate (rational multiples of the base period T),
whose link delays are fixed and whose trigger sends every update, the event sequence
is periodic with the hyperperiod H = lcm(T_i) (true time). The homogeneous part of
the estimator recursion (the plant at rest, x = 0, no noise: what remains of the
error recursion once the forcing by the state is taken out, docs/time.rst) is then a
linear periodic system, and its monodromy map M over one hyperperiod -- from every
agent's estimate, every stored neighbour estimate and every message in flight at a
time t0 to the same slots at t0 + H -- decides its growth: rho(M)^(T/H) per base
period, exactly.

M is computed by running the family's own timed estimators
(:mod:`netsim.estimators.timed`) on coefficient matrices instead of vectors: after a
warm-up, every live slot is replaced by its own block of an identity, and after one
hyperperiod the slots' coefficient blocks are M's rows. On one clock and one grid this
is the augmented closed loop of LCSYS2022 eq. (9) (compensated) or the delay-tolerant
eq. (11) (uncompensated), and the radii agree (tests/test_timed.py).

What the radius leaves out is the forcing by the state, p_ij (Phi(tau) -
Phi(tau + Delta)) x: it vanishes for the compensating estimator on true clocks, and
not otherwise; with it, the error grows at least as fast as the plant's unstable modes.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Any

import numpy as np

from netsim.models.clocks import Clock, sample_times

__all__ = ["LiftedAnalysis", "lifted_analysis", "lifted_summary", "why_not", "MAX_HYPERPERIOD",
           "MAX_SLOTS"]

#: Largest hyperperiod (in base periods) analysed.
MAX_HYPERPERIOD = 200
#: Largest size of the monodromy map.
MAX_SLOTS = 3000


@dataclass(frozen=True)
class LiftedAnalysis:
    """The exact growth of one timed family's homogeneous recursion.

    Attributes
    ----------
    family : str
    hyperperiod : float
        H in base periods.
    size : int
        Dimension of the monodromy map M.
    rho_hyperperiod : float
        rho(M).
    rho_per_period : float
        rho(M)^(T/H): the growth factor per base period.
    forced : bool
        Whether the state forces the error (clock offsets seen by a compensating
        estimator; always for the uncompensated one on a moving state).
    """

    family: str
    hyperperiod: float
    size: int
    rho_hyperperiod: float
    rho_per_period: float
    forced: bool

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return {"family": self.family, "hyperperiod": self.hyperperiod, "size": self.size,
                "rho_hyperperiod": self.rho_hyperperiod,
                "rho_per_period": self.rho_per_period, "forced_by_state": self.forced}


def _hyperperiod(periods: list[float], T: float) -> Fraction | None:
    """lcm of the periods in units of T, or None when they are not commensurate."""
    out = Fraction(0)
    for p in periods:
        f = Fraction(p / T).limit_denominator(1000)
        if abs(float(f) * T - p) > 1e-12 * p:
            return None
        out = f if out == 0 else Fraction(math.lcm(out.numerator, f.numerator),
                                          math.gcd(out.denominator, f.denominator))
    return out


def why_not(scenario: Any, delays: np.ndarray | None) -> str:
    """'' when :func:`lifted_analysis` applies to the scenario, else why not."""
    timing = scenario.timing
    if timing is None:
        return "no [time] table"
    if timing.offset.kind != "fixed":
        return "clock offsets drawn per trial (give them as numbers for the exact radius)"
    if not timing.drift_ppm.zero or any(timing.jitter):
        return "clock drift or read jitter (the event sequence is not periodic)"
    if not timing.trigger.neutral:
        return "a trigger (whether a message is sent depends on the estimates)"
    if timing.sync is not None:
        return "clock synchronisation (the corrections depend on the link delays drawn)"
    if delays is None:
        return "delays not fixed"
    if scenario.topology is not None:
        return "a time-varying topology"
    H = _hyperperiod(list(timing.periods), scenario.sample_period)
    if H is None or H > MAX_HYPERPERIOD:
        return (f"periods not commensurate with T within a hyperperiod of "
                f"{MAX_HYPERPERIOD} T")
    return ""


def lifted_analysis(scenario: Any, gains: Any, delays: np.ndarray, family: str
                    ) -> LiftedAnalysis:
    """The monodromy radius of ``family`` (``compensated`` or ``uncompensated``).

    Parameters
    ----------
    scenario : netsim.models.scenario.Scenario
        With a ``[time]`` table for which :func:`why_not` is ''.
    gains : netsim.estimators.gains.GainDesign
    delays : numpy.ndarray, shape (N, N), int
        Fixed step delays d_ij of link j -> i.

    Raises
    ------
    ValueError
        When the map would exceed :data:`MAX_SLOTS`.
    """
    from netsim.estimators.consensus import ConsensusParameters
    from netsim.estimators.timed import TIMED_CLASSES

    timing = scenario.timing
    T = float(scenario.sample_period)
    model = timing.model
    n = model.n_states
    N = scenario.n_agents
    hyper = _hyperperiod(list(timing.periods), T)
    if hyper is None:
        raise ValueError("the periods are not commensurate with T")
    H = float(hyper) * T
    if family not in TIMED_CLASSES:
        raise ValueError(f"estimator family {family!r} has no timed form "
                         f"(those with one: {', '.join(TIMED_CLASSES)})")
    make = TIMED_CLASSES[family]
    plant, P, graph = scenario.plant, scenario.weights, scenario.graph
    # timed estimators: message stamps are local times (floats)
    agents: list[Any] = [make(ConsensusParameters(agent=i, weights=P[i], A=plant.A, C=plant.C[i],
                                       L=gains.L[i], prior=plant.x0_mean), model)
              for i in range(N)]
    outs = [sorted(graph.successors(i)) for i in range(N)]
    clocks = [Clock(timing.offset.values[i], 0.0, 0.0, timing.periods[i], timing.phases[i])
              for i in range(N)]
    warm = (int(delays.max(initial=0)) + 2) * T + 2 * max(timing.periods) + 2 * H
    horizon = warm + H + 2 * T
    # events in integer ticks (1e-9 T): arrivals meeting samples up to rounding are equal
    def tick(t: float) -> int:
        return round(t / T * 1e9)

    heap: list[tuple[int, int, int, str, Any]] = []
    seq = 0
    for i, clock in enumerate(clocks):
        for t in sample_times(clock, horizon)[0].tolist():
            heapq.heappush(heap, (tick(t), 1, seq, "sample", (i, t)))
            seq += 1
    # the cut t0: halfway between two events after the warm-up
    ticks = sorted({h[0] for h in heap})
    after = [k for k in ticks if k > tick(warm)]
    t0 = (after[0] + after[1]) // 2 if len(after) > 1 else tick(warm)
    t1 = t0 + tick(H)
    last_local: list[float | None] = [None] * N
    in_flight: dict[int, tuple[int, int, int, float, np.ndarray]] = {}  # seq -> message
    D = 0
    snapshot: list[tuple[str, Any]] = []
    zero_y = [np.zeros((C.shape[0], 1)) for C in plant.C]

    def live_slots() -> list[tuple[str, Any]]:
        slots: list[tuple[str, Any]] = [("estimate", i) for i in range(N)]
        for i, a in enumerate(agents):
            slots += [("stored", (i, p)) for p, v in enumerate(a._payloads) if v is not None]
        # in flight by link and send order (the same slots one hyperperiod later)
        flights = sorted(in_flight.items(), key=lambda kv: (kv[1][0], kv[1][1], kv[1][2]))
        slots += [("flight", (k, position)) for position, (k, _) in enumerate(flights)]
        return slots

    def read(slot: tuple[str, Any]) -> np.ndarray:
        kind, where = slot
        if kind == "estimate":
            return np.asarray(agents[where]._estimate)
        if kind == "stored":
            return np.asarray(agents[where[0]]._payloads[where[1]])
        return in_flight[where[0]][4]

    def write(slot: tuple[str, Any], value: np.ndarray) -> None:
        kind, where = slot
        if kind == "estimate":
            agents[where]._estimate = value
        elif kind == "stored":
            agents[where[0]]._payloads[where[1]] = value
        else:
            j, i, s, stamp, _ = in_flight[where[0]]
            in_flight[where[0]] = (j, i, s, stamp, value)

    cut_done = False
    while heap:
        k, _, _, kind, data = heapq.heappop(heap)
        if not cut_done and k > t0:
            # replace every live slot by its own identity block (coefficients w.r.t. t0)
            snapshot = live_slots()
            D = n * len(snapshot)
            if D > MAX_SLOTS:
                raise ValueError(f"the monodromy map would have {D} > {MAX_SLOTS} rows")
            for q, slot in enumerate(snapshot):
                block = np.zeros((n, D))
                block[:, q * n:(q + 1) * n] = np.eye(n)
                write(slot, block)
            zero_y = [np.zeros((C.shape[0], D)) for C in plant.C]
            cut_done = True
        if k > t1:
            break
        if kind == "deliver":
            message_seq = data
            j, i, s, stamp, payload = in_flight.pop(message_seq)
            agents[i].message_arrived(j, stamp, payload)
            continue
        i, t = data
        local = clocks[i].local(t)
        previous = last_local[i]
        elapsed = 0.0 if previous is None else local - previous
        y = zero_y[i] if cut_done else np.zeros(plant.C[i].shape[0])
        estimate = agents[i].step_at(local, y, elapsed, model.transition(elapsed))
        last_local[i] = local
        for r in outs[i]:
            arrive = t + (1 + int(delays[r, i])) * T
            in_flight[seq] = (i, r, k, local, estimate)
            heapq.heappush(heap, (tick(arrive), 0, seq, "deliver", seq))
            seq += 1
    later = live_slots()
    if [s[0] for s in later] != [s[0] for s in snapshot] or len(later) != len(snapshot):
        raise ValueError("the slots one hyperperiod later do not match (not periodic)")
    M = np.vstack([read(slot) for slot in later])
    rho = float(np.max(np.abs(np.linalg.eigvals(M)), initial=0.0))
    forced = not make.compensates or not timing.offset.zero
    return LiftedAnalysis(family, H / T, D, rho, rho ** (T / H), forced)


def lifted_summary(scenario: Any, gains: Any, delays: np.ndarray | None,
                   families: tuple[str, ...] = ("compensated", "uncompensated")
                   ) -> dict[str, Any]:
    """JSON-ready analyses of ``families`` and the lines ``netsim run`` prints."""
    reason = why_not(scenario, delays)
    if reason:
        return {"lifted": None, "lifted_note": f"no exact radius: {reason}; measured"}
    assert delays is not None
    out: dict[str, Any] = {"lifted": {}}
    lines = []
    rho_a = float(np.max(np.abs(np.linalg.eigvals(scenario.plant.A))))
    for family in families:
        try:
            a = lifted_analysis(scenario, gains, delays, family)
        except ValueError as exc:
            out["lifted"][family] = {"error": str(exc)}
            continue
        out["lifted"][family] = a.to_dict()
        forcing = (f"; forced by the state (plant rho(A) = {rho_a:.4g} per T)"
                   if a.forced else "; not forced by the state")
        lines.append(f"exact (fixed offsets, commensurate periods, hyperperiod "
                     f"{a.hyperperiod:g} T): {family} homogeneous recursion rho = "
                     f"{a.rho_per_period:.4f} per T{forcing}")
    out["summary_lines"] = lines
    return out
