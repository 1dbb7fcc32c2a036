"""
Which estimator families are there?
===================================

``netsim estimators`` lists every registered family and installed entry point with its
source and traits (see :ref:`netsim-estimators`). The same listing from Python, after
registering a family of our own, and the traits as a table.
"""

import matplotlib.pyplot as plt
import numpy as np
from netsim.estimators.registry import family_listing

import netsim
from netsim.cli import main


class Hold:
    """Keeps its prior: the simplest estimator that fits the contract."""

    name = "hold"

    def __init__(self, setup):
        self.estimate = np.array(setup.prior_mean, dtype=float)

    def message_arrived(self, sender, sent_step, payload):
        return False

    def step(self, k, y):
        return self.estimate


netsim.register_estimator(Hold, replace_existing=True)

# %%
# The command line
# ----------------
# ``netsim estimators`` (here through :func:`netsim.cli.main`, as the shell runs it):
# the registered family ``hold`` is listed after the built-ins, registered from Python.
status = main(["estimators"])

# %%
# From Python
# -----------
# :func:`~netsim.estimators.registry.family_listing` returns the same as
# ``netsim estimators --json``: a dict per family with its source, origin and traits.
listing = family_listing()
for item in listing:
    print(f"{item['name']:15s} {item['source']:12s} {item['origin']}")

# %%
# The traits, family by family (a filled cell: the family declares it).
traits = ["needs_gains", "timestamps", "vectorised", "needs_graph_sequence",
          "centralised", "delay_free"]
rows = [item for item in listing if item["traits"]]
table = np.array([[bool(item["traits"][t]) for t in traits] for item in rows], dtype=float)
fig, ax = plt.subplots(figsize=(6.5, 0.35 * len(rows) + 1.2))
ax.imshow(table, cmap="Blues", vmin=0, vmax=1.4, aspect="auto")
ax.set_xticks(range(len(traits)), traits, rotation=30, ha="right")
ax.set_yticks(range(len(rows)), [item["name"] for item in rows])
ax.set_title("Traits of the registered estimator families")
fig.tight_layout()
