"""The network layer: packets, transmit queues and MAC models in SimPy.

One module per MAC model, each registering itself (:mod:`netsim.medium.registry`):
:mod:`~netsim.medium.p2p` (point-to-point FIFO links), :mod:`~netsim.medium.switched`
(output-queued switch), :mod:`~netsim.medium.tdma` (slot schedule),
:mod:`~netsim.medium.csma` (unslotted CSMA/CA, IEEE 802.15.4), :mod:`~netsim.medium.can`
(CAN arbitration) and :mod:`~netsim.medium.aloha` (slotted ALOHA); the packet/queue core
(:mod:`~netsim.medium.core`); and the schedule pre-pass (:mod:`~netsim.medium.schedule`)
that turns a scenario's ``[network.medium]`` into per-message delays and drops
(:mod:`netsim.models.medium` parses the table and feeds them to the link-model path).
"""

from __future__ import annotations

from netsim.medium.catalog import mac_model
from netsim.medium.core import Medium, Packet, Recorder, TransmitQueue, poisson_source
from netsim.medium.registry import MAC_MODELS, register_mac
from netsim.medium.schedule import MediumRun, simulate_medium

__all__ = ["MAC_MODELS", "Medium", "MediumRun", "Packet", "Recorder", "TransmitQueue",
           "mac_model", "poisson_source", "register_mac", "simulate_medium"]
