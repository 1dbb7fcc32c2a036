"""The schedule pre-pass: one trial's medium, driven by the scenario's message schedule.

:class:`MediumRun` simulates the medium of one trial in its own SimPy environment
(clock in seconds): at every step k, at time k Ts (``time_unit`` seconds per time unit),
every agent hands its estimate to the MAC, as one broadcast packet to its out-neighbours
or one packet per out-link (``addressing``), in agent order; optional Poisson background
traffic (``background_rate`` packets per second per node, per link on point-to-point and
switched networks) shares the queues. The run is lazy and unbounded: asking for the
outcome of the message sent on link (j, i) at step s advances the simulation until that
packet is delivered or dropped at i. Nothing about it depends on the estimates, so the
event kernel and the vectorised engine, which both ask the same questions of a trial's
fresh run, see the same delays and drops (:mod:`netsim.models.medium`).

The medium's random numbers come from the trial's seed: ``network/medium/mac`` (backoffs,
ALOHA attempts), ``network/medium/jitter`` and ``network/medium/background/<node>`` (one
per source).
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from typing import Any

import simpy

from netsim.medium.catalog import mac_model
from netsim.medium.core import Medium, Packet, Recorder, poisson_source
from netsim.models.medium import MediumOutcome, MediumSpec
from netsim.models.seeding import SeedLike, stream

__all__ = ["MediumRun", "simulate_medium"]


class MediumRun:
    """One trial's medium under the scenario's message schedule (lazy, unbounded).

    Parameters
    ----------
    spec : MediumSpec
    links : sequence of (j, i)
        The scenario's links; agent j sends to every i with (j, i) a link.
    sample_period : float
        Ts (time units).
    seed : seed-like
        The trial's seed.
    keep_background : bool
        Keep the background packets' records (tests, statistics).

    Attributes
    ----------
    medium : netsim.medium.core.Medium
    events : int
        SimPy events processed so far.
    """

    def __init__(self, spec: MediumSpec, links: Sequence[tuple[int, int]],
                 sample_period: float = 1.0, seed: SeedLike = 0, *,
                 keep_background: bool = False) -> None:
        self.spec = spec
        n = spec.n_agents
        self.env = env = simpy.Environment()
        self.links = set(links)
        outs: list[list[int]] = [[] for _ in range(n)]
        for j, i in sorted(self.links):
            outs[j].append(i)
        self.out_neighbours = outs
        self.recorder = Recorder()
        self.recorder.keep_background = keep_background
        params = spec.params
        self.time_unit = float(params["time_unit"])
        self.period = float(sample_period) * self.time_unit
        self.medium: Medium = mac_model(spec.model)(
            env, params, n, outs, stream(seed, "network/medium", "mac"), self.recorder)
        self.bits = float(spec.packet_bits if spec.model != "can" else 8 * spec.payload_bytes)
        self.broadcast = params["addressing"] == "broadcast"
        self.events = 0
        self.jitter = float(params["jitter"])
        self._jitter_rng = stream(seed, "network/medium", "jitter")
        env.process(self._traffic())
        rate = float(params["background_rate"])
        if rate > 0:
            size = params["background_bytes"]
            bits = (self.bits if size is None else
                    8.0 * (size + (0 if spec.model == "can" else int(params["header_bytes"]))))
            per_link = spec.model in ("point-to-point", "switched")
            for j in range(n):
                targets = [(i,) for i in outs[j]] if per_link else [tuple(outs[j])]
                for dest in targets:
                    if not dest:
                        continue
                    name = f"{j}-{dest[0]}" if per_link else str(j)
                    env.process(poisson_source(env, self.medium, j, dest, rate, bits,
                                               stream(seed, "network/medium", "background",
                                                      name)))

    def _traffic(self) -> Generator[simpy.Event, Any, None]:
        env, medium = self.env, self.medium
        jitter, rng = self.jitter, self._jitter_rng
        submit = medium.submit
        if jitter > 0:
            def submit(packet: Packet) -> None:
                later = env.timeout(float(rng.uniform(0.0, jitter)))
                later.callbacks.append(lambda _e: medium.submit(packet))
        k = 0
        while True:
            now = k * self.period
            if now > env.now:
                yield env.timeout(now - env.now)
            for j, outs in enumerate(self.out_neighbours):
                if not outs:
                    continue
                if self.broadcast:
                    submit(Packet(j, tuple(outs), k, now, self.bits))
                else:
                    for i in outs:
                        submit(Packet(j, (i,), k, now, self.bits))
            k += 1

    def outcome(self, sender: int, receiver: int, step: int) -> MediumOutcome:
        """What the medium did to the message sent on (sender, receiver) at ``step``:
        its latency in time units of Ts (until delivery, or until the drop) and the drop
        reason (None: delivered)."""
        key = (sender, receiver, step)
        outcomes = self.recorder.outcomes
        found = outcomes.get(key)
        if found is None:
            if (sender, receiver) not in self.links or step < 0:
                raise ValueError(f"the medium carries no message on link {sender}->{receiver} "
                                 f"at step {step}")
            env_step = self.env.step
            while found is None:
                env_step()
                self.events += 1
                found = outcomes.get(key)
        created, done, reason = found
        return MediumOutcome((done - created) / self.time_unit, reason)

    def run_until(self, time: float) -> None:
        """Advance the simulation to ``time`` seconds (statistics, benchmarks)."""
        env = self.env
        while env.peek() <= time:
            env.step()
            self.events += 1


def simulate_medium(spec: MediumSpec, links: Sequence[tuple[int, int]], sample_period: float,
                    seed: SeedLike) -> Any:
    """The registered simulator of :mod:`netsim.models.medium`: a fresh :class:`MediumRun`,
    or for ``model = "ns3"`` a :class:`netsim.medium.ns3source.Ns3Run`."""
    if spec.model == "ns3":
        from netsim.medium.ns3source import Ns3Run

        return Ns3Run(spec, links, sample_period, seed)
    return MediumRun(spec, links, sample_period, seed)
