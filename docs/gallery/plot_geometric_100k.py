"""
100,000 agents
==============

``examples/geometric-100k.toml``: the LCSYS2022 n = 6 plant observed by 100,000 sensors
on a random geometric graph, tau = 3, with the local gain design. Such a network is
built sparse end to end (:doc:`/large-networks`): no N x N array is ever formed.

.. note::

   This example is executed only when the site is built with ``NETSIM_DOCS_FULL=1``:
   from a cold gain cache the design's one structured spectral radius takes about two
   minutes (later runs read the gain cache). Without it, this page shows the code only.
   Run it yourself from the repository root with
   ``python docs/gallery/plot_geometric_100k.py`` or
   ``netsim run examples/geometric-100k.toml``.
"""

import os
import time
from pathlib import Path

import matplotlib.pyplot as plt

import netsim

root = Path(os.environ.get("NETSIM_REPO_ROOT", "."))
start = time.perf_counter()
scenario = netsim.load_scenario(root / "examples" / "geometric-100k.toml")
print(f"{scenario.n_agents:,} agents, {len(scenario.link_table.src):,} links "
      f"({time.perf_counter() - start:.1f} s to build)")

# %%
# One trial of 100 steps on the vectorised engine.
start = time.perf_counter()
result = netsim.run(scenario, steps=100, trials=1)
print(f"run: {time.perf_counter() - start:.1f} s")
summary = result.summary["compensated"]
print(summary.verdict)

# %%
fig, ax = plt.subplots(figsize=(7, 4))
ax.semilogy(result["compensated"].mse)
ax.set_xlabel("step k")
ax.set_ylabel("network MSE")
ax.set_title("geometric-100k: 100,000 agents, tau = 3")
fig.tight_layout()
