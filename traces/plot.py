"""One PNG summarising traces: MSE, delays, spectral radius versus the papers' bounds.

:func:`plot_traces` draws up to four panels (a ``matplotlib.figure.Figure`` written
straight to PNG: no pyplot, the user's matplotlib backend is never changed); a panel
with nothing to show (no delays recorded, no P, A, C_i, L_i in the traces, no AoI
observer) is left out:

1. the network MSE (1/N) sum_i ||x_k - x-hat^i_k||^2 over time, one line per trace
   (labelled by family and trial), log scale;
2. delay histograms: the ``delay_steps`` d of every delivered message (all links, all
   traces; usable at s + 1 + d) and, per consensus trace, the effective delays
   r_ij[k] >= 0 its agents used (own-estimate substitutions counted in the legend);
3. spectral radius versus delay for homogeneous delays tau = 0..max(tau_obs, tau*+2)
   (every link delayed by tau, self-loops 0): the exact rho of the compensating
   estimator's augmented closed loop (LCSYS2022 eq. 9-10; also the uncompensated one's,
   delay-tolerant eq. 11, dashed) against the eq. (26) bound
   rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)) and the delay-tolerant bound
   rho(A-hat)^(1/(tau+1)); a horizontal line at 1, a vertical line at the observed
   maximum delay tau_obs (and a dotted one at tau*), and a marker per consensus trace
   at the exact rho of its realised (last-step) delay pattern;
4. for AoI traces, the largest freshness index per agent over time.

This module imports ``models`` (``netsim.models.augmented``), never ``netsim`` or ``simpy``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from netsim.models.extras import missing

try:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
except ModuleNotFoundError as _error:  # matplotlib is the plot extra
    raise missing(_error.name or "matplotlib", "plot", "plotting traces") from None
from netsim.models.augmented import (
    augmented_spectral_radius,
    delay_bound_lcsys,
    delay_bound_tolerant,
    tau_star,
)
from netsim.traces.reader import NOT_USED, Trace
from netsim.traces.replay import TraceSystem, effective_pattern, trace_system

__all__ = ["plot_traces", "traces_figure", "homogeneous_rho", "TAU_PLOT_MAX"]

#: Largest homogeneous delay drawn in the spectral panel (the augmented matrices grow
#: as N n (tau+1)).
TAU_PLOT_MAX = 40


#: Colour of the i-th trace in every panel; the spectral curves use other colours.
_TRACE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:cyan", "tab:pink", "tab:gray",
                  "gold", "navy")


def _colour(index: int) -> str:
    return _TRACE_COLOURS[index % len(_TRACE_COLOURS)]


def _label(trace: Trace) -> str:
    trial = "?" if trace.trial is None else trace.trial
    return f"{trace.family or '?'} trial {trial}"


def homogeneous_rho(system: TraceSystem, tau: int, compensated: bool) -> float:
    """Exact rho of the augmented closed loop with every link delayed by ``tau``
    (self-loops 0), by ``netsim.models.augmented.augmented_spectral_radius``."""
    N = system.n_agents
    delays = np.where((system.P != 0) & ~np.eye(N, dtype=bool), int(tau), 0)
    with np.errstate(over="ignore", invalid="ignore"):
        return float(augmented_spectral_radius(system.P, system.A, system.C, system.L,
                                               delays, tau=int(tau),
                                               compensated=compensated))


def _effective_delays(trace: Trace, system: TraceSystem | None) -> tuple[np.ndarray, int]:
    """(r >= 0 used on the graph's edges at k >= 1, number of substitutions)."""
    D = trace.effective_delays()
    if system is None or D.shape[0] < 2 or D.shape[1:] != system.P.shape:
        return np.zeros(0, dtype=int), 0
    N = system.n_agents
    edge = (system.P != 0) & ~np.eye(N, dtype=bool)
    vals = D[1:][np.broadcast_to(edge, D[1:].shape)]
    return vals[vals >= 0].astype(int), int(np.sum(vals == -1))


def _link_delays(trace: Trace) -> list[int]:
    return [int(m.delay_steps) for (j, i) in trace.links
            for m in trace.link_events(j, i, "delivered")]


def _mse_panel(ax: Axes, traces: Sequence[Trace]) -> None:
    drawn = 0
    for index, trace in enumerate(traces):
        sq = trace.squared_errors()
        if sq.size == 0:
            continue
        with np.errstate(invalid="ignore"):
            rows = np.any(np.isfinite(sq), axis=1)
            mse = np.full(sq.shape[0], np.nan)
            mse[rows] = np.nanmean(sq[rows], axis=1)
        exact_zero = mse == 0
        positive = mse[np.isfinite(mse) & (mse > 0)]
        # an estimator that is exact (e.g. AoI finite time) would vanish from a log
        # axis: draw its zeros at a floor far below the smallest positive value
        floor = (positive.min() if positive.size else 1.0) * 1e-6
        mse = np.where(exact_zero, floor, np.where(mse > 0, mse, np.nan))
        if not np.any(np.isfinite(mse)):
            continue
        label = _label(trace) + (" (0 drawn at floor)" if exact_zero.any() else "")
        ax.plot(np.arange(len(mse)), mse, lw=1.3, color=_colour(index), label=label)
        drawn += 1
    ax.set_yscale("log")
    ax.set_xlabel("step k")
    ax.set_ylabel(r"network MSE  $N^{-1}\sum_i \|x_k - \hat{x}^i_k\|^2$")
    ax.set_title("Network mean-squared error")
    ax.grid(True, which="both", alpha=0.3)
    if drawn:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no errors recorded", ha="center", va="center",
                transform=ax.transAxes)


def _freshness_panel(ax: Axes, traces: Sequence[Trace]) -> None:
    """Largest freshness index (age of information) per AoI agent over time."""
    for trace in traces:
        ages = trace.freshness()
        for i in trace.agents:
            col = ages[:, i].astype(float)
            col[col < -1] = np.nan  # not recorded
            ax.step(np.arange(len(col)), col, where="post", lw=1.2,
                    label=f"{_label(trace)}: agent {i}")
    ax.axhline(-1, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("step k")
    ax.set_ylabel("largest freshness index (-1 = omega, not yet triggered)")
    ax.set_title("Age of information (AoI observer)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)


_DelayGroups = list[tuple[str, np.ndarray, str]]


def _delay_groups(traces: Sequence[Trace], systems: list[TraceSystem | None]
                  ) -> tuple[_DelayGroups, int | None]:
    """The histograms to draw and tau_obs (max effective delay of consensus traces)."""
    groups: _DelayGroups = []
    link = np.array([d for t in traces for d in _link_delays(t)], dtype=int)
    if link.size:
        groups.append((f"link delay d, delivered messages, all traces ({link.size})", link,
                       "0.45"))
    tau_obs: int | None = None
    for index, (trace, system) in enumerate(zip(traces, systems, strict=True)):
        if trace.recursion_compensated is None:
            continue
        vals, subs = _effective_delays(trace, system)
        if vals.size:
            tau_obs = max(tau_obs or 0, int(vals.max()))
            extra = f", {subs} substituted" if subs else ""
            groups.append((f"effective r used, {_label(trace)} ({vals.size}{extra})", vals,
                           _colour(index)))
    if tau_obs is None and link.size:
        tau_obs = int(link.max())
    return groups, tau_obs


def _delay_panel(ax: Axes, groups: _DelayGroups) -> None:
    """Draw the delay histograms (integer ticks, thinned by MaxNLocator)."""
    top = max(int(v.max()) for _, v, _ in groups)
    bins = np.arange(top + 1)
    width = 0.8 / len(groups)
    for g, (name, vals, colour) in enumerate(groups):
        frac = np.bincount(vals, minlength=top + 1)[: top + 1] / vals.size
        ax.bar(bins - 0.4 + width * (g + 0.5), frac, width=width, color=colour, label=name)
    ax.set_xlim(-0.6, top + 0.6)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    ax.set_xlabel("delay (steps)")
    ax.set_ylabel("fraction of messages / of uses")
    ax.set_title("Delay histograms")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=1)


def _has_errors(traces: Sequence[Trace]) -> bool:
    for trace in traces:
        sq = trace.squared_errors()
        if sq.size and np.any(np.isfinite(sq) & (sq >= 0)):
            return True
    return False


def _spectral_panel(ax: Axes, traces: Sequence[Trace],
                    systems: list[TraceSystem | None], tau_obs: int | None,
                    tau_range: int | None) -> None:
    system = next(s for s in systems if s is not None)
    P, A, C, L = system.P, system.A, system.C, system.L
    star = tau_star(P, A, C, L, tau_max=TAU_PLOT_MAX)
    if tau_range is None:
        hi = max(tau_obs or 0, (star if star is not None else 0) + 2)
        tau_range = min(hi, TAU_PLOT_MAX)
    taus = np.arange(int(tau_range) + 1)
    exact_c = [homogeneous_rho(system, int(t), True) for t in taus]
    exact_u = [homogeneous_rho(system, int(t), False) for t in taus]
    with np.errstate(over="ignore", invalid="ignore"):
        eq26 = [float(delay_bound_lcsys(P, A, C, L, int(t))) for t in taus]
    tolerant = [float(delay_bound_tolerant(P, A, C, L, int(t))) for t in taus]
    ax.plot(taus, exact_c, "o-", color="tab:purple", lw=1.8, ms=4,
            label="exact rho, compensated (eq. 9-10)")
    ax.plot(taus, exact_u, "s--", color="tab:olive", lw=1.2, ms=3,
            label="exact rho, uncompensated (delay-tol. eq. 11)")
    ax.plot(taus, eq26, "^-", color="tab:red", lw=1.4, ms=4,
            label=r"LCSYS2022 eq. (26): $\rho((I-KD)(P\otimes A^{\tau+1}))^{1/(\tau+1)}$")
    ax.plot(taus, tolerant, "v-", color="tab:brown", lw=1.4, ms=4,
            label=r"delay-tolerant: $\rho(\hat{A})^{1/(\tau+1)}$")
    ax.axhline(1.0, color="k", lw=1.0, label="rho = 1")
    if tau_obs is not None:
        ax.axvline(tau_obs, color="0.35", lw=1.2, ls="-.", label=f"tau_obs = {tau_obs}")
    if star is not None and star <= taus[-1]:
        ax.axvline(star, color="tab:red", lw=1.0, ls=":", label=f"tau* (Theorem 1) = {star}")
    markers = "DPX*hp"
    m = 0
    for index, (trace, sys_) in enumerate(zip(traces, systems, strict=True)):
        if sys_ is None or trace.recursion_compensated is None:
            continue
        D = trace.effective_delays()
        if D.shape[0] < 2 or D.shape[1:] != sys_.P.shape or np.any(D[-1] == -1):
            continue
        edge = (sys_.P != 0) & ~np.eye(sys_.n_agents, dtype=bool)
        if np.any(edge & (D[-1] == NOT_USED)):
            continue
        P_eff, r_eff = effective_pattern(sys_.P, D[-1])
        rho = float(augmented_spectral_radius(P_eff, sys_.A, sys_.C, sys_.L, r_eff,
                                              compensated=trace.recursion_compensated))
        depth = int(r_eff[edge].max()) if np.any(edge) else 0
        ax.plot([depth], [rho], markers[m % len(markers)], ms=10, mec="k",
                color=_colour(index), label=f"realised last-step pattern, {_label(trace)}")
        m += 1
    ax.set_xlabel(r"homogeneous delay $\tau$ (steps, every link)")
    ax.set_ylabel("spectral radius")
    ax.set_title("Spectral radius vs delay and the papers' bounds")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2)


def traces_figure(traces: Sequence[Trace], *, title: str | None = None,
                  tau_range: int | None = None) -> Figure:
    """The ``matplotlib.figure.Figure`` of :func:`plot_traces` (panels with data only)."""
    traces = list(traces)
    if not traces:
        raise ValueError("plot_traces needs at least one trace")
    systems = [trace_system(t)[0] for t in traces]
    aoi = [t for t in traces if any(name.endswith("/freshness") for name in t.counts)]
    groups, tau_obs = _delay_groups(traces, systems)
    panels: list[str] = []
    if _has_errors(traces) or not (groups or aoi or any(s is not None for s in systems)):
        panels.append("mse")  # an empty trace still gets its (labelled) MSE panel
    if groups:
        panels.append("delays")
    if any(s is not None for s in systems):
        panels.append("spectral")
    if aoi:
        panels.append("freshness")
    fig = Figure(figsize=(6.5 * len(panels) + 1, 8), dpi=100)
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    for ax, panel in zip(axes, panels, strict=True):
        if panel == "mse":
            _mse_panel(ax, traces)
        elif panel == "delays":
            _delay_panel(ax, groups)
        elif panel == "spectral":
            _spectral_panel(ax, traces, systems, tau_obs, tau_range)
        else:
            _freshness_panel(ax, aoi)
    if title is None:
        name = traces[0].scenario.get("name", "")
        title = f"{name}: {len(traces)} trace(s)" if name else f"{len(traces)} trace(s)"
    fig.suptitle(title, fontsize=13)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return fig


def plot_traces(traces: Sequence[Trace], path: str | os.PathLike[str], *,
                title: str | None = None, tau_range: int | None = None) -> Path:
    """Write one PNG with the panels that have data (see the module docstring).

    Parameters
    ----------
    traces : sequence of Trace
        Read with :func:`netsim.traces.reader.read_trace`; the spectral panel uses the matrices
        of the first trace that has P, A, C_i and L_i (left out when none has them).
    path : str or os.PathLike
        The PNG file to write (parent directories must exist).
    title : str, optional
        Figure title (default: the scenario name of the first trace).
    tau_range : int, optional
        Largest homogeneous delay of the spectral panel (default max(tau_obs, tau*+2),
        at most TAU_PLOT_MAX).

    Returns
    -------
    pathlib.Path
    """
    fig = traces_figure(traces, title=title, tau_range=tau_range)
    out = Path(path)
    fig.savefig(out, format="png")
    return out
