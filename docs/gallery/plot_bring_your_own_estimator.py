"""
Bring your own estimator
========================

An estimator is a plain object, one per agent, with ``message_arrived``, ``step`` and
``estimate`` (the contract :class:`netsim.Estimator`). Here: a naive consensus
estimator that ignores delays and time-stamps, run beside the paper's compensating
estimator and the centralised Kalman filter on the LCSYS2022 scenario.
"""

# %%
# The estimator
# -------------
# netsim builds it once per agent as ``cls(setup)``; ``setup`` is the agent's
# :class:`netsim.AgentSetup` (its neighbours, weights, the plant, its gain ``L`` when
# the family says ``needs_gains = True``).
import matplotlib.pyplot as plt
import numpy as np

import netsim


class NaiveConsensus:
    """Average the latest arrivals with the consensus weights, predict with A, correct
    with the designed gain: the delays are ignored."""

    name = "naive"
    needs_gains = True

    def __init__(self, setup):
        self.i = setup.agent
        self.A, self.C, self.L = setup.A, setup.C, setup.L
        self.weights = setup.weights
        self.estimate = np.array(setup.prior_mean, dtype=float)
        self.latest = {}

    def message_arrived(self, sender, sent_step, payload):
        self.latest[sender] = np.asarray(payload, dtype=float)
        return True

    def step(self, k, y):
        if k > 0:
            mixed = self.weights[self.i] * self.estimate
            for j, xj in self.latest.items():
                mixed = mixed + self.weights[j] * xj
            # neighbours not heard from yet: the agent's own estimate in their place
            missing = sum(w for j, w in enumerate(self.weights)
                          if w and j != self.i and j not in self.latest)
            prediction = self.A @ (mixed + missing * self.estimate)
        else:
            prediction = self.estimate
        self.estimate = prediction + self.L @ (y - self.C @ prediction)
        return self.estimate


netsim.register_estimator(NaiveConsensus, replace_existing=True)

# %%
# Run it
# ------
# The registered name works everywhere a built-in does: ``netsim.run``, a scenario's
# ``run.estimators``, and ``--estimators`` on the command line (as ``module:attribute``).
scenario = netsim.load_scenario("lcsys2022-heterogeneous")
result = netsim.run(scenario, steps=150, trials=4,
                    estimators=["compensated", "naive", "centralized-kf"])
for name in result:
    s = result.summary[name]
    print(f"{name:15s} {s.verdict}")

# %%
# The network MSE of each family over time.
fig, ax = plt.subplots(figsize=(7, 4))
for name in result:
    ax.semilogy(result[name].mse, label=name)
ax.set_xlabel("step k")
ax.set_ylabel("network MSE")
ax.set_title("lcsys2022-heterogeneous, tau = 3, 4 trials")
ax.legend()
fig.tight_layout()
