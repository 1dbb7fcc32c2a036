"""
Delays made by a shared medium
==============================

The delays of a ``[network.medium]`` scenario come from the network itself: here N agents
share one IEEE 802.15.4 channel (unslotted CSMA/CA, the standard's parameters) and each
broadcasts its estimate (2 float64 values + a 17-byte header) every Ts = 50 ms. As N
grows, the channel gets busier: the latencies grow and more frames are lost to
collisions and channel-access failures. Only the medium is simulated here (no
estimator), from the scenario's message schedule, as both engines use it.
"""

import matplotlib.pyplot as plt
import numpy as np

import netsim
from netsim.medium import MediumRun


def scenario(agents):
    return netsim.load_scenario({
        "name": f"csma-{agents}",
        "run": {"steps": 40, "sample_period": 0.05, "estimators": ["compensated"]},
        "plant": {"A": [[0.98, -0.1], [0.1, 0.98]], "C": [[[1.0, 0.0]], [[0.0, 1.0]]],
                  "sensors": agents, "Q": 0.001, "R": 0.01},
        "network": {"topology": "random", "agents": agents,
                    "edge_probability": min(1.0, 3.1 / (agents - 1)), "seed": 3,
                    "medium": {"model": "csma", "queue": 4, "policy": "drop-oldest",
                               "jitter": 0.025}},
    })


fig, ax = plt.subplots(figsize=(7, 4))
for agents in (4, 8, 16, 32):
    s = scenario(agents)
    run = MediumRun(s.medium, s.links, s.sample_period, seed=0)
    outcomes = [run.outcome(j, i, k) for k in range(40) for j, i in s.links]
    latency = np.sort([o.latency for o in outcomes if o.reason is None]) * 1e3  # ms
    lost = 1 - latency.size / len(outcomes)
    print(f"N = {agents:2d}: median latency {np.median(latency):5.1f} ms, "
          f"99 % {np.quantile(latency, 0.99):5.1f} ms, lost {lost:.0%}")
    ax.step(latency, np.arange(1, latency.size + 1) / latency.size, where="post",
            label=f"N = {agents} ({lost:.0%} lost)")
ax.axvline(50, color="k", lw=0.8, ls=":")
ax.text(50.5, 0.05, "Ts", fontsize=8)
ax.set_xlabel("latency of delivered messages (ms)")
ax.set_ylabel("fraction of delivered messages")
ax.set_title("one 802.15.4 channel, unslotted CSMA/CA, 40 steps")
ax.legend(loc="lower right")
fig.tight_layout()
