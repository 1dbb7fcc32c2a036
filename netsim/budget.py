"""Resource guards: estimate a request's memory and time before allocating it.

Every engine and analysis asks this module, from the request alone (steps, trials,
agents, links, states, the delay horizon that can matter within the steps), how much
memory and time it will take, and refuses what this machine cannot hold with a
:class:`ResourceError`: one line naming the parameter, the estimate and the limit.
The command line maps it to exit code 2.

Limits
------
- memory: ``min(MemAvailable, RLIMIT_AS - address space in use, RLIMIT_DATA - data in
  use, cgroup memory.max - memory.current)`` times :data:`SAFETY`; the environment
  variable ``NETSIM_MEMORY_LIMIT`` (bytes, or with a K/M/G/T suffix) replaces it.
- time: :data:`DEFAULT_TIME_LIMIT` seconds of estimated dense linear algebra at the
  nominal :data:`FLOPS` rate; ``NETSIM_TIME_LIMIT`` (seconds) replaces it. Only the
  dense-algebra estimates (eigenvalues, LMIs) are held to it; simulations are held
  to memory and show progress instead.

The estimates are upper-bound sketches of the arrays the code allocates (documented
next to each function), not measurements; they are meant to separate "fits easily"
from "cannot possibly fit", a factor of a few either way does not matter.

Delay horizon: a message sent at step s with delay d is usable at s + 1 + d, so within
steps 0..K no delay above K can ever matter (:func:`delay_horizon`).
"""

from __future__ import annotations

import math
import os
import resource
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from netsim.taskoptions import getenv

__all__ = [
    "ResourceError",
    "SAFETY",
    "FLOPS",
    "DEFAULT_TIME_LIMIT",
    "memory_limit",
    "time_limit",
    "format_bytes",
    "format_seconds",
    "delay_horizon",
    "check_memory",
    "check_time",
    "run_bytes",
    "vectorised_batch_bytes",
    "kernel_trial_bytes",
    "trace_bytes",
    "trace_write_bytes",
    "trace_channels",
    "check_trace_size",
    "check_duration",
    "MCAP_MAX_CHANNELS",
    "eig_cost",
    "check_run",
    "guard_run",
    "check_counts",
    "BATCH_ELEMENTS",
    "KERNEL_LINK_BYTES",
    "KERNEL_AGENT_STEP_BYTES_PER_STATE",
    "NETWORK_BUILD_BYTES_PER_LINK",
    "NETWORK_HELD_BYTES_PER_LINK",
    "check_gain_design",
    "analysis_cost",
    "check_analysis",
    "exact_observability_cost",
]

#: Fraction of the free memory a request may plan to use.
SAFETY = 0.75

#: Nominal rate (floating-point operations per second) of LAPACK's dense
#: non-symmetric eigenvalue routines on one machine of the kind netsim runs on.
FLOPS = 2e9

#: Seconds of estimated dense linear algebra a request may take.
DEFAULT_TIME_LIMIT = 7200.0

_SUFFIX = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


class ResourceError(Exception):
    """A request this machine cannot hold (or finish in time); one line, exit 2.

    Attributes
    ----------
    parameter : str
        The request's parameter to lower (e.g. ``steps``, ``trials``, ``--tau-max``).
    estimate, limit : float
        Bytes (or seconds, for a time refusal).
    """

    def __init__(self, message: str, parameter: str, estimate: float, limit: float) -> None:
        super().__init__(message)
        self.parameter = parameter
        self.estimate = estimate
        self.limit = limit


def format_bytes(value: float) -> str:
    """``value`` bytes in binary units, e.g. ``72.8 TiB``."""
    value = float(value)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(value) < 1024 or unit == "PiB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.1f} {unit}"
        value /= 1024
    raise AssertionError("unreachable")  # pragma: no cover


def format_seconds(value: float) -> str:
    """``value`` seconds as s, min, h or days."""
    if value < 120:
        return f"{value:.0f} s"
    if value < 7200:
        return f"{value / 60:.0f} min"
    if value < 172800:
        return f"{value / 3600:.1f} h"
    return f"{value / 86400:.3g} days"


def _parse_size(text: str) -> int:
    text = text.strip().upper().removesuffix("B").removesuffix("I")
    suffix = text[-1:] if text[-1:] in _SUFFIX else ""
    number = float(text[: len(text) - len(suffix)])
    if not (number > 0 and math.isfinite(number)):
        raise ValueError(text)
    return int(number * _SUFFIX[suffix])


def _proc_status(field: str) -> int | None:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _available_ram() -> int | None:
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return None


def _cgroup_free() -> int | None:
    try:
        with open("/sys/fs/cgroup/memory.max", encoding="ascii") as fh:
            raw = fh.read().strip()
        if raw == "max":
            return None
        with open("/sys/fs/cgroup/memory.current", encoding="ascii") as fh:
            return int(raw) - int(fh.read().strip())
    except (OSError, ValueError):
        return None


def memory_limit() -> tuple[int, str]:
    """Bytes a request may plan to allocate, and where the limit comes from.

    Returns
    -------
    (int, str)
        ``SAFETY`` times the smallest of the free RAM, the room left under
        RLIMIT_AS / RLIMIT_DATA and the cgroup's room; or ``NETSIM_MEMORY_LIMIT``.
    """
    env = getenv("NETSIM_MEMORY_LIMIT")  # a sweep's task carries the client's
    if env:
        try:
            return _parse_size(env), "NETSIM_MEMORY_LIMIT"
        except (ValueError, IndexError):
            pass  # an unreadable override is ignored, the machine's limit applies
    candidates: list[tuple[int, str]] = []
    ram = _available_ram()
    if ram is not None:
        candidates.append((ram, "available RAM"))
    for name, used_field in (("RLIMIT_AS", "VmSize"), ("RLIMIT_DATA", "VmData")):
        soft = resource.getrlimit(getattr(resource, name))[0]
        if soft != resource.RLIM_INFINITY:
            candidates.append((soft - (_proc_status(used_field) or 0), f"{name} room"))
    cgroup = _cgroup_free()
    if cgroup is not None:
        candidates.append((cgroup, "cgroup memory.max room"))
    if not candidates:  # pragma: no cover - no way to tell
        return 1 << 34, "default 16 GiB"
    free, source = min(candidates)
    return max(0, int(free * SAFETY)), f"{SAFETY:g} x {source}"


def time_limit() -> float:
    """Seconds of estimated dense linear algebra a request may take."""
    env = getenv("NETSIM_TIME_LIMIT")  # a sweep's task carries the client's
    if env:
        try:
            value = float(env)
            if value > 0:
                return value
        except ValueError:
            pass
    return DEFAULT_TIME_LIMIT


def _named(parameter: str, value: Any) -> str:
    return parameter if value is None else f"{parameter} = {value}"


def check_memory(estimate: float, parameter: str, what: str, value: Any = None,
                 hint: str | None = None) -> None:
    """Raise :class:`ResourceError` if ``estimate`` bytes exceed :func:`memory_limit`.

    The message: ``{parameter} = {value}: {what} needs about X, more than the Y this
    machine can give (...); lower {parameter}``.
    """
    limit, source = memory_limit()
    if estimate > limit:
        raise ResourceError(
            f"{_named(parameter, value)}: {what} needs about {format_bytes(estimate)}, more "
            f"than the {format_bytes(limit)} this machine can give ({source}); "
            f"{hint or 'lower ' + parameter}", parameter, estimate, limit)


def check_time(seconds: float, parameter: str, what: str, value: Any = None,
               hint: str | None = None) -> None:
    """Raise :class:`ResourceError` if ``seconds`` exceed :func:`time_limit`."""
    limit = time_limit()
    if seconds > limit:
        raise ResourceError(
            f"{_named(parameter, value)}: {what} would take about "
            f"{format_seconds(seconds)} (at a nominal {FLOPS:.0e} flop/s), more than the "
            f"limit of {format_seconds(limit)} (NETSIM_TIME_LIMIT); "
            f"{hint or 'lower ' + parameter}", parameter, seconds, limit)


def check_duration(seconds: float, parameter: str, value: Any, what: str,
                   hint: str | None = None) -> None:
    """Raise :class:`ResourceError` if ``what`` would take longer than
    :func:`time_limit`, estimated as ``seconds`` from the request's counts (by a
    per-unit cost measured on the reference machine, not by flops)."""
    limit = time_limit()
    if seconds > limit:
        raise ResourceError(
            f"{_named(parameter, value)}: {what} would take about "
            f"{format_seconds(seconds)}, more than the limit of {format_seconds(limit)} "
            f"(NETSIM_TIME_LIMIT); {hint or 'lower ' + parameter}", parameter, seconds, limit)


def delay_horizon(max_delay: float, steps: int) -> int:
    """Largest delay that can matter within steps 0..``steps``: ``min(max_delay, steps)``.

    A message sent at s with delay d is usable at s + 1 + d; for d >= steps that is
    after the last step, so it never arrives and no power A^r with r > steps + 1 is
    ever applied.
    """
    if not math.isfinite(max_delay):
        return int(steps)
    return int(max(0, min(int(max_delay), int(steps))))


# -- simulations ----------------------------------------------------------------------


#: Largest trials x links x (steps + 2) of one lockstep batch of the vectorised engine
#: (:func:`netsim.vectorised.run_vectorised` splits the trials so). Links with random
#: delays, losses or buffers need about 75 bytes per element at the peak (measured by
#: benchmarks/engine_scaling.py), so a full batch takes about 0.75 GB; constant delays
#: need far less. One trial is never split.
BATCH_ELEMENTS = 10_000_000


def _is_counts(scenario: Any) -> bool:
    """Whether ``scenario`` is only its counts (before the network is built)."""
    from netsim.models.scenario import ScenarioCounts

    return isinstance(scenario, ScenarioCounts)


def _sizes(scenario: Any) -> tuple[int, int, int, int, int, int]:
    """(n, N, L, m_total, m_max, noise width) of a scenario (or of its
    :class:`~netsim.models.scenario.ScenarioCounts`)."""
    if _is_counts(scenario):
        c = scenario
        return (c.n_states, c.n_agents, c.links, c.measurements, c.max_measurements,
                c.noise_width)
    plant = scenario.plant
    n = int(plant.n_states)
    N = int(scenario.n_agents)
    table = getattr(scenario, "link_table", None)
    L = len(table) if table is not None else len(scenario.links)
    ms = [int(c.shape[0]) for c in plant.C] or [0]
    width = int(getattr(plant, "noise_width", n + sum(ms)))
    return n, N, L, sum(ms), max(ms), width


def _constant_links(scenario: Any) -> bool:
    if _is_counts(scenario):
        return True  # unknown before the build: the lightest case (a lower bound)
    try:
        model = scenario.delay_model(0)
    except Exception:  # noqa: BLE001 - only an estimate: assume the general path
        return False
    return (scenario.link_spec is None and scenario.topology is None
            and bool(getattr(model, "time_invariant", False))
            and getattr(model, "unit", "steps") == "steps")


def _one_delay(scenario: Any) -> bool:
    """Plain fixed delays with no per-link entry (homogeneous, or model none)."""
    from netsim.models.delays import FixedDelays

    if _is_counts(scenario):
        return True  # unknown before the build: the lightest case (a lower bound)
    try:
        model = scenario.delay_model(0)
    except Exception:  # noqa: BLE001 - only an estimate
        return False
    return type(model) is FixedDelays and not model.delays


#: Bytes the event kernel holds per link for a whole trial (its link object, buffer,
#: delay and loss streams, scheduled events): measured 4.3-4.5 kB per link with
#: tracemalloc at N = 240 and 480 (2,094 and 5,312 links, geometric networks).
KERNEL_LINK_BYTES = 4500
#: Bytes the event kernel adds per agent and step, per state of the plant plus one:
#: measured about 290 bytes per agent-step at n = 6 (48 x 7 = 336 counted).
KERNEL_AGENT_STEP_BYTES_PER_STATE = 48
#: Peak bytes per link of building a sparse network (points, k-d tree pairs, sort, CSR
#: weights, the connectivity check): measured 98-99 with tracemalloc at N = 20,000 and
#: 100,000 geometric agents.
NETWORK_BUILD_BYTES_PER_LINK = 100
#: Bytes per link a built sparse network keeps for the run (link arrays, CSR weights):
#: measured 19 (the process's resident set after loading a 14.6-million-link network).
NETWORK_HELD_BYTES_PER_LINK = 24


def _kernel_bytes(n: int, N: int, L: int, m: int, width: int, steps: int,
                  record_delays: bool) -> int:
    K1 = int(steps) + 1
    per_step = (8 * (width + n + m) + KERNEL_AGENT_STEP_BYTES_PER_STATE * (n + 1) * N
                + (4 * N * N if record_delays else 0))
    return KERNEL_LINK_BYTES * L + K1 * per_step


def kernel_trial_bytes(scenario: Any, steps: int, *, record_delays: bool = False) -> int:
    """Peak bytes of one event-kernel trial: its links (:data:`KERNEL_LINK_BYTES` each)
    and per step the noise, states, measurements and every agent's estimate, error and
    bookkeeping (:data:`KERNEL_AGENT_STEP_BYTES_PER_STATE`), with, if recorded, the
    effective delays (K+1, N, N)."""
    n, N, L, m, _, width = _sizes(scenario)
    return _kernel_bytes(n, N, L, m, width, steps, record_delays)


def vectorised_batch_bytes(scenario: Any, steps: int, trials: int, *,
                           record_estimates: bool = False, horizon: int | None = None) -> int:
    """Peak bytes of one lockstep batch of ``trials`` trials (netsim.vectorised).

    Plant noise, states and measurements, the agents' measurements (K+1, N, T, m),
    squared errors, recorded estimates, the message selection (K+1, L, T) with its
    link schedule (about 75 bytes per message for random delays, losses or buffers,
    16 for constant delays), the ring of past estimates and the powers A^0..A^H,
    H = the delay horizon (:func:`delay_horizon`).
    """
    n, N, L, m, m_max, width = _sizes(scenario)
    K1 = int(steps) + 1
    T = int(trials)
    if horizon is None:
        if _is_counts(scenario):
            longest = scenario.max_delay + 1
        else:
            longest = max(scenario.max_delay, scenario.delay_bound + 1)
        horizon = delay_horizon(longest, steps)
    per_message = 16 if _constant_links(scenario) else 75
    if per_message == 16 and _one_delay(scenario):
        # one delay on every link: the schedule is broadcast views, and so is the
        # message selection when a message goes every step; the block family's
        # selection (a message every tau + 1 steps) is two int32 per message
        # (netsim.linkschedule._select_constant)
        per_message = 8
    per_step_trial = (8 * (width + n + m + N * m_max + N + (N * n if record_estimates else 0))
                      + L * per_message)
    ring = (horizon + 2) * N * T * n * 8
    powers = 2 * (horizon + 2) * n * n * 8
    return K1 * T * per_step_trial + ring + powers


def trace_bytes(scenario: Any, steps: int) -> int:
    """Bytes of one MCAP trace file: per step the truth, every agent's estimate and
    every link's message (n doubles each, about 64 bytes of framing)."""
    n, N, L, m, _, _ = _sizes(scenario)
    return (int(steps) + 1) * ((1 + N + L) * (8 * n + 64) + 8 * m)


def trace_write_bytes(scenario: Any, steps: int) -> int:
    """Memory the vectorised engine's bulk writer takes to write one trial's trace
    (format 3, :func:`netsim.vectrace.write_trial_steps`): its tables of every step
    (per link the message's delay, fate and order of delivery; per in-link the effective
    delay; every agent's estimate and error norm) and their records. Measured 47 bytes
    per step and link at N = 1,000 with 28,394 links; counted as 48 per link, 8 per
    in-link and 16 per state value of every agent, per step."""
    n, N, L, _, _, _ = _sizes(scenario)
    return (int(steps) + 1) * (48 * L + 8 * L + 16 * N * n)


#: Channels one MCAP file can hold (16-bit channel ids).
MCAP_MAX_CHANNELS = 65536


def trace_channels(scenario: Any, trace_format: int = 2) -> int:
    """Most channels (topics) one trace of ``scenario`` can need. Format 2:
    ``/plant/state``, one per sensor, three per agent (estimate, update, freshness) and
    three per link (sent, delivered, dropped) (:mod:`netsim.traces.schemas` names them);
    format 3: its eight topics whatever the network (:mod:`netsim.traces.schemas3`)."""
    if trace_format == 3:
        from netsim.traces.schemas3 import TOPICS

        return len(TOPICS)
    _, N, L, _, _, _ = _sizes(scenario)
    return 1 + len(scenario.plant.C) + 3 * N + 3 * L


def check_trace_size(scenario: Any, trace: str | os.PathLike[str],
                     trace_format: int | None = None, steps: int | None = None,
                     engine: str = "vectorised") -> None:
    """Refuse (:class:`ResourceError`, one line naming ``--trace``) a trace of
    ``scenario`` that cannot be written: more topics than MCAP's channels
    (:func:`trace_channels`; format 2 only), sparse weights beyond the dense-P limit
    (a trace stores P as a dense ``.npy``), or (``steps`` given, vectorised engine) more
    memory than the machine can give to write one trial's trace in bulk
    (:func:`trace_write_bytes`, beside the trial itself). Run before the simulation, so
    nothing computed is lost. ``trace_format``: None for the recorder's default."""
    if trace_format is None:
        from netsim.traces.recorder import DEFAULT_TRACE_FORMAT

        trace_format = DEFAULT_TRACE_FORMAT
    if steps is not None and engine == "vectorised":
        _, N, L, _, _, _ = _sizes(scenario)
        _, one = run_bytes(scenario, steps, 1, "vectorised", keep_estimates=True)
        check_memory(one + trace_write_bytes(scenario, steps), "--steps",
                     f"writing the trace of one trial (N = {N} agents, {L} links) from "
                     f"the vectorised engine's arrays", steps,
                     hint="lower --steps, or trace with --engine events (it writes as "
                     "it runs)")
    channels = trace_channels(scenario, trace_format)
    if channels > MCAP_MAX_CHANNELS:
        _, N, L, _, _, _ = _sizes(scenario)
        raise ResourceError(
            f"--trace {trace}: a format-2 trace of N = {N} agents and {L} links has up to "
            f"{channels:,} topics, more than the {MCAP_MAX_CHANNELS:,} channels an MCAP "
            f"file can hold; use --trace-format 3 (8 topics at any size), trace a smaller "
            f"network, or run this one without --trace",
            "--trace", channels, MCAP_MAX_CHANNELS)
    if hasattr(scenario.weights, "toarray"):  # sparse: the trace stores P dense
        from netsim.models.scenario import DENSE_WEIGHTS_MAX_AGENTS

        _, N, _, _, _, _ = _sizes(scenario)
        if N > DENSE_WEIGHTS_MAX_AGENTS:
            raise ResourceError(
                f"--trace {trace}: a trace stores the N x N consensus matrix P dense "
                f"({format_bytes(8 * N * N)} at N = {N}); traces go up to "
                f"{DENSE_WEIGHTS_MAX_AGENTS:,} agents; run this network without --trace",
                "--trace", 8 * N * N, 8 * DENSE_WEIGHTS_MAX_AGENTS ** 2)


def check_counts(counts: Any, steps: int | None, trials: int | None,
                 engines: Sequence[str], *, steps_name: str = "run.steps",
                 trials_name: str = "run.trials") -> None:
    """Refuse, before the network is built, a run that cannot fit in memory.

    From a scenario's counts (:class:`netsim.models.scenario.ScenarioCounts`) alone:
    building the network (:data:`NETWORK_BUILD_BYTES_PER_LINK`), then the run as
    :func:`check_run` counts it in the lightest of ``engines``, its links taken at their
    lightest (one constant delay). A lower bound of what the run needs, so nothing that
    fits is refused; :func:`guard_run` checks the built scenario exactly afterwards.

    Parameters
    ----------
    counts : ScenarioCounts
    steps, trials : int or None
        ``--steps`` / ``--trials`` (None: the counts' ``run.steps`` / ``run.trials``).
    engines : sequence of str
        The engines the run may use (``"events"``, ``"vectorised"``).
    steps_name, trials_name : str
        The options to name (``--steps`` or ``run.steps``, ...).

    Raises
    ------
    ResourceError
        One line, naming the option, N and the estimated links.
    """
    K = counts.steps if steps is None else int(steps)
    M = counts.trials if trials is None else int(trials)
    n, N, L = counts.n_states, counts.n_agents, counts.links
    what = (f"N = {N:,} agents, about {L:,} links, n = {n} states; estimated from the "
            "scenario's counts before building the network")
    check_memory(NETWORK_BUILD_BYTES_PER_LINK * L, "network.agents",
                 f"building the network ({what})", N)
    total, one, engine = min(
        (*run_bytes(counts, K, M, e), e) for e in (set(engines) or {"events", "vectorised"}))
    held = NETWORK_HELD_BYTES_PER_LINK * L  # the network stays while the run goes
    check_memory(held + one, steps_name, f"one trial ({engine} engine, {what})", K)
    check_memory(held + total, trials_name, f"the run ({engine} engine, {K} steps x {M} "
                 f"trials, {what})", M)


def run_bytes(scenario: Any, steps: int, trials: int, engine: str, *,
              keep_estimates: bool = False) -> tuple[int, int]:
    """(peak bytes, bytes of one trial) of a Monte Carlo run of one family.

    The runner keeps every trial's result until the family is summarised (states,
    measurements, squared errors; estimates too in the kernel or with
    ``keep_estimates``), on top of the engine's working set: one kernel trial, or one
    lockstep batch as :func:`netsim.vectorised.run_vectorised` splits the trials.
    """
    n, N, L, m, _, _ = _sizes(scenario)
    K1 = int(steps) + 1
    kept = 8 * K1 * (n + m + N + (N * n if keep_estimates or engine != "vectorised" else 0))
    if keep_estimates:
        kept += 4 * K1 * N * N  # the kept trials' (K+1, N, N) effective-delay records
    if engine == "vectorised":
        per = max(1, BATCH_ELEMENTS // (max(1, L) * (K1 + 1)))
        batch = min(int(trials), per)
        work = vectorised_batch_bytes(scenario, steps, batch, record_estimates=keep_estimates)
        one = vectorised_batch_bytes(scenario, steps, 1, record_estimates=keep_estimates)
    else:
        work = one = kernel_trial_bytes(scenario, steps, record_delays=keep_estimates)
    return int(trials) * kept + work + 8 * K1 * int(trials), kept + one


def check_run(scenario: Any, steps: int, trials: int, engines: Sequence[str], *,
              steps_name: str = "steps", trials_name: str = "trials",
              keep_trials: bool = False) -> None:
    """Refuse a Monte Carlo run (:class:`ResourceError`) that cannot fit in memory.

    ``engines``: the engine of each family (they run one after another, so the
    largest counts). The parameter named is ``steps_name`` when one trial alone does
    not fit, else ``trials_name``.
    """
    worst = (0, 0, "events")
    for engine in set(engines) or {"events"}:
        total, one = run_bytes(scenario, steps, trials, engine, keep_estimates=keep_trials)
        worst = max(worst, (total, one, engine))
    total, one, engine = worst
    limit, _ = memory_limit()
    n, N, L, _, _, _ = _sizes(scenario)
    shape = f"{steps} steps x {trials} trials, N = {N} agents, n = {n} states, {L} links"
    if one > limit:
        check_memory(one, steps_name, f"one trial ({engine} engine, N = {N} agents, "
                     f"n = {n} states, {L} links)", steps)
    check_memory(total, trials_name, f"the run ({engine} engine, {shape})", trials)


def guard_run(scenario: Any, steps: int | None, trials: int | None,
              engines: Sequence[str], trace: str | None = None) -> list[str]:
    """The command line's check of ``netsim run``: refuse what cannot fit, say what is capped.

    Parameters
    ----------
    scenario : Scenario
    steps, trials : int or None
        ``--steps`` / ``--trials`` (None: the scenario's ``run.steps`` / ``run.trials``,
        named so in the message).
    engines : sequence of str
        The engine (``"events"`` or ``"vectorised"``) each family will run in
        (:func:`netsim.runner.planned_engines`).
    trace : str, optional
        The ``--trace`` path: the trace files must fit on its file system.

    Returns
    -------
    list of str
        Notes for stderr (e.g. delays beyond the last step, which never arrive).
    """
    K = scenario.steps if steps is None else int(steps)
    M = scenario.trials if trials is None else int(trials)
    engines = list(engines)
    check_run(scenario, K, M, engines, steps_name="--steps" if steps is not None
              else "run.steps", trials_name="--trials" if trials is not None
              else "run.trials")
    if trace is not None:
        check_trace_size(scenario, trace)
        folder = Path(trace).resolve().parent
        if folder.is_dir():
            need = trace_bytes(scenario, K) * M * max(1, len(engines))
            free = shutil.disk_usage(folder).free
            if need > free:
                raise ResourceError(
                    f"--trace {trace}: the trace files need about {format_bytes(need)}, more "
                    f"than the {format_bytes(free)} free on {folder}; lower --trials or "
                    f"--steps", "--trace", need, free)
    notes = []
    longest = max(int(scenario.max_delay), int(scenario.delay_bound))
    if longest > K:
        notes.append(
            f"delays up to {longest} steps exceed the {K} steps of the run: a message "
            f"delayed past step {K} never arrives (and a block period beyond it never "
            f"ends), so the vectorised engine builds A^r only up to r = {K}")
    return notes


# -- dense linear algebra ---------------------------------------------------------------


def eig_cost(dim: int, *, vectors: bool = False) -> tuple[float, float]:
    """(bytes, seconds) of dense eigenvalues of a real ``dim x dim`` matrix.

    About 10 dim^3 flops for the values (Hessenberg + QR), 25 dim^3 with vectors;
    memory: the matrix, LAPACK's copy and workspace, complex vectors.
    """
    d = float(dim)
    flops = (25.0 if vectors else 10.0) * d ** 3
    memory = d * d * 8 * (2 + (2 if vectors else 0)) + 64 * d * 8
    return memory, flops / FLOPS


def exact_observability_cost(n: int, n_agents: int) -> tuple[float, float]:
    """(bytes, seconds) of the exact observability checks of an (n, N) scenario:
    the PBH screening eigendecomposition of the (N n)-dimensional pair (P kron A,
    D_C-bar) and of A."""
    mem_big, t_big = eig_cost(n * n_agents, vectors=True)
    mem_a, t_a = eig_cost(n, vectors=True)
    return max(mem_big, mem_a), t_big + t_a


def check_gain_design(scenario: Any, method: str | None = None,
                      parameter: str = "plant.A") -> None:
    """Refuse a gain design (:class:`ResourceError`) that cannot run here.

    Costs: the PBH observability test of (P kron A, D_C-bar) (an (N n)-dimensional
    eigendecomposition) and an SDP whose largest semidefinite block is 2 N n
    (LCSYS2022 eq. 13; the CCL design has two N n x N n matrix variables): the
    first-order solver projects on that cone every iteration (a symmetric
    eigendecomposition of size 2 N n, about 100 iterations) and stores the
    constraint matrix.
    Explicit gains (``[gains] K``) need only the certificate (the same SDP).
    """
    n = int(scenario.plant.n_states)
    N = int(scenario.n_agents)
    Nn = n * N
    what = f"gain design for n = {n} states x N = {N} agents (N n = {Nn})"
    from netsim.estimators.gains import LARGE_LMI_STATES, LOCAL_AUTO_MIN_STATES

    spec = getattr(scenario, "gains", None)
    chosen = method or getattr(spec, "method", "lmi")
    if chosen == "refined":
        chosen = getattr(spec, "refine_from", None) or "auto"
    if chosen == "local" or (chosen == "auto" and Nn > LOCAL_AUTO_MIN_STATES):
        # the local design: the structured spectral radius (ARPACK, Krylov basis of
        # about 40 vectors of N n, the block-sparse operator of nnz(P) n x n blocks,
        # stored twice) per gain scale tried; no SDP, no N n eigendecomposition
        L = len(scenario.link_table) if hasattr(scenario, "link_table") else N * N
        memory = 8.0 * Nn * 60 + 2 * 8.0 * (L + N) * n * n
        check_memory(memory, parameter, what + " (local design)", f"{n} x {n}",
                     "use fewer agents N")
        return
    hint = ("use fewer states n or agents N, or [gains] method = 'local' (or 'auto') "
            "for large networks")
    mem_obs, t_obs = exact_observability_cost(n, N)

    # up to LARGE_LMI_STATES an interior-point solve of the 2 N n cone; above it the
    # split form (one N n cone) with SCS
    cone = 2 * Nn if Nn <= LARGE_LMI_STATES else Nn
    mem_sdp = 8.0 * cone * cone * 6
    # about 2000 first-order iterations over the bisection's solves, each a symmetric
    # eigendecomposition (9 d^3 flops, at about four times the non-symmetric rate)
    t_sdp = 2000 * 9.0 * float(cone) ** 3 / (4 * FLOPS)
    check_memory(max(mem_obs, mem_sdp), parameter, what, f"{n} x {n}", hint)
    check_time(t_obs + t_sdp, parameter, what, f"{n} x {n}", hint)


def analysis_cost(n: int, n_agents: int, taus: Sequence[int]) -> tuple[float, float]:
    """(bytes, seconds) of the exact spectral radii of the augmented closed loops
    (compensated and uncompensated, dimension N n (tau + 1)) for every tau in ``taus``.

    Dense eigenvalues up to :data:`netsim.models.augmented.DENSE_SIZE_THRESHOLD`;
    above it ARPACK on the structured operator (Krylov basis of 2k + 1 vectors, about
    ARPACK_MAXITER / 3 restarts of that many block-companion products of
    N n^2 (tau + 1) flops each) with the dense fallback up to DENSE_FALLBACK_MAX.
    """
    from netsim.models.augmented import (
        ARPACK_K,
        ARPACK_MAXITER,
        DENSE_FALLBACK_MAX,
        DENSE_SIZE_THRESHOLD,
    )

    Nn = n * n_agents
    memory = 0.0
    seconds = 0.0
    stop = 10 * time_limit()  # past this the sum only confirms a refusal
    # the largest first: the memory peak (a range is walked lazily, never listed)
    ordered = (reversed(taus) if isinstance(taus, range) and taus.step > 0
               else sorted(taus, reverse=True))
    for tau in ordered:
        if seconds > stop:
            break
        dim = Nn * (int(tau) + 1)
        if dim <= DENSE_SIZE_THRESHOLD:
            mem, sec = eig_cost(dim)
        else:
            ncv = 2 * ARPACK_K + 1
            mem = 16.0 * dim * (ncv + 4) + 8.0 * (int(tau) + 2) * n * n
            matvecs = ncv * ARPACK_MAXITER / 3
            sec = matvecs * 2.0 * (n * Nn + Nn) * (int(tau) + 1) / FLOPS
            if dim <= DENSE_FALLBACK_MAX:  # ARPACK often fails here: dense fallback
                fallback = eig_cost(dim)
                mem, sec = max(mem, fallback[0]), sec + fallback[1]
        memory = max(memory, mem)
        seconds += 2 * sec
    return memory, seconds


def check_analysis(n: int, n_agents: int, taus: Sequence[int], parameter: str,
                   what: str, value: Any = None) -> float:
    """Refuse an analysis (:class:`ResourceError`) whose estimate exceeds the limits;
    returns the estimated seconds."""
    memory, seconds = analysis_cost(n, n_agents, taus)
    check_memory(memory, parameter, what, value)
    check_time(seconds, parameter, what, value)
    return seconds
