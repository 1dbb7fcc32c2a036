"""The figures and tables of the four papers: what each shows, how ours is computed.

Every item of :data:`ITEMS` is one figure or table of a paper that has data (the
papers' diagrams -- aoi Fig. 1, dkfe Figs. 1-2 -- are left out). Its builder computes
the data with the functions that already exist (``netsim bench delay-tolerance``'s
:func:`netsim.bench.delay_tolerance.run_delay_tolerance`, :func:`netsim.aoi.node_errors`,
:mod:`netsim.fusion`, :func:`netsim.models.dkfe.table1_rows`), writes the data (CSV and
JSON) and returns a ``matplotlib.figure.Figure`` (no pyplot) drawn with the paper's axes.
The report (:mod:`netsim.reproduce.report`) puts each beside the paper's text.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from netsim.models.jsonsafe import json_tree

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["PAPERS", "PAPER_TITLES", "Item", "ItemResult", "BuildContext", "ITEMS",
           "items_for", "DKFE_EX1_STEPS", "DKFE_EX2_STEPS", "FIG5_STEPS", "AOI_STEPS",
           "FIG7_INITIAL", "FIG3_GAMMAS", "FIG4_GAMMAS"]

#: Paper keys (as in the claim registry) in report order.
PAPERS = ("LCSYS2022", "delay-tolerant", "aoi", "dkfe")
PAPER_TITLES = {
    "LCSYS2022": "Consensus-based distributed estimation with known delays (LCSYS2022)",
    "delay-tolerant": "Delay-tolerant consensus-based distributed estimation",
    "aoi": "Finite-time distributed observer with age of information (aoi)",
    "dkfe": "Delay-dependent distributed Kalman fusion with dimensionality reduction (dkfe)",
}

#: Horizons of our figures (the papers' are not in the text).
DKFE_EX1_STEPS = 100
DKFE_EX2_STEPS = 200
#: Fig. 5 shows the first steps of the Example 2 trajectory (the plant is unstable).
FIG5_STEPS = 100
AOI_STEPS = 40
#: Fig. 3 / Fig. 4 split of gamma_11 = 0, 0.1, ..., 1 (ours: the paper's is in its images).
FIG3_GAMMAS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
FIG4_GAMMAS = (0.6, 0.7, 0.8, 0.9, 1.0)
#: Fig. 7: the two initial covariances of x(0) (ours; the paper does not give them).
FIG7_INITIAL = (1.0, 10.0)


@dataclass
class ItemResult:
    """What a builder made: the figure, the data files, numbers for the report."""

    figure: Figure
    data_files: list[str]
    ours: list[str]
    differs: list[str] = field(default_factory=list)
    bench_claims: list[dict[str, Any]] = field(default_factory=list)
    numbers: dict[str, Any] = field(default_factory=dict)


@dataclass
class BuildContext:
    """Settings and shared results of one ``netsim reproduce`` run."""

    out: Path
    trials: int
    seed: int = 0
    workers: int = 2
    cache: dict[str, Any] = field(default_factory=dict)

    def cached(self, key: str, make: Callable[[], Any]) -> Any:
        """``cache[key]``, computed by ``make()`` the first time."""
        if key not in self.cache:
            self.cache[key] = make()
        return self.cache[key]


@dataclass(frozen=True)
class Item:
    """One figure or table of a paper.

    Attributes
    ----------
    id : str
        File stem (``lcsys2022-fig1``).
    paper : str
        One of :data:`PAPERS`.
    label : str
        As the paper names it (``Fig. 1``, ``Table I``).
    caption : str
        The paper's caption.
    paper_says : str
        What the paper's text states about it.
    differs : tuple of str
        Where our system differs from the paper's (fixed facts; builders add numbers).
    claims : tuple of str
        Claim registry ids it bears on (missing ids are skipped).
    build : callable(BuildContext) -> ItemResult
    """

    id: str
    paper: str
    label: str
    caption: str
    paper_says: str
    differs: tuple[str, ...]
    claims: tuple[str, ...]
    build: Callable[[BuildContext], ItemResult]


# -- helpers ---------------------------------------------------------------------------------


def _write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    from netsim.outfiles import safe_output

    with safe_output(path, "--out") as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow(["" if (isinstance(v, float) and not math.isfinite(v)) else v
                        for v in row])
    return path.name


def _write_json(path: Path, data: Any) -> str:
    from netsim.outfiles import write_text_safely

    write_text_safely(path, json.dumps(json_tree(data), indent=1, allow_nan=False) + "\n",
                      "--out")
    return path.name


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
        return f"{v:.3e}"
    return f"{v:.{digits}f}"


def _figure(**kwargs: Any) -> Figure:
    """A ``matplotlib.figure.Figure`` (matplotlib imported here, on first use)."""
    from matplotlib.figure import Figure

    return Figure(dpi=110, layout="constrained", **kwargs)


def _positive(values: Sequence[float]) -> np.ndarray:
    a = np.asarray(values, dtype=float)
    return np.where(np.isfinite(a) & (a > 0), a, np.nan)


# -- the delay benchmarks (LCSYS2022 Fig. 1, delay-tolerant Figs. 1-2) -------------------------


def _bench(ctx: BuildContext, preset_name: str) -> dict[str, Any]:
    def make() -> dict[str, Any]:
        from netsim.bench.delay_tolerance import run_delay_tolerance
        from netsim.bench.presets import PRESETS
        from netsim.models.scenario import resolve_scenario

        preset = PRESETS[preset_name]
        scenario = resolve_scenario(preset.scenario)
        return run_delay_tolerance(
            scenario, taus=preset.taus, delays=preset.delays, trials=ctx.trials,
            steps=preset.steps, seed=scenario.seed, preset=preset, workers=ctx.workers,
            executor="serial" if ctx.workers == 1 else "local", progress=False)

    return ctx.cached(f"bench:{preset_name}", make)


def _bench_curves(data: dict[str, Any], family: str) -> list[tuple[str, int, list[int],
                                                                   list[float], str]]:
    """(setting, tau, steps, mse, verdict) of ``family``'s cells (tau = 0 once)."""
    out = []
    for c in data["cells"]:
        if c["family"] != family:
            continue
        curve = (c.get("measured") or {}).get("curve")
        if not curve:
            continue
        mse = [math.nan if v is None else float(v) for v in curve["mse"]]
        out.append((c["setting"], int(c["tau"]), list(curve["steps"]), mse,
                    c["measured"]["verdict"]))
    return out


def _bench_files(ctx: BuildContext, item_id: str, data: dict[str, Any], family: str
                 ) -> list[str]:
    rows = []
    for setting, tau, steps, mse, _ in _bench_curves(data, family):
        rows += [(family, setting, tau, k, v) for k, v in zip(steps, mse, strict=True)]
    files = [_write_csv(ctx.out / f"{item_id}.csv",
                        ("family", "delay_setting", "tau_bar", "step", "mse"), rows)]
    files.append(_write_json(ctx.out / f"{item_id}.json", data))
    return files


def _bench_common(data: dict[str, Any]) -> tuple[list[str], list[str]]:
    scan = data.get("analysis") or {}
    g = data.get("gains") or {}
    ours = [f"Monte Carlo: {data['trials']} trials x {data['steps']} steps per curve "
            f"(vectorised engine), seed {data['seed']}, scenario "
            f"`{data['scenario']['name']}`.",
            f"Our gains: rho(A-hat) = {_fmt(g.get('rho_delay_free'))}, tau* (Theorem 1) = "
            f"{scan.get('tau_star')}."]
    differs = [f"Our instance has rho(A-hat) = {_fmt(g.get('rho_delay_free'))} (paper 0.64) "
               f"and tau* = {scan.get('tau_star')} (paper 10): the LMI gains of the paper "
               "cannot be reproduced without its matrices."]
    return ours, differs


def _mse_axes(ax: Any, title: str) -> None:
    ax.set_yscale("log")
    ax.set_xlabel("time step k")
    ax.set_ylabel("MSE")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def _build_lcsys_fig1(ctx: BuildContext) -> ItemResult:
    data = _bench(ctx, "lcsys2022-fig1")
    curves = _bench_curves(data, data["preset"]["focus"])
    fig = _figure(figsize=(11, 4.4))
    axes = fig.subplots(1, 2, sharey=True)
    colours = {0: "k", 3: "tab:blue", 8: "tab:green", 19: "tab:red"}
    for ax, setting in zip(axes, ("homogeneous", "heterogeneous"), strict=True):
        for s, tau, steps, mse, verdict in sorted(curves, key=lambda c: c[1]):
            if s not in (setting, "none"):
                continue
            label = "no delay" if tau == 0 else rf"$\bar\tau$ = {tau} ({verdict})"
            ax.plot(steps, _positive(mse), color=colours.get(tau), lw=1.3, label=label)
        _mse_axes(ax, f"{setting} delays")
    axes[1].set_ylabel("")
    fig.suptitle("LCSYS2022 Fig. 1 (ours): MSE of the distributed estimator (4)-(5) "
                 f"with delay compensation, {data['trials']} trials", fontsize=11)
    ours, differs = _bench_common(data)
    focus = data["preset"]["focus"]  # the compensating estimator
    for c in data["cells"]:
        if c["family"] == focus and c["tau"] == 19:
            a = c.get("analytics") or {}
            ours.append(f"tau-bar = 19, {c['setting']}: verdict {c['measured']['verdict']}, "
                        f"exact rho = {_fmt(a.get('exact'))}, eq. (26) bound = "
                        f"{_fmt(a.get('bound'))}.")
    return ItemResult(fig, _bench_files(ctx, "lcsys2022-fig1", data, focus), ours,
                      differs, list(data.get("claims", [])))


def _build_tolerant(ctx: BuildContext, preset: str, item_id: str, title: str
                    ) -> ItemResult:
    data = _bench(ctx, preset)
    curves = _bench_curves(data, data["preset"]["focus"])
    fig = _figure(figsize=(6.6, 4.4))
    ax = fig.subplots()
    names = {"none": "no delay", "time-varying": "asynchronous time-varying",
             "synchronous": "synchronous time-varying",
             "asynchronous-fixed": "asynchronous fixed"}
    order = list(data["settings"])
    for s, tau, steps, mse, verdict in sorted(
            curves, key=lambda c: (c[1], order.index(c[0]) if c[0] in order else -1)):
        if preset.endswith("fig2") and s == "none":
            continue
        label = "no delay" if tau == 0 else rf"{names.get(s, s)}, $\bar\tau$ = {tau}"
        ax.plot(steps, _positive(mse), lw=1.3, label=f"{label} ({verdict})")
    _mse_axes(ax, f"{title} (ours): MSE of the estimator (6)-(7), {data['trials']} trials")
    ours, differs = _bench_common(data)
    differs.append("The paper's bounds rho(A-hat)^(1/(tau+1)) = 0.96 / 0.983 follow from its "
                   "0.64; ours follow from our rho(A-hat).")
    return ItemResult(fig, _bench_files(ctx, item_id, data, data["preset"]["focus"]), ours,
                      differs, list(data.get("claims", [])))


# -- aoi Fig. 2 -------------------------------------------------------------------------------


def _build_aoi_fig2(ctx: BuildContext) -> ItemResult:
    from netsim.aoi import illustrative_example, node_errors

    trials = max(1, min(ctx.trials, 20))
    sc = illustrative_example(steps=AOI_STEPS, seed=ctx.seed)
    runs = node_errors(sc, ("naive-uniform", "naive-tree", "aoi"), trials=trials)
    rows = []
    for name, r in runs.items():
        M, K1, N = r.errors.shape
        for m in range(M):
            for k in range(K1):
                for i in range(N):
                    rows.append((name, m, k, i + 1, float(r.errors[m, k, i])))
    files = [_write_csv(ctx.out / "aoi-fig2.csv", ("observer", "trial", "step", "node",
                                                   "error"), rows)]
    summary = {name: {"growth_rate": r.growth_rate, "verdict": r.verdict}
               for name, r in runs.items()}
    files.append(_write_json(ctx.out / "aoi-fig2.json", {
        "scenario": sc.summary(), "steps": AOI_STEPS, "trials": trials,
        "observers": summary,
        "closed_forms": {"naive-uniform": (1 + 5 ** 0.5) / 2, "naive-tree": 2.0}}))
    fig = _figure(figsize=(13, 4.2))
    axes = fig.subplots(1, 3)
    titles = {"naive-uniform": "(left) consensus weights uniform over neighbours",
              "naive-tree": "(right) weights along the tree rooted at node 1",
              "aoi": "freshness-index observer (Sec. 4; not in Fig. 2)"}
    steps = np.arange(AOI_STEPS + 1)
    # (family, freshness observer?) per panel: left, right, ours
    panels = (("naive-uniform", False), ("naive-tree", False), ("aoi", True))
    for ax, (name, freshness) in zip(axes, panels, strict=True):
        e = runs[name].errors[0]
        for i in range(e.shape[1]):
            if freshness:
                ax.plot(steps, e[:, i], "o-", ms=3, lw=1.1, label=f"node {i + 1}")
            else:
                ok = np.isfinite(e[:, i]) & (e[:, i] > 0)
                ax.plot(steps[ok], e[ok, i], "o-", ms=3, lw=1.1, label=f"node {i + 1}")
        if not freshness:
            ax.set_yscale("log")
            ax.set_title(f"{titles[name]}\ngrowth {_fmt(runs[name].growth_rate)} per step",
                         fontsize=9)
        else:
            ax.set_xlim(-0.5, 12)
            ax.set_title(f"{titles[name]}\n{runs[name].verdict}", fontsize=9)
        ax.set_xlabel("time-step k")
        ax.set_ylabel(r"estimation error $|x[k] - \hat{x}_i[k]|$")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("aoi Fig. 2 (ours): estimation errors of the nodes, x[k+1] = 2 x[k], "
                 "trial 0", fontsize=11)
    ours = [f"Growth of the largest node error per step: uniform weights "
            f"{_fmt(runs['naive-uniform'].growth_rate)} (golden ratio 1.6180), tree weights "
            f"{_fmt(runs['naive-tree'].growth_rate)} (a = 2).",
            f"Freshness-index observer: {runs['aoi'].verdict}.",
            f"{trials} trials (x[0] ~ N(0, 1)); the figure shows trial 0, the CSV all."]
    return ItemResult(fig, files, ours, numbers=summary)


# -- dkfe ---------------------------------------------------------------------------------------


def _build_table1(ctx: BuildContext) -> ItemResult:
    from netsim.models.dkfe import table1_rows

    rows = ctx.cached("table1", table1_rows)
    header = ("gamma11", "c75_ours", "c76_ours", "c74_ours", "c75_paper", "c76_paper",
              "c74_paper", "second_moment_radius", "c76_lambda_max", "zeta_inf", "zeta_2",
              "agrees")
    out = []
    for r in rows:
        p = r["paper"] or {}
        out.append((r["gamma11"], r["c75"], r["c76"], r["c74"]["holds"], p.get("c75"),
                    p.get("c76"), p.get("c74"), r["second_moment_radius"], r["c76_value"],
                    r["c74"]["zeta_inf"], r["c74"]["zeta_2"], r["agrees"]))
    files = [_write_csv(ctx.out / "dkfe-table1.csv", header, out),
             _write_json(ctx.out / "dkfe-table1.json", rows)]
    fig = _figure(figsize=(9.5, 4.6))
    ax = fig.subplots()
    ax.axis("off")
    cells = [[f"{r['gamma11']:.1f}", str(r["c75"]), str(r["c76"]), str(r["c74"]["holds"]),
              _fmt(r["second_moment_radius"], 3),
              "/".join(str((r["paper"] or {}).get(k)) for k in ("c75", "c76", "c74")),
              "yes" if r["agrees"] else "NO"] for r in rows]
    table = ax.table(cellText=cells, colLabels=[r"$\gamma_{11}$", "(75)", "(76) by [32]",
                                                "(74) by [26]", "MS radius (ours)",
                                                "paper (75)/(76)/(74)", "agrees"],
                     loc="center", cellLoc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.scale(1, 1.25)
    for (row, col), cell in table.get_celld().items():
        if row > 0 and col == 1 and cells[row - 1][1] == "True":
            cell.set_facecolor("#d8f0d8")
    ax.set_title("dkfe Table I (ours): conditions (75), (76), (74) for Example 1, d_1 = 0",
                 fontsize=11)
    agree = sum(bool(r["agrees"]) for r in rows)
    feas = [r["gamma11"] for r in rows if r["c75"]]
    ours = [f"(75) (LMI, cvxpy) holds for gamma_11 = {feas}; {agree} of {len(rows)} rows "
            "agree with Table I in all three columns.",
            "MS radius: rho(E{A_1(t) kron A_1(t)}), the exact mean-square test of the CSE "
            "error chain (65) (ours, not in the paper); (75) holds exactly where it is < 1."]
    return ItemResult(fig, files, ours, numbers={"rows_agree": agree, "feasible_75": feas})


def _xi11(ctx: BuildContext) -> dict[str, Any]:
    def make() -> dict[str, Any]:
        from netsim.fusion import mse_curves, xi11_trace_curves

        gammas = FIG3_GAMMAS + FIG4_GAMMAS
        exact = xi11_trace_curves(gammas, DKFE_EX1_STEPS)
        mc = {g: mse_curves("dkfe-example1", DKFE_EX1_STEPS, ctx.trials, ctx.seed,
                            gamma11=g)["CSE 1 (d=0)"] for g in gammas}
        return {"exact": exact, "monte_carlo": mc}

    return ctx.cached("xi11", make)


def _build_fig34(ctx: BuildContext, item_id: str, gammas: Sequence[float], label: str
                 ) -> ItemResult:
    d = _xi11(ctx)
    rows = []
    for g in gammas:
        for t, (e, m) in enumerate(zip(d["exact"][g], d["monte_carlo"][g], strict=True)):
            rows.append((g, t, e, m))
    files = [_write_csv(ctx.out / f"{item_id}.csv",
                        ("gamma11", "t", "trace_Xi11_exact", "mse_cse_monte_carlo"), rows)]
    fig = _figure(figsize=(6.8, 4.6))
    ax = fig.subplots()
    tt = np.arange(DKFE_EX1_STEPS + 1)
    cmap = {g: f"C{i}" for i, g in enumerate(gammas)}
    for g in gammas:
        ax.plot(tt, _positive(d["exact"][g]), color=cmap[g], lw=1.5,
                label=rf"$\gamma_{{11}}$ = {g:.1f}")
        ax.plot(tt[::5], _positive(d["monte_carlo"][g])[::5], "o", color=cmap[g], ms=3,
                mfc="none")
    ax.set_yscale("log")
    ax.set_xlabel("t")
    ax.set_ylabel(r"Tr$\{\Xi_{11}(t)\}$")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    ax.set_title(f"dkfe {label} (ours): CSE performance Tr{{Xi_11(t)}}, Example 1; lines: "
                 f"exact\ncovariance recursion, circles: Monte Carlo MSE ({ctx.trials} "
                 "trials)", fontsize=10)
    final = {g: d["exact"][g][-1] for g in gammas}
    ours = ["Tr Xi_11 at t = " + str(DKFE_EX1_STEPS) + ": "
            + ", ".join(f"gamma {g:.1f}: {_fmt(v)}" for g, v in final.items()) + "."]
    if 0.5 in final:
        ours.append(f"At gamma_11 = 0.5 the limit is {_fmt(final[0.5])}.")
    ours.append("Where the CSE is mean-square unstable the Monte Carlo mean of "
                "||x - x^c||^2 lies far below the exact trace: the second moment of a product "
                "of random matrices is carried by rare selection sequences that a few trials "
                "miss (gamma_11 = 0 and 1 are deterministic and agree). Where it is stable the "
                "circles scatter around the lines.")
    return ItemResult(fig, files, ours, numbers={"final_trace_Xi11": final})


def _ex2(ctx: BuildContext) -> dict[str, Any]:
    def make() -> dict[str, Any]:
        from netsim.fusion import exact_trace_curves, fusion_trajectories, mse_curves
        from netsim.models.dkfe import example2

        setup = example2()
        return {"setup": setup, "exact": exact_trace_curves(setup, DKFE_EX2_STEPS),
                "mse": mse_curves(setup, DKFE_EX2_STEPS, ctx.trials, ctx.seed),
                "trajectory": fusion_trajectories(setup, DKFE_EX2_STEPS, ctx.seed)}

    return ctx.cached("ex2", make)


def _build_fig5(ctx: BuildContext) -> ItemResult:
    d = _ex2(ctx)
    tr = d["trajectory"]
    K1, n = FIG5_STEPS + 1, tr.states.shape[1]
    rows = [(t, i + 1, float(tr.states[t, i]), float(tr.dkfe[t, i]))
            for t in range(K1) for i in range(n)]
    files = [_write_csv(ctx.out / "dkfe-fig5.csv", ("t", "component", "x", "x_hat_dkfe"),
                        rows)]
    fig = _figure(figsize=(10, 6.2))
    axes = fig.subplots(2, 2, sharex=True).ravel()
    t = np.arange(K1)
    for i, ax in enumerate(axes):
        ax.plot(t, tr.states[:K1, i], color="k", lw=1.4, label=f"x(t) component {i + 1}")
        ax.plot(t, tr.dkfe[:K1, i], color="tab:red", lw=1.0, ls="--",
                label=rf"DKFE $\hat{{x}}(t)$ component {i + 1}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
        if i >= 2:
            ax.set_xlabel("t")
    fig.suptitle("dkfe Fig. 5 (ours): the state x(t) and the DKFE, Example 2, trial 0",
                 fontsize=11)
    x, xh = tr.states[:K1], tr.dkfe[:K1]
    err = float(np.sqrt(np.mean(np.sum((x - xh) ** 2, axis=1)[K1 // 2:])))
    rms_state = float(np.sqrt(np.mean(np.sum(x ** 2, axis=1)[K1 // 2:])))
    ours = [f"t = {K1 // 2}..{K1 - 1}: RMS error ||x - x-hat|| = {_fmt(err)} against RMS "
            f"||x|| = {_fmt(rms_state)} (the plant is unstable, rho(A) = 1.0441)."]
    return ItemResult(fig, files, ours)


def _build_fig6(ctx: BuildContext) -> ItemResult:
    d = _ex2(ctx)
    exact, mse = d["exact"], d["mse"]
    keys = ("CSE 1 (d=1)", "CSE 2 (d=2)", "DKFE", "ODKFE (d=0)")
    names = {"CSE 1 (d=1)": "CSE 1", "CSE 2 (d=2)": "CSE 2", "DKFE": "DKFE",
             "ODKFE (d=0)": "ODKFE"}
    rows = [(t, *[exact[k][t] for k in keys], *[mse[k][t] for k in keys])
            for t in range(DKFE_EX2_STEPS + 1)]
    files = [_write_csv(ctx.out / "dkfe-fig6.csv",
                        ("t", *[f"trace_{names[k]}_exact" for k in keys],
                         *[f"mse_{names[k]}_monte_carlo" for k in keys]), rows)]
    fig = _figure(figsize=(6.8, 4.6))
    ax = fig.subplots()
    t = np.arange(DKFE_EX2_STEPS + 1)
    for i, k in enumerate(keys):
        ax.plot(t, exact[k], color=f"C{i}", lw=1.5, label=names[k])
        ax.plot(t[::8], np.asarray(mse[k])[::8], "o", color=f"C{i}", ms=3, mfc="none")
    ax.set_xlabel("t")
    ax.set_ylabel("trace of the estimation error covariance")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("dkfe Fig. 6 (ours): CSEs, DKFE and ODKFE, Example 2; lines exact,\n"
                 f"circles Monte Carlo MSE ({ctx.trials} trials)", fontsize=10)
    last = {names[k]: exact[k][-1] for k in keys}
    better = all(exact["DKFE"][s] <= min(exact[keys[0]][s], exact[keys[1]][s]) + 1e-12
                 for s in range(DKFE_EX2_STEPS + 1))
    worse = all(exact["DKFE"][s] >= exact["ODKFE (d=0)"][s] - 1e-12
                for s in range(DKFE_EX2_STEPS + 1))
    ours = ["Exact traces at t = " + str(DKFE_EX2_STEPS) + ": "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in last.items()) + ".",
            f"DKFE <= each CSE at every step: {better}; DKFE >= ODKFE at every step: {worse}."]
    return ItemResult(fig, files, ours, numbers={"final": last, "dkfe_better_than_cses": better,
                                                 "dkfe_worse_than_odkfe": worse})


def _build_fig7(ctx: BuildContext) -> ItemResult:
    from netsim.fusion import covariance_norm_curves

    d = _ex2(ctx)
    setup = d["setup"]
    n = setup.n
    curves = covariance_norm_curves(setup, DKFE_EX2_STEPS,
                                    [s * np.eye(n) for s in FIG7_INITIAL])
    rows = []
    for j, c in enumerate(curves):
        for t in range(DKFE_EX2_STEPS + 1):
            rows.append((j + 1, FIG7_INITIAL[j], t, c["P"][t], c["Omega_1"][t],
                         c["Omega_2"][t]))
    files = [_write_csv(ctx.out / "dkfe-fig7.csv", ("initial_value", "x0_cov_scale", "t",
                                                    "norm2_P", "norm2_Omega_1",
                                                    "norm2_Omega_2"), rows)]
    fig = _figure(figsize=(12, 4.0))
    axes = fig.subplots(1, 3)
    tt = np.arange(DKFE_EX2_STEPS + 1)
    labels = {"P": r"$\|P^i(t)\|_2$", "Omega_1": r"$\|\Omega^i_1(t)\|_2$",
              "Omega_2": r"$\|\Omega^i_2(t)\|_2$"}
    for ax, key in zip(axes, ("P", "Omega_1", "Omega_2"), strict=True):
        for j, c in enumerate(curves):
            ax.plot(tt, c[key], lw=1.4, ls="-" if j == 0 else "--",
                    label=f"i = {j + 1}: P_0 = {FIG7_INITIAL[j]:g} I")
        ax.set_xlabel("t")
        ax.set_ylabel(labels[key])
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("dkfe Fig. 7 (ours): matrix 2-norms of P(t), Omega_1(t), Omega_2(t) from "
                 "two initial values, Example 2", fontsize=11)
    gap = {k: abs(curves[0][k][-1] - curves[1][k][-1]) for k in ("P", "Omega_1", "Omega_2")}
    ours = [f"At t = {DKFE_EX2_STEPS}: ||P||_2 = {_fmt(curves[0]['P'][-1])}, ||Omega_1||_2 = "
            f"{_fmt(curves[0]['Omega_1'][-1])}, ||Omega_2||_2 = "
            f"{_fmt(curves[0]['Omega_2'][-1])}; difference between the two initial values: "
            + ", ".join(f"{k} {_fmt(v)}" for k, v in gap.items()) + "."]
    return ItemResult(fig, files, ours, numbers={"final_gap": gap})


def _build_fig8(ctx: BuildContext) -> ItemResult:
    d = _ex2(ctx)
    tr = d["trajectory"]
    er = tr.dkfe - tr.sdkfe
    K1, n = er.shape
    rows = [(t, *[float(v) for v in er[t]]) for t in range(K1)]
    files = [_write_csv(ctx.out / "dkfe-fig8.csv",
                        ("t", *[f"Er_{i + 1}" for i in range(n)]), rows)]
    fig = _figure(figsize=(6.8, 4.4))
    ax = fig.subplots()
    for i in range(n):
        ax.plot(np.arange(K1), er[:, i], lw=1.2, label=rf"$Er_{i + 1}(t)$")
    ax.set_xlabel("t")
    ax.set_ylabel(r"$Er_i(t) = \hat{x}(i,t) - \hat{x}_s(i,t)$")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("dkfe Fig. 8 (ours): DKFE minus SDKFE, Example 2, trial 0", fontsize=10)
    tail = float(np.max(np.abs(er[-20:])))
    head = float(np.max(np.abs(er[:20])))
    ours = [f"max |Er_i| over the first 20 steps {_fmt(head)}, over the last 20 "
            f"{_fmt(tail)}."]
    return ItemResult(fig, files, ours, numbers={"max_abs_first20": head,
                                                 "max_abs_last20": tail})


def _build_example2(ctx: BuildContext) -> ItemResult:
    from netsim.fusion import example2

    data, _ = ctx.cached("example2", example2)
    files = [_write_json(ctx.out / "dkfe-example2.json", data)]
    rows: list[tuple[str, int | str, int | str, Any, Any]] = []  # (scalars: no row, column)
    for i, (ours, paper) in enumerate(zip(data["weights"], data["paper_weights_eq94"],
                                          strict=True)):
        for r in range(len(ours)):
            for c in range(len(ours[r])):
                rows.append((f"Omega_{i + 1}", r + 1, c + 1, ours[r][c], paper[r][c]))
    scalars = [("(93) rho, sink 1", data["c77_rho"][0], data["paper_c77_rho_eq93"][0]),
               ("(93) rho, sink 2", data["c77_rho"][1], data["paper_c77_rho_eq93"][1]),
               ("(95) zeta_inf,1", data["zeta_inf"][0], data["paper_zeta_inf_eq95"][0]),
               ("(95) zeta_inf,2", data["zeta_inf"][1], data["paper_zeta_inf_eq95"][1])]
    rows += [(name, "", "", o, p) for name, o, p in scalars]
    files.insert(0, _write_csv(ctx.out / "dkfe-example2.csv",
                               ("quantity", "row", "column", "ours", "paper"), rows))
    fig = _figure(figsize=(12, 4.0))
    axes = fig.subplots(1, 3)
    for i, ax in enumerate(axes[:2]):
        ours = np.asarray(data["weights"][i]).ravel()
        paper = np.asarray(data["paper_weights_eq94"][i]).ravel()
        lo, hi = min(ours.min(), paper.min()) - 0.05, max(ours.max(), paper.max()) + 0.05
        ax.plot([lo, hi], [lo, hi], color="0.6", lw=1)
        ax.plot(paper, ours, "o", ms=5)
        ax.set_xlabel(rf"printed (94) $\Omega_{i + 1}$ entries")
        ax.set_ylabel(rf"ours $\Omega_{i + 1}$ entries")
        ax.set_title(rf"$\Omega_{i + 1}$: largest difference "
                     f"{_fmt(data['weights_minus_paper_max_abs'][i])}", fontsize=10)
        ax.grid(True, alpha=0.3)
    ax = axes[2]
    x = np.arange(len(scalars))
    ax.bar(x - 0.2, [o for _, o, _ in scalars], 0.4, label="ours")
    ax.bar(x + 0.2, [p for _, _, p in scalars], 0.4, label="printed")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(x, [n for n, _, _ in scalars], rotation=20, fontsize=8)
    ax.set_title("conditions (77) and (74)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle("dkfe Example 2 (ours): steady-state weights (94) and the printed checks "
                 "(93), (95)", fontsize=11)
    st = data["steady_state"]
    ours_lines = [
        f"Xi(t) converged after {st['steps']} steps: tr P = {_fmt(st['trace_P'])} (DKFE), "
        f"ODKFE {_fmt(st['trace_P_odkfe'])}, centralised KF "
        f"{_fmt(st['trace_P_centralized_kf'])}.",
        "(93): " + ", ".join(f"{_fmt(o)} (printed {p})" for _, o, p in scalars[:2])
        + "; (95): " + ", ".join(f"{_fmt(o)} (printed {p})" for _, o, p in scalars[2:]) + ".",
        "Phi_K (88): largest difference to the printed matrices "
        + ", ".join(_fmt(v) for v in data["Phi_K_minus_paper_eq88_max_abs"]) + "."]
    return ItemResult(fig, files, ours_lines, numbers={
        "weights_minus_paper_max_abs": data["weights_minus_paper_max_abs"]})


# -- the catalogue ------------------------------------------------------------------------------

_LCSYS_SYSTEM = ("The paper does not print A, C, P or K (n = 6, N = 4): we use our own "
                 "instance with its stated properties (scenario lcsys2022-heterogeneous).")
_DKFE_X0 = "x(0) ~ N(0, I) is our choice: the paper gives no initial statistics."

ITEMS: tuple[Item, ...] = (
    Item("lcsys2022-fig1", "LCSYS2022", "Fig. 1",
         "MSEs are bounded steady-state stable for tau-bar = 0, 3, 8. For tau-bar = 19 > "
         "tau-bar* = 10 the MSE is marginally unstable for the homogeneous case, while it is "
         "stable for the heterogeneous case.",
         "Monte Carlo (100 trials) MSE for no delay and homogeneous/heterogeneous delays "
         "tau-bar = 3, 8, 19; rho(A-bar) = 0.64, tau* = 10, eq. (26) bounds 0.74, 0.94, 1.45; "
         "for homogeneous tau-bar = 19, rho(A-bar) = 1; longer delays decrease the decay "
         "rate for tau-bar <= tau*.",
         (_LCSYS_SYSTEM, "Heterogeneous delays are drawn once per link (uniform in "
          "0..tau-bar) from our seed; the paper's draw is unknown."),
         ("L-rho", "L-tau-star", "L-eq26", "L-stable-0-3-8", "L-hom-19", "L-het-19",
          "L-decay", "L-theorem1"),
         _build_lcsys_fig1),
    Item("delay-tolerant-fig1", "delay-tolerant", "Fig. 1",
         "MSEs are bounded steady-state stable in absence of delay and presence of delay "
         "with tau-bar = 10 and tau-bar = 25. Clearly, longer delays result in lower MSE "
         "decay rate.",
         "MSEE over the network with no delay, arbitrary random delays tau-bar = 10 "
         "(rho <= 0.64^(1/11) = 0.96) and tau-bar = 25 (0.983); rho(A-hat) = 0.64.",
         ("The paper does not print its system, weights or gains: we use the LCSYS2022 "
          "instance (scenario lcsys2022-heterogeneous).",
          "Random delays: a uniform draw in 0..tau-bar per link and message (our reading "
          "of 'arbitrary random delays')."),
         ("T-rho", "T-bounds", "T-fig1-stable", "T-decay", "T-theorem1"),
         lambda ctx: _build_tolerant(ctx, "delay-tolerant-fig1", "delay-tolerant-fig1",
                                     "delay-tolerant Fig. 1")),
    Item("delay-tolerant-fig2", "delay-tolerant", "Fig. 2",
         "MSEs are bounded steady-state stable in presence of asynchronous varying delays, "
         "synchronous varying delays, and asynchronous fixed delays (with tau-bar = 15).",
         "Compares (i) asynchronous time-varying, (ii) synchronous time-varying and (iii) "
         "asynchronous time-invariant delays, all with tau-bar = 15.",
         ("The paper does not print its system: we use the LCSYS2022 instance.",),
         ("T-fig2-stable", "T-theorem1"),
         lambda ctx: _build_tolerant(ctx, "delay-tolerant-fig2", "delay-tolerant-fig2",
                                     "delay-tolerant Fig. 2")),
    Item("aoi-fig2", "aoi", "Fig. 2",
         "Estimation error plots of the nodes for the model in Figure 1. Simulations are "
         "performed for a model where a = 2. The figure on the left corresponds to the "
         "case where consensus weights are distributed uniformly among neighbors, while the "
         "one on the right is the case where weights are placed along a tree rooted at "
         "node 1.",
         "In each case (uniform weights, tree weights) the error dynamics are unstable; "
         "node 1 has perfect information of the state.",
         ("Figure 1's two graphs are an image; we infer them from the text: (a) = "
          "{1->2, 2->3}, (b) = {1->3, 3->2} (netsim.aoi).",
          "The initial state and the horizon are not given: x[0] ~ N(0, 1), 40 steps; the "
          "errors are on a log axis (zeros, exact estimates, are not drawn).",
          "The third panel (freshness-index observer, Section 4) is ours, for comparison."),
         ("A-naive-growth", "A-corollary1"),
         _build_aoi_fig2),
    Item("dkfe-table1", "dkfe", "Table I",
         "Comparison of the result in Theorem 2 and the results in [26] and [32].",
         "Example 1 (d_1 = 0), gamma_11 = 0, 0.1, ..., 1: (75) True exactly for 0.4..0.8, "
         "(76) (derived by [32]) and (74) (derived by [26]) False for every gamma_11.",
         ("(75) is solved with cvxpy (the paper: Matlab LMI Toolbox).",
          "(74) is read as the conjunction of its two lines."),
         ("D-table1", "D-cond75"),
         _build_table1),
    Item("dkfe-fig3", "dkfe", "Fig. 3",
         "The estimation performances of the CSE (i.e., Tr{Xi_11(t)}) with different "
         "selection probabilities gamma_11.",
         "The sequence Tr{Xi_11(t)} is convergent when gamma_11 in {0.4, 0.5, 0.6, 0.7, "
         "0.8}, as condition (75) predicts.",
         ("Which gamma_11 are in Fig. 3 and which in Fig. 4 is not in the text (the figures "
          "are images): ours has 0..0.5 in Fig. 3 and 0.6..1 in Fig. 4.",
          "Horizon t = 0..100 and x(0) ~ N(0, I) are ours; " + _DKFE_X0),
         ("D-cond75", "D-table1"),
         lambda ctx: _build_fig34(ctx, "dkfe-fig3", FIG3_GAMMAS, "Fig. 3")),
    Item("dkfe-fig4", "dkfe", "Fig. 4",
         "The estimation performances of the CSE (i.e., Tr{Xi_11(t)}) with different "
         "selection probabilities gamma_11.",
         "The sequence Tr{Xi_11(t)} is convergent when gamma_11 in {0.4, 0.5, 0.6, 0.7, "
         "0.8}.",
         ("The split of gamma_11 between Figs. 3 and 4 is ours (see Fig. 3).", _DKFE_X0),
         ("D-cond75", "D-table1"),
         lambda ctx: _build_fig34(ctx, "dkfe-fig4", FIG4_GAMMAS, "Fig. 4")),
    Item("dkfe-fig5", "dkfe", "Fig. 5",
         "The trajectories of the DKFE x-hat(t) and the state x(t).",
         "The designed DKFE is able to estimate the original state x(t) well (Example 2, "
         "d_1 = 1, d_2 = 2).",
         (_DKFE_X0, "One trial of our seed over t = 0..100 (the paper's horizon and noise "
          "draw are unknown)."),
         ("D-cond77",),
         _build_fig5),
    Item("dkfe-fig6", "dkfe", "Fig. 6",
         "Comparison of estimation performance for the CSEs, DKFE and ODKFE.",
         "The DKFE is better than each CSE at each time step (57) and worse than the ODKFE "
         "(no delays); the MSEs of the DKFE and CSEs converge to steady-state values (73), "
         "(78).",
         (_DKFE_X0, "Our steady-state weights differ from the printed (94) by up to 0.13 "
          "(netsim fusion example2), so the paper's curves may differ in level."),
         ("D-cond77",),
         _build_fig6),
    Item("dkfe-fig7", "dkfe", "Fig. 7",
         "The trajectories of ||P^i(t)||_2, ||Omega^i_1(t)||_2 and ||Omega^i_2(t)||_2 "
         "(i = 1, 2) under different initial values.",
         "||P(t)||_2 and ||Omega_i(t)||_2 converge to the unique steady-state values under "
         "different initial values (Theorem 3).",
         ("The paper does not give its two initial values: ours are P_0 = I and 10 I "
          "(covariance of x(0)).",
          "Our steady Omega_i differ from the printed (94) by up to 0.13."),
         ("D-cond77",),
         _build_fig7),
    Item("dkfe-fig8", "dkfe", "Fig. 8",
         "The trajectories of Er_i(t) (i = 1, 2, 3, 4).",
         "With the same measurements, the errors between the DKFE and the SDKFE converge to "
         "zero as t increases.",
         (_DKFE_X0, "The SDKFE uses our steady-state weights (79) (with P, not P^-1, see "
          "netsim.models.dkfe), which differ from the printed (94)."),
         ("D-cond77",),
         _build_fig8),
    Item("dkfe-example2", "dkfe", "Example 2",
         "Example 2's printed numbers: Phi_K (88), condition (77) (93), the steady-state "
         "weighting matrices (94) and the norm condition (74) (95).",
         "rho(A (I - H_1) A) = 0.5759 < 1 and rho(A^2 (I - H_2) A) = 0.6631 < 1, so (77) "
         "holds and the SDKFE exists (Theorem 3); zeta_inf,1 = 0.8657 < 1 but zeta_inf,2 "
         "= 1.3554 > 1, so (74) of [26] fails for the second sink; Algorithm 1 gives the "
         "steady-state weights (94).",
         ("Our steady-state weights differ from (94) by up to 0.13; our Xi(t) is confirmed "
          "by Monte Carlo and by the paper's own recursions (45), (55) (netsim.models.dkfe).",
          "(93)'s second value: ours 0.6613 against the printed 0.6631 (a digit swap); "
          "(95)'s second line prints H_1 where H_2 gives the printed 1.3554.",
          "(79) prints P^-1 I_a^T Xi^-1; we use P I_a^T Xi^-1, the limit of (31)."),
         ("D-cond77",),
         _build_example2),
)


def items_for(papers: Sequence[str] | None) -> list[Item]:
    """The items of the given papers (case-insensitive keys of :data:`PAPERS`); all for
    none. ValueError names an unknown paper."""
    if not papers:
        return list(ITEMS)
    keys = {p.lower(): p for p in PAPERS}
    chosen = []
    for name in papers:
        key = keys.get(str(name).lower())
        if key is None:
            raise ValueError(f"unknown paper {name!r}; choose from {', '.join(PAPERS)}")
        if key not in chosen:
            chosen.append(key)
    return [it for it in ITEMS if it.paper in chosen]
