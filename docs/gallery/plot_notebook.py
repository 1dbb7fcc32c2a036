"""
A run in a notebook
===================

What a :class:`netsim.api.RunResult` shows in Jupyter: its summary (a few lines of
text, or an HTML table), ``plot()``, and ``to_dataframe(what=...)`` for tidy pandas
tables. Needs the ``notebook`` extra (``pip install 'netsim[notebook]'``: pandas,
pyarrow, matplotlib). The page :doc:`/notebook` describes every table and column.
"""

# %%
# Run and look at the result
# --------------------------
# The last expression of a cell is displayed: Jupyter (and this page) show the HTML
# summary table, ``repr`` the same in a few lines of text.
import netsim

result = netsim.run("lcsys2022-heterogeneous", steps=50, trials=2,
                    estimators=["compensated", "uncompensated", "centralized-kf"])
result  # noqa: B018 (the last expression of a cell is displayed)

# %%
# The text form, for a terminal or a log:
print(repr(result))

# %%
# ``plot()``: the network MSE of every family over time, on new axes (or ``ax=``).
ax = result.plot()
ax.figure.tight_layout()

# %%
# Table 1: the squared errors
# ---------------------------
# ``to_dataframe()`` (``what="errors"``) has one row per family, trial, step and agent;
# their mean per family and step is the MSE the summary and ``plot()`` show.
errors = result.to_dataframe(what="errors")
print(errors.shape)
errors.head()

# %%
mse = errors.groupby(["family", "step"]).squared_error.mean().unstack("family")
mse.tail()

# %%
# Table 2: the estimates, against the true states
# -----------------------------------------------
# ``what="estimates"`` has one row per family, trial, step, agent and state component;
# ``what="states"`` the true state of each family's trials. Joined on (family, trial,
# step, component), they give each agent's estimate beside the state it tracks.
estimates = result.to_dataframe(what="estimates")
states = result.to_dataframe(what="states")
both = estimates.merge(states, on=["family", "trial", "step", "time", "component"])
one = both.query("family == 'compensated' and trial == 0 and component == 0")
one.head()

# %%
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(7, 3.5))
truth = one[one.agent == 0]
ax.plot(truth.time, truth.state, color="black", linewidth=2, label="x_k[0] (true)")
for agent, rows in one.groupby("agent"):
    ax.plot(rows.time, rows.estimate, linewidth=1, label=f"agent {agent}")
ax.set_xlabel("time (s)")
ax.set_ylabel("state component 0")
ax.set_title("compensated, trial 0: every agent's estimate of x[0]")
ax.legend(ncol=3, fontsize="small")
fig.tight_layout()

# %%
# Files: ``to_csv`` and ``to_parquet`` write the same tables (an existing file only with
# ``force=True``); ``what="delays"`` and ``what="drops"`` give the effective delays and
# the dropped messages of an untraced run.
delays = result.to_dataframe(what="delays")
print(delays.groupby("family").delay.describe()[["count", "mean", "max"]])
