"""Experiments LCSYS2022 leaves out (issue 31), declared by :mod:`netsim.papers.lcsys2022`.

- **Baselines against the delay bound** (preset and item ``lcsys2022-baselines``): on the
  paper's plant (our instance, scenario ``lcsys2022-heterogeneous``), the steady-state
  MSE and the measured decay factor of the error per step against the delay bound tau,
  for homogeneous fixed and asynchronous time-varying delays, with every family on the
  same axes: the compensating estimator (4)-(5), the uncompensated one (the
  delay-tolerant paper's (6)-(7)), the centralised Kalman filter (the optimum, no
  network), local Kalman filters (no communication) and the field's distributed filters
  ``kcf`` (Olfati-Saber 2009), ``ci`` (Battistelli & Chisci 2014) and ``diffkf``
  (Cattivelli & Sayed 2010).
- **Packet loss** (sweep preset and item ``lcsys2022-loss``): the same families on the
  same plant with the scenario's own heterogeneous fixed delays (tau-bar = 3), every link
  losing each message independently with probability p (``[links] loss = {model =
  "bernoulli"}``), steady MSE against p. The paper's Assumption 2 has no loss (a lost
  message is a delay without bound), so nothing in it predicts these curves.

A run with fewer than :data:`FULL_TRIALS` trials (the tests' quick run) uses the short
horizon :data:`QUICK_STEPS` and the coarse grids, and says so in the report.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from netsim.bench.presets import Preset, SweepPreset
from netsim.reproduce.items import (
    BuildContext,
    ItemResult,
    figure,
    fmt,
    positive,
    write_csv,
    write_json,
)

__all__ = ["BASELINE_FAMILIES", "BASELINE_TAUS", "QUICK_TAUS", "LOSSES", "QUICK_LOSSES",
           "EXPERIMENT_STEPS", "QUICK_STEPS", "FULL_TRIALS", "MAX_TRIALS", "BASELINES_PRESET",
           "LOSS_SWEEP",
           "build_baselines", "build_loss", "loss_variant", "loss_rows"]

#: The families on the same axes: both consensus estimators, the references, the baselines.
BASELINE_FAMILIES = ("compensated", "uncompensated", "centralized-kf", "local-kf", "kcf",
                     "ci", "diffkf")
#: The delay bounds of the baseline experiment (tau* of our instance is 8).
BASELINE_TAUS = (0, 1, 2, 3, 5, 8)
QUICK_TAUS = (0, 2, 5)
#: Bernoulli loss probabilities of every link.
LOSSES = (0.0, 0.05, 0.1, 0.2, 0.3, 0.5)
QUICK_LOSSES = (0.0, 0.2, 0.5)
#: Horizon: 300 steps keep the unstable plant's state (1.04^k) far from round-off.
EXPERIMENT_STEPS = 300
QUICK_STEPS = 100
#: Trials from which the full grids and horizon are used; at most MAX_TRIALS are run
#: (the baselines have no batched form: they run in the event kernel).
FULL_TRIALS = 10
MAX_TRIALS = 20
_SCENARIO = "lcsys2022-heterogeneous"

BASELINES_PRESET = Preset(
    name="lcsys2022-baselines",
    scenario=_SCENARIO,
    taus=BASELINE_TAUS,
    delays=("homogeneous", "time-varying"),
    trials=MAX_TRIALS,
    steps=EXPERIMENT_STEPS,
    focus="compensated",
    description="LCSYS2022 plant (our instance), not in the paper: steady MSE and decay "
                "factor against the delay bound tau = 0..8 for the compensating and "
                "uncompensated estimators beside the centralised and local Kalman filters "
                "and the kcf, ci and diffkf baselines, homogeneous fixed and asynchronous "
                "time-varying delays",
    claims=("L-theorem1", "L-decay", "T-theorem1"),
    families=BASELINE_FAMILIES,
)


LOSS_SWEEP = SweepPreset(
    name="lcsys2022-loss",
    scenario=_SCENARIO,
    axes={"loss": LOSSES},
    families=BASELINE_FAMILIES,
    trials=MAX_TRIALS,
    steps=EXPERIMENT_STEPS,
    description="LCSYS2022 plant (our instance), not in the paper: steady MSE against the "
                "Bernoulli loss probability of every link, heterogeneous fixed delays "
                "tau-bar = 3, every family",
)


def _limits(ax: Any, values: list[float]) -> None:
    """A log axis around the steady MSEs (the runs without one are off its scale)."""
    finite = [v for v in values if math.isfinite(v) and v > 0]
    if finite:
        ax.set_ylim(min(finite) / 2, max(finite) * 3)


def _quick(ctx: BuildContext) -> bool:
    return ctx.trials < FULL_TRIALS


def _trials(ctx: BuildContext) -> int:
    return max(1, min(ctx.trials, MAX_TRIALS))


def _value(m: dict[str, Any]) -> tuple[float, bool]:
    """A cell's or run's MSE: the steady one (True) or the last trusted one (False)."""
    if m.get("steady_state_mse") is not None:
        return float(m["steady_state_mse"]), True
    v = m.get("last_trusted_mse")
    return (math.nan if v is None else float(v)), False


# -- baselines against the delay bound ----------------------------------------------------


def _baselines_data(ctx: BuildContext) -> dict[str, Any]:
    def make() -> dict[str, Any]:
        from netsim.bench.delay_tolerance import run_delay_tolerance
        from netsim.models.scenario import resolve_scenario

        p = BASELINES_PRESET
        scenario = resolve_scenario(p.scenario)
        quick = _quick(ctx)
        return run_delay_tolerance(
            scenario, taus=QUICK_TAUS if quick else p.taus, delays=p.delays,
            trials=_trials(ctx), steps=QUICK_STEPS if quick else p.steps,
            seed=scenario.seed, families=list(p.families), preset=p, workers=ctx.workers,
            executor="serial" if ctx.workers == 1 else "local", progress=False)

    return ctx.cached(f"bench:{BASELINES_PRESET.name}", make)


def build_baselines(ctx: BuildContext) -> ItemResult:
    """Steady MSE and decay factor against tau per family (the baselines experiment)."""
    data = _baselines_data(ctx)
    families, taus = list(data["families"]), list(data["taus"])
    settings = list(data["settings"])
    rows = []
    for c in data["cells"]:
        m, a = c["measured"], c.get("analytics") or {}
        value, steady = _value(m)
        decay = m.get("decay_factor")
        rows.append((c["family"], c["setting"], c["tau"], m["verdict"],
                     value if steady else math.nan, value,
                     math.nan if decay is None else float(decay),
                     math.nan if a.get("exact") is None else float(a["exact"])))
    files = [write_csv(ctx.out / "lcsys2022-baselines.csv",
                       ("family", "delay_setting", "tau_bar", "verdict", "steady_mse",
                        "last_trusted_mse", "decay_factor", "exact_rho"), rows),
             write_json(ctx.out / "lcsys2022-baselines.json", data)]
    fig = figure(figsize=(11, 7.5))
    axes = fig.subplots(2, len(settings), sharex=True, squeeze=False)
    colours = dict(zip(families, ("k", "tab:grey", "tab:blue", "tab:cyan", "tab:orange",
                                  "tab:green", "tab:red", "tab:purple", "tab:brown"),
                       strict=False))
    for col, setting in enumerate(settings):
        for family in families:
            pts = sorted((r[2], r[5], r[4], r[6]) for r in rows
                         if r[0] == family and r[1] == setting)
            if not pts:
                continue
            t = [p[0] for p in pts]
            style = {"color": colours.get(family), "lw": 1.2}
            values = [p[2] for p in pts]
            label = family if any(math.isfinite(v) for v in values) else (
                f"{family} (no steady state)")
            axes[0][col].plot(t, positive([p[1] for p in pts]), ls=":", **style)
            axes[0][col].plot(t, positive(values), "o-", label=label, **style)
            axes[1][col].plot(t, [p[3] for p in pts], "o-", label=family, **style)
        axes[0][col].set_yscale("log")
        _limits(axes[0][col], [r[4] for r in rows if r[1] == setting])
        axes[0][col].set_title(f"{setting} delays: steady MSE (dotted: last trusted)",
                               fontsize=9)
        axes[1][col].set_title(f"{setting} delays: error decay factor per step", fontsize=9)
        axes[1][col].set_xlabel(r"delay bound $\bar\tau$")
        for ax in axes[:, col]:
            ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("MSE")
    axes[1][0].set_ylabel("decay factor (smaller: faster)")
    axes[0][-1].legend(fontsize=7)
    fig.suptitle(f"LCSYS2022 plant, not in the paper: MSE and decay against the delay bound, "
                 f"{data['trials']} trials x {data['steps']} steps", fontsize=11)
    ours = [f"Monte Carlo: {data['trials']} trials x {data['steps']} steps per cell (the "
            "consensus estimators and the centralised filter in the vectorised engine, the "
            "others in the event kernel), scenario `" + data["scenario"]["name"] + "`, seed "
            f"{data['seed']}, tau-bar in {taus}."]
    if _quick(ctx):
        ours.append(f"A quick run (fewer than {FULL_TRIALS} trials): the short horizon and "
                    "the coarse grid; `netsim reproduce` with the default trials runs "
                    f"tau-bar = {list(BASELINE_TAUS)} over {EXPERIMENT_STEPS} steps.")
    for t in data["tolerance"]:
        ours.append(f"{t['family']}, {t['setting']}: stable for tau-bar = "
                    f"{t['stable_taus']} (largest from 0 on: {t['measured_max']}; "
                    f"predicted: {t['predicted'] if t['predicted'] is not None else '-'})")
    traits = data.get("family_traits") or {}
    # the filters that exchange messages (the registry's delay_free: none, or centralised)
    distributed = [f for f in families if not (traits.get(f) or {}).get("delay_free")]
    for setting in settings:
        best = []
        for tau in taus:
            cand = [(r[4], r[0]) for r in rows if r[1] == setting and r[2] == tau
                    and r[0] in distributed and math.isfinite(r[4])]
            if cand:
                best.append(f"tau-bar {tau}: {min(cand)[1]} ({fmt(min(cand)[0])})")
        if best:
            ours.append(f"Lowest steady MSE of the distributed filters, {setting}: "
                        + ", ".join(best) + ".")
    for family in families:
        zero = [r for r in rows if r[0] == family and r[2] == 0]
        if zero:
            ours.append(f"{family} at tau-bar = 0: {zero[0][3]}, MSE {fmt(zero[0][5])}"
                        + ("" if not math.isnan(zero[0][4]) else " (no steady state)"))
    differs = ["The paper compares no baselines: the centralised and local Kalman filters "
               "and kcf / ci / diffkf are ours, each implemented from its own paper "
               "(docs: estimators/baselines), with netsim's rules for late, lost and "
               "reordered messages.",
               "Our instance has rho(A-hat) = 0.8276 and tau* = 8, not the paper's 0.64 and "
               "10 (the paper prints no A, C, P or K)."]
    return ItemResult(fig, files, ours, differs, list(data.get("claims", [])),
                      {"tolerance": data["tolerance"]})


# -- packet loss ------------------------------------------------------------------------


def loss_variant(p: float, scenario: str = _SCENARIO) -> Any:
    """The scenario with every link losing each message with probability ``p``
    (Bernoulli, ``[links] loss``), as a cell of ``netsim bench sweep --losses``; ``p =
    0``: the scenario itself."""
    from netsim.bench.variants import scenario_data, sweep_variant

    data, source = scenario_data(scenario)
    return sweep_variant(data, source, {"loss": float(p)})


def loss_rows(losses: tuple[float, ...], trials: int, steps: int,
              families: tuple[str, ...] = BASELINE_FAMILIES,
              workers: int = 1) -> list[dict[str, Any]]:
    """The sweep preset ``lcsys2022-loss`` (``netsim bench sweep``, one cell per loss
    probability, each a ``netsim run`` of every family with the scenario's seed and one
    gain design): per family the verdict, the steady (or last trusted) MSE and the
    messages sent and delivered."""
    from netsim.bench.scenario_sweep import run_scenario_sweep

    result = run_scenario_sweep(
        LOSS_SWEEP.scenario, axes={"loss": list(losses)}, trials=trials, steps=steps,
        families=list(families), seed=0, executor="serial" if workers == 1 else "local",
        workers=workers, progress=False)
    out = []
    for row in result.rows:
        p = float(row["params"]["loss"])
        for family, e in row["result"]["estimators"].items():
            value, steady = _value(e)
            out.append({"loss": p, "family": family, "verdict": e["verdict"],
                        "steady_mse": value if steady else None,
                        "last_trusted_mse": e.get("last_trusted_mse"),
                        "growth_rate": e.get("growth_rate"),
                        "sent": e["messages_sent"], "delivered": e["messages_delivered"]})
    order = {f: i for i, f in enumerate(families)}
    return sorted(out, key=lambda r: (r["loss"], order.get(r["family"], len(order))))


def build_loss(ctx: BuildContext) -> ItemResult:
    """Steady MSE against the Bernoulli loss probability per family."""
    quick = _quick(ctx)
    losses = QUICK_LOSSES if quick else LOSSES
    trials, steps = _trials(ctx), QUICK_STEPS if quick else EXPERIMENT_STEPS
    rows = ctx.cached("lcsys2022-loss",
                      lambda: loss_rows(losses, trials, steps, workers=ctx.workers))
    keys = ("loss", "family", "verdict", "steady_mse", "last_trusted_mse", "growth_rate",
            "sent", "delivered")
    files = [write_csv(ctx.out / "lcsys2022-loss.csv", keys,
                       [tuple(math.nan if r[k] is None else r[k] for k in keys)
                        for r in rows]),
             write_json(ctx.out / "lcsys2022-loss.json",
                        {"scenario": _SCENARIO, "trials": trials, "steps": steps,
                         "losses": list(losses), "rows": rows})]
    fig = figure(figsize=(11, 4.4))
    left, right = fig.subplots(1, 2)
    families = list(dict.fromkeys(r["family"] for r in rows))
    for family in families:
        mine = [r for r in rows if r["family"] == family]
        ps = [r["loss"] for r in mine]
        steady = [math.nan if r["steady_mse"] is None else r["steady_mse"] for r in mine]
        last = [math.nan if r["last_trusted_mse"] is None else r["last_trusted_mse"]
                for r in mine]
        label = family if any(math.isfinite(v) for v in steady) else (
            f"{family} (no steady state, off scale)")
        line = left.plot(ps, positive(steady), "o-", lw=1.2, label=label)[0]
        left.plot(ps, positive(last), ":", lw=1.0, color=line.get_color())
        sent = np.array([r["sent"] for r in mine], dtype=float)
        if np.all(sent > 0):
            right.plot(ps, np.array([r["delivered"] for r in mine]) / sent, "o-", lw=1.2,
                       color=line.get_color(), label=family)
    left.set_yscale("log")
    _limits(left, [math.nan if r["steady_mse"] is None else r["steady_mse"] for r in rows])
    left.set_xlabel("loss probability p (every link, Bernoulli)")
    left.set_ylabel("steady MSE (dotted: last trusted MSE)")
    left.grid(True, which="both", alpha=0.3)
    left.legend(fontsize=7)
    right.plot(list(losses), [1 - p for p in losses], "k--", lw=0.8, label="1 - p")
    right.set_xlabel("loss probability p")
    right.set_ylabel("messages delivered / sent")
    right.grid(True, alpha=0.3)
    right.legend(fontsize=7)
    fig.suptitle(f"LCSYS2022 plant, not in the paper: packet loss, heterogeneous fixed delays "
                 f"tau-bar = 3, {trials} trials x {steps} steps", fontsize=11)
    ours = [f"Monte Carlo: {trials} trials x {steps} steps per loss probability (p in "
            f"{list(losses)}), scenario `{_SCENARIO}` with `[links] loss = {{model = "
            "\"bernoulli\", p}`, one gain design for all."]
    if quick:
        ours.append(f"A quick run (fewer than {FULL_TRIALS} trials): p in {list(losses)} "
                    f"over {steps} steps; the default trials run p in {list(LOSSES)} over "
                    f"{EXPERIMENT_STEPS} steps.")
    for family in families:
        mine = [r for r in rows if r["family"] == family]
        ends = [r["steady_mse"] for r in (mine[0], mine[-1])]
        if len(mine) > 1 and all(v is not None and v > 0 for v in ends):
            ours.append(f"{family}: steady MSE x{ends[1] / ends[0]:.3f} from p = "
                        f"{mine[0]['loss']:g} to p = {mine[-1]['loss']:g}.")
    for family in families:
        mine = [r for r in rows if r["family"] == family]
        ours.append(f"{family}: " + ", ".join(
            f"p {r['loss']:g}: {r['verdict']}, MSE "
            + fmt(r["steady_mse"] if r["steady_mse"] is not None else r["last_trusted_mse"])
            for r in mine))
    differs = ["Not in the paper: its Assumption 2 bounds every delay, a lost message is a "
               "delay without bound, so neither Theorem 1 nor eq. (26) covers these runs.",
               "An estimator that waits for a message uses what it has when it is lost "
               "(each family's rule for lost messages; docs: estimators/baselines)."]
    return ItemResult(fig, files, ours, differs, [], {"rows": rows})
