"""The dkfe paper's figures and tables for ``netsim reproduce`` (private to
:mod:`netsim.papers.dkfe`, which declares them): Table I, Figs. 3-8 and Example 2's
printed numbers, computed by :mod:`netsim.fusion` and :mod:`netsim.models.dkfe`.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

from netsim.reproduce.items import (
    BuildContext,
    ItemResult,
    figure,
    fmt,
    positive,
    write_csv,
    write_json,
)

__all__ = ["DKFE_EX1_STEPS", "DKFE_EX2_STEPS", "FIG5_STEPS", "FIG3_GAMMAS", "FIG4_GAMMAS",
           "FIG7_INITIAL", "build_table1", "build_fig34", "build_fig5", "build_fig6",
           "build_fig7", "build_fig8", "build_example2", "example2_data", "table1_data"]

#: Horizons of our figures (the papers' are not in the text).
DKFE_EX1_STEPS = 100
DKFE_EX2_STEPS = 200
#: Fig. 5 shows the first steps of the Example 2 trajectory (the plant is unstable).
FIG5_STEPS = 100
#: Fig. 3 / Fig. 4 split of gamma_11 = 0, 0.1, ..., 1 (ours: the paper's is in its images).
FIG3_GAMMAS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
FIG4_GAMMAS = (0.6, 0.7, 0.8, 0.9, 1.0)
#: Fig. 7: the two initial covariances of x(0) (ours; the paper does not give them).
FIG7_INITIAL = (1.0, 10.0)


@functools.lru_cache(maxsize=1)
def _example2_once() -> tuple[dict[str, Any], str]:
    from netsim.fusion import example2

    return example2()


@functools.lru_cache(maxsize=1)
def _table1_once() -> list[dict[str, Any]]:
    from netsim.models.dkfe import table1_rows

    return table1_rows()


def example2_data() -> tuple[dict[str, Any], str]:
    """:func:`netsim.fusion.example2` (data, text), computed once per process (the
    Example 2 item and the claims on it read the same numbers); a deep copy each call."""
    return copy.deepcopy(_example2_once())


def table1_data() -> list[dict[str, Any]]:
    """:func:`netsim.models.dkfe.table1_rows`, computed once per process (the Table I
    item and its claims); a deep copy each call."""
    return copy.deepcopy(_table1_once())


def build_table1(ctx: BuildContext) -> ItemResult:
    """Table I: (75), (76), (74) over gamma_11, ours beside the printed rows."""

    rows = ctx.cached("table1", table1_data)
    header = ("gamma11", "c75_ours", "c76_ours", "c74_ours", "c75_paper", "c76_paper",
              "c74_paper", "second_moment_radius", "c76_lambda_max", "zeta_inf", "zeta_2",
              "agrees")
    out = []
    for r in rows:
        p = r["paper"] or {}
        out.append((r["gamma11"], r["c75"], r["c76"], r["c74"]["holds"], p.get("c75"),
                    p.get("c76"), p.get("c74"), r["second_moment_radius"], r["c76_value"],
                    r["c74"]["zeta_inf"], r["c74"]["zeta_2"], r["agrees"]))
    files = [write_csv(ctx.out / "dkfe-table1.csv", header, out),
             write_json(ctx.out / "dkfe-table1.json", rows)]
    fig = figure(figsize=(9.5, 4.6))
    ax = fig.subplots()
    ax.axis("off")
    cells = [[f"{r['gamma11']:.1f}", str(r["c75"]), str(r["c76"]), str(r["c74"]["holds"]),
              fmt(r["second_moment_radius"], 3),
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


def build_fig34(ctx: BuildContext, item_id: str, gammas: Sequence[float], label: str
                 ) -> ItemResult:
    """Figs. 3-4: Tr Xi_11(t) of the CSE for the given gamma_11 (exact and Monte Carlo)."""
    d = _xi11(ctx)
    rows = []
    for g in gammas:
        for t, (e, m) in enumerate(zip(d["exact"][g], d["monte_carlo"][g], strict=True)):
            rows.append((g, t, e, m))
    files = [write_csv(ctx.out / f"{item_id}.csv",
                        ("gamma11", "t", "trace_Xi11_exact", "mse_cse_monte_carlo"), rows)]
    fig = figure(figsize=(6.8, 4.6))
    ax = fig.subplots()
    tt = np.arange(DKFE_EX1_STEPS + 1)
    cmap = {g: f"C{i}" for i, g in enumerate(gammas)}
    for g in gammas:
        ax.plot(tt, positive(d["exact"][g]), color=cmap[g], lw=1.5,
                label=rf"$\gamma_{{11}}$ = {g:.1f}")
        ax.plot(tt[::5], positive(d["monte_carlo"][g])[::5], "o", color=cmap[g], ms=3,
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
            + ", ".join(f"gamma {g:.1f}: {fmt(v)}" for g, v in final.items()) + "."]
    if 0.5 in final:
        ours.append(f"At gamma_11 = 0.5 the limit is {fmt(final[0.5])}.")
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


def build_fig5(ctx: BuildContext) -> ItemResult:
    """Fig. 5: the DKFE estimate and the state over one trial of Example 2."""
    d = _ex2(ctx)
    tr = d["trajectory"]
    K1, n = FIG5_STEPS + 1, tr.states.shape[1]
    rows = [(t, i + 1, float(tr.states[t, i]), float(tr.dkfe[t, i]))
            for t in range(K1) for i in range(n)]
    files = [write_csv(ctx.out / "dkfe-fig5.csv", ("t", "component", "x", "x_hat_dkfe"),
                        rows)]
    fig = figure(figsize=(10, 6.2))
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
    ours = [f"t = {K1 // 2}..{K1 - 1}: RMS error ||x - x-hat|| = {fmt(err)} against RMS "
            f"||x|| = {fmt(rms_state)} (the plant is unstable, rho(A) = 1.0441)."]
    return ItemResult(fig, files, ours)


def build_fig6(ctx: BuildContext) -> ItemResult:
    """Fig. 6: the CSEs, the DKFE and the ODKFE: exact traces and Monte Carlo MSE."""
    d = _ex2(ctx)
    exact, mse = d["exact"], d["mse"]
    keys = ("CSE 1 (d=1)", "CSE 2 (d=2)", "DKFE", "ODKFE (d=0)")
    names = {"CSE 1 (d=1)": "CSE 1", "CSE 2 (d=2)": "CSE 2", "DKFE": "DKFE",
             "ODKFE (d=0)": "ODKFE"}
    rows = [(t, *[exact[k][t] for k in keys], *[mse[k][t] for k in keys])
            for t in range(DKFE_EX2_STEPS + 1)]
    files = [write_csv(ctx.out / "dkfe-fig6.csv",
                        ("t", *[f"trace_{names[k]}_exact" for k in keys],
                         *[f"mse_{names[k]}_monte_carlo" for k in keys]), rows)]
    fig = figure(figsize=(6.8, 4.6))
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
            + ", ".join(f"{k} {fmt(v)}" for k, v in last.items()) + ".",
            f"DKFE <= each CSE at every step: {better}; DKFE >= ODKFE at every step: {worse}."]
    return ItemResult(fig, files, ours, numbers={"final": last, "dkfe_better_than_cses": better,
                                                 "dkfe_worse_than_odkfe": worse})


def build_fig7(ctx: BuildContext) -> ItemResult:
    """Fig. 7: ||P(t)||_2 and ||Omega_i(t)||_2 from two initial covariances."""
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
    files = [write_csv(ctx.out / "dkfe-fig7.csv", ("initial_value", "x0_cov_scale", "t",
                                                    "norm2_P", "norm2_Omega_1",
                                                    "norm2_Omega_2"), rows)]
    fig = figure(figsize=(12, 4.0))
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
    ours = [f"At t = {DKFE_EX2_STEPS}: ||P||_2 = {fmt(curves[0]['P'][-1])}, ||Omega_1||_2 = "
            f"{fmt(curves[0]['Omega_1'][-1])}, ||Omega_2||_2 = "
            f"{fmt(curves[0]['Omega_2'][-1])}; difference between the two initial values: "
            + ", ".join(f"{k} {fmt(v)}" for k, v in gap.items()) + "."]
    return ItemResult(fig, files, ours, numbers={"final_gap": gap})


def build_fig8(ctx: BuildContext) -> ItemResult:
    """Fig. 8: the difference between the DKFE and the SDKFE estimates."""
    d = _ex2(ctx)
    tr = d["trajectory"]
    er = tr.dkfe - tr.sdkfe
    K1, n = er.shape
    rows = [(t, *[float(v) for v in er[t]]) for t in range(K1)]
    files = [write_csv(ctx.out / "dkfe-fig8.csv",
                        ("t", *[f"Er_{i + 1}" for i in range(n)]), rows)]
    fig = figure(figsize=(6.8, 4.4))
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
    ours = [f"max |Er_i| over the first 20 steps {fmt(head)}, over the last 20 "
            f"{fmt(tail)}."]
    return ItemResult(fig, files, ours, numbers={"max_abs_first20": head,
                                                 "max_abs_last20": tail})


def build_example2(ctx: BuildContext) -> ItemResult:
    """Example 2's printed numbers (88), (93), (94), (95) beside ours."""

    data, _ = ctx.cached("example2", example2_data)
    files = [write_json(ctx.out / "dkfe-example2.json", data)]
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
    files.insert(0, write_csv(ctx.out / "dkfe-example2.csv",
                               ("quantity", "row", "column", "ours", "paper"), rows))
    fig = figure(figsize=(12, 4.0))
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
                     f"{fmt(data['weights_minus_paper_max_abs'][i])}", fontsize=10)
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
        f"Xi(t) converged after {st['steps']} steps: tr P = {fmt(st['trace_P'])} (DKFE), "
        f"ODKFE {fmt(st['trace_P_odkfe'])}, centralised KF "
        f"{fmt(st['trace_P_centralized_kf'])}.",
        "(93): " + ", ".join(f"{fmt(o)} (printed {p})" for _, o, p in scalars[:2])
        + "; (95): " + ", ".join(f"{fmt(o)} (printed {p})" for _, o, p in scalars[2:]) + ".",
        "Phi_K (88): largest difference to the printed matrices "
        + ", ".join(fmt(v) for v in data["Phi_K_minus_paper_eq88_max_abs"]) + "."]
    return ItemResult(fig, files, ours_lines, numbers={
        "weights_minus_paper_max_abs": data["weights_minus_paper_max_abs"]})


