"""
Opening a trace in Foxglove
===========================

``netsim.run(..., trace=...)`` writes an MCAP file that any MCAP reader and Foxglove
open; :func:`netsim.traces.layout.write_layout` writes a Foxglove layout for it (a tab
of plots per topic group). This example writes both into a temporary folder and draws
what the layout's panels show. It cannot start Foxglove; to look at the files there:

1. in Foxglove (the desktop app or app.foxglove.dev), *Open local file* and pick
   ``run.mcap``;
2. *Layouts > Import from file* and pick ``run.layout.json``.

The same from the command line: ``netsim run lcsys2022-heterogeneous --tau 3 --trials 1
--steps 60 --estimators compensated --trace run.mcap --layout``.
"""

import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
from netsim.traces.layout import render_layout, write_layout

import netsim

folder = Path(tempfile.mkdtemp(prefix="netsim-foxglove-"))
trace_path = folder / "run.mcap"
netsim.run("lcsys2022-heterogeneous", steps=60, trials=1, estimators=["compensated"],
           trace=trace_path)
layout_path = write_layout(trace_path)  # run.layout.json beside the trace
print(trace_path.name, f"{trace_path.stat().st_size / 1e3:.0f} kB;", layout_path.name)

# %%
# What the file holds: the per-step topics and the estimates of every agent.
trace = netsim.read_trace(trace_path)
print(sorted(trace.file_topics))
print("estimates:", trace.estimates().shape, "(steps, agents, states)")

# %%
# The layout is JSON: tabs of Plot panels whose series are message paths into the
# trace's own topics.
layout = json.loads(layout_path.read_text())
print(len(json.dumps(layout)), "characters of layout JSON")

# %%
# A picture of the layout's panels, drawn from the trace's data by the same message
# paths (``netsim layout run.mcap --figure run.png`` does the same).
png = render_layout(trace, layout, folder / "layout.png", tabs=["Errors", "State"])
fig, ax = plt.subplots(figsize=(10, 6))
ax.imshow(plt.imread(png))
ax.set_axis_off()
fig.tight_layout()
