"""Lockstep engine for ``[time]`` scenarios whose sampling instants every trial shares.

The timed event kernel (:mod:`netsim.timedkernel`) is the reference. When the clocks
are deterministic -- offsets and drifts given as numbers (not distributions), no read
jitter -- and no trigger or clock synchronisation makes a trial's messages depend on
its own estimates, every trial samples at the same true instants, on the same clock
readings, and sends after every sample. The timeline of events (reports k T and every
agent's samples) is then one for the whole batch, and all trials advance through it
together: each sample updates a (trials, n) array. What differs between trials is
their plant noise and the fate of their messages (delay, loss), both computed ahead:

* the plant: each trial's standard normals from ``stream(seed_t, "plant")``, laid out
  as the kernel draws them, propagated over the timeline's intervals by the exact
  discretisation (:class:`netsim.models.continuous.ContinuousModel`);
* the links: each sender's messages are its samples m = 0, 1, ...; their delays,
  losses and outages come from :func:`netsim.linkschedule.build_schedule` with
  ``send_steps`` = m (the kernel draws each link's delay with the sample index m), and
  a message sent at the kernel's environment time tau arrives at tau + wait, usable at
  a sample no earlier than that (within the kernel's snapping tolerance);
* the update: the timed estimators' own blocks
  (:meth:`netsim.estimators.timed.TimedCompensatingEstimator.own_block`,
  ``neighbour_block``, ``neighbour_lag``: LCSYS2022 eqs. (4)-(5) with Phi(t - s_j), or
  the delay-tolerant paper's eqs. (6)-(7) with Phi(h_i)), applied per trial to the
  message the receiver holds (freshest time-stamp, or most recently arrived).

What it cannot express runs on the kernel (:func:`lockstep_refusal` says why in one
line): offsets or drifts drawn per trial, read jitter, a trigger that can hold a
message back (a threshold of 0 sends every update: that one runs here), clock
synchronisation, a time-varying topology, a ``[network.medium]``, link buffers, and
families without a built-in timed form.

The products are those of the kernel's single update operator, split per term
(own, each neighbour, innovation) and summed, and the plant is propagated for all
trials with one matrix product per interval: estimates agree with the kernel's to
round-off, not bit for bit (tests/test_timed_lockstep.py holds them to 1e-9
relative). Message counts, drops, discards, divergence steps and effective delays are
the kernel's exactly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from netsim.models.seeding import SeedLike

__all__ = ["lockstep_refusal", "run_timed_lockstep", "TimedTimeline", "timed_timeline"]

#: Values (trials x events x width) one batch of trials holds at most.
BATCH_VALUES = 1 << 23


def lockstep_refusal(scenario: Any, family: Any = None) -> str | None:
    """Why the lockstep engine cannot run a ``[time]`` scenario (one line), or None.

    Parameters
    ----------
    scenario : netsim.models.scenario.Scenario
        A scenario with a ``[time]`` table.
    family : netsim.estimators.registry.EstimatorFamily, optional
        Also check that the family has a built-in timed form.
    """
    timing = scenario.timing
    if timing is None:
        return "the scenario has no [time] table"
    if timing.offset.kind != "fixed":
        return ("time.offset: the vectorised engine needs fixed offsets (a distribution "
                "draws other sampling instants in every trial)")
    if timing.drift_ppm.kind != "fixed":
        return ("time.drift_ppm: the vectorised engine needs fixed drifts (a distribution "
                "draws other sampling instants in every trial)")
    if any(timing.jitter):
        return ("time.jitter: the vectorised engine needs jitter-free clocks (each reading "
                "is drawn per trial)")
    trigger = timing.trigger
    if not (trigger.neutral or (trigger.threshold == 0 and (
            trigger.kind == "send-on-delta" or trigger.every == 1))):  # (0: sends always)
        return (f"time.trigger: the vectorised engine runs without a trigger (a "
                f"{timing.trigger.kind} trigger decides from each trial's estimates, so "
                "the trials send different messages)")
    if timing.sync is not None:
        return ("time.sync: the vectorised engine runs without clock synchronisation (each "
                "trial's exchanges move its clocks by its own delays)")
    if scenario.topology is not None:
        return "topology: the vectorised engine does not model a time-varying [topology]"
    if scenario.medium is not None:
        return ("network.medium: the vectorised engine does not run a [time] scenario over "
                "a medium")
    buffered = _buffered_link(scenario)
    if buffered is not None:
        return (f"links: link {buffered[0]}->{buffered[1]} has a buffer; the vectorised "
                "engine runs [time] scenarios on links without one")
    if family is not None:
        from netsim.estimators.timed import TIMED_FORMS

        if family.source != "builtin" or family.name not in TIMED_FORMS:
            return (f"estimator family {family.name!r}: the vectorised engine runs the "
                    f"timed forms of {', '.join(sorted(TIMED_FORMS))} only")
    return None


def _buffered_link(scenario: Any) -> tuple[int, int] | None:
    """The first link whose model has a buffer (capacity or keep-latest), or None."""
    from netsim.links import resolve_link
    from netsim.models.seeding import child_sequence

    model = scenario.delay_model(child_sequence(0, "probe"))
    for j, i in scenario.links:
        _, link = resolve_link(model, int(j), int(i))
        if link is not None and (link.buffer_capacity is not None
                                 or link.buffer_policy == "keep-latest"):
            return int(j), int(i)
    return None


@dataclass
class TimedTimeline:
    """The events every trial shares (the kernel's timeline).

    Attributes
    ----------
    tau : numpy.ndarray, shape (E,)
        Event instants in base periods (snapped as the kernel snaps them).
    now : list of float, length E
        The kernel's environment time at each event (sums of SimPy timeouts).
    sampling : list of list of int, length E
        Agents sampling at each event, in agent order.
    report : list of int or None, length E
        The report step k of each event, or None.
    report_rows : numpy.ndarray, shape (K+1,)
        Event of each report step.
    sample_events : list of numpy.ndarray, each (M_i,)
        Events of agent i's samples.
    local : list of numpy.ndarray, each (M_i,)
        Agent i's clock reading at each sample (the stamp on what it sends).
    """

    tau: np.ndarray
    now: list[float]
    sampling: list[list[int]]
    report: list[int | None]
    report_rows: np.ndarray
    sample_events: list[np.ndarray]
    local: list[np.ndarray]

    def limit(self, e: int) -> float:
        """The latest arrival time handed over before event e's samples."""
        from netsim.timedkernel import _SNAP  # the kernel's calendar tolerance

        now = self.now[e]
        return now + _SNAP * max(1.0, abs(now))


def timed_timeline(clocks: Sequence[Any], steps: int, period: float) -> TimedTimeline:
    """The timeline of :class:`netsim.timedkernel.TimedSimulation` for these clocks.

    Parameters
    ----------
    clocks : sequence of netsim.models.clocks.Clock
        One per agent (jitter-free).
    steps : int
        K: reports at 0, T, ..., K T.
    period : float
        T.
    """
    from netsim.models.clocks import sample_times
    from netsim.timedkernel import _env_times  # the kernel's own snapping, not a copy

    horizon = steps * period
    sampling = [_env_times(sample_times(clock, horizon)[0], period) for clock in clocks]
    report = np.arange(steps + 1, dtype=float)
    timeline = np.unique(np.concatenate([report, *sampling]))
    timeline = timeline[(timeline >= 0) & (timeline <= steps)]
    index = {tau: e for e, tau in enumerate(timeline.tolist())}
    at: list[list[int]] = [[] for _ in timeline]
    sample_events = []
    for i, times in enumerate(sampling):
        events = [index[tau] for tau in times.tolist() if tau in index]
        for e in events:
            at[e].append(i)
        sample_events.append(np.array(events, dtype=np.int64))
    reports: list[int | None] = [None] * len(timeline)
    rows = np.searchsorted(timeline, report)
    for k, e in enumerate(rows.tolist()):
        reports[e] = k
    # the environment's clock: each event a timeout of (tau - now) from the last one
    now = [0.0] * len(timeline)
    current = 0.0
    for e, tau in enumerate(timeline.tolist()):
        if tau > current:
            current = current + (tau - current)
        now[e] = current
    local = [np.array([clock.read(float(timeline[e]) * period, None) + 0.0
                       for e in events.tolist()], dtype=float)
             for clock, events in zip(clocks, sample_events, strict=True)]
    return TimedTimeline(timeline, now, at, reports, rows, sample_events, local)


def _simulate_plant(plant: Any, model: Any, seeds: Sequence[SeedLike], timeline: np.ndarray,
                    period: float) -> tuple[np.ndarray, np.ndarray]:
    """States (T, E, n) and stacked measurements (T, E, M) of the trials at the events.

    The kernel's draws (:meth:`netsim.models.plant.LinearPlant.standard_noise`, one row
    per event) and propagation (the plant's own :meth:`simulate` on the base grid, else
    Phi(h) and the factor of Q_d(h) per interval), for all trials at once.
    """
    from netsim.models.plant import _factor
    from netsim.models.seeding import stream

    E = len(timeline)
    noise = np.stack([plant.standard_noise(stream(seed, "plant"), E - 1) for seed in seeds])
    intervals = np.diff(timeline)
    if E == 1 or (np.all(intervals == 1.0) and timeline[0] == 0.0):
        trajectory = plant.simulate(np.ascontiguousarray(noise.transpose(1, 0, 2)))
        return (trajectory.states.transpose(1, 0, 2).copy(),
                trajectory.measurements.transpose(1, 0, 2).copy())
    n = plant.n_states
    states = np.empty((len(seeds), E, n))
    states[:, 0] = plant.x0_mean + noise[:, 0, :n] @ _factor(plant.x0_cov).T
    factors: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    with np.errstate(over="ignore", invalid="ignore"):
        for e in range(1, E):
            h = float(intervals[e - 1]) * period
            pair = factors.get(h)
            if pair is None:
                pair = factors[h] = (model.transition(h).T.copy(),
                                     _factor(model.noise(h)).T.copy())
            states[:, e] = states[:, e - 1] @ pair[0] + noise[:, e, :n] @ pair[1]
        C = plant.C_stacked
        _, factor, diagonal, _ = plant._stacked_measurement
        z = noise[:, :, n:]
        measurements = states @ C.T + (z * factor if diagonal else z @ factor.T)
    return states, measurements


@dataclass
class _LinkPlan:
    """One link's messages in a batch: arrivals, fates, and what the receiver holds."""

    sender: int
    receiver: int
    send_events: np.ndarray  # (M_j,)
    arrival: np.ndarray  # (T, M_j) environment time
    delivered: np.ndarray  # (T, M_j) bool: not dropped
    fate: np.ndarray  # (T, M_j) int: 0 or 1 + reason code
    reasons: list[str]


def _links(scenario: Any, seeds: Sequence[SeedLike], line: TimedTimeline,
           out_neighbours: Sequence[Sequence[int]]) -> list[_LinkPlan]:
    """Every link's messages, by sender then receiver (the kernel's link order)."""
    from netsim.linkschedule import DELIVERED, build_schedule

    models = [scenario.delay_model(seed) for seed in seeds]
    now = np.array(line.now)
    plans = []
    for j, receivers in enumerate(out_neighbours):
        if not receivers:
            continue
        events = line.sample_events[j]
        links = [(j, int(i)) for i in receivers]
        schedule = build_schedule(models, links, np.arange(len(events)),
                                  sample_period=scenario.sample_period)
        send_now = now[events]
        for l_, (_, i) in enumerate(links):
            wait = (schedule.delay_steps[:, l_] + 1.0 if schedule.wait is None
                    else schedule.wait[:, l_])
            fate = np.asarray(schedule.fate[:, l_])
            plans.append(_LinkPlan(j, i, events, send_now[None, :] + wait,
                                   fate == DELIVERED, fate, list(schedule.reasons)))
    return plans


def _held(link: _LinkPlan, line: TimedTimeline, receiver_events: np.ndarray,
          timestamps: bool) -> np.ndarray:
    """The message index q the receiver holds at each of its samples, shape (R, T)
    (-1: nothing yet): the largest time-stamp delivered (``timestamps``) or the most
    recently arrived. A message is there at a sample when it was sent at an earlier
    event and arrived by the sample's hand-over limit (:meth:`TimedTimeline.limit`)."""
    T, M = link.arrival.shape
    R = len(receiver_events)
    limits = np.array([line.limit(int(e)) for e in receiver_events.tolist()])
    first = np.maximum(np.searchsorted(limits, link.arrival, side="left"),
                       np.searchsorted(receiver_events, link.send_events, side="right")[None])
    first = np.where(link.delivered, first, R)
    q = np.broadcast_to(np.arange(M), (T, M))
    if timestamps:
        value = q
    else:  # rank in arrival order (time, then sending order)
        order = np.lexsort((q, link.arrival), axis=-1)
        value = np.empty_like(order)
        np.put_along_axis(value, order, np.arange(M)[None].repeat(T, 0), axis=-1)
    best = np.full((T, R + 1), -1, dtype=np.int64)
    rows = np.broadcast_to(np.arange(T)[:, None], (T, M))
    np.maximum.at(best, (rows, first), value)
    best = np.maximum.accumulate(best, axis=1)[:, :R]
    if not timestamps:
        best = np.where(best >= 0, np.take_along_axis(order, np.maximum(best, 0), axis=1), -1)
    return best.T.copy()


def _counts(link: _LinkPlan, end_now: np.ndarray, end_limit: np.ndarray,
            end_event: np.ndarray, discards: bool) -> tuple[np.ndarray, ...]:
    """Per trial: sent, delivered, dropped, discarded (freshest rule) by the trial's end,
    and the dropped mask (T, M). Delivered by the end: arrived by its instant, or
    pending then and handed over early before its samples (``end_limit``)."""
    sent_mask = link.send_events[None, :] <= end_event[:, None]
    early = (link.arrival <= end_limit[:, None]) & (
        link.send_events[None, :] < end_event[:, None])
    arrived = link.delivered & ((link.arrival <= end_now[:, None]) | early)
    dropped = ~link.delivered & sent_mask
    discarded = np.zeros(len(end_event), dtype=np.int64)
    if discards:
        T, M = link.arrival.shape
        q = np.broadcast_to(np.arange(M), (T, M))
        order = np.lexsort((q, np.where(link.delivered, link.arrival, np.inf)), axis=-1)
        in_order = np.take_along_axis(np.where(link.delivered, q, -1), order, axis=-1)
        before = np.maximum.accumulate(in_order, axis=-1)
        before = np.concatenate([np.full((T, 1), -1), before[:, :-1]], axis=1)
        stale = np.zeros((T, M), dtype=bool)
        np.put_along_axis(stale, order, (in_order >= 0) & (in_order < before), axis=-1)
        discarded = np.count_nonzero(stale & arrived, axis=1)
    return (np.count_nonzero(sent_mask, axis=1), np.count_nonzero(arrived, axis=1),
            np.count_nonzero(dropped, axis=1), discarded, dropped)


def run_timed_lockstep(
    scenario: Any,
    family: str,
    gains: Any,
    trial_seeds: Sequence[SeedLike],
    steps: int | None = None,
    *,
    record_delays: bool | Collection[int] = False,
    record_estimates: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[Any]:
    """Run trials of a ``[time]`` scenario in lockstep; one TrialResult per trial.

    Parameters
    ----------
    scenario : netsim.models.scenario.Scenario
        A scenario :func:`lockstep_refusal` accepts.
    family : str
        ``compensated`` or ``uncompensated`` (their timed forms).
    gains : netsim.estimators.gains.GainDesign
        Innovation gains L_i.
    trial_seeds : sequence of seed-like, length T
        Trial t's seed, as :func:`netsim.runner.run_trial` takes it.
    steps : int, optional
        Last report step K (default: the scenario's).
    record_delays : bool or collection of int
        Effective delays (K+1, N, N) and drop records of every trial or of the listed.
    record_estimates : bool
        Fill ``TrialResult.estimates`` (K+1, N, n); otherwise shape (0, N, n).
    progress : callable(int), optional
        Called with the batch size after each batch.

    Returns
    -------
    list of netsim.kernel.TrialResult
        As :func:`netsim.timedkernel.run_timed_trial` returns them (``messages``
        empty), with ``extras["timing"]``.
    """
    from netsim.estimators.timed import TIMED_FORMS
    from netsim.timedkernel import MAX_EVENTS

    why = lockstep_refusal(scenario)
    if why is not None:
        raise ValueError(why)
    if family not in TIMED_FORMS:
        raise ValueError(f"estimator family {family!r} has no timed lockstep form")
    if gains is None:
        raise ValueError(f"estimator family {family!r} needs gains")
    K = scenario.steps if steps is None else int(steps)
    timing = scenario.timing
    events = (K + 1) + sum(1.1 * K * scenario.sample_period / p + 1 for p in timing.periods)
    if events > MAX_EVENTS:
        raise ValueError(f"time.periods: {events:.3g} sampling events over {K} steps "
                         f"exceed {MAX_EVENTS:.0e} (longer periods or fewer steps)")
    seeds = list(trial_seeds)
    if not seeds:
        return []
    clocks = timing.clocks(seeds[0])
    line = timed_timeline(clocks, K, scenario.sample_period)
    plant = scenario.plant
    width = plant.noise_width + plant.n_states * (1 + scenario.n_agents)
    per = max(1, BATCH_VALUES // (len(line.tau) * width))
    wanted = set(range(len(seeds))) if record_delays is True else set(record_delays or ())
    results: list[Any] = []
    for start in range(0, len(seeds), per):
        chunk = seeds[start:start + per]
        results += _run_batch(scenario, family, gains, chunk, K, line, clocks,
                              {t - start for t in wanted if start <= t < start + len(chunk)},
                              record_estimates)
        if progress is not None:
            progress(len(chunk))
    return results


def _run_batch(scenario: Any, family: str, gains: Any, seeds: Sequence[SeedLike], K: int,
               line: TimedTimeline, clocks: Sequence[Any], wanted: set[int],
               record_estimates: bool) -> list[Any]:
    """One batch of trials (see :func:`run_timed_lockstep`)."""
    from netsim import interrupt
    from netsim.estimators.consensus import NO_MESSAGE
    from netsim.estimators.registry import FamilyContext
    from netsim.estimators.timed import TIMED_FORMS
    from netsim.kernel import NOT_USED, ROUNDOFF_RELATIVE_ERROR, TrialResult, squared_threshold
    from netsim.models.continuous import ContinuousModel
    from netsim.timedkernel import SampleRecord

    T = len(seeds)
    N = scenario.n_agents
    period = scenario.sample_period
    plant = scenario.plant
    n = plant.n_states
    model = scenario.timing.model
    if not (np.array_equal(model.A, plant.A) and np.array_equal(model.Q, plant.Q)):
        model = ContinuousModel.from_discrete(plant.A, plant.Q, period)
    plans = TIMED_FORMS[family](FamilyContext(scenario, gains, seeds[0], family))
    agents = [plan.estimator for plan in plans]
    timestamps = bool(agents[0].uses_timestamps) if agents else True
    slices = plant.sensor_slices
    columns = [np.concatenate([np.arange(slices[s].start, slices[s].stop)
                               for s in plan.sensors]).astype(np.int64)
               if len(plan.sensors) else np.zeros(0, dtype=np.int64) for plan in plans]
    states, measurements = _simulate_plant(plant, model, seeds, line.tau, period)
    links = _links(scenario, seeds, line, [plan.out_neighbours for plan in plans])
    # what each receiver holds from each of its neighbours (by position), per sample
    held: list[list[np.ndarray | None]] = []
    depth = [1] * N
    by_pair = {(link.sender, link.receiver): link for link in links}
    for i, est in enumerate(agents):
        row: list[np.ndarray | None] = []
        for j in est.neighbours:
            link = by_pair.get((j, i))
            if link is None:
                row.append(None)
                continue
            h = _held(link, line, line.sample_events[i], timestamps)
            # j's samples up to each of i's (at the same event too: j may have written
            # its slot already); the ring must reach back from there to h
            latest = np.searchsorted(line.sample_events[j], line.sample_events[i],
                                     side="right") - 1
            age = np.where(h >= 0, latest[:, None] - h, 0)
            depth[j] = max(depth[j], int(age.max(initial=0)) + 1)
            row.append(h)
        held.append(row)
    history = [np.zeros((depth[j], T, n)) for j in range(N)]
    x = [np.broadcast_to(np.asarray(est.estimate, dtype=float), (T, n)).copy()
         for est in agents]
    previous: list[float | None] = [None] * N
    count = [0] * N
    own_cache: dict[tuple[int, float, int], np.ndarray] = {}
    threshold_sq = squared_threshold(scenario.divergence_threshold)
    diverged = np.full(T, -1, dtype=np.int64)
    live = np.ones(T, dtype=bool)
    sq = np.full((T, K + 1, N), np.nan)
    estimates = np.full((T, K + 1, N, n), np.nan) if record_estimates else None
    report_states = states[:, line.report_rows]
    estimate_now = np.empty((T, N, n))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for e in range(len(line.tau)):
            interrupt.check()
            t_true = float(line.tau[e]) * period
            sampled = line.sampling[e]
            for i in sampled:
                est = agents[i]
                r = count[i]
                local = float(line.local[i][r])
                y = measurements[:, e, columns[i]]
                if r == 0:
                    prior = x[i]
                    x[i] = prior + (y - prior @ est.params.C.T) @ est.params.L.T
                else:
                    elapsed = local - previous[i]  # type: ignore[operator]
                    x[i] = _update(est, i, r, local, elapsed, model.transition(elapsed),
                                   x[i], y, held[i], history, line, own_cache)
                previous[i] = local
                history[i][r % depth[i]] = x[i]
                count[i] = r + 1
            k = line.report[e]
            if k is None:
                continue
            for i in range(N):
                if i in sampled or previous[i] is None:
                    estimate_now[:, i] = x[i]
                else:
                    ahead = clocks[i].local(t_true) + 0.0 - previous[i]
                    estimate_now[:, i] = x[i] @ model.transition(ahead).T
            if estimates is not None:
                estimates[:, k] = estimate_now
            difference = estimate_now - report_states[:, k, None, :]
            per_agent = np.einsum("tij,tij->ti", difference, difference)
            sq[:, k] = per_agent
            total = per_agent.sum(axis=1)
            test = live & ~(total < threshold_sq)
            if test.any():
                worst = per_agent.max(axis=1, initial=0.0)
                xx = np.einsum("ti,ti->t", report_states[:, k], report_states[:, k])
                bad = test & ((worst == math.inf) | ~(
                    (worst <= threshold_sq) | (worst <= ROUNDOFF_RELATIVE_ERROR**2 * xx)))
                diverged[bad] = k
                live &= ~bad
                if not live.any():
                    break
    # per trial: the last report and its event
    ends = np.where(diverged >= 0, diverged, K)
    end_events = line.report_rows[ends]
    end_now = np.array([line.now[int(e)] for e in end_events.tolist()])
    end_limits = np.array([line.limit(int(e)) if line.sampling[int(e)] else line.now[int(e)]
                           for e in end_events.tolist()])
    sent = np.zeros(T, dtype=np.int64)
    delivered = np.zeros(T, dtype=np.int64)
    dropped = np.zeros(T, dtype=np.int64)
    discarded = np.zeros(T, dtype=np.int64)
    reasons: list[dict[str, int]] = [{} for _ in range(T)]
    # per trial: (event, sender, receiver, sample index, drop time, reason)
    drops: list[list[tuple[int, int, int, int, float, str]]] = [[] for _ in range(T)]
    for link in links:
        neighbour = link.sender in agents[link.receiver].neighbours
        s, d, lost, stale, lost_mask = _counts(link, end_now, end_limits, end_events,
                                              timestamps and neighbour)
        sent += s
        delivered += d
        dropped += lost
        discarded += stale
        if link.reasons and lost.any():
            for t in np.flatnonzero(lost).tolist():
                codes = np.bincount(link.fate[t][lost_mask[t]],
                                    minlength=len(link.reasons) + 1)
                for reason, c in zip(link.reasons, codes[1:].tolist(), strict=True):
                    if c:
                        reasons[t][reason] = reasons[t].get(reason, 0) + c
                if t in wanted:
                    for q in np.flatnonzero(lost_mask[t]).tolist():
                        e = int(link.send_events[q])
                        drops[t].append((e, link.sender, link.receiver, q, line.now[e],
                                         link.reasons[int(link.fate[t, q]) - 1]))
    # the samples of the run, in the kernel's order (by event, then agent)
    order = sorted((int(e), i, m) for i in range(N)
                   for m, e in enumerate(line.sample_events[i].tolist()))
    sample_event = np.array([e for e, _, _ in order], dtype=np.int64)
    sample_agent = np.array([i for _, i, _ in order], dtype=np.int64)
    sample_index = np.array([m for _, _, m in order], dtype=np.int64)
    sample_true = line.tau[sample_event] * period if order else np.zeros(0)
    sample_local = np.array([line.local[i][m] for _, i, m in order], dtype=float)
    clock_list = [{"offset": c.offset, "drift_ppm": c.drift_ppm, "jitter": c.jitter,
                   "period": c.period, "phase": c.phase} for c in clocks]
    report_meas = measurements[:, line.report_rows]
    results = []
    for t in range(T):
        last = int(ends[t])
        st = report_states[t].copy()
        meas = report_meas[t].copy()
        st[last + 1:] = np.nan
        meas[last + 1:] = np.nan
        errors = sq[t].copy()
        errors[last + 1:] = np.nan
        if diverged[t] >= 0:
            errors[last] = np.where(np.isfinite(errors[last]), errors[last], np.inf)
        if estimates is not None:
            mine = estimates[t].copy()
            mine[last + 1:] = np.nan
        else:
            mine = np.zeros((0, N, n))
        samples = int(np.searchsorted(sample_event, end_events[t], side="right"))
        record = SampleRecord(sample_agent[:samples].copy(), sample_index[:samples].copy(),
                              sample_true[:samples].copy(), sample_local[:samples].copy(),
                              np.ones(samples, dtype=bool))
        duration = last * period
        timing = {
            "samples": samples, "broadcasts": samples, "messages_sent": int(sent[t]),
            "duration": duration,
            "message_rate": samples / (N * duration) if duration > 0 else math.nan,
            "send_fraction": 1.0 if samples else math.nan,
            "clocks": [dict(c) for c in clock_list], "sample_record": record,
        }
        delays = None
        dropped_list: list[tuple[int, int, int, float, str]] | None = None
        if t in wanted:
            delays = _effective_delays(agents, held, line, t, last, K, period, NOT_USED,
                                       NO_MESSAGE)
            dropped_list = [(j, i, q, when, why)
                            for _, j, i, q, when, why in sorted(drops[t])]
        results.append(TrialResult(
            states=st, measurements=[meas[:, rows] for rows in slices], estimates=mine,
            squared_errors=errors, effective_delays=delays,
            diverged_at=last if diverged[t] >= 0 else None,
            messages_sent=int(sent[t]), messages_delivered=int(delivered[t]),
            messages_dropped=int(dropped[t]), messages_discarded=int(discarded[t]),
            messages=[], drop_reasons=reasons[t], drops=dropped_list,
            extras={"timing": timing}))
    return results


def _update(est: Any, i: int, r: int, local: float, elapsed: float, transition: np.ndarray,
            x: np.ndarray, y: np.ndarray, held: Sequence[np.ndarray | None],
            history: Sequence[np.ndarray], line: TimedTimeline,
            own_cache: dict[tuple[int, float, int], np.ndarray]) -> np.ndarray:
    """Agent i's update at its sample r for every trial, shape (T, n): the timed
    estimator's operator [G_i, G_j..., L_i] applied term by term to the messages each
    trial holds (:meth:`netsim.estimators.timed.TimedCompensatingEstimator.step_at`)."""
    T = x.shape[0]
    neighbours = est.neighbours
    now = [None if h is None else h[r] for h in held]
    silent = np.zeros(T, dtype=np.int64)
    for p, q in enumerate(now):
        if q is None:
            silent |= 1 << p
        else:
            silent |= (q < 0).astype(np.int64) << p
    codes = np.unique(silent)
    out = np.empty_like(x)
    for code in codes.tolist():
        key = (i, elapsed, code)
        block = own_cache.get(key)
        if block is None:
            block = est.own_block(tuple(bool(code >> p & 1) for p in range(len(neighbours))),
                                  transition).T.copy()
            if len(own_cache) < 4096:
                own_cache[key] = block
        if len(codes) == 1:
            np.matmul(x, block, out=out)
        else:
            rows = silent == code
            out[rows] = x[rows] @ block
    for p, q in enumerate(now):
        if q is None:
            continue
        rows = np.flatnonzero(q >= 0)
        if not len(rows):
            continue
        j = neighbours[p]
        ring = history[j]
        qs = q[rows]
        payload = ring[qs % len(ring), rows]
        stamps = line.local[j][qs]
        lags = est.neighbour_lag(local, elapsed, stamps)
        if np.ndim(lags) == 0:
            out[rows] += payload @ est.neighbour_block(p, float(lags)).T
            continue
        unique, inverse = np.unique(lags, return_inverse=True)
        if len(unique) == 1:
            out[rows] += payload @ est.neighbour_block(p, float(unique[0])).T
            continue
        blocks = np.stack([est.neighbour_block(p, float(u)) for u in unique.tolist()])
        out[rows] += np.matmul(blocks[inverse], payload[:, :, None])[:, :, 0]
    out += y @ est.params.L.T
    return out


def _effective_delays(agents: Sequence[Any], held: Sequence[Sequence[np.ndarray | None]],
                      line: TimedTimeline, t: int, last: int, K: int, period: float,
                      not_used: int, no_message: int) -> np.ndarray:
    """Trial t's r_ij at each report instant where agent i sampled, shape (K+1, N, N):
    round((t_i - s_j) / T) - 1 of the message used, NO_MESSAGE when none (the
    kernel's ``last_delays``)."""
    N = len(agents)
    out = np.full((K + 1, N, N), not_used, dtype=np.int32)
    for i, est in enumerate(agents):
        for r, e in enumerate(line.sample_events[i].tolist()):
            k = line.report[e]
            if k is None or k > last:
                continue
            local = float(line.local[i][r])
            for p, j in enumerate(est.neighbours):
                h = held[i][p]
                q = -1 if h is None or r == 0 else int(h[r, t])
                out[k, i, j] = no_message if q < 0 else round(
                    (local - float(line.local[j][q])) / period) - 1
    return out
