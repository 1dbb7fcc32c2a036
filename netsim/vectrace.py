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

__all__ = ["replay_trial", "trial_events", "write_trial", "write_trial_steps"]

# phases of the events at one time (the kernel's order within an instant)
_EARLY = 0  # deliveries scheduled before this instant (URGENT)
_STEP = 1  # plant, agents' updates and sends
_LATE = 2  # deliveries scheduled at this instant (zero latency)


def _neighbours(P: Any) -> list[list[int]]:
    """In-neighbours j != i with p_ij != 0 of every agent, sorted (the estimators');
    ``P`` dense (N, N) or scipy sparse (the weights of large networks)."""
    if hasattr(P, "tocsr"):
        csr = P.tocsr()
        csr.sort_indices()
        return [[int(j) for j, w in zip(csr.indices[csr.indptr[i]:csr.indptr[i + 1]],
                                        csr.data[csr.indptr[i]:csr.indptr[i + 1]],
                                        strict=True) if j != i and w != 0]
                for i in range(csr.shape[0])]
    rows, cols = np.nonzero(np.asarray(P))  # row major: rows, then columns, increasing
    off = rows != cols
    bounds = np.searchsorted(rows[off], np.arange(P.shape[0] + 1))
    cols = cols[off].tolist()
    return [cols[bounds[i]:bounds[i + 1]] for i in range(P.shape[0])]


def _traced_result(batch: VectorisedBatch, trial: int) -> tuple[Any, int]:
    """A trial's result and its last step (K, or the step it diverged at); refused if
    the batch kept no estimates."""
    result = batch.results[trial]
    if result.estimates.shape[0] == 0:
        raise ValueError("the batch kept no estimates; run it with record_estimates=True")
    K = result.states.shape[0] - 1
    return result, K if result.diverged_at is None else int(result.diverged_at)


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
    result, end = _traced_result(batch, trial)
    estimates, states = result.estimates, result.states
    ys = result.measurements
    ts = float(scenario.sample_period)
    schedule, selection = batch.schedule, batch.selection
    n_agents = estimates.shape[1]
    updated = set(int(k) for k in batch.updated)

    if schedule is None or selection is None:  # centralised filter: one agent, no links
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
    neighbours = _neighbours(scenario.weights)
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


# -- bulk trace writing -----------------------------------------------------------------

_ENCODERS: dict[tuple[str, tuple[tuple[str, int], ...]], Any] = {}


def _encoder(type_name: str, lengths: dict[str, int]) -> Any:
    from netsim.traces.bulkproto import BulkEncoder
    from netsim.traces.schemas import message_classes

    key = (type_name, tuple(sorted(lengths.items())))
    found = _ENCODERS.get(key)
    if found is None:
        found = _ENCODERS[key] = BulkEncoder(message_classes()[type_name].DESCRIPTOR, lengths)
    return found


class _Group:
    """Messages of one type and one payload length, in their topics' order (``when``
    non-decreasing); encoded when written."""

    __slots__ = ("type_name", "topics", "topic", "when", "log_time", "publish_time",
                 "sequence", "columns", "lengths")

    def __init__(self, type_name: str, topics: list[str], topic: np.ndarray, when: np.ndarray,
                 log_time: np.ndarray, publish_time: np.ndarray, sequence: np.ndarray,
                 columns: dict[str, Any], lengths: dict[str, int],
                 order: np.ndarray | None = None) -> None:
        if order is not None:
            topic, when, log_time, publish_time, sequence = (
                topic[order], when[order], log_time[order], publish_time[order],
                sequence[order])
            columns = {key: v[order] if np.ndim(v) and np.shape(v)[0] == len(order) else v
                       for key, v in columns.items()}
        self.type_name, self.topics, self.topic, self.when = type_name, topics, topic, when
        self.log_time, self.publish_time, self.sequence = log_time, publish_time, sequence
        self.columns, self.lengths = columns, lengths


def _ns(origin: int, t: np.ndarray) -> np.ndarray:
    """origin + round(t * 1e9) ns, as the recorder's ``_ns`` (round half to even)."""
    return (np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)
            + np.int64(origin)).astype(np.uint64)


_NO_DELAYS = {"neighbours": 0, "effective_delay": 0, "used_timestamp": 0}


def write_trial(batch: VectorisedBatch, trial: int, scenario: Scenario, family: str,
                recorder: Any) -> None:
    """Write one trial's trace from the batch arrays, in bulk (no observer calls).

    The messages are those :func:`replay_trial` makes the recorder write, with the same
    topics, fields, times and per-topic order; per window of steps, each type's messages
    are encoded at once straight into MCAP Message records
    (:meth:`netsim.traces.bulkproto.BulkEncoder.records`) and written (a window is
    about one chunk of ``chunk_size`` bytes; the recorder's ``flush_every``, which
    bounds what a crash loses while the event kernel is still running, does not apply:
    the trial is already computed; each chunk is
    compressed on a background thread while the next window is added, and written and
    flushed as soon as it is done, at most two chunks behind) through the recorder's
    bulk writer (:meth:`netsim.traces.recorder.TraceRecorder.bulk_channels`). Within a
    window the file holds the messages grouped by type, so messages of different topics
    at the same log_time may be in another order than the kernel's (each topic's are
    not); the message indexes list every topic in log_time order.

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
    recorder : netsim.traces.recorder.TraceRecorder
        An open recorder writing format 2 through the bulk writer (format 3:
        :func:`write_trial_steps`).

    Notes
    -----
    A graceful Ctrl-C (:mod:`netsim.interrupt`) is honoured between windows: the trace
    then ends with the last complete window.
    """
    from netsim.traces.schemas import (
        estimate_topic,
        link_topic,
        plant_topic,
        sensor_topic,
        update_topic,
    )

    if getattr(recorder, "trace_format", 2) == 3:
        write_trial_steps(batch, trial, scenario, family, recorder)
        return
    result, end = _traced_result(batch, trial)
    estimates, states = result.estimates, result.states
    ys = result.measurements
    ts = float(scenario.sample_period)
    origin = int(getattr(recorder, "time_origin_ns", 0))
    n_agents, n = estimates.shape[1], estimates.shape[2]
    schedule, selection = batch.schedule, batch.selection
    groups: list[_Group] = []

    k = np.arange(end + 1)
    t_k = k * ts
    ns_k = _ns(origin, t_k)
    u_k = k.astype(np.uint32)
    x = states[:end + 1].reshape(end + 1, -1)
    groups.append(_Group("PlantState", [plant_topic()], np.zeros(end + 1, dtype=np.int64),
                         k.astype(float), ns_k, ns_k, u_k,
                         {"step": k, "time": t_k, "state": x}, {"state": x.shape[1]}))

    def per_step(members: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Rows (k, member) for every step, k major: step and member index arrays."""
        return np.repeat(k, len(members)), np.tile(np.asarray(members, dtype=np.int64),
                                                   end + 1)

    # measurements: sensors with the same output count together
    widths: dict[int, list[int]] = {}
    for i, y in enumerate(ys):
        widths.setdefault(int(np.prod(np.shape(y)[1:], dtype=np.int64)), []).append(i)
    sensor_topics = [sensor_topic(i) for i in range(len(ys))]
    for m, members in widths.items():
        kk, ii = per_step(members)
        values = np.stack([np.asarray(ys[i][:end + 1], dtype=float).reshape(end + 1, m)
                           for i in members], axis=1).reshape(-1, m)
        groups.append(_Group("Measurement", sensor_topics, ii, kk.astype(float), ns_k[kk],
                             ns_k[kk], u_k[kk], {"step": kk, "time": t_k[kk], "sensor": ii,
                                                 "values": values}, {"values": m}))
    # estimates: rows (k, i), k major
    kk, ii = per_step(list(range(n_agents)))
    est = estimates[:end + 1].reshape(-1, n)
    error = est - x[kk]
    sq = np.einsum("ij,ij->i", error, error)
    with np.errstate(invalid="ignore"):
        norm = np.sqrt(sq)
    ns_kk, t_kk, u_kk = ns_k[kk], t_k[kk], u_k[kk]
    groups.append(_Group("Estimate", [estimate_topic(i) for i in range(n_agents)], ii,
                         kk.astype(float), ns_kk, ns_kk, u_kk,
                         {"step": kk, "time": t_kk, "agent": ii, "estimate": est,
                          "error": error, "squared_error": sq, "error_norm": norm},
                         {"estimate": n, "error": n}))
    update_topics = [update_topic(i) for i in range(n_agents)]
    if schedule is None or selection is None:  # centralised filter: no links, no delays
        groups.append(_Group("EstimatorUpdate", update_topics, ii, kk.astype(float), ns_kk,
                             ns_kk, u_kk, {"step": kk, "time": t_kk, "agent": ii},
                             _NO_DELAYS))
        _write_groups(recorder, groups, end)
        return
    t = trial
    link_index = {link: q for q, link in enumerate(schedule.links)}
    send = np.asarray(schedule.send_steps)
    n_sends = int(np.searchsorted(send, end, side="right"))
    neighbours = _neighbours(scenario.weights)
    is_update = np.zeros(end + 1, dtype=bool)
    up = np.asarray(batch.updated, dtype=np.int64)
    is_update[up[up <= end]] = True
    # updates without delays: steps where the estimators did not update, agents
    # without in-neighbours
    lonely = [i for i in range(n_agents) if not neighbours[i]]
    rest = ~is_update[kk] | np.isin(ii, lonely)
    if rest.any():
        groups.append(_Group("EstimatorUpdate", update_topics, ii[rest],
                             kk[rest].astype(float), ns_kk[rest], ns_kk[rest], u_kk[rest],
                             {"step": kk[rest], "time": t_kk[rest], "agent": ii[rest]},
                             _NO_DELAYS))
    ku = np.flatnonzero(is_update)
    chosen = selection.chosen
    degrees: dict[int, list[int]] = {}
    for i in range(n_agents):
        if neighbours[i]:
            degrees.setdefault(len(neighbours[i]), []).append(i)
    for d, members in degrees.items() if ku.size else ():
        # r[u, a, c]: effective delay of agent members[a] on its c-th in-neighbour
        r = np.full((ku.size, len(members), d), -1, dtype=np.int64)
        for a, i in enumerate(members):
            for c, j in enumerate(neighbours[i]):
                l_ = link_index.get((j, i), -1)
                if l_ < 0:
                    continue
                held = np.where(ku > 0, np.asarray(chosen[ku, l_, t], dtype=np.int64), -1)
                ok = held >= 0
                r[ok, a, c] = ku[ok] - 1 - send[held[ok]]
        used = np.where(r >= 0, ku[:, None, None] - 1 - r, -1)
        kr = np.repeat(ku, len(members))
        ir = np.tile(np.asarray(members, dtype=np.int64), ku.size)
        nb = np.asarray([neighbours[i] for i in members], dtype=float)
        groups.append(_Group("EstimatorUpdate", update_topics, ir, kr.astype(float), ns_k[kr],
                             ns_k[kr], u_k[kr],
                             {"step": kr, "time": t_k[kr], "agent": ir,
                              "neighbours": np.tile(nb, (ku.size, 1)),
                              "effective_delay": r.reshape(-1, d).astype(float),
                              "used_timestamp": used.reshape(-1, d).astype(float)},
                             {"neighbours": d, "effective_delay": d, "used_timestamp": d}))
    if n_sends:
        _link_groups(groups, recorder, schedule, selection, t, n_sends, end, estimates, ts,
                     origin, link_topic)
    _write_groups(recorder, groups, end)


def _link_groups(groups: list[_Group], recorder: Any, schedule: Any, selection: Any,
                 t: int, n_sends: int, end: int, estimates: np.ndarray, ts: float,
                 origin: int, link_topic: Any) -> None:
    """The sent, delivered and dropped messages of every link (see :func:`_replay`)."""
    links = schedule.links
    L = len(links)
    send = np.asarray(schedule.send_steps)[:n_sends]
    fate = np.asarray(schedule.fate[t, :, :n_sends])
    wait = np.asarray(schedule.wait_of(t)[:, :n_sends], dtype=float)
    delay = np.asarray(schedule.delay_steps[t, :, :n_sends], dtype=np.int64)
    drop_step = np.asarray(schedule.drop_time[t, :, :n_sends])
    discarded = np.asarray(selection.discarded[t, :, :n_sends])
    sender = np.array([j for j, _ in links], dtype=np.int64)
    receiver = np.array([i for _, i in links], dtype=np.int64)
    s_f = send.astype(float)
    send_time = s_f * ts  # (S,)
    arrival = s_f[None, :] + wait  # (L, S) in steps
    arrival_time = arrival * ts
    # every (link, message) as flat arrays, message major (by send step, then link: the
    # kernel's order of the sent messages; the other groups sort with (link, message)
    # among their keys, so their order does not depend on this one)
    qq_grid, ll_grid = np.meshgrid(np.arange(n_sends), np.arange(L), indexing="ij")
    ll, qq = ll_grid.ravel(), qq_grid.ravel()

    def flat(a: np.ndarray) -> np.ndarray:
        return a.T.ravel()  # (L, S) -> message major

    ss = send[qq]
    dd = flat(delay)
    common = {"sender": sender[ll], "receiver": receiver[ll], "sent_step": ss,
              "usable_step": ss + 1 + dd, "sequence": qq, "send_time": send_time[qq],
              "arrival_time": flat(arrival_time), "delay_steps": dd}
    publish = _ns(origin, send_time)[qq]
    seq = qq.astype(np.uint32)
    payload = bool(getattr(recorder, "record_payloads", True))
    n = estimates.shape[2]
    columns = dict(common)
    if payload:
        columns["payload"] = estimates[ss, sender[ll]]
    groups.append(_Group("LinkSent", [link_topic(j, i, "sent") for j, i in links], ll,
                         ss.astype(float), publish, publish, seq, columns,
                         {"payload": n if payload else 0}))
    flat_fate = flat(fate)
    a = flat(arrival)
    phase = np.where(a <= ss, _LATE, _EARLY)
    delivered = (flat_fate == DELIVERED) & (a <= end)
    if delivered.any():
        m = np.flatnonzero(delivered)
        order = np.lexsort((ll[m], qq[m], phase[m], a[m]))
        log_time = _ns(origin, common["arrival_time"][m])
        columns = {key: v[m] for key, v in common.items()}
        columns["accepted"] = (~flat(discarded)[m].astype(bool)).astype(np.uint32)
        groups.append(_Group("LinkDelivered", [link_topic(j, i, "delivered") for j, i in links],
                             ll[m], a[m], log_time, publish[m], seq[m], columns, {}, order))
        recorder.max_delay_steps = max(recorder.max_delay_steps, int(dd[m].max()))
    m, when, reason = _dropped_messages(recorder, schedule, flat_fate, ss, a,
                                        flat(drop_step), qq, ll, end)
    if not m.size:
        return
    columns = {key: v[m] for key, v in common.items()}
    columns["reason"] = reason
    columns["drop_time"] = when * ts
    groups.append(_Group("LinkDropped", [link_topic(j, i, "dropped") for j, i in links],
                         ll[m], when, _ns(origin, when * ts), publish[m], seq[m], columns, {}))


def _dropped_messages(recorder: Any, schedule: Any, fate: np.ndarray, sent: np.ndarray,
                      arrival: np.ndarray, drop_at: np.ndarray, q: np.ndarray,
                      link: np.ndarray, end: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The drops among messages (1-D per message: fate code, send step, arrival and drop
    steps, send index, link) in the kernel's order: at sending, drop-oldest victims (at
    the cancelling send) and keep-latest supersessions (at arrival), the run's end
    permitting.

    Returns their indices, their times in steps and their reason codes, registered
    with the recorder (its ``drop_reasons`` table) in the order the kernel meets them.
    """
    reasons = schedule.reasons
    code_oldest = reasons.index(REASON_DROP_OLDEST) + 1 if REASON_DROP_OLDEST in reasons else -1
    code_superseded = (reasons.index(REASON_SUPERSEDED) + 1
                       if REASON_SUPERSEDED in reasons else -1)
    victim = (fate == code_oldest) & (drop_at <= end)
    superseded = (fate == code_superseded) & (arrival <= end)
    at_send = ~np.isin(fate, [DELIVERED, code_superseded, code_oldest])
    m = np.flatnonzero(at_send | victim | superseded)
    victim, superseded = victim[m], superseded[m]
    when = np.where(superseded, arrival[m], np.where(victim, drop_at[m], sent[m])).astype(float)
    phase = np.where(superseded, np.where(arrival[m] <= sent[m], _LATE, _EARLY), _STEP)
    # at a send step: by sender, its out-links in order, at-send drop before the victim;
    # the timed ones by send index, then link
    sender = np.array([j for j, _ in schedule.links], dtype=np.int64)
    x = np.where(phase == _STEP, sender[link[m]], q[m])
    order = np.lexsort((victim.astype(np.int64), link[m], x, phase, when))
    m, when = m[order], when[order]
    texts = [REASON_SUPERSEDED if s_ else REASON_DROP_OLDEST if v else reasons[c - 1]
             for s_, v, c in zip(superseded[order].tolist(), victim[order].tolist(),
                                 fate[m].tolist(), strict=True)]
    code_of: dict[str, int] = {}
    for text in texts:  # codes of first appearance (writes the drop_reasons table)
        if text not in code_of:
            code_of[text] = recorder._drop_code(text)
    return m, when, np.array([code_of[text] for text in texts], dtype=np.uint32)


#: The bulk path encodes the records of about this many bytes of windows at once.
ENCODE_BLOCK_BYTES = 8 * 1024 * 1024


def _write_groups(recorder: Any, groups: list[_Group], end: int) -> None:
    """Write the groups window by window (about one chunk each), flushing each: every
    block of windows (about :data:`ENCODE_BLOCK_BYTES`) encodes its slice of every
    group into Message records, each window adds its part (so the encoded records in
    memory are about a block, not the whole trace)."""
    writer = recorder.writer
    # windows of about one chunk (chunk_size bytes of records): the whole trial is
    # written at once, so a window by steps (the kernel's flush_every, which bounds what
    # a crash loses while a slow run is still going) would only add chunks, each with
    # its compression call, CRC and message indexes (at N = 4 the 25-step windows made
    # the trace 1.8x slower to write: benchmarks/trace_throughput.py)
    encoders = [_encoder(g.type_name, g.lengths) for g in groups]
    total = sum((e.payload_length + 31) * len(g.when) for g, e in zip(groups, encoders,
                                                                       strict=True))
    chunk = int(writer.chunk_size)
    per_step = max(1.0, total / (end + 1))
    window = max(1, int(chunk // per_step))
    edges = np.arange(0, end + 1 + window, window, dtype=float)
    edges[-1] = np.inf
    packed = []
    for g, encoder in zip(groups, encoders, strict=True):
        rows = len(g.when)
        if not rows:
            continue
        ids = recorder.bulk_channels(g.type_name, g.topics, g.topic)[g.topic]
        cuts = np.searchsorted(g.when, edges, side="left")
        packed.append((g, encoder, ids, cuts, rows))
        recorder._last_log_time = max(recorder._last_log_time, int(g.log_time.max()))
    windows = len(edges) - 1
    # encoded a block of windows at a time: one encoder call per type and block (each
    # call costs tens of microseconds), records in memory at most ENCODE_BLOCK_BYTES
    block = max(1, ENCODE_BLOCK_BYTES // max(1, chunk))
    for first in range(0, windows, block):
        last = min(windows, first + block)
        encoded = []
        for g, encoder, ids, cuts, rows in packed:
            lo, hi = int(cuts[first]), int(cuts[last])
            if hi > lo:
                columns = {key: v[lo:hi] if np.ndim(v) and np.shape(v)[0] == rows else v
                           for key, v in g.columns.items()}
                records, _ = encoder.records(columns, ids[lo:hi], g.sequence[lo:hi],
                                             g.log_time[lo:hi], g.publish_time[lo:hi],
                                             n=hi - lo)
                encoded.append((records, 31 + encoder.payload_length, lo, ids, g.log_time,
                                cuts))
        for w in range(first, last):
            if w:
                interrupt.check()
            for records, size, base, ids, log_time, cuts in encoded:
                lo, hi = int(cuts[w]), int(cuts[w + 1])
                if hi > lo:
                    writer.add_records(records[(lo - base) * size:(hi - base) * size],
                                       np.arange(hi - lo, dtype=np.int64) * size,
                                       ids[lo:hi], log_time[lo:hi])
            recorder.last_step = min(end, int(edges[w + 1]) - 1) if w + 1 < windows else end
            # chunks compress in the background while the next window is added; the
            # last window waits for all of them
            recorder.flush(wait=w + 1 >= windows)


# -- trace format 3 ------------------------------------------------------------------


def _by_bucket(bucket: np.ndarray, end: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows (the buckets that have events, increasing) and the events per row, of
    events already in order and with non-decreasing ``bucket``."""
    counts = np.bincount(bucket, minlength=end + 1) if bucket.size else np.zeros(0, np.int64)
    rows = np.flatnonzero(counts)
    return rows, counts[rows]


def write_trial_steps(batch: VectorisedBatch, trial: int, scenario: Scenario, family: str,
                      recorder: Any) -> None:
    """Write one trial's trace in format 3 (a message per step and kind) from the batch.

    The same messages as the event kernel's format-3 path
    (:class:`netsim.traces.stepwriter.StepLog` fed by the kernel's observer calls, which
    :func:`replay_trial` reproduces), read back the same (link and update entries may be
    in another order in the ``trace_layout`` lists); built for all steps at once from the
    batch arrays and written in windows of about one chunk, each compressed on a
    background thread while the next is encoded.

    Parameters
    ----------
    batch, trial, scenario, family
        As for :func:`write_trial`.
    recorder : netsim.traces.recorder.TraceRecorder
        An open recorder with ``trace_format=3``.
    """
    from netsim.traces.schemas3 import ABSENT
    from netsim.traces.stepcodec import Column
    from netsim.traces.stepwriter import StepWriter, arrival_column

    result, end = _traced_result(batch, trial)
    estimates, states = result.estimates, result.states
    ts = float(scenario.sample_period)
    N, n = estimates.shape[1], estimates.shape[2]
    R = end + 1
    k = np.arange(R)
    x = states[:R].reshape(R, -1)
    ys = [np.asarray(y[:R], dtype=float).reshape(R, -1) for y in result.measurements]
    est = estimates[:R]
    if result.diverged_at is None and result.squared_errors.shape[0] >= R:
        sq = result.squared_errors[:R]  # the engine's ||x-hat^i_k - x_k||^2
    else:  # at a divergence the engine reports non-finite errors as inf: as the kernel
        error = est - x[:, None, :]
        sq = np.einsum("kia,kia->ki", error, error)
    with np.errstate(invalid="ignore"):
        norm = np.sqrt(sq)
    tables: list[tuple[str, np.ndarray, dict[str, Column]]] = [
        ("PlantState", k, {"state": Column(x)}),
        ("Measurements", k, {"values": Column(np.concatenate(ys, axis=1) if ys
                                              else np.zeros((R, 0)))}),
        ("Estimates", k, {"updated": Column(np.ones((R, N), dtype=bool)),
                          "estimate": Column(est.reshape(R, N * n)),
                          "error_norm": Column(norm)}),
    ]
    schedule, selection = batch.schedule, batch.selection
    neighbours = _neighbours(scenario.weights)
    links = list(schedule.links) if schedule is not None else []
    entries = [(j, i) for i in range(N) for j in neighbours[i]] if schedule is not None else []
    L, E = len(links), len(entries)
    delays = sends_delay = None  # (R, E) and (R, L), ints; ABSENT where nothing
    sends_arrival = np.empty((R, L))  # filled only when arrivals are not at steps
    deliveries = drops = None
    in_steps = True
    if schedule is not None and selection is not None:  # (both or neither)
        link_index = {link: q for q, link in enumerate(links)}
        send = np.asarray(schedule.send_steps)
        n_sends = int(np.searchsorted(send, end, side="right"))
        up = np.asarray(batch.updated, dtype=np.int64)
        entry_link = np.array([link_index.get(x_, -1) for x_ in entries], dtype=np.int64)
        if E and (entry_link >= 0).all():
            # r_ij[k] = k - 1 - s of the message held (chosen) at k; -1: none held
            held = np.asarray(selection.chosen[:R, :, trial])[:, entry_link]  # (R, E)
            none_held = held < 0
            # the sent step s of the message held (a fresh array, then k - 1 - s in place)
            delays = (held.astype(np.int32, copy=False)
                      if np.array_equal(send[:n_sends], np.arange(n_sends))
                      else send[np.maximum(held, 0)].astype(np.int32))
            np.subtract((k.astype(np.int32) - 1)[:, None], delays, out=delays)
            delays[none_held] = -1
            delays[0] = -1
            not_updated = np.ones(R, dtype=bool)
            not_updated[up[up <= end]] = False
            delays[not_updated] = ABSENT
        else:  # an entry without a link (never for the built-in families)
            ku = up[(up <= end) & (up > 0)]
            delays = np.full((R, E), ABSENT, dtype=np.int32)
            delays[up[up <= end]] = -1
            for e, l_ in enumerate(entry_link.tolist()):
                if l_ >= 0 and ku.size:
                    held = np.asarray(selection.chosen[ku, l_, trial], dtype=np.int64)
                    ok = held >= 0
                    delays[ku[ok], e] = ku[ok] - 1 - send[held[ok]]
        # the narrowest integers that hold every delay (and ABSENT): the column is
        # encoded as varints either way (int8: a quarter of the fresh memory of int32)
        longest = int(np.max(schedule.delay_steps[trial], initial=0))
        narrow = np.int8 if longest <= 127 else np.int16 if longest <= 32767 else np.int32
        sends_delay = np.empty((R, L), dtype=narrow)
        silent = np.ones(R, dtype=bool)  # steps without sends
        silent[send[:n_sends]] = False
        sends_delay[silent] = ABSENT
        if n_sends:
            deliveries, drops, in_steps = _step_link_events(
                recorder, schedule, selection, trial, n_sends, end, ts, sends_delay,
                sends_arrival)
    if delays is None:
        delays = np.full((R, E), ABSENT, dtype=np.int32)
    if sends_delay is None:
        sends_delay = np.full((R, L), ABSENT, dtype=np.int32)
    tables.append(("Updates", k, {"effective_delay": Column(delays)}))
    # arrival times follow from the delays (left out) unless some arrive between steps
    arrival = (Column(np.zeros((R, 0))) if in_steps
               else arrival_column(k, sends_delay, sends_arrival, ts))
    tables.append(("LinkSends", k, {"delay_steps": Column(sends_delay),
                                    "arrival_time": arrival}))
    if drops is not None:
        tables.append(("LinkDrops",) + drops)
    if deliveries is not None:
        tables.append(("LinkDeliveries",) + deliveries)
    out = StepWriter(recorder) if recorder._steps is None else recorder._steps.out
    out.layout({"agents": N, "n_states": n, "sensor_widths": [y.shape[1] for y in ys],
                "links": [list(x_) for x_ in links], "updates": [list(x_) for x_ in entries],
                "freshness_sizes": [],
                "payload": "estimate" if recorder.record_payloads else "none",
                "payload_width": 0})
    _write_step_windows(recorder, out, tables, end, ts)


def _step_link_events(recorder: Any, schedule: Any, selection: Any, t: int, n_sends: int,
                      end: int, ts: float, sends_delay: np.ndarray, sends_arrival: np.ndarray
                      ) -> tuple[Any, Any, bool]:
    """Fill the sends (rows = send steps) and return the deliveries and drops tables
    (rows, columns) of format 3, or None for either without events (:func:`_link_groups`
    has the kernel's rules), and whether every message arrives at its usable step (then
    ``sends_arrival`` is not filled: the arrival times follow from the delays)."""
    from netsim.traces.stepcodec import Column

    send = np.asarray(schedule.send_steps)[:n_sends]
    delay = np.asarray(schedule.delay_steps[t, :, :n_sends])  # (L, S)
    L = len(schedule.links)
    sends_delay[send] = delay.T
    in_steps = schedule.wait is None  # every message arrives at its usable step
    wait = None
    if not in_steps:
        wait = np.asarray(schedule.wait_of(t)[:, :n_sends], dtype=float)
        in_steps = np.array_equal(wait, delay + 1.0)
    if not in_steps:
        sends_arrival.fill(np.nan)
        sends_arrival[send] = ((send[None, :] + wait) * ts).T
    # a message is usable from step send + 1 + delay (not built as an (L, S) array: at
    # N = 32 each is 250 KB of fresh pages)
    lossless = bool(getattr(schedule, "lossless_steps", False))
    fate = None if lossless else np.asarray(schedule.fate[t, :, :n_sends])
    arrived = delay <= (end - 1 - send)[None, :] if in_steps else send[None, :] + wait <= end
    delivered = arrived if lossless else arrived & (fate == DELIVERED)
    deliveries = drops = None
    if delivered.any():
        kept, counts_all = _in_usable_order(
            delay, send + 1, delivered, ~np.asarray(selection.discarded[t, :, :n_sends]),
            end + 2)
        rows = np.flatnonzero(counts_all)
        deliveries = (rows, {"accepted": Column(kept, counts_all[rows])})
        longest = int(np.max(delay, where=delivered, initial=-1))
        recorder.max_delay_steps = max(recorder.max_delay_steps, longest)
    if lossless:
        return deliveries, drops, in_steps
    assert fate is not None  # (None only when lossless)
    # drops, message major (m = q L + l): at sending, drop-oldest victims (at the
    # cancelling send), superseded (at arrival)
    m = np.flatnonzero((fate != DELIVERED).T.ravel())
    if not m.size:
        return deliveries, drops, in_steps
    q, l_ = m // L, m % L
    ss = send[q]
    if in_steps:
        a = (ss + 1 + delay[l_, q]).astype(float)
    else:
        assert wait is not None  # (arrivals off the steps come from the wait times)
        a = (ss + wait[l_, q]).astype(float)
    drop_at = np.asarray(schedule.drop_time[t, :, :n_sends])[l_, q]
    kept, when, reason = _dropped_messages(recorder, schedule, fate[l_, q], ss, a, drop_at,
                                           q, l_, end)
    if not kept.size:
        return deliveries, drops, in_steps
    l_, ss = l_[kept], ss[kept]
    # the step that lists a drop: netsim.traces.stepwriter.drop_bucket, in steps
    bucket = np.ceil(when - 1e-9).astype(np.int64)
    rows, counts = _by_bucket(bucket, end + 1)
    drops = (rows, {"link": Column(l_, counts), "sent_step": Column(ss, counts),
                    "reason": Column(reason, counts), "drop_time": Column(when * ts, counts)})
    return deliveries, drops, in_steps


def _in_usable_order(delay: np.ndarray, first: np.ndarray, delivered: np.ndarray,
                     flags: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The flags of the delivered messages ordered by (usable step, link, sent step), and
    the deliveries per usable step.

    Parameters
    ----------
    delay, delivered, flags : numpy.ndarray, shape (L, S)
        Per link and send: the delay in steps (int), whether the message is delivered
        by the run's end, and its flag (bool).
    first : numpy.ndarray, shape (S,), int
        Per send, the step its messages would be usable from without delay: message
        (l, q) is usable from ``first[q] + delay[l, q]`` (below ``steps``).
    steps : int
        Length of the counts.

    Returns
    -------
    ordered : numpy.ndarray, shape (delivered.sum(),), bool
        ``flags[delivered]`` in the deliveries' order.
    counts : numpy.ndarray, shape (steps,), int64
        Delivered messages usable from each step.

    Notes
    -----
    When the keys fit 31 bits, each message is one int32, ``(usable * L S + l S + q) * 2
    + flag``: unique, so a plain (SIMD) sort orders them as the stable sort by usable
    step of the link-major order would, the flag rides in the lowest bit and the counts
    are where each step's keys begin (at N = 32, 63,000 messages: 0.15 ms against
    0.55 ms for the radix argsort and the gather it needs). Else that argsort. The
    temporaries are few and made in place: each is a fresh 250 KB at N = 32, and
    a fresh page costs about as much as sorting it.
    """
    L, S = delay.shape
    span = 2 * L * S
    if delay.size and (int(delay.max()) + int(first.max()) + 1) * span < 2**31:
        key = delay.astype(np.int32)  # in the arrays' memory order (S-major here)
        key += first.astype(np.int32)[None, :]
        key *= np.int32(span)
        key += (np.arange(L, dtype=np.int32) * np.int32(2 * S))[:, None]
        key += np.arange(0, 2 * S, 2, dtype=np.int32)[None, :]
        key += flags
        # sorted in place, the undelivered last (every key is below 2**31 - 1, so the
        # clipped bounds stay int32 and count only delivered keys)
        key[~delivered] = np.int32(2**31 - 1)
        chosen = _memory_order(key).reshape(-1)  # a view (astype made key contiguous)
        chosen.sort()
        chosen = chosen[:int(np.count_nonzero(delivered))]
        bounds = np.minimum(np.arange(steps + 1, dtype=np.int64) * span, 2**31 - 1)
        counts = np.diff(np.searchsorted(chosen, bounds.astype(np.int32)))
        chosen &= 1
        return chosen.astype(bool), counts
    usable = (np.asarray(first, dtype=np.int64)[None, :] + delay)[delivered]
    order = np.argsort(usable, kind="stable")
    return flags[delivered][order], np.bincount(usable, minlength=steps)


def _memory_order(a: np.ndarray) -> np.ndarray:
    """A contiguous 2-D array, or its transpose when it is laid out column-major: a view
    whose C order is its memory order."""
    return a.T if a.flags.f_contiguous and not a.flags.c_contiguous else a


def _write_step_windows(recorder: Any, out: Any, tables: list[tuple[str, np.ndarray, dict]],
                        end: int, ts: float) -> None:
    """Write the format-3 tables in windows of steps (about :data:`ENCODE_BLOCK_BYTES`
    each, flushed at its end)."""
    from netsim.traces.stepcodec import Column

    total = 0
    for _, rows, columns in tables:
        for col in columns.values():
            total += col.values.nbytes + 16 * len(rows)
    # windows of about ENCODE_BLOCK_BYTES (the writer closes chunks of chunk_size within
    # them): a window costs one encoder call per message type
    window = max(1, int(ENCODE_BLOCK_BYTES // max(1.0, total / (end + 1))))
    edges = list(range(0, end + 1, window)) + [np.iinfo(np.int64).max]
    # per table: row boundaries of each window, element offsets of ragged columns
    cuts = [np.searchsorted(rows, edges, side="left") for _, rows, _ in tables]
    starts = [{name: None if col.counts is None else
               np.concatenate([[0], np.cumsum(col.counts)]) for name, col in columns.items()}
              for _, _, columns in tables]
    windows = len(edges) - 1
    for w in range(windows):
        if w:
            interrupt.check()
        for (type_name, rows, columns), cut, start in zip(tables, cuts, starts, strict=True):
            lo, hi = int(cut[w]), int(cut[w + 1])
            if hi <= lo:
                continue
            part = {}
            for name, col in columns.items():
                if col.counts is None:
                    part[name] = Column(col.values[lo:hi])
                else:
                    s = start[name]
                    assert s is not None  # (the offsets of every ragged column)
                    part[name] = Column(col.values[s[lo]:s[hi]], col.counts[lo:hi])
            out.emit(type_name, rows[lo:hi], rows[lo:hi] * ts, part)
        recorder.last_step = min(end, edges[w + 1] - 1)
        recorder.flush(wait=w + 1 >= windows)
