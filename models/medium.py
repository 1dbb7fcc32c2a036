"""Delays made by the network: the ``[network.medium]`` table (parameters, no simulation).

A scenario that names a medium does not draw its link delays: every message is a packet
of ``header + payload`` bytes (payload: the sender's estimate, 8 n bytes for n float64
values, or ``payload_bytes``) that crosses a simulated network, and its delay is what the
network does to it: queueing in the sender's transmit queue, medium access, transmission
(size / bit rate) and propagation (DESIGN.md, "Delays made by the network"). A packet the
network loses (a collision, a full queue, a channel-access failure) is a dropped message
with a reason code, like every other drop.

This module only parses and checks the table and turns a simulated medium into the
link-model objects the rest of netsim already understands: :func:`medium_links` returns a
:class:`netsim.models.linkmodels.NetworkLinks` whose every link has a
:class:`MediumDelays` (the packet's latency, in time units of Ts) and a
:class:`MediumLoss` (the medium's drop reason). The event kernel, the vectorised engine's
schedule, traces, ``inspect`` and the verdicts therefore see the medium's delays and
losses through the same path as trace replay. The simulation itself is SimPy code in
:mod:`netsim.medium` (``models`` does not import ``simpy``): the ``netsim`` package
registers it here (:func:`register_medium_simulator`) when it is imported.

Models (``model = ...``; the MAC models of :mod:`netsim.medium`):

* ``point-to-point``: every link is its own wire with a FIFO transmit queue at the sender
  (``per_link``: a bit rate and a propagation delay of its own for listed links);
* ``switched``: output-queued switch; each node's uplink and each output port run at
  ``bit_rate`` and an output port holds ``switch_buffer`` packets;
* ``tdma``: a shared medium with a repeating slot schedule (one slot per entry of
  ``schedule``, default agents 0..N-1);
* ``csma``: unslotted CSMA/CA with binary exponential backoff, IEEE 802.15.4 (2.4 GHz
  O-QPSK PHY) parameters by default; one collision domain (every node hears every other);
* ``can``: CAN bus, priority arbitration (lowest identifier wins), frames of at most
  ``frame_payload_bytes`` data bytes with worst-case bit stuffing;
* ``aloha``: slotted ALOHA, a backlogged node transmits in a slot with probability ``p``;
* ``ns3``: the optional ns-3 delay source (the ``ns3`` package): an 802.11b ad hoc
  network in ns-3 (:mod:`netsim.medium.ns3source`).

Times are in seconds (``bit_rate`` in bit/s); ``time_unit`` is the number of seconds in
one time unit of ``run.sample_period`` (default 1: Ts is in seconds).

The traffic is the scenario's message schedule: at every step k (time k Ts) every agent
sends its estimate to its out-neighbours, as one broadcast packet (``addressing =
"broadcast"``, the default on shared media) or one packet per out-link (``"unicast"``),
handed to its MAC ``jitter`` x U(0, 1) seconds later (default 0: every agent at k Ts, so
a shared medium sees all of them contend at once; the jitter counts in the delay).
Because that schedule does not depend on the estimates, each trial's medium is simulated
once, ahead of the estimators, from the trial's seed (stream ``network/medium``), and both
engines read the same per-message delays. This holds whenever every agent sends at every
step; an estimator that sends less (block updates, triggers) still sees the delays of the
full load, since the medium is not re-simulated with its actual sends.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

# Light at import: the netsim package registers the simulator here at start-up, so this
# module imports numpy and the link models only when a medium is used.
if TYPE_CHECKING:
    import numpy as np
    from netsim.models.linkmodels import NetworkLinks
    from netsim.models.seeding import SeedLike

__all__ = [
    "MEDIUM_MODELS",
    "MEDIUM_PARAMETERS",
    "COMMON_PARAMETERS",
    "MediumError",
    "MediumSpec",
    "MediumDelays",
    "MediumLoss",
    "MediumOutcome",
    "parse_medium",
    "scenario_medium",
    "nominal_bound",
    "PILOT_QUANTILE",
    "PILOT_MAX_STEPS",
    "medium_links",
    "register_medium_simulator",
    "medium_simulator",
    "can_frame_bits",
]

Link = tuple[int, int]

#: Parameters every medium takes: name -> default (None: see the model's default).
COMMON_PARAMETERS: dict[str, Any] = {
    "model": None,
    "bit_rate": None,
    "propagation": 0.0,
    "header_bytes": None,
    "payload_bytes": None,
    "queue": 16,
    "policy": "drop-tail",
    "time_unit": 1.0,
    "addressing": None,
    "background_rate": 0.0,
    "background_bytes": None,
    "jitter": 0.0,
    "bound": None,
}

#: Each model's own parameters and its defaults of the common ones (seconds, bit/s).
MEDIUM_PARAMETERS: dict[str, dict[str, Any]] = {
    "point-to-point": {"bit_rate": 1e6, "header_bytes": 38, "addressing": "unicast",
                       "per_link": None},
    "switched": {"bit_rate": 100e6, "header_bytes": 38, "addressing": "unicast",
                 "switch_buffer": 64, "switch_policy": "drop-tail"},
    "tdma": {"bit_rate": 250e3, "header_bytes": 17, "addressing": "broadcast",
             "slot": None, "guard": 0.0, "schedule": None},
    # IEEE 802.15.4-2006, 2.4 GHz O-QPSK: 62.5 ksymbol/s (16 us a symbol),
    # aUnitBackoffPeriod 20 symbols, CCA 8 symbols, aTurnaroundTime 12 symbols,
    # macMinBE 3, macMaxBE 5, macMaxCSMABackoffs 4, macMaxFrameRetries 3,
    # macAckWaitDuration 54 symbols, aMaxPHYPacketSize 127 bytes; header: SHR 5 + PHR 1
    # + MAC header 9 (short addresses) + FCS 2 = 17 bytes
    "csma": {"bit_rate": 250e3, "header_bytes": 17, "addressing": "broadcast",
             "symbol": 16e-6, "unit_backoff": 20, "cca": 8, "turnaround": 12,
             "min_be": 3, "max_be": 5, "max_backoffs": 4, "max_frame_retries": 3,
             "ack_wait": 54, "max_frame_bytes": 127},
    "can": {"bit_rate": 500e3, "header_bytes": 0, "addressing": "broadcast",
            "priorities": None, "frame_payload_bytes": 8},
    "aloha": {"bit_rate": 250e3, "header_bytes": 17, "addressing": "broadcast",
              "slot": None, "p": None, "max_attempts": 0},
    # the optional ns-3 delay source (netsim.medium.ns3source): 802.11b ad hoc; header:
    # UDP 8 + IPv4 20 + LLC/SNAP 8 + MAC 24 + FCS 4 = 64 bytes (the PHY preamble aside)
    "ns3": {"bit_rate": None, "header_bytes": 64, "addressing": "broadcast",
            "data_mode": "DsssRate11Mbps", "spacing": 5.0, "horizon": 200},
}

#: ns-3 802.11b data modes and their bit rates.
NS3_DATA_MODES = {"DsssRate1Mbps": 1e6, "DsssRate2Mbps": 2e6, "DsssRate5_5Mbps": 5.5e6,
                  "DsssRate11Mbps": 11e6}

#: Names accepted for ``network.medium.model``.
MEDIUM_MODELS = tuple(MEDIUM_PARAMETERS)


class MediumError(ValueError):
    """A bad ``[network.medium]`` entry; ``key`` names it (the scenario loader turns this
    into its one-line ScenarioError)."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.detail = message


def can_frame_bits(data_bytes: int) -> int:
    """Bits of a CAN 2.0A frame with ``data_bytes`` data bytes, worst-case bit stuffing.

    g + 8 s + 13 + floor((g + 8 s - 1) / 4) with g = 34 (11-bit identifiers): Davis,
    Burns, Bril and Lukkien, "Controller Area Network (CAN) schedulability analysis:
    refuted, revisited and revised", Real-Time Systems 35 (2007), eq. (1); 135 bits for
    8 data bytes.
    """
    s = int(data_bytes)
    return 34 + 8 * s + 13 + (34 + 8 * s - 1) // 4


@dataclass(frozen=True)
class MediumSpec:
    """A validated ``[network.medium]`` table.

    Attributes
    ----------
    model : str
        One of :data:`MEDIUM_MODELS`.
    params : dict
        Every parameter of the model (the common ones and its own), defaults filled in;
        times in seconds, ``bit_rate`` in bit/s.
    n_agents : int
    n_states : int
        n (the payload is n float64 values unless ``payload_bytes`` is given).
    """

    model: str
    params: dict[str, Any]
    n_agents: int
    n_states: int
    _cache: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    def __getitem__(self, key: str) -> Any:
        return self.params[key]

    @property
    def payload_bytes(self) -> int:
        """Bytes of a message's payload: 8 n (n float64 values) unless given."""
        given = self.params["payload_bytes"]
        return 8 * self.n_states if given is None else int(given)

    @property
    def packet_bits(self) -> float:
        """Bits of one scenario packet on the medium (CAN: of all its frames)."""
        if self.model == "can":
            per = int(self.params["frame_payload_bytes"])
            payload = self.payload_bytes
            full, rest = divmod(payload, per)
            return float(full * can_frame_bits(per) + (can_frame_bits(rest) if rest or not
                                                       full else 0))
        return 8.0 * (int(self.params["header_bytes"]) + self.payload_bytes)

    @property
    def transmission_time(self) -> float:
        """Seconds to transmit one scenario packet at ``bit_rate``."""
        return self.packet_bits / float(self.params["bit_rate"])

    @property
    def bound(self) -> int | None:
        """The step-delay bound the agents assume (``bound``), None: nominal (see
        :meth:`netsim.models.scenario.Scenario.delay_bound`)."""
        b = self.params["bound"]
        return None if b is None else int(b)

    def describe(self) -> dict[str, Any]:
        """JSON-ready parameters plus the packet size and transmission time."""
        out: dict[str, Any] = {k: (list(v) if isinstance(v, tuple) else v)
                               for k, v in self.params.items()}
        per_link = self.params.get("per_link")
        if isinstance(per_link, dict):
            out["per_link"] = [{"from": j, "to": i, "bit_rate": r, "propagation": p}
                               for (j, i), (r, p) in sorted(per_link.items())]
        out["packet_bits"] = self.packet_bits
        out["transmission_time"] = self.transmission_time
        return out


# -- parsing -----------------------------------------------------------------------------


def _num(value: Any, key: str, *, minimum: float | None = None, strict: bool = False,
         integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MediumError(key, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise MediumError(key, f"must be finite, got {value!r}")
    if integer and v != int(v):
        raise MediumError(key, f"expected an integer, got {value!r}")
    if minimum is not None and (v <= minimum if strict else v < minimum):
        raise MediumError(key, f"must be {'>' if strict else '>='} {minimum:g}, got {value!r}")
    return int(v) if integer else v


def _choice(value: Any, key: str, options: Sequence[str]) -> str:
    if value not in options:
        raise MediumError(key, f"unknown value {value!r}; expected one of {', '.join(options)}")
    return str(value)


def _agent_list(value: Any, key: str, n_agents: int, *, permutation: bool = False
                ) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise MediumError(key, "expected a non-empty list of agent indices")
    out = []
    for e, v in enumerate(value):
        a = int(_num(v, f"{key}[{e}]", minimum=0, integer=True))
        if a >= n_agents:
            raise MediumError(f"{key}[{e}]", f"agent index {a} out of range 0..{n_agents - 1}")
        out.append(a)
    if permutation and len(set(out)) != len(out):
        raise MediumError(key, "an agent is listed twice")
    return tuple(out)


def _per_link(value: Any, key: str, n_agents: int
              ) -> dict[tuple[int, int], tuple[float | None, float | None]]:
    """``per_link = [{from, to, bit_rate, propagation}, ...]`` of a point-to-point medium:
    (j, i) -> (bit rate or None, propagation or None), None: the medium's."""
    if value is None:
        return {}
    if not isinstance(value, list):
        raise MediumError(key, "expected a list of {from, to, bit_rate, propagation} tables")
    out: dict[tuple[int, int], tuple[float | None, float | None]] = {}
    for e, entry in enumerate(value):
        where = f"{key}[{e}]"
        if not isinstance(entry, dict):
            raise MediumError(where, f"expected a table, got {entry!r}")
        for k in entry:
            if k not in ("from", "to", "bit_rate", "propagation"):
                raise MediumError(f"{where}.{k}", "unknown key; allowed: from, to, bit_rate, "
                                  "propagation")
        for k in ("from", "to"):
            if k not in entry:
                raise MediumError(f"{where}.{k}", "is missing")
        j = int(_num(entry["from"], f"{where}.from", minimum=0, integer=True))
        i = int(_num(entry["to"], f"{where}.to", minimum=0, integer=True))
        if j >= n_agents or i >= n_agents:
            raise MediumError(where, f"agent index out of range 0..{n_agents - 1}")
        if (j, i) in out:
            raise MediumError(where, f"link {j} -> {i} is listed twice")
        rate = (None if "bit_rate" not in entry else
                _num(entry["bit_rate"], f"{where}.bit_rate", minimum=0, strict=True))
        prop = (None if "propagation" not in entry else
                _num(entry["propagation"], f"{where}.propagation", minimum=0))
        out[(j, i)] = (rate, prop)
    return out


def parse_medium(table: Any, *, n_agents: int, n_states: int,
                 key: str = "network.medium") -> MediumSpec:
    """Validate a ``[network.medium]`` table.

    Parameters
    ----------
    table : dict
        The TOML table.
    n_agents, n_states : int
        N and n of the scenario (the slot schedule, the priorities, the packet size).
    key : str
        The table's name in messages.

    Raises
    ------
    MediumError
        Naming the first offending key, in one line.
    """
    from netsim.models.linkmodels import BUFFER_POLICIES

    if not isinstance(table, dict):
        raise MediumError(key, f"expected a table, got {table!r}")
    if "model" not in table:
        raise MediumError(f"{key}.model", f"is missing; expected one of {', '.join(MEDIUM_MODELS)}")
    model = _choice(table["model"], f"{key}.model", MEDIUM_MODELS)
    own = MEDIUM_PARAMETERS[model]
    allowed = set(COMMON_PARAMETERS) | set(own)
    for k in table:
        if k not in allowed:
            import difflib

            close = difflib.get_close_matches(k, sorted(allowed), n=1)
            hint = f" (did you mean '{close[0]}'?)" if close else ""
            raise MediumError(f"{key}.{k}", f"unknown key for model {model!r}{hint}; allowed: "
                              f"{', '.join(sorted(allowed))}")
    params = {**COMMON_PARAMETERS, **own, **table}
    params["model"] = model
    if model == "ns3":
        params["data_mode"] = _choice(params["data_mode"], f"{key}.data_mode",
                                      tuple(NS3_DATA_MODES))
        if "bit_rate" in table:
            raise MediumError(f"{key}.bit_rate", "is set by data_mode for model 'ns3'")
        params["bit_rate"] = NS3_DATA_MODES[params["data_mode"]]
        params["spacing"] = _num(params["spacing"], f"{key}.spacing", minimum=0, strict=True)
        params["horizon"] = _num(params["horizon"], f"{key}.horizon", minimum=1, integer=True)
        if params["addressing"] != "broadcast":
            raise MediumError(f"{key}.addressing", "model 'ns3' sends broadcasts only")
        if params["background_rate"]:
            raise MediumError(f"{key}.background_rate", "no background traffic with model "
                              "'ns3'")

    def k_(name: str) -> str:
        return f"{key}.{name}"

    params["bit_rate"] = _num(params["bit_rate"], k_("bit_rate"), minimum=0, strict=True)
    params["propagation"] = _num(params["propagation"], k_("propagation"), minimum=0)
    params["header_bytes"] = _num(params["header_bytes"], k_("header_bytes"), minimum=0,
                                  integer=True)
    if params["payload_bytes"] is not None:
        params["payload_bytes"] = _num(params["payload_bytes"], k_("payload_bytes"), minimum=0,
                                       integer=True)
    params["queue"] = _num(params["queue"], k_("queue"), minimum=1, integer=True)
    params["policy"] = _choice(params["policy"], k_("policy"), BUFFER_POLICIES)
    params["time_unit"] = _num(params["time_unit"], k_("time_unit"), minimum=0, strict=True)
    params["addressing"] = _choice(params["addressing"], k_("addressing"),
                                   ("broadcast", "unicast"))
    params["background_rate"] = _num(params["background_rate"], k_("background_rate"),
                                     minimum=0)
    if params["background_bytes"] is not None:
        params["background_bytes"] = _num(params["background_bytes"], k_("background_bytes"),
                                          minimum=0, integer=True)
    params["jitter"] = _num(params["jitter"], k_("jitter"), minimum=0)
    if params["bound"] is not None:
        params["bound"] = _num(params["bound"], k_("bound"), minimum=0, integer=True)
    if model == "point-to-point":
        params["per_link"] = _per_link(params["per_link"], k_("per_link"), n_agents)
    if model == "switched":
        params["switch_buffer"] = _num(params["switch_buffer"], k_("switch_buffer"), minimum=1,
                                       integer=True)
        params["switch_policy"] = _choice(params["switch_policy"], k_("switch_policy"),
                                          BUFFER_POLICIES)
    if model in ("tdma", "aloha") and params["slot"] is not None:
        params["slot"] = _num(params["slot"], k_("slot"), minimum=0, strict=True)
    if model == "tdma":
        params["guard"] = _num(params["guard"], k_("guard"), minimum=0)
        params["schedule"] = (tuple(range(n_agents)) if params["schedule"] is None else
                              _agent_list(params["schedule"], k_("schedule"), n_agents))
    if model == "csma":
        params["symbol"] = _num(params["symbol"], k_("symbol"), minimum=0, strict=True)
        for name in ("unit_backoff", "cca"):
            params[name] = _num(params[name], k_(name), minimum=1, integer=True)
        for name in ("turnaround", "max_backoffs", "max_frame_retries", "ack_wait"):
            params[name] = _num(params[name], k_(name), minimum=0, integer=True)
        params["min_be"] = _num(params["min_be"], k_("min_be"), minimum=0, integer=True)
        params["max_be"] = _num(params["max_be"], k_("max_be"), minimum=params["min_be"],
                                integer=True)
        if params["max_be"] > 30:
            raise MediumError(k_("max_be"), f"must be <= 30, got {params['max_be']}")
        params["max_frame_bytes"] = _num(params["max_frame_bytes"], k_("max_frame_bytes"),
                                         minimum=1, integer=True)
    if model == "can":
        params["frame_payload_bytes"] = _num(params["frame_payload_bytes"],
                                             k_("frame_payload_bytes"), minimum=1, integer=True)
        if params["frame_payload_bytes"] > 64:
            raise MediumError(k_("frame_payload_bytes"), "must be <= 64 (CAN FD's largest "
                              f"frame), got {params['frame_payload_bytes']}")
        params["priorities"] = (tuple(range(n_agents)) if params["priorities"] is None else
                                _agent_list(params["priorities"], k_("priorities"),
                                            max(n_agents, 2048)))
        if len(params["priorities"]) != n_agents:
            raise MediumError(k_("priorities"), f"has {len(params['priorities'])} entries, "
                              f"expected one identifier per agent ({n_agents})")
        if len(set(params["priorities"])) != n_agents:
            raise MediumError(k_("priorities"), "identifiers must be distinct (CAN "
                              "arbitration needs a unique identifier per sender)")
    if model == "aloha":
        if params["p"] is None:
            params["p"] = 1.0 / n_agents
        params["p"] = _num(params["p"], k_("p"), minimum=0, strict=True)
        if params["p"] > 1:
            raise MediumError(k_("p"), f"must be in (0, 1], got {params['p']}")
        params["max_attempts"] = _num(params["max_attempts"], k_("max_attempts"), minimum=0,
                                      integer=True)
    spec = MediumSpec(model, params, int(n_agents), int(n_states))
    tx = spec.transmission_time
    if model == "csma" and spec.packet_bits / 8 - 6 > params["max_frame_bytes"]:
        raise MediumError(k_("payload_bytes" if params["payload_bytes"] is not None
                             else "header_bytes"),
                          f"a frame of {int(spec.packet_bits / 8) - 6} bytes (MAC header + "
                          f"payload {spec.payload_bytes} + FCS) exceeds max_frame_bytes = "
                          f"{params['max_frame_bytes']} (802.15.4's aMaxPHYPacketSize); "
                          "fewer states or a larger max_frame_bytes")
    if model in ("tdma", "aloha"):
        if params["slot"] is None:
            params["slot"] = tx + (params["guard"] if model == "tdma" else 0.0)
        elif params["slot"] < tx + (params["guard"] if model == "tdma" else 0.0):
            raise MediumError(k_("slot"), f"= {params['slot']:g} s is shorter than one packet "
                              f"({tx:g} s for {spec.packet_bits:g} bits at "
                              f"{params['bit_rate']:g} bit/s"
                              + (f", plus guard {params['guard']:g} s" if model == "tdma"
                                 else "") + ")")
    return spec


# -- the simulator registry and the link-model objects ------------------------------------


@dataclass
class MediumOutcome:
    """What the medium did to one message: its latency (time units of Ts) or its drop."""

    latency: float
    reason: str | None = None


#: simulator(spec, links, sample_period, seed) -> object with
#: ``outcome(sender, receiver, step) -> MediumOutcome``.
_SIMULATOR: list[Callable[..., Any]] = []


def register_medium_simulator(simulator: Callable[..., Any]) -> None:
    """Register the medium simulator (the ``netsim`` package does, on import).

    ``simulator(spec, links, sample_period, seed)`` returns an object whose
    ``outcome(sender, receiver, step)`` gives a :class:`MediumOutcome`.
    """
    _SIMULATOR[:] = [simulator]


def medium_simulator() -> Callable[..., Any]:
    """The registered medium simulator (ValueError if none is registered)."""
    if not _SIMULATOR:
        raise ValueError("no medium simulator is registered (import netsim first)")
    return _SIMULATOR[0]


class MediumDelays:
    """Kernel delay model: each message's latency through the simulated medium.

    One instance per trial, shared by all links (the medium is one simulation); draws
    look messages up by (link, sending step), so the kernel's order of draws and the
    vectorised schedule's give the same values. ``unit`` is ``"time"`` (time units of
    Ts); a dropped message's latency is the time until its drop.
    """

    unit: Literal["steps", "time"] = "time"
    time_invariant = False

    def __init__(self, run: Any, max_delay: int) -> None:
        self.run = run
        self.max_delay = int(max_delay)

    def draw(self, sender: int, receiver: int, send_step: int) -> float:
        return float(self.run.outcome(sender, receiver, int(send_step)).latency)

    def draw_many(self, sender: int, receiver: int, send_steps: np.ndarray) -> np.ndarray:
        """The latencies ``draw`` gives for messages sent at ``send_steps``, in order."""
        import numpy as np

        return np.array([self.run.outcome(sender, receiver, int(s)).latency
                         for s in np.asarray(send_steps).tolist()], dtype=float)


class MediumLoss:
    """The medium's drops on one link, as a link model's loss (``drop_reason``)."""

    def __init__(self, run: Any, link: Link) -> None:
        self.run = run
        self.link = link

    def drop_reason(self, step: int, sequence: int) -> str | None:
        reason = self.run.outcome(self.link[0], self.link[1], int(step)).reason
        return None if reason is None else f"medium: {reason}"


def medium_links(spec: MediumSpec, links: Sequence[Link], base: Any, trial_seed: SeedLike, *,
                 sample_period: float, max_delay: int) -> NetworkLinks:
    """The delay model of one trial whose delays and losses come from the medium.

    Parameters
    ----------
    spec : MediumSpec
    links : sequence of (j, i)
        The scenario's links (the traffic: every agent sends on its out-links each step).
    base : DelayModel
        The scenario's ``[delays]`` model (unused by the links; kept as the fallback).
    trial_seed : seed-like
        The trial's seed: the medium's randomness is stream ``network/medium`` of it.
    sample_period : float
        Ts.
    max_delay : int
        The nominal step-delay bound reported as the model's ``max_delay``.
    """
    from netsim.models.linkmodels import LinkModel, NetworkLinks

    run = medium_simulator()(spec, list(links), float(sample_period), trial_seed)
    delays = MediumDelays(run, max_delay)
    models: Mapping[Link, LinkModel] = {
        link: LinkModel(delay=delays, loss=MediumLoss(run, link)) for link in links}
    out = NetworkLinks(base, models, sample_period)
    out.max_delay = int(max_delay)
    return out


def scenario_medium(data: Mapping[str, Any], *, n_agents: int, n_states: int
                    ) -> MediumSpec | None:
    """The ``[network.medium]`` of a scenario document, checked against the rest of it.

    None when the scenario names no medium. A medium makes the delays and losses, so
    it excludes a ``[links]`` table, a ``[delays]`` model other than ``none``, a
    time-varying ``[topology]`` and a ``[time]`` table (MediumError naming the
    conflicting key).
    """
    network = data.get("network")
    if not isinstance(network, dict) or "medium" not in network:
        return None
    spec = parse_medium(network["medium"], n_agents=n_agents, n_states=n_states)
    if "links" in data:
        raise MediumError("links", "cannot be combined with [network.medium]: the medium "
                          "makes every link's delays and losses")
    delays = data.get("delays")
    if isinstance(delays, dict) and delays.get("model", "none") != "none":
        raise MediumError("delays.model", f"is {delays.get('model')!r} but [network.medium] "
                          "makes the delays; leave [delays] out or set model = 'none'")
    if "time" in data:
        raise MediumError("time", "the [time] table (clocks, asynchronous sampling, "
                          "triggers) is not modelled with [network.medium] (its traffic is "
                          "every agent sending at every step k Ts)")
    if "topology" in data:
        raise MediumError("topology", "a time-varying [topology] is not modelled with "
                          "[network.medium] (the medium carries the [network] links)")
    return spec


#: Quantile of a pilot run's step delays reported as the medium's nominal bound.
PILOT_QUANTILE = 0.999
#: Most steps a pilot run simulates.
PILOT_MAX_STEPS = 1000


def nominal_bound(spec: MediumSpec, links: Sequence[Link], *, sample_period: float,
                  seed: SeedLike, steps: int) -> int:
    """The medium's nominal step-delay bound: a pilot run's :data:`PILOT_QUANTILE` step delay.

    The medium's delays are not bounded in general (backoffs, queues), so, as for the
    unbounded link-delay distributions, the bound the agents and the analytics assume
    is a quantile: of the delivered messages' step delays d = max(ceil(l / Ts) - 1, 0)
    in one run of the schedule over min(``steps``, :data:`PILOT_MAX_STEPS`) steps from
    ``seed`` (the scenario's seed). ``bound`` in the table overrides it.
    """
    import numpy as np
    from netsim.models.delays import latency_to_steps

    key = f"bound/{sample_period!r}/{seed!r}/{steps}/{sorted(links)!r}"
    if key in spec._cache:
        return int(spec._cache[key])
    run = medium_simulator()(spec, list(links), float(sample_period), seed)
    latencies = [o.latency for s in range(min(int(steps), PILOT_MAX_STEPS)) for j, i in links
                 if (o := run.outcome(j, i, s)).reason is None]
    if not latencies:
        value = 0
    else:
        top = float(np.quantile(np.asarray(latencies), PILOT_QUANTILE, method="inverted_cdf"))
        value = latency_to_steps(top, sample_period)
    spec._cache[key] = value
    return value
