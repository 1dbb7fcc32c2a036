"""The optional ns-3 delay source ([network.medium] model = "ns3"); slow, skipped without ns3."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from netsim.models.scenario import parse_scenario

pytestmark = pytest.mark.slow

SCENARIO = {
    "name": "ns3-small",
    "run": {"steps": 20, "trials": 1, "seed": 2, "sample_period": 0.01,
            "estimators": ["compensated"]},
    "plant": {"A": [[0.95, 0.1], [-0.1, 0.95]], "C": [[[1.0, 0.0]], [[0.0, 1.0]]],
              "sensors": 4, "Q": 0.01, "R": 0.01},
    "network": {"topology": "cycle", "agents": 4, "weights": "uniform",
                "medium": {"model": "ns3", "jitter": 0.002, "horizon": 20}},
    "gains": {"method": "lmi"},
}


def test_ns3_schedule_delays_are_physical_and_feed_both_engines():
    pytest.importorskip("ns")
    import netsim
    from netsim.medium.ns3source import Ns3Run

    scenario = parse_scenario(copy.deepcopy(SCENARIO), "test")
    run = Ns3Run(scenario.medium, scenario.links, scenario.sample_period, 0)
    outcomes = [run.outcome(j, i, k) for k in range(20) for j, i in scenario.links]
    delivered = np.array([o.latency for o in outcomes if o.reason is None])
    assert delivered.size > 0.5 * len(outcomes)  # 5 m apart at 11 Mbit/s: mostly received
    # no packet can arrive before its bits are on the air: payload + 64 header bytes at
    # 11 Mbit/s, plus the 802.11b long preamble (192 us)
    floor = (8 * (scenario.medium.payload_bytes + 64)) / 11e6 + 192e-6
    assert delivered.min() >= floor - 1e-9
    assert delivered.max() < 0.5  # and nothing waits half a second on an idle channel
    # the same trial twice gives the same delays (seeded ns-3 run number)
    again = Ns3Run(scenario.medium, scenario.links, scenario.sample_period, 0)
    assert [again.outcome(j, i, k) for k in range(20) for j, i in scenario.links] == outcomes
    events = netsim.run(scenario, engine="events", steps=15)
    vector = netsim.run(scenario, engine="vectorised", steps=15)
    np.testing.assert_allclose(events["compensated"].squared_errors,
                               vector["compensated"].squared_errors, rtol=1e-9, atol=1e-12)
