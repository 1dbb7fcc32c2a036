"""Link models: delay distributions, losses, outages, buffers, serialisation, replay.

Everything here is plain numpy (and scipy for quantiles); the event kernel
(:mod:`netsim.links`) applies it. Every random sampler owns its generator, derived
by name from a seed with :func:`netsim.models.seeding.stream`, so adding a loss model
or a delay model never changes the numbers another one sees. The asynchronous delays of
the links sharing a configuration come from one stream per trial as a (messages x
links) table (seed layout 2), so adding or removing one of those links changes the
others' draws.

Delays
------
A *delay distribution* (:class:`DelayDistribution`) draws raw delays in one unit:

* ``"steps"``: integer step delays d >= 0; a message sent at step s is usable by
  the receiver's update at step s + 1 + d (DESIGN.md).
* ``"time"``: continuous latencies l >= 0 in the time unit of the sampling period
  Ts; the step delay is d = max(ceil(l / Ts) - 1, 0)
  (:func:`netsim.models.delays.latency_to_steps`).

Available: :class:`ConstantDelay`, :class:`UniformDelay` (steps or time),
:class:`GeometricDelay` (steps), :class:`ShiftedGamma` and :class:`ShiftedPareto`
(time; Pareto type II / Lomax, a heavy tail), :class:`EmpiricalDelay` (resampled
from a one-column CSV of measured latencies) and trace replay (:class:`TraceReplay`:
the per-link delays *and* losses recorded in an earlier MCAP trace, message by
message by per-link sequence number).

:class:`DistributionDelays` turns a distribution into a kernel delay model
(:class:`netsim.models.delays.DelayModel`) with one of three *modes*, the cases of the
delay-tolerant paper's Fig. 2:

* ``"asynchronous"`` (time-varying): an independent draw per link per message, from
  the trial's one stream of the links sharing the configuration (a link with a delay
  of its own: its own stream); messages can be reordered;
* ``"synchronous"`` (time-varying): one draw per sending step, shared by every link
  using the model;
* ``"fixed"`` (asynchronous, time-invariant): one draw per link, made once from a
  scenario-level seed (the same in every trial), like LCSYS2022's heterogeneous delays.

Losses, outages
---------------
:class:`BernoulliLoss` loses each message independently with probability p.
:class:`GilbertElliottLoss` is a two-state Markov chain advanced once per message:
good -> bad with probability p, bad -> good with probability r, and a message is lost
with probability ``loss_good`` / ``loss_bad`` in the state it finds; the first
message finds the stationary distribution (P(bad) = p / (p + r)). With
``loss_good = 0`` and ``loss_bad = 1`` the loss bursts are the sojourns in the bad
state, geometric with mean length 1 / r messages. :class:`Outages` drops every
message sent at a step s in one of the half-open intervals [start, end).

Buffers
-------
A link's *buffer* is the number of messages it holds **in flight**: sent and
accepted by the link (not lost, not on a down link), whose delivery time has not
been reached yet. ``capacity`` bounds that number; when a message is sent while
``capacity`` messages are in flight, the policy decides:

* ``"drop-tail"``: the new message is dropped (reason ``buffer full (drop-tail)``);
* ``"drop-oldest"``: the in-flight message sent earliest (smallest sequence number,
  i.e. oldest time-stamp) is cancelled, dropped at that instant (reason
  ``buffer full (drop-oldest)``), and the new message is accepted;
* ``"keep-latest"``: as drop-oldest when full, and in addition a message whose
  delivery comes after that of a *newer* message on the same link is dropped on
  arrival (reason ``superseded (keep-latest)``): the link never delivers out of
  order, it keeps only the latest (a sequence-numbered "latest value" channel). With
  ``capacity = None`` only the superseding applies.

The papers' buffer, ``capacity = "tau+1"``: LCSYS2022 Assumption 2 calls a delay
bound tau-bar "a tau-bar + 1-slot transmission buffer". With one message per step and
every delay d <= tau-bar, at most tau-bar + 1 messages are ever in flight (the ones
sent at k - tau-bar .. k when step k's message leaves), so such a buffer never drops.
With larger delays it overflows only when tau-bar + 1 messages are in flight, and then
(drop-oldest, its default policy) the message it drops is always one whose delay
exceeds tau-bar; a late message can still be delivered if the buffer never filled
while it was in flight.

Serialisation
-------------
A link with a ``bandwidth`` (bits per time unit of Ts) adds the serialisation time
``message_size / bandwidth`` to every message's latency. A step delay d counts as
the latency (d + 1) Ts (the latest arrival with that step delay), so on a step-delay
model any positive serialisation time moves the message to a later step; on a
continuous-latency model it is added to the latency before the step rule.

Order of the checks on sending: link availability (topology), outages, loss, buffer.
The delay is drawn first, for every message (lost or not), so that a link's n-th
message always gets the delay model's n-th draw (trace replay relies on it).
"""

from __future__ import annotations

import csv
import math
from bisect import bisect_right
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from netsim.models.delays import BatchedDraws, DelayModel, LinkBlockDraws, latency_to_steps
from netsim.models.delaysources import delay_source
from netsim.models.seeding import SeedLike, stream

__all__ = [
    "DELAY_DISTRIBUTIONS",
    "DELAY_MODES",
    "BUFFER_POLICIES",
    "LOSS_MODELS",
    "NOMINAL_QUANTILE",
    "DelayDistribution",
    "ConstantDelay",
    "UniformDelay",
    "GeometricDelay",
    "ShiftedGamma",
    "ShiftedPareto",
    "EmpiricalDelay",
    "DistributionDelays",
    "SerialisedDelays",
    "BernoulliLoss",
    "GilbertElliottLoss",
    "Outages",
    "LinkRecord",
    "TraceReplay",
    "TraceDelays",
    "TraceLoss",
    "LinkModel",
    "NetworkLinks",
    "DelayConfig",
    "LossConfig",
    "BufferConfig",
    "LinkConfig",
    "LinksSpec",
    "load_latency_csv",
    "load_trace_replay",
    "serialisation_time",
]

Link = tuple[int, int]
Unit = Literal["steps", "time"]

#: Names accepted for ``distribution`` in a scenario's ``[links]`` delay table.
DELAY_DISTRIBUTIONS = ("constant", "uniform", "geometric", "gamma", "pareto", "empirical",
                       "trace")
#: How a distribution's draws are laid out over links and time (see module docstring).
DELAY_MODES = ("asynchronous", "synchronous", "fixed")
#: Buffer policies (see module docstring).
BUFFER_POLICIES = ("drop-tail", "drop-oldest", "keep-latest")
#: Loss models.
LOSS_MODELS = ("none", "bernoulli", "gilbert-elliott")
#: Unbounded distributions report this quantile's step delay as their nominal bound.
NOMINAL_QUANTILE = 0.999
# -- distributions ---------------------------------------------------------------------


def _finite(value: float, what: str, minimum: float | None = None,
            strict: bool = False) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{what} must be finite, got {value}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{what} must be {'>' if strict else '>='} {minimum:g}, got {value:g}")
    return value


class DelayDistribution:
    """A distribution of raw delays in ``unit`` (``"steps"`` or ``"time"``).

    Subclasses implement :meth:`sample`, :meth:`cdf`, :meth:`quantile`, :meth:`mean`
    and :attr:`upper` (the supremum of the support, ``inf`` if unbounded).
    """

    name = "distribution"
    unit: Unit = "time"

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        raise NotImplementedError

    def cdf(self, x: Any) -> np.ndarray:
        """P(X <= x)."""
        raise NotImplementedError

    def quantile(self, q: float) -> float:
        raise NotImplementedError

    def mean(self) -> float:
        raise NotImplementedError

    @property
    def upper(self) -> float:
        return math.inf

    @property
    def discrete(self) -> bool:
        return self.unit == "steps"

    def step_bound(self, sample_period: float = 1.0) -> int:
        """Largest step delay a draw can have; for an unbounded distribution the step
        delay of its :data:`NOMINAL_QUANTILE` quantile (a nominal bound)."""
        top = self.upper if math.isfinite(self.upper) else self.quantile(NOMINAL_QUANTILE)
        if self.unit == "steps":
            return int(top)
        return latency_to_steps(top, sample_period)

    def describe(self) -> dict[str, Any]:
        return {"distribution": self.name, "unit": self.unit}


class ConstantDelay(DelayDistribution):
    """Always ``value`` (steps: a non-negative integer; time: a latency >= 0)."""

    name = "constant"

    def __init__(self, value: float, unit: Unit = "steps") -> None:
        self.unit = unit
        self.value = _finite(value, "value", 0.0)
        if unit == "steps" and self.value != int(self.value):
            raise ValueError(f"a step delay must be an integer, got {value}")
        if unit == "steps":
            self.value = int(self.value)

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        return np.full(size, self.value, dtype=int if self.unit == "steps" else float)

    def cdf(self, x: Any) -> np.ndarray:
        return (np.asarray(x, dtype=float) >= self.value).astype(float)

    def quantile(self, q: float) -> float:
        return float(self.value)

    def mean(self) -> float:
        return float(self.value)

    @property
    def upper(self) -> float:
        return float(self.value)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "value": self.value}


class UniformDelay(DelayDistribution):
    """Uniform on {low, ..., high} (steps) or on [low, high] (time)."""

    name = "uniform"

    def __init__(self, low: float, high: float, unit: Unit = "steps") -> None:
        self.unit = unit
        self.low = _finite(low, "low", 0.0)
        self.high = _finite(high, "high", 0.0)
        if self.high < self.low:
            raise ValueError(f"high ({high:g}) must be >= low ({low:g})")
        if unit == "steps":
            if self.low != int(self.low) or self.high != int(self.high):
                raise ValueError(f"step delays must be integers, got low={low}, high={high}")
            self.low, self.high = int(self.low), int(self.high)

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        if self.unit == "steps":
            return rng.integers(int(self.low), int(self.high) + 1, size=size)
        return rng.uniform(self.low, self.high, size=size)

    def cdf(self, x: Any) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self.unit == "steps":
            count = self.high - self.low + 1
            return np.clip((np.floor(x) - self.low + 1) / count, 0.0, 1.0)
        if self.high == self.low:
            return (x >= self.low).astype(float)
        return np.clip((x - self.low) / (self.high - self.low), 0.0, 1.0)

    def quantile(self, q: float) -> float:
        if self.unit == "steps":
            count = self.high - self.low + 1
            return float(self.low + max(math.ceil(q * count) - 1, 0))
        return self.low + q * (self.high - self.low)

    def mean(self) -> float:
        return (self.low + self.high) / 2.0

    @property
    def upper(self) -> float:
        return float(self.high)

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "low": self.low, "high": self.high}


class GeometricDelay(DelayDistribution):
    """Step delay shift + G, P(G = k) = (1 - p)^k p for k = 0, 1, ... (unbounded).

    Mean shift + (1 - p) / p: e.g. the number of retransmissions of a message whose
    every attempt succeeds with probability p, one step each.
    """

    name = "geometric"
    unit: Unit = "steps"

    def __init__(self, p: float, shift: int = 0) -> None:
        self.p = _finite(p, "p", 0.0, strict=True)
        if self.p > 1:
            raise ValueError(f"p must be in (0, 1], got {p}")
        if int(shift) != shift or shift < 0:
            raise ValueError(f"shift must be a non-negative integer, got {shift}")
        self.shift = int(shift)

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        return self.shift + rng.geometric(self.p, size=size) - 1

    def cdf(self, x: Any) -> np.ndarray:
        k = np.floor(np.asarray(x, dtype=float)) - self.shift
        return np.where(k < 0, 0.0, 1.0 - (1.0 - self.p) ** (k + 1))

    def pmf(self, k: Any) -> np.ndarray:
        k = np.asarray(k) - self.shift
        return np.where(k < 0, 0.0, self.p * (1.0 - self.p) ** np.maximum(k, 0))

    def quantile(self, q: float) -> float:
        if self.p == 1.0:
            return float(self.shift)
        k = math.ceil(math.log1p(-q) / math.log1p(-self.p)) - 1
        return float(self.shift + max(k, 0))

    def mean(self) -> float:
        return self.shift + (1.0 - self.p) / self.p

    @property
    def upper(self) -> float:
        return float(self.shift) if self.p == 1.0 else math.inf

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "p": self.p, "shift": self.shift}


class ShiftedGamma(DelayDistribution):
    """Latency shift + Gamma(shape, scale) (time units of Ts); mean shift + shape * scale."""

    name = "gamma"
    unit: Unit = "time"

    def __init__(self, shape: float, scale: float, shift: float = 0.0) -> None:
        self.shape = _finite(shape, "shape", 0.0, strict=True)
        self.scale = _finite(scale, "scale", 0.0, strict=True)
        self.shift = _finite(shift, "shift", 0.0)

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        return self.shift + rng.gamma(self.shape, self.scale, size=size)

    def cdf(self, x: Any) -> np.ndarray:
        from scipy.stats import gamma

        return gamma.cdf(np.asarray(x, dtype=float) - self.shift, self.shape, scale=self.scale)

    def quantile(self, q: float) -> float:
        from scipy.stats import gamma

        return float(self.shift + gamma.ppf(q, self.shape, scale=self.scale))

    def mean(self) -> float:
        return self.shift + self.shape * self.scale

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "shape": self.shape, "scale": self.scale,
                "shift": self.shift}


class ShiftedPareto(DelayDistribution):
    """Latency shift + Lomax(alpha, scale): a heavy (power-law) tail.

    P(l - shift > x) = (1 + x / scale)^(-alpha) for x >= 0 (Pareto type II); the mean
    shift + scale / (alpha - 1) exists for alpha > 1, the variance for alpha > 2.
    """

    name = "pareto"
    unit: Unit = "time"

    def __init__(self, alpha: float, scale: float, shift: float = 0.0) -> None:
        self.alpha = _finite(alpha, "alpha", 0.0, strict=True)
        self.scale = _finite(scale, "scale", 0.0, strict=True)
        self.shift = _finite(shift, "shift", 0.0)

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        return self.shift + self.scale * rng.pareto(self.alpha, size=size)

    def cdf(self, x: Any) -> np.ndarray:
        z = np.maximum(np.asarray(x, dtype=float) - self.shift, 0.0)
        return 1.0 - (1.0 + z / self.scale) ** (-self.alpha)

    def quantile(self, q: float) -> float:
        return self.shift + self.scale * ((1.0 - q) ** (-1.0 / self.alpha) - 1.0)

    def mean(self) -> float:
        return self.shift + self.scale / (self.alpha - 1.0) if self.alpha > 1 else math.inf

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "alpha": self.alpha, "scale": self.scale,
                "shift": self.shift}


class EmpiricalDelay(DelayDistribution):
    """Resampling (with replacement, uniformly) of measured delays.

    Parameters
    ----------
    values : sequence of float
        Measured latencies (time units of Ts) or step delays (``unit="steps"``,
        integers), all >= 0.
    unit : ``"time"`` or ``"steps"``
    source : str
        Where the values came from (for messages).
    """

    name = "empirical"

    def __init__(self, values: Sequence[float], unit: Unit = "time", source: str = "") -> None:
        self.unit = unit
        arr = np.asarray(values, dtype=float).ravel()
        where = f" in {source}" if source else ""
        if arr.size == 0:
            raise ValueError(f"no delay values{where}")
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise ValueError(f"delays must be finite and >= 0{where}")
        if unit == "steps":
            if np.any(arr != np.round(arr)):
                raise ValueError(f"step delays must be integers{where}")
            arr = arr.astype(int)
        self.values = arr
        self.source = source

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        return self.values[rng.integers(0, self.values.size, size=size)]

    def cdf(self, x: Any) -> np.ndarray:
        ordered = np.sort(self.values)
        return np.searchsorted(ordered, np.asarray(x, dtype=float), side="right") / ordered.size

    def quantile(self, q: float) -> float:
        return float(np.quantile(self.values, q, method="inverted_cdf"))

    def mean(self) -> float:
        return float(self.values.mean())

    @property
    def upper(self) -> float:
        return float(self.values.max())

    def describe(self) -> dict[str, Any]:
        return {**super().describe(), "file": self.source, "count": int(self.values.size)}


def load_latency_csv(path: str | Path, *, scale: float = 1.0, unit: Unit = "time"
                     ) -> EmpiricalDelay:
    """Read a one-column CSV of measured latencies into an :class:`EmpiricalDelay`.

    One number per line; a first line that is not a number is taken as a header;
    blank lines are skipped. Each value is multiplied by ``scale`` (e.g. 0.001 for
    milliseconds when Ts is in seconds).

    Raises
    ------
    ValueError
        Naming the file (and the line): unreadable, empty, more than one column,
        not a number, negative, NaN or infinite.
    """
    path = Path(path)
    scale = _finite(scale, "scale", 0.0, strict=True)
    from netsim.models.inputfiles import MAX_TABLE_BYTES, read_input_bytes

    try:
        text = read_input_bytes(path, "latency file", MAX_TABLE_BYTES).decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"latency file {path} is not UTF-8 text") from None
    values: list[float] = []
    for number, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not cells or all(not c for c in cells):
            continue
        if len(cells) != 1:
            raise ValueError(f"latency file {path}, line {number}: expected one column, "
                             f"got {len(cells)}")
        try:
            value = float(cells[0])
        except ValueError:
            if not values and number == 1:
                continue  # header
            raise ValueError(f"latency file {path}, line {number}: not a number: "
                             f"{cells[0]!r}") from None
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"latency file {path}, line {number}: latency must be finite "
                             f"and >= 0, got {cells[0]}")
        values.append(value * scale)
    if not values:
        raise ValueError(f"latency file {path} has no latencies")
    return EmpiricalDelay(values, unit=unit, source=str(path))


# -- delay models for the kernel -------------------------------------------------------


class DistributionDelays:
    """A :class:`DelayDistribution` as a kernel delay model, in one of :data:`DELAY_MODES`.

    Parameters
    ----------
    distribution : DelayDistribution
    mode : str
        ``asynchronous`` (a draw per link per message: for the links of ``links``
        from the trial's one stream ``(seed, name, "asynchronous")`` as (messages,
        links) blocks, :class:`netsim.models.delays.LinkBlockDraws`, seed layout 2;
        a link outside ``links`` from its own stream ``(seed, name, "j-i")``),
        ``synchronous`` (a draw per sending step shared by all links, stream
        ``(seed, name, "synchronous")``) or ``fixed`` (one draw per link, stream
        ``(static_seed, name, "fixed", "j-i")``, the same in every trial).
    seed : seed-like
        The trial's seed (time-varying modes).
    static_seed : seed-like
        The scenario-level seed of ``fixed`` draws.
    name : str
        Stream name prefix.
    sample_period : float
        Ts (for the step bound of latencies).
    links : sequence of (int, int), optional
        The link set whose asynchronous draws share one block stream.
    """

    def __init__(self, distribution: DelayDistribution, mode: str = "asynchronous",
                 seed: SeedLike = 0, static_seed: SeedLike = 0, *, name: str = "links/delay",
                 sample_period: float = 1.0, links: Sequence[Link] | None = None) -> None:
        if mode not in DELAY_MODES:
            raise ValueError(f"unknown delay mode {mode!r}; expected one of "
                             f"{', '.join(DELAY_MODES)}")
        self.distribution = distribution
        self.mode = mode
        self.unit: Unit = distribution.unit
        self.time_invariant = mode == "fixed" or isinstance(distribution, ConstantDelay)
        self.max_delay = distribution.step_bound(sample_period)
        self._seed = seed
        self._static_seed = static_seed
        self._name = name
        self._per_link: dict[Link, Any] = {}
        self._steps: list = []
        self._sync: BatchedDraws | None = None
        #: the link set's block stream (asynchronous mode with links)
        self.block = (LinkBlockDraws(stream(seed, name, "asynchronous"), distribution.sample,
                                     links)
                      if mode == "asynchronous" and links is not None else None)

    def _block_of(self, sender: int, receiver: int) -> LinkBlockDraws | None:
        """The link set's block stream if the link is in it, else None."""
        block = self.block
        return block if block is not None and (sender, receiver) in block.column else None

    def _sampler(self, sender: int, receiver: int) -> BatchedDraws:
        sampler = self._per_link.get((sender, receiver))
        if sampler is None:
            sampler = self._per_link[(sender, receiver)] = BatchedDraws(
                stream(self._seed, self._name, f"{sender}-{receiver}"),
                self.distribution.sample)
        return sampler

    def _sync_steps(self, last_step: int) -> None:
        if self._sync is None:
            self._sync = BatchedDraws(stream(self._seed, self._name, "synchronous"),
                                      self.distribution.sample)
        if len(self._steps) <= last_step:
            self._steps.extend(self._sync.take(last_step + 1 - len(self._steps)).tolist())

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        mode = self.mode
        if mode == "asynchronous":
            if (block := self._block_of(sender, receiver)) is not None:
                return block.next((sender, receiver))
            return self._sampler(sender, receiver).next()
        if mode == "synchronous":
            self._sync_steps(send_step)
            return self._steps[send_step]
        value = self._per_link.get((sender, receiver))
        if value is None:
            rng = stream(self._static_seed, self._name, "fixed", f"{sender}-{receiver}")
            value = self._per_link[(sender, receiver)] = self.distribution.sample(rng, 1)[0].item()
        return value

    def sampler(self, sender: int, receiver: int) -> Any:
        """The link's ``draw`` as one callable send_step -> delay."""
        if self.mode == "asynchronous":
            if (block := self._block_of(sender, receiver)) is not None:
                return block.sampler((sender, receiver))
            return self._sampler(sender, receiver).sampler
        return lambda send_step: self.draw(sender, receiver, send_step)

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """The delays ``draw`` gives for messages sent at ``send_steps``, in order."""
        count = len(send_steps)
        if self.mode == "asynchronous":
            if (block := self._block_of(sender, receiver)) is not None:
                return block.take([(sender, receiver)], count)[:, 0]
            return self._sampler(sender, receiver).take(count)
        if self.mode == "synchronous":
            steps = np.asarray(send_steps, dtype=np.int64)
            if not steps.size:
                return np.zeros(0)
            self._sync_steps(int(steps.max()))
            return np.asarray(self._steps)[steps]
        return np.full(count, self.draw(sender, receiver, 0))

    def draw_block(self, links: Sequence[Link], send_steps: np.ndarray) -> np.ndarray:
        """:meth:`draw_many` of each of ``links``, shape (len(send_steps), len(links))."""
        if self.block is not None and all(link in self.block.column for link in links):
            return self.block.take(links, len(send_steps))
        if not len(links):
            return np.zeros((len(send_steps), 0))
        return np.stack([np.asarray(self.draw_many(j, i, send_steps)) for j, i in links],
                        axis=1)


class SerialisedDelays:
    """A delay model plus a constant serialisation time (latency units of Ts).

    A step delay d of the base model counts as the latency (d + 1) Ts, so the result
    is a latency (``unit = "time"``) of (d + 1) Ts + ``extra`` or l + ``extra``.
    """

    unit: Unit = "time"

    def __init__(self, base: DelayModel, extra: float, sample_period: float = 1.0) -> None:
        self.base = base
        self.extra = _finite(extra, "serialisation time", 0.0)
        self.sample_period = float(sample_period)
        self.time_invariant = bool(base.time_invariant)
        self._steps = base.unit == "steps"
        # base.max_delay = d means a latency of at most (d + 1) Ts
        self.max_delay = latency_to_steps((base.max_delay + 1) * self.sample_period + self.extra,
                                          self.sample_period)

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        raw = self.base.draw(sender, receiver, send_step)
        if self._steps:
            return (int(raw) + 1) * self.sample_period + self.extra
        return float(raw) + self.extra

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """The latencies ``draw`` gives for messages sent at ``send_steps``, in order."""
        many = getattr(self.base, "draw_many", None)
        if many is None:
            raw = np.array([self.base.draw(sender, receiver, int(s)) for s in send_steps])
        else:
            raw = np.asarray(many(sender, receiver, send_steps))
        if self._steps:
            return (raw.astype(np.int64) + 1) * self.sample_period + self.extra
        return raw.astype(float) + self.extra


def serialisation_time(message_size: float, bandwidth: float) -> float:
    """``message_size`` (bits) / ``bandwidth`` (bits per time unit of Ts)."""
    return _finite(message_size, "message_size", 0.0) / _finite(bandwidth, "bandwidth", 0.0,
                                                                strict=True)


# -- losses and outages ----------------------------------------------------------------


class BernoulliLoss:
    """Each message lost independently with probability ``p`` (own stream ``rng``)."""

    reason = "loss: bernoulli"

    def __init__(self, p: float, rng: np.random.Generator) -> None:
        self.p = _finite(p, "p", 0.0)
        if self.p > 1:
            raise ValueError(f"loss probability must be in [0, 1], got {p}")
        self._u = BatchedDraws(rng, lambda g, n: g.random(n))

    def drop_reason(self, step: int, sequence: int) -> str | None:
        return self.reason if self._u.next() < self.p else None


class GilbertElliottLoss:
    """Bursty loss: a two-state (good/bad) Markov chain advanced once per message.

    Parameters
    ----------
    p : float
        P(good -> bad) per message.
    r : float
        P(bad -> good) per message; the mean sojourn in the bad state is 1 / r messages.
    loss_good, loss_bad : float
        Loss probability of a message in each state (defaults 0 and 1: the
        Gilbert model, whose loss bursts have mean length 1 / r).
    rng : numpy.random.Generator
        Own stream.

    The first message finds the stationary state distribution, P(bad) = p / (p + r);
    every later message first moves the chain one step. The long-run loss rate is
    (r loss_good + p loss_bad) / (p + r).
    """

    REASON_GOOD = "loss: gilbert-elliott (good state)"
    REASON_BAD = "loss: gilbert-elliott (bad state)"

    def __init__(self, p: float, r: float, rng: np.random.Generator, loss_good: float = 0.0,
                 loss_bad: float = 1.0) -> None:
        for name, value in (("p", p), ("r", r), ("loss_good", loss_good),
                            ("loss_bad", loss_bad)):
            v = _finite(value, name, 0.0)
            if v > 1:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        if p + r <= 0:
            raise ValueError("p + r must be > 0 (the chain must be able to move)")
        self.p, self.r = float(p), float(r)
        self.loss_good, self.loss_bad = float(loss_good), float(loss_bad)
        self._u = BatchedDraws(rng, lambda g, n: g.random(n))
        self.bad: bool | None = None

    @property
    def stationary_bad(self) -> float:
        return self.p / (self.p + self.r)

    @property
    def loss_rate(self) -> float:
        """Long-run fraction of messages lost."""
        pb = self.stationary_bad
        return (1 - pb) * self.loss_good + pb * self.loss_bad

    @property
    def mean_burst_length(self) -> float:
        """Mean sojourn in the bad state, 1 / r (the mean loss burst for the Gilbert model)."""
        return math.inf if self.r == 0 else 1.0 / self.r

    def drop_reason(self, step: int, sequence: int) -> str | None:
        u = self._u.next()
        if self.bad is None:
            self.bad = u < self.stationary_bad
        elif self.bad:
            self.bad = u >= self.r
        else:
            self.bad = u < self.p
        if self.bad:
            return self.REASON_BAD if self._u.next() < self.loss_bad else None
        return self.REASON_GOOD if self._u.next() < self.loss_good else None


class Outages:
    """The link is down for sending steps s in any half-open interval [start, end)."""

    reason = "outage"

    def __init__(self, intervals: Iterable[tuple[int, int]]) -> None:
        merged: list[list[int]] = []
        for start, end in sorted((int(a), int(b)) for a, b in intervals):
            if start < 0 or end < start:
                raise ValueError(f"outage interval [{start}, {end}) must have 0 <= start <= end")
            if merged and start <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], end)
            elif end > start:
                merged.append([start, end])
        self.intervals = tuple((a, b) for a, b in merged)
        self._starts = [a for a, _ in self.intervals]

    def down(self, step: int) -> bool:
        index = bisect_right(self._starts, step) - 1
        return index >= 0 and step < self.intervals[index][1]

    def drop_reason(self, step: int, sequence: int) -> str | None:
        return self.reason if self.down(step) else None


# -- trace replay ----------------------------------------------------------------------


@dataclass(frozen=True)
class LinkRecord:
    """What a trace recorded for one link, indexed by sequence number."""

    sent_steps: np.ndarray
    latencies: np.ndarray     # arrival_time - send_time (time units)
    delay_steps: np.ndarray
    on_boundary: bool         # every arrival at (s + 1 + d) Ts: a step-delay model
    dropped: Mapping[int, str]


class TraceReplay:
    """Per-link delays and losses recorded in a trace, replayed message by message.

    The n-th message sent on link (j, i) in the replay gets the n-th recorded message's
    delay (sequence number n) and is dropped if that one was dropped. When every
    recorded arrival lies exactly at (s + 1 + d) Ts (a step-delay model) and the
    replay has the same Ts, the step delays d are replayed (unit ``steps``); otherwise
    the latencies arrival - send (unit ``time``; exact to the last bit for Ts = 1).

    Parameters
    ----------
    records : mapping (j, i) -> LinkRecord
    sample_period : float
        Ts of the recorded run.
    source : str
        The trace file.
    """

    def __init__(self, records: Mapping[Link, LinkRecord], sample_period: float,
                 source: str = "") -> None:
        self.records = dict(records)
        self.sample_period = float(sample_period)
        self.source = source

    @property
    def links(self) -> list[Link]:
        return sorted(self.records)

    @property
    def on_boundary(self) -> bool:
        return all(r.on_boundary for r in self.records.values())

    @property
    def max_delay(self) -> int:
        sizes = [int(r.delay_steps.max()) for r in self.records.values() if r.delay_steps.size]
        return max(sizes, default=0)

    def messages(self, link: Link) -> int:
        return int(self.records[link].sent_steps.size)

    def describe(self) -> dict[str, Any]:
        return {"distribution": "trace", "file": self.source,
                "messages": {f"{j}->{i}": self.messages((j, i)) for j, i in self.links}}


def load_trace_replay(path: str | Path) -> TraceReplay:
    """Read the link events of an MCAP trace written by netsim into a :class:`TraceReplay`.

    ``models`` does not read traces itself: this calls the ``"trace"`` delay source of
    :mod:`netsim.models.delaysources`, which the ``netsim`` package registers
    (:func:`netsim.traces.linkdelays.load_trace_replay`, imported when first called).

    Raises
    ------
    ValueError
        Naming the file: not readable as a netsim trace, no link topics, or a link
        whose sequence numbers do not start at 0.
    """
    return delay_source("trace")(path)


class TraceDelays:
    """Kernel delay model replaying a :class:`TraceReplay` (one instance per run).

    Counts the draws per link: the n-th draw on a link is its message with sequence
    number n (the kernel draws exactly once per message, in sending order).
    """

    def __init__(self, replay: TraceReplay, sample_period: float = 1.0) -> None:
        self.replay = replay
        steps = replay.on_boundary and float(sample_period) == replay.sample_period
        self.unit: Unit = "steps" if steps else "time"
        self.time_invariant = False
        self.max_delay = replay.max_delay
        self._count: dict[Link, int] = {}

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        link = (sender, receiver)
        record = self.replay.records.get(link)
        if record is None:
            raise ValueError(f"trace {self.replay.source} has no link {sender}->{receiver}")
        n = self._count.get(link, 0)
        self._count[link] = n + 1
        if n >= record.sent_steps.size:
            raise ValueError(
                f"trace {self.replay.source} recorded {record.sent_steps.size} messages on "
                f"link {sender}->{receiver}; message {n} (sent at step {send_step}) has no "
                "recorded delay to replay"
            )
        if self.unit == "steps":
            return int(record.delay_steps[n])
        return float(record.latencies[n])


class TraceLoss:
    """Drops the messages a trace recorded as dropped on one link (by sequence number)."""

    def __init__(self, replay: TraceReplay, link: Link) -> None:
        self.dropped = replay.records[link].dropped

    def drop_reason(self, step: int, sequence: int) -> str | None:
        reason = self.dropped.get(sequence)
        return None if reason is None else f"trace: {reason}"


# -- per-link models and the network -----------------------------------------------


@dataclass
class LinkModel:
    """Everything the kernel applies on one link besides the scenario's delays.

    Attributes
    ----------
    delay : DelayModel or None
        The link's delay model (None: the simulation's).
    loss : object with drop_reason(step, sequence) -> str | None, or None
    outages : Outages or None
    buffer_capacity : int or None
        Largest number of messages in flight (see the module docstring); None: unbounded.
    buffer_policy : str
        One of :data:`BUFFER_POLICIES`.
    """

    delay: DelayModel | None = None
    loss: Any = None
    outages: Outages | None = None
    buffer_capacity: int | None = None
    buffer_policy: str = "drop-tail"

    def __post_init__(self) -> None:
        if self.buffer_policy not in BUFFER_POLICIES:
            raise ValueError(f"unknown buffer policy {self.buffer_policy!r}; expected one of "
                             f"{', '.join(BUFFER_POLICIES)}")
        if self.buffer_capacity is not None and int(self.buffer_capacity) < 1:
            raise ValueError(f"buffer capacity must be >= 1, got {self.buffer_capacity}")

    @property
    def trivial(self) -> bool:
        """No loss, outage or buffer: the kernel's plain (fastest) link suffices."""
        return (self.loss is None and (self.outages is None or not self.outages.intervals)
                and self.buffer_capacity is None and self.buffer_policy != "keep-latest")


class NetworkLinks:
    """The delay model of a run whose links have their own models.

    A :class:`netsim.models.delays.DelayModel` (so code that only needs delays keeps working)
    whose :meth:`link` gives the kernel each link's :class:`LinkModel`.

    Parameters
    ----------
    base : DelayModel
        Delays of links without a model of their own.
    links : mapping (j, i) -> LinkModel
    sample_period : float
    """

    def __init__(self, base: DelayModel, links: Mapping[Link, LinkModel],
                 sample_period: float = 1.0) -> None:
        self.base = base
        self.links = dict(links)
        self.sample_period = float(sample_period)
        models = [self._delay(link) for link in self.links] or [base]
        self.unit: Unit = "steps" if all(m.unit == "steps" for m in models) else "time"
        self.max_delay = int(max(m.max_delay for m in models))
        self.time_invariant = (all(m.time_invariant for m in models)
                               and all(lm.trivial for lm in self.links.values()))

    def _delay(self, link: Link) -> DelayModel:
        model = self.links.get(link)
        return model.delay if model is not None and model.delay is not None else self.base

    def link(self, sender: int, receiver: int) -> LinkModel | None:
        """The model of link sender -> receiver (its ``delay`` always set)."""
        model = self.links.get((sender, receiver))
        if model is None:
            return None
        if model.delay is None:
            model.delay = self.base
        return model

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        model = self._delay((sender, receiver))
        raw = model.draw(sender, receiver, send_step)
        if self.unit == "steps" or model.unit == "time":
            return raw
        return (int(raw) + 1) * self.sample_period

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """The delays ``draw`` gives for messages sent at ``send_steps``, in order."""
        model = self._delay((sender, receiver))
        many = getattr(model, "draw_many", None)
        if many is None:
            raw = np.array([model.draw(sender, receiver, int(s)) for s in send_steps])
        else:
            raw = np.asarray(many(sender, receiver, send_steps))
        if self.unit == "steps" or model.unit == "time":
            return raw
        return (raw.astype(np.int64) + 1) * self.sample_period


# -- configuration (parsed from a scenario, no randomness) ------------------------------


@dataclass(frozen=True)
class DelayConfig:
    """A delay distribution (or a trace replay) and its mode."""

    distribution: Any  # DelayDistribution | TraceReplay
    mode: str = "asynchronous"

    def describe(self) -> dict[str, Any]:
        out = dict(self.distribution.describe())
        if not isinstance(self.distribution, TraceReplay):
            out["mode"] = self.mode
        return out

    def step_bound(self, sample_period: float) -> int:
        if isinstance(self.distribution, TraceReplay):
            return self.distribution.max_delay
        return self.distribution.step_bound(sample_period)


@dataclass(frozen=True)
class LossConfig:
    """``model`` in :data:`LOSS_MODELS` with its parameters."""

    model: str = "none"
    p: float = 0.0
    r: float = 1.0
    loss_good: float = 0.0
    loss_bad: float = 1.0

    def build(self, rng: np.random.Generator) -> Any:
        if self.model == "bernoulli":
            return BernoulliLoss(self.p, rng)
        if self.model == "gilbert-elliott":
            return GilbertElliottLoss(self.p, self.r, rng, self.loss_good, self.loss_bad)
        return None

    def describe(self) -> dict[str, Any]:
        if self.model == "bernoulli":
            return {"model": self.model, "p": self.p}
        if self.model == "gilbert-elliott":
            return {"model": self.model, "p": self.p, "r": self.r,
                    "loss_good": self.loss_good, "loss_bad": self.loss_bad}
        return {"model": "none"}


@dataclass(frozen=True)
class BufferConfig:
    """``capacity`` (int, ``"tau+1"`` or None) and ``policy``."""

    capacity: int | str | None = None
    policy: str = "drop-tail"

    def resolve(self, tau: int) -> int | None:
        if self.capacity == "tau+1":
            return int(tau) + 1
        return None if self.capacity is None else int(self.capacity)

    def describe(self) -> dict[str, Any]:
        return {"capacity": self.capacity, "policy": self.policy}


@dataclass(frozen=True)
class LinkConfig:
    """The link settings of the scenario's ``[links]`` table (defaults or one link)."""

    delay: DelayConfig | None = None
    loss: LossConfig | None = None
    buffer: BufferConfig | None = None
    outages: tuple[tuple[int, int], ...] = ()
    bandwidth: float | None = None
    message_size: float | None = None

    def merged(self, override: Mapping[str, Any]) -> LinkConfig:
        """Copy with the given fields replaced."""
        values = {name: getattr(self, name) for name in
                  ("delay", "loss", "buffer", "outages", "bandwidth", "message_size")}
        values.update(override)
        return LinkConfig(**values)

    def serialisation(self, n_states: int) -> float:
        if self.bandwidth is None:
            return 0.0
        size = 64.0 * n_states if self.message_size is None else self.message_size
        return serialisation_time(size, self.bandwidth)

    def describe(self, n_states: int | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.delay is not None:
            out["delay"] = self.delay.describe()
        if self.loss is not None and self.loss.model != "none":
            out["loss"] = self.loss.describe()
        if self.buffer is not None:
            out["buffer"] = self.buffer.describe()
        if self.outages:
            out["outages"] = [list(iv) for iv in self.outages]
        if self.bandwidth is not None:
            out["bandwidth"] = self.bandwidth
            out["message_size"] = (self.message_size if self.message_size is not None
                                   else (64 * n_states if n_states else None))
        return out


@dataclass(frozen=True)
class LinksSpec:
    """A scenario's ``[links]`` table: defaults, per-link settings, seed and bound.

    Attributes
    ----------
    default : LinkConfig
        Settings of every link not listed in ``per_link``.
    per_link : dict (j, i) -> LinkConfig
        Complete settings of listed links (defaults already merged in).
    seed : int
        Seed of ``fixed``-mode delay draws (the same in every trial).
    bound : int or None
        The delay bound tau-bar the agents and the analytics assume (``links.bound``);
        None: derived from the distributions (see :meth:`max_delay`).
    """

    default: LinkConfig = field(default_factory=LinkConfig)
    per_link: dict[Link, LinkConfig] = field(default_factory=dict)
    seed: int = 0
    bound: int | None = None

    def config(self, link: Link) -> LinkConfig:
        return self.per_link.get(link, self.default)

    @property
    def sets_delays(self) -> bool:
        """Whether any link's delay comes from here rather than the ``[delays]`` model."""
        return self.default.delay is not None or any(
            c.delay is not None for c in self.per_link.values())

    def max_delay(self, links: Sequence[Link], base_max: int, sample_period: float,
                  n_states: int) -> int:
        """Largest step delay over ``links`` (nominal for unbounded distributions),
        serialisation included; ``base_max`` for links on the ``[delays]`` model."""
        worst = 0
        for link in links:
            cfg = self.config(link)
            d = cfg.delay.step_bound(sample_period) if cfg.delay is not None else base_max
            extra = cfg.serialisation(n_states)
            if extra > 0:
                d = latency_to_steps((d + 1) * sample_period + extra, sample_period)
            worst = max(worst, d)
        return worst

    def build(self, links: Sequence[Link], base: DelayModel, trial_seed: SeedLike, *,
              sample_period: float, tau: int, n_states: int) -> NetworkLinks:
        """The :class:`NetworkLinks` of one trial.

        Time-varying delay draws and losses use ``trial_seed``; ``fixed`` delays use
        :attr:`seed`. Links sharing the default delay configuration share one
        :class:`DistributionDelays` (stream prefix ``links/delay``; synchronous draws
        are common to them); a link with a delay of its own in ``per_link`` gets its own
        (prefix ``links/link/j-i/delay``). Losses use ``links/loss/j-i``: adding a loss or
        a buffer to a link changes no delay draw. ``tau`` resolves ``capacity = "tau+1"``.
        """
        shared: dict[int, DelayModel] = {}
        replays: dict[int, TraceDelays] = {}
        out: dict[Link, LinkModel] = {}
        # the links sharing each default delay configuration: one block stream each
        sharing: dict[int, list[Link]] = {}
        for link in links:
            cfg = self.config(link)
            if cfg.delay is not None and cfg.delay is self.default.delay:
                sharing.setdefault(id(cfg.delay), []).append(link)
        for link in links:
            j, i = link
            cfg = self.config(link)
            own = cfg.delay is not self.default.delay  # the link has a delay of its own
            delay: DelayModel | None = None
            loss: Any = None  # as LinkModel.loss: any object with drop_reason
            if cfg.delay is not None:
                dist = cfg.delay.distribution
                if isinstance(dist, TraceReplay):
                    key = id(cfg.delay)
                    if key not in replays:
                        replays[key] = TraceDelays(dist, sample_period)
                    delay = replays[key]
                    if link not in dist.records:
                        raise ValueError(f"trace {dist.source} has no link {j}->{i}")
                    loss = TraceLoss(dist, link)
                else:
                    key = id(cfg.delay) if not own else -1
                    if own or key not in shared:
                        name = f"links/link/{j}-{i}/delay" if own else "links/delay"
                        model: DelayModel = DistributionDelays(
                            dist, cfg.delay.mode, trial_seed, self.seed, name=name,
                            sample_period=sample_period, links=[link] if own else sharing[key])
                        if not own:
                            shared[key] = model
                    else:
                        model = shared[key]
                    delay = model
            extra = cfg.serialisation(n_states)
            if extra > 0:
                delay = SerialisedDelays(delay if delay is not None else base, extra,
                                         sample_period)
            if cfg.loss is not None and cfg.loss.model != "none":
                random_loss = cfg.loss.build(stream(trial_seed, "links/loss", f"{j}-{i}"))
                loss = random_loss if loss is None else _Both(loss, random_loss)
            capacity = policy = None
            if cfg.buffer is not None:
                capacity = cfg.buffer.resolve(tau)
                policy = cfg.buffer.policy
            out[link] = LinkModel(
                delay=delay,
                loss=loss,
                outages=Outages(cfg.outages) if cfg.outages else None,
                buffer_capacity=capacity,
                buffer_policy=policy or "drop-tail",
            )
        return NetworkLinks(base, out, sample_period)

    def describe(self, n_states: int | None = None) -> dict[str, Any]:
        return {
            "default": self.default.describe(n_states),
            "per_link": {f"{j}->{i}": c.describe(n_states)
                         for (j, i), c in sorted(self.per_link.items())},
            "seed": self.seed,
            "bound": self.bound,
        }


class _Both:
    """Two loss processes: the first one's drop wins; both advance on every message."""

    def __init__(self, first: Any, second: Any) -> None:
        self.first, self.second = first, second

    def drop_reason(self, step: int, sequence: int) -> str | None:
        a = self.first.drop_reason(step, sequence)
        b = self.second.drop_reason(step, sequence)
        return a if a is not None else b
