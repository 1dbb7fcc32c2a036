"""Replay one trial of a vectorised batch as the event kernel's observer calls.

The vectorised engine (:mod:`netsim.vectorised`) computes a batch of trials without
events, but everything the event kernel reports to its observer (a
:class:`netsim.kernel.KernelObserver`, e.g. the MCAP :class:`netsim.traces.recorder.TraceRecorder`)
follows from what it keeps: the states and measurements, every agent's estimates, the
link schedule (each message's delay, arrival and fate) and the message selection
(which message each receiver held at each step, which ones the freshest rule
discarded). :func:`replay_trial` calls the observer's hooks for one trial in exactly
the order and with the arguments the kernel would use for the same seed, so a trace
written from a vectorised run is the kernel's trace (estimates to round-off).

The kernel's order of events (:mod:`netsim.kernel`, :mod:`netsim.links`): SimPy
processes events by (time, priority, scheduling order). Within time k:

1. deliveries arriving at k that were scheduled before k (URGENT), in scheduling
   order, i.e. by sending step, then sending agent, then its out-links in order
   (``on_delivered``, or ``on_dropped`` for a message superseded on a keep-latest link);
2. the plant: ``on_plant(k, x_k, [y^0_k, ...])``;
3. every agent in order: ``on_update(i, k, estimate, r_ij[k])``, then, if it sends at
   k, per out-link ``on_sent`` and at once ``on_dropped`` for a message the link drops
   at sending (outage, loss, drop-tail) or for the in-flight message drop-oldest
   cancels to make room;
4. deliveries at time k scheduled at k itself (zero latency), in sending order;

then deliveries at non-integer times (continuous latencies) at their own times. A run
that diverged at step k_d stops after the monitor at k_d: nothing after item 4 of k_d.
"""

from __future__ import annotations

import bisect
from typing import Any

import numpy as np

from netsim import interrupt
from netsim.kernel import KernelObserver
from netsim.links import REASON_DROP_OLDEST, REASON_SUPERSEDED, Message
from netsim.linkschedule import DELIVERED
from netsim.models.scenario import Scenario
from netsim.vectorised import VectorisedBatch

__all__ = ["replay_trial", "trial_events"]

# phases of the events at one time (the kernel's order within an instant)
_EARLY = 0  # deliveries scheduled before this instant (URGENT)
_STEP = 1  # plant, agents' updates and sends
_LATE = 2  # deliveries scheduled at this instant (zero latency)


def _neighbours(P: np.ndarray) -> list[list[int]]:
    """In-neighbours j != i with p_ij > 0 of every agent, sorted (the estimators')."""
    return [[int(j) for j in np.flatnonzero(P[i]) if j != i] for i in range(P.shape[0])]


def trial_events(batch: VectorisedBatch, trial: int, scenario: Scenario, family: str
                 ) -> list[tuple[Any, ...]]:
    """Return the kernel's observer calls for one trial, in order.

    Parameters
    ----------
    batch : VectorisedBatch
        From :func:`netsim.vectorised.run_batch` with ``record_estimates=True``.
    trial : int
        Index of the trial in the batch.
    scenario : Scenario
        The scenario the batch ran.
    family : str
        The estimator family the batch ran.

    Returns
    -------
    list of tuple
        ``(hook name, *arguments)`` per call, e.g. ``("on_sent", message)``,
        ``("on_dropped", message, reason, drop_time)``.
    """
    calls: list[tuple[Any, ...]] = []
    _replay(batch, trial, scenario, family,
            lambda name, *args: calls.append((name, *args)), check=False)
    return calls


def replay_trial(batch: VectorisedBatch, trial: int, scenario: Scenario, family: str,
                 observer: KernelObserver) -> None:
    """Call the observer's hooks for one trial as the event kernel would.

    Parameters
    ----------
    batch : VectorisedBatch
        From :func:`netsim.vectorised.run_batch` with ``record_estimates=True``.
    trial : int
        Index of the trial in the batch.
    scenario : Scenario
        The scenario the batch ran.
    family : str
        The estimator family the batch ran.
    observer : KernelObserver
        Receives ``on_plant``, ``on_update``, ``on_sent``, ``on_delivered`` and
        ``on_dropped`` (hooks it lacks are skipped, as the kernel skips ``on_dropped``).

    Notes
    -----
    A graceful Ctrl-C (:mod:`netsim.interrupt`) raises KeyboardInterrupt where the
    kernel's plant process checks for it (at step k, after the deliveries due by k),
    so an interrupted trace also ends at the same event.
    """
    hooks: dict[str, Any] = {}
    for name in ("on_plant", "on_update", "on_sent", "on_delivered", "on_dropped"):
        hooks[name] = getattr(observer, name, None)

    def call(name: str, *args: Any) -> None:
        hook = hooks[name]
        if hook is not None:
            hook(*args)

    _replay(batch, trial, scenario, family, call, check=True)


def _replay(batch: VectorisedBatch, trial: int, scenario: Scenario, family: str,
            call: Any, *, check: bool) -> None:
    result = batch.results[trial]
    estimates = result.estimates
    if estimates.shape[0] == 0:
        raise ValueError("the batch kept no estimates; run it with record_estimates=True")
    states = result.states
    K = states.shape[0] - 1
    end = K if result.diverged_at is None else int(result.diverged_at)
    ys = result.measurements
    ts = float(scenario.sample_period)
    schedule, selection = batch.schedule, batch.selection
    n_agents = estimates.shape[1]
    updated = set(int(k) for k in batch.updated)

    if schedule is None:  # centralised filter: one agent, no links
        for k in range(end + 1):
            if check:
                interrupt.check()
            call("on_plant", k, states[k], [y[k] for y in ys])
            for i in range(n_agents):
                call("on_update", i, k, estimates[k, i], {})
        return

    t = trial
    links = schedule.links
    link_index = {link: q for q, link in enumerate(links)}
    send = schedule.send_steps
    n_sends = int(np.searchsorted(send, end, side="right"))  # messages sent by `end`
    send_list = send[:n_sends].tolist()
    send_at = {s: q for q, s in enumerate(send_list)}
    fate = schedule.fate[t, :, :n_sends]
    arrival = schedule.arrival[t, :, :n_sends]
    wait = schedule.wait_of(t)[:, :n_sends]
    delay_steps = schedule.delay_steps[t, :, :n_sends]
    drop_time = schedule.drop_time[t, :, :n_sends]
    discarded = selection.discarded[t, :, :n_sends]
    chosen = selection.chosen
    reasons = schedule.reasons
    code_oldest = reasons.index(REASON_DROP_OLDEST) + 1 if REASON_DROP_OLDEST in reasons else -1
    code_superseded = (reasons.index(REASON_SUPERSEDED) + 1
                       if REASON_SUPERSEDED in reasons else -1)
    out_links: list[list[int]] = [[] for _ in range(n_agents)]
    for l_, (j, _) in enumerate(links):
        out_links[j].append(l_)
    neighbours = _neighbours(np.asarray(scenario.weights))
    held_links = [[link_index[(j, i)] if (j, i) in link_index else -1 for j in nb]
                  for i, nb in enumerate(neighbours)]

    messages: dict[tuple[int, int], Message] = {}

    def message(l_: int, q: int) -> Message:
        found = messages.get((l_, q))
        if found is None:
            j, i = links[l_]
            s = send_list[q]
            now = float(s)
            found = Message(j, i, s, q, estimates[s, j], now * ts,
                            (now + float(wait[l_, q])) * ts, int(delay_steps[l_, q]))
            messages[(l_, q)] = found
        return found

    # timed link events: deliveries and keep-latest supersessions, at their arrival
    timed: list[tuple[float, int, int, int]] = []
    for l_, q in zip(*np.nonzero(((fate == DELIVERED) | (fate == code_superseded))
                                 & (arrival <= end)), strict=True):
        a = float(arrival[l_, q])
        phase = _LATE if a <= send_list[q] else _EARLY
        timed.append((a, phase, int(q), int(l_)))
    timed.sort()
    # drop-oldest victims, by the (link, step) of the send that cancelled them
    victims: dict[tuple[int, int], int] = {}
    for l_, q in zip(*np.nonzero(fate == code_oldest), strict=True):
        victims[(int(l_), int(drop_time[l_, q]))] = int(q)
    timed_keys = [(a, phase) for a, phase, _, _ in timed]
    position = 0

    def flush_until(key: tuple[float, int]) -> None:
        nonlocal position
        stop = bisect.bisect_left(timed_keys, key, lo=position)
        for a, _, q, l_ in timed[position:stop]:
            m = message(l_, q)
            if fate[l_, q] == DELIVERED:
                call("on_delivered", m, not bool(discarded[l_, q]))
            else:
                call("on_dropped", m, REASON_SUPERSEDED, a * ts)
            del messages[(l_, q)]
        position = stop

    for k in range(end + 1):
        flush_until((float(k), _STEP))
        if check:
            interrupt.check()  # where the kernel's plant process checks: after deliveries
        call("on_plant", k, states[k], [y[k] for y in ys])
        q_now = send_at.get(k)
        update = k in updated
        for i in range(n_agents):
            delays: dict[int, int] = {}
            if update:
                for j, l_ in zip(neighbours[i], held_links[i], strict=True):
                    held = int(chosen[k, l_, t]) if l_ >= 0 and k > 0 else -1
                    delays[j] = k - 1 - int(send[held]) if held >= 0 else -1
            call("on_update", i, k, estimates[k, i], delays)
            if q_now is None:
                continue
            for l_ in out_links[i]:
                m = message(l_, q_now)
                call("on_sent", m)
                code = int(fate[l_, q_now])
                if code not in (DELIVERED, code_superseded, code_oldest):
                    call("on_dropped", m, reasons[code - 1], k * ts)
                    del messages[(l_, q_now)]
                victim = victims.get((l_, k))
                if victim is not None:
                    call("on_dropped", message(l_, victim), REASON_DROP_OLDEST, k * ts)
                    del messages[(l_, victim)]
        flush_until((float(k), _LATE + 1))
