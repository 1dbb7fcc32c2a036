"""Optional ns-3 delay source: the scenario's message schedule through an ns-3 network.

With the ``ns3`` package installed (``pip install ns3``; an optional extra, about two
minutes to install and 20 s to import), ``[network.medium] model = "ns3"`` builds the
scenario's agents as nodes of an IEEE 802.11b ad hoc network in ns-3 (YANS channel with
its default log-distance propagation loss, constant-rate manager at ``data_mode``, nodes
on a line ``spacing`` metres apart), and every agent broadcasts one UDP packet of
``payload_bytes`` (default 8 n) at every step k, at k Ts + U(0, ``jitter``) seconds. Each
out-neighbour's reception time is the message's delay; a message an out-neighbour never
receives is dropped (``ns-3: not received``: collisions, interference or fading, which
ns-3 does not tell apart here). ns-3 adds its own UDP, IP, LLC and MAC headers.

The schedule is simulated up to a horizon of steps (``horizon``, default 200) and
simulated again from the start, with the same ns-3 run number, over twice the horizon
when a later message is asked for. Like :class:`netsim.medium.schedule.MediumRun` the run
answers ``outcome(sender, receiver, step)``, so the kernel, the vectorised engine, traces
and ``inspect`` see the ns-3 delays through the same link-model path.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from netsim.models.medium import MediumOutcome, MediumSpec
from netsim.models.seeding import SeedLike, stream

__all__ = ["Ns3Run", "ns3_available", "REASON_NS3"]

REASON_NS3 = "ns-3: not received"

_CPP = r"""
#include <vector>
namespace netsim_ns3 {
using namespace ns3;

struct Rx { int sender; int receiver; int step; double time; };
static std::vector<Rx> received;
static std::vector<std::vector<int>> wanted;   // wanted[sender] = out-neighbours
static std::vector<Ptr<Socket>> senders;

static void Receive(Ptr<Socket> socket) {
  Ptr<Packet> packet;
  int me = socket->GetNode()->GetId();
  while ((packet = socket->Recv())) {
    uint8_t buffer[8];
    packet->CopyData(buffer, 8);
    int32_t sender, step;
    std::memcpy(&sender, buffer, 4);
    std::memcpy(&step, buffer + 4, 4);
    for (int r : wanted[sender]) {
      if (r == me) { received.push_back({sender, me, step, Simulator::Now().GetSeconds()}); }
    }
  }
}

static void Send(int sender, int step, int size) {
  std::vector<uint8_t> data(size < 8 ? 8 : size, 0);
  int32_t s = sender, k = step;
  std::memcpy(data.data(), &s, 4);
  std::memcpy(data.data() + 4, &k, 4);
  senders[sender]->Send(Create<Packet>(data.data(), data.size()));
}

int Run(int n, const std::vector<int>& src, const std::vector<int>& dst,
        const std::vector<double>& times, const std::vector<int>& who,
        const std::vector<int>& steps, int size, double spacing, std::string mode,
        double stop, uint32_t run) {
  received.clear();
  senders.clear();
  wanted.assign(n, std::vector<int>());
  for (size_t e = 0; e < src.size(); ++e) wanted[src[e]].push_back(dst[e]);
  RngSeedManager::SetSeed(1);
  RngSeedManager::SetRun(run);
  NodeContainer nodes;
  nodes.Create(n);
  WifiHelper wifi;
  wifi.SetStandard(WIFI_STANDARD_80211b);
  wifi.SetRemoteStationManager("ns3::ConstantRateWifiManager", "DataMode",
                               StringValue(mode), "ControlMode", StringValue(mode));
  YansWifiPhyHelper phy;
  YansWifiChannelHelper channel = YansWifiChannelHelper::Default();
  phy.SetChannel(channel.Create());
  WifiMacHelper mac;
  mac.SetType("ns3::AdhocWifiMac");
  NetDeviceContainer devices = wifi.Install(phy, mac, nodes);
  // fixed stream numbers: ns-3's automatic ones keep counting across runs in a process
  wifi.AssignStreams(devices, 0);
  MobilityHelper mobility;
  Ptr<ListPositionAllocator> positions = CreateObject<ListPositionAllocator>();
  for (int i = 0; i < n; ++i) positions->Add(Vector(spacing * i, 0.0, 0.0));
  mobility.SetPositionAllocator(positions);
  mobility.SetMobilityModel("ns3::ConstantPositionMobilityModel");
  mobility.Install(nodes);
  InternetStackHelper internet;
  internet.Install(nodes);
  internet.AssignStreams(nodes, 100000);
  Ipv4AddressHelper address;
  address.SetBase("10.1.0.0", "255.255.0.0");
  address.Assign(devices);
  TypeId udp = TypeId::LookupByName("ns3::UdpSocketFactory");
  for (int i = 0; i < n; ++i) {
    Ptr<Socket> sink = Socket::CreateSocket(nodes.Get(i), udp);
    sink->Bind(InetSocketAddress(Ipv4Address::GetAny(), 9999));
    sink->SetRecvCallback(MakeCallback(&Receive));
    Ptr<Socket> out = Socket::CreateSocket(nodes.Get(i), udp);
    out->SetAllowBroadcast(true);
    out->Connect(InetSocketAddress(Ipv4Address("255.255.255.255"), 9999));
    senders.push_back(out);
  }
  for (size_t q = 0; q < times.size(); ++q) {
    Simulator::Schedule(Seconds(times[q]), &Send, who[q], steps[q], size);
  }
  Simulator::Stop(Seconds(stop));
  Simulator::Run();
  Simulator::Destroy();
  return (int)received.size();
}
}  // namespace netsim_ns3
"""

_LOADED: list[Any] = []


def ns3_available() -> bool:
    """Whether the ``ns3`` package can be imported."""
    try:
        _ns()
    except ImportError:
        return False
    return True


def _ns() -> Any:
    """The ns-3 bindings with the netsim helper compiled in (once per process)."""
    if _LOADED:
        return _LOADED[0]
    import importlib

    from netsim.models.extras import MissingExtra

    try:
        ns = importlib.import_module("ns").ns  # the optional extra; about 20 s to import
    except ImportError:
        raise MissingExtra("[network.medium] model = 'ns3' needs ns3, which is not "
                           "installed: pip install 'netsim[ns3]'", name="ns") from None
    ns.cppyy.cppdef(_CPP)
    _LOADED.append(ns)
    return ns


class Ns3Run:
    """One trial's message schedule through ns-3 (see the module docstring).

    Parameters
    ----------
    spec : MediumSpec
        ``model = "ns3"``.
    links : sequence of (j, i)
    sample_period : float
        Ts (time units; ``time_unit`` seconds each).
    seed : seed-like
        The trial's seed: the send jitter (stream ``network/medium/jitter``) and the
        ns-3 run number.
    """

    def __init__(self, spec: MediumSpec, links: Sequence[tuple[int, int]],
                 sample_period: float = 1.0, seed: SeedLike = 0) -> None:
        self.spec = spec
        self.links = sorted(set(links))
        self.time_unit = float(spec["time_unit"])
        self.period = float(sample_period) * self.time_unit
        self.jitter = float(spec["jitter"])
        self.horizon = 0
        self.seed = seed
        self.run_number = 1 + zlib.crc32(repr(stream(seed, "network/medium", "ns3")
                                              .integers(0, 2**31)).encode()) % (2**31)
        self.outcomes: dict[tuple[int, int, int], MediumOutcome] = {}

    def _simulate(self, steps: int) -> None:
        ns = _ns()
        n = self.spec.n_agents
        senders = sorted({j for j, _ in self.links})
        rng = stream(self.seed, "network/medium", "jitter")
        times, who, ks = [], [], []
        for k in range(steps):
            u = rng.uniform(0.0, self.jitter, len(senders)) if self.jitter > 0 else \
                np.zeros(len(senders))
            for j, d in zip(senders, u.tolist(), strict=True):
                times.append(k * self.period + d)
                who.append(j)
                ks.append(k)
        std = ns.cppyy.gbl.std
        vec_i = std.vector["int"]
        vec_d = std.vector["double"]
        src = vec_i([j for j, _ in self.links])
        dst = vec_i([i for _, i in self.links])
        stop = steps * self.period + 5.0
        helper = ns.cppyy.gbl.netsim_ns3
        helper.Run(n, src, dst, vec_d(times), vec_i(who), vec_i(ks),
                   int(self.spec.payload_bytes), float(self.spec["spacing"]),
                   str(self.spec["data_mode"]), float(stop), int(self.run_number))
        sent = {(j, k): t for t, j, k in zip(times, who, ks, strict=True)}
        first: dict[tuple[int, int, int], float] = {}
        for rx in helper.received:
            key = (int(rx.sender), int(rx.receiver), int(rx.step))
            first.setdefault(key, float(rx.time))
        self.outcomes = {}
        for k in range(steps):
            created = k * self.period
            for j, i in self.links:
                t = first.get((j, i, k))
                if t is None:
                    self.outcomes[(j, i, k)] = MediumOutcome(
                        (sent[(j, k)] - created) / self.time_unit, REASON_NS3)
                else:
                    self.outcomes[(j, i, k)] = MediumOutcome((t - created) / self.time_unit)
        self.horizon = steps

    def outcome(self, sender: int, receiver: int, step: int) -> MediumOutcome:
        """The latency (time units of Ts) and drop reason of the message sent on link
        (sender, receiver) at ``step``."""
        if step >= self.horizon:
            self._simulate(max(int(self.spec["horizon"]), 2 * self.horizon, step + 1))
        try:
            return self.outcomes[(sender, receiver, step)]
        except KeyError:
            raise ValueError(f"the medium carries no message on link {sender}->{receiver} "
                             f"at step {step}") from None
