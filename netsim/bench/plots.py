"""The delay-tolerance report as a PNG (a ``matplotlib.figure.Figure``, imported when called;
no pyplot, so the user's backend is never changed)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from netsim.bench.cells import find_cell as _cell

__all__ = ["plot_report"]


def plot_report(data: dict[str, Any], path: str | Path) -> Path:
    """PNG: steady-state MSE vs tau per estimator (one panel per delay setting; a run
    that is not stable has no steady MSE: its last trusted MSE is marked x) and the
    focus estimator's MSE over time for each tau."""
    from netsim.models.extras import require

    colormaps = require("matplotlib", "plot", "the --plot figure").colormaps
    from matplotlib.figure import Figure

    settings = list(data["settings"])
    ncol = max(1, len(settings))
    fig = Figure(figsize=(5.2 * ncol, 8.2))
    axes = fig.subplots(2, ncol, squeeze=False)
    focus = (data["preset"] or {}).get("focus") or "compensated"
    if focus not in data["families"]:
        focus = data["families"][0]
    colours = {"compensated": "C0", "uncompensated": "C3", "block": "C2",
               "centralized-kf": "0.4"}
    for col, setting in enumerate(settings):
        ax = axes[0][col]
        finite_top = []
        for family in data["families"]:
            pts = []
            for tau in data["taus"]:
                c = _cell(data, setting, tau, family)
                if c is None:
                    continue
                m = c["measured"]
                # a steady MSE for stable runs only; the others: their last trusted MSE
                v = m.get("steady_state_mse", m.get("last_trusted_mse"))
                pts.append((tau, v, m["verdict"]))
                if isinstance(v, float) and math.isfinite(v) and v > 0:
                    finite_top.append(v)
            traits = data.get("family_traits", {}).get(family, {})
            if traits.get("delay_free"):  # one value whatever the delays: a line
                vals = [v for _, v, _ in pts if isinstance(v, float) and v > 0]
                if vals:
                    label = ("centralised KF (reference)" if traits.get("centralised")
                             else f"{family} (no communication)")
                    ax.axhline(vals[0], color=colours.get(family, "0.6"), ls="--", lw=1,
                               label=label)
                continue
            xs = [t for t, v, verdict in pts
                  if verdict == "stable" and isinstance(v, float) and v > 0]
            ys = [v for _, v, verdict in pts
                  if verdict == "stable" and isinstance(v, float) and v > 0]
            ax.plot(xs, ys, "o-", color=colours.get(family), label=family)
            bad = [(t, v) for t, v, verdict in pts if verdict != "stable"]
            for t, v in bad:
                y = v if isinstance(v, float) and v > 0 else None
                if y is None:
                    y = max(finite_top) * 3 if finite_top else 1.0
                ax.plot([t], [y], "x", color=colours.get(family), ms=11, mew=2.5)
        ax.set_yscale("log")
        ax.set_xlabel("delay bound tau (steps)")
        ax.set_ylabel("steady-state MSE")
        ax.set_title(f"{setting}: steady MSE vs tau (x: not stable, last MSE)", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
        ax2 = axes[1][col]
        cmap = colormaps["viridis"]
        for n, tau in enumerate(data["taus"]):
            c = _cell(data, setting, tau, focus)
            if c is None or not c["measured"].get("curve"):
                continue
            curve = c["measured"]["curve"]
            mse = np.array([np.nan if v is None else v for v in curve["mse"]], dtype=float)
            ax2.plot(curve["steps"], mse, color=cmap(n / max(1, len(data["taus"]) - 1)),
                     label=f"tau = {tau} ({c['measured']['verdict']})")
        ax2.set_yscale("log")
        ax2.set_xlabel("step k")
        ax2.set_ylabel("network MSE")
        ax2.set_title(f"{setting}: {focus} MSE over time ({data['trials']} trials)",
                      fontsize=10)
        ax2.grid(True, which="both", alpha=0.3)
        ax2.legend(fontsize=8)
    title = data["preset"]["name"] if data["preset"] else data["scenario"]["name"]
    fig.suptitle(f"netsim bench delay-tolerance: {title}", fontsize=12)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path
