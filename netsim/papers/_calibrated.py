"""The calibrated instances as evidence (issue 31), declared by :mod:`netsim.papers.lcsys2022`
and :mod:`netsim.papers.delay_tolerant`.

The two consensus papers print no A, C, P or K, only properties and numbers.
``netsim calibrate`` (:mod:`netsim.calibrate`) searched for instances with every stated
property that match the numbers, and bundled them as scenarios:
``lcsys2022-calibrated-rho-tau`` (rho(A-hat) and tau* required, the rest reported),
``lcsys2022-calibrated`` (the closest to every number, no-root reading) and
``delay-tolerant-calibrated``. This module reads them (no search) and gives:

- the checks of the printed-number claims (``L-rho``, ``L-tau-star``, ``L-eq26``,
  ``L-hom-19``, ``T-rho``, ``T-bounds``): a printed number that a calibrated instance with
  every stated property reaches is *proved for this instance*, which shows that the number
  is attainable by an instance of the kind the paper describes, not that the paper's own
  instance had it; a printed number that no calibrated instance reaches is *undecided*,
  with each instance's value (the searches for every number ended undecided within their
  budget: not a proof that no instance has it);
- the reproduce item ``lcsys2022-fig1-calibrated``: LCSYS2022 Fig. 1 (the compensating
  estimator (4)-(5), tau-bar = 0, 3, 8, 19, homogeneous and heterogeneous fixed delays)
  run by ``netsim bench delay-tolerance`` on ``lcsys2022-calibrated-rho-tau`` beside our
  instance ``lcsys2022-heterogeneous`` with the same settings.

Each check takes the paper's printed numbers as ``printed`` (a mapping: LCSYS2022
``rho_delay_free``, ``tau_star``, ``eq26`` (tau -> value), ``hom19_rho``; delay-tolerant
``rho_delay_free``, ``bounds`` (tau-bar -> value)), bound by the paper module with
:func:`functools.partial`, so that this module imports neither paper module.

A printed number is matched when the value rounds to its printed digits (at least two
decimals: half a unit of its last digit, :data:`netsim.calibrate.TOLERANCE` for 0.64),
as ``netsim calibrate`` matches; tau* = 10 also needs no passing tau in 11..30.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from netsim.claims.checks import rounded
from netsim.claims.core import PROVED, UNDECIDED, Context, Outcome
from netsim.reproduce.items import (
    BuildContext,
    ItemResult,
    figure,
    fmt,
    mse_axes,
    positive,
    write_csv,
    write_json,
)

__all__ = ["RHO_TAU", "CLOSEST", "TOLERANT_CALIBRATED", "OURS", "FIG1_TAUS", "FIG1_SETTINGS",
           "FIG1_FAMILY", "QUICK_STEPS", "FULL_TRIALS", "half_unit", "calibrated_numbers",
           "check_lcsys_rho", "check_lcsys_tau_star", "check_lcsys_eq26",
           "check_lcsys_hom19", "check_tolerant_rho", "check_tolerant_bounds",
           "fig1_run", "fig1_contrast", "build_fig1_calibrated"]

#: The bundled scenarios (netsim calibrate): rho(A-hat) and tau* required; the closest to
#: every LCSYS2022 number (no-root reading); the delay-tolerant match.
RHO_TAU = "lcsys2022-calibrated-rho-tau"
CLOSEST = "lcsys2022-calibrated"
TOLERANT_CALIBRATED = "delay-tolerant-calibrated"
#: Our instance of the LCSYS2022 system (the one every other LCSYS2022 item uses).
OURS = "lcsys2022-heterogeneous"
#: Fig. 1's delay bounds and settings, and the family it shows.
FIG1_TAUS = (0, 3, 8, 19)
FIG1_SETTINGS = ("homogeneous", "heterogeneous")
FIG1_FAMILY = "compensated"
#: Fewer than FULL_TRIALS trials (the tests' quick run): QUICK_STEPS steps instead of the
#: lcsys2022-fig1 preset's 500 (the four taus are the figure: the grid stays).
QUICK_STEPS = 100
FULL_TRIALS = 10

_ATTAINABLE = ("the paper prints no A, C, P or K, so this shows that the printed number is "
               "attainable by an instance with every stated property, not that the paper's "
               "own instance had it")
_NOT_PROOF = ("the calibration searches for every printed number ended undecided within "
              "their budget, which is no proof that no instance reaches it")


def half_unit(printed: float) -> float:
    """Half a unit of the last printed digit, at least two decimals (0.64: 0.005, 0.983:
    0.0005, 1: 0.005)."""
    text = f"{printed:g}"
    decimals = len(text.split(".")[1]) if "." in text else 0
    return 0.5 * 10.0 ** (-max(2, decimals))


def _matches(value: float | None, printed: float) -> bool:
    return value is not None and abs(value - printed) <= half_unit(printed) + 1e-12


def _instance(name: str) -> Any:
    """The calibrated instance of a bundled scenario (:class:`netsim.calibrate.Instance`)."""
    from netsim.calibrate import Instance
    from netsim.models.scenario import resolve_scenario
    from netsim.runner import scenario_gains

    sc = resolve_scenario(name)
    g = scenario_gains(sc)
    return Instance(np.asarray(sc.plant.A, float), tuple(sc.plant.C),
                    np.asarray(sc.weights, float), tuple(g.K), tuple(g.L))


def calibrated_numbers(context: Context, name: str) -> dict[str, Any]:
    """A bundled calibrated instance's printed quantities and stated properties (cached).

    Parameters
    ----------
    context : Context
        The claims run (its cache holds the result under ``calibrated:<name>``).
    name : str
        :data:`RHO_TAU`, :data:`CLOSEST` (LCSYS2022: :func:`netsim.calibrate.measure`) or
        :data:`TOLERANT_CALIBRATED` (:func:`netsim.calibrate.measure_tolerant`).

    Returns
    -------
    dict
        The measured quantities (``rho_delay_free``, ``tau_star``, ``theorem1_tau{3,8,19}``
        without the root, ``eq26_tau{3,8,19}`` with it, ``homogeneous_tau19``,
        ``heterogeneous_tau19``; or ``bound_tau{10,25}``, ``exact_hom{10,25}``,
        ``exact_het{10,25}``), plus ``properties`` (name -> holds, by
        :func:`netsim.calibrate.properties`) and ``all_properties``.
    """
    def make() -> dict[str, Any]:
        from netsim.calibrate import measure, measure_tolerant, properties

        inst = _instance(name)
        m = measure_tolerant(inst) if name == TOLERANT_CALIBRATED else measure(inst)
        props = {k: bool(v["holds"]) for k, v in properties(inst).items()}
        out = {k: v for k, v in m.items() if "delays" not in k}
        out["properties"] = props
        out["all_properties"] = all(props.values())
        return out

    return context.cached(f"calibrated:{name}", make)


def _props_words(m: dict[str, Any]) -> str:
    p = m["properties"]
    if m["all_properties"]:
        return f"every stated property holds ({len(p)} of {len(p)} checked)"
    return "stated properties FAIL: " + ", ".join(k for k, v in p.items() if not v)


def _ours_lcsys(context: Context) -> tuple[float, int | None]:
    from netsim.papers._consensus import lcsys_instance

    inst = lcsys_instance(context)
    return float(inst["gains"].rho), inst["star"].contiguous


def _star_text(star: int | None) -> str:
    from netsim.cliutil import tau_star_text

    return tau_star_text(star)


def _attained(name: str, m: dict[str, Any], what: str, ours: str,
              numbers: dict[str, Any]) -> Outcome:
    """``proved for this instance`` on the calibrated instance ``name``."""
    text = (f"attainable: {what} on {name}, an instance on which {_props_words(m)}; "
            f"{_ATTAINABLE}; {ours}")
    return Outcome(PROVED, text, numbers)


def _lcsys_pair(context: Context) -> tuple[dict[str, Any], dict[str, Any]]:
    return calibrated_numbers(context, RHO_TAU), calibrated_numbers(context, CLOSEST)


def _pair_met(m: dict[str, Any], printed: Mapping[str, Any]) -> str:
    """``, while rho(A-hat) = 0.64 and tau* = 10 are met on <RHO_TAU>`` when they are."""
    rho, star = printed["rho_delay_free"], printed["tau_star"]
    if m["all_properties"] and _matches(m["rho_delay_free"], rho) and _star_ok(m, star):
        return f", while rho(A-hat) = {rho:g} and tau* = {star} are met on {RHO_TAU}"
    return ""


def check_lcsys_rho(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """LCSYS2022 Section IV, rho(A-hat) = 0.64, on the calibrated instances."""
    p_rho = printed["rho_delay_free"]
    m, c = _lcsys_pair(context)
    rho, star = _ours_lcsys(context)
    numbers = {"rho_delay_free": rounded(rho), "tau_star": star,
               "calibrated": {RHO_TAU: rounded(m["rho_delay_free"]),
                              CLOSEST: rounded(c["rho_delay_free"])}}
    ours = f"our instance: rho(A-hat) = {rho:.4f}, tau* = {_star_text(star)}"
    for name, x in ((RHO_TAU, m), (CLOSEST, c)):
        if x["all_properties"] and _matches(x["rho_delay_free"], p_rho):
            return _attained(name, x, f"rho(A-hat) = {x['rho_delay_free']:.4f} (printed "
                             f"{p_rho:g})", ours, numbers)
    why = (f"no calibrated instance reaches rho(A-hat) = {p_rho:g} ({RHO_TAU}: "
           f"{m['rho_delay_free']:.4f}, {CLOSEST}: {c['rho_delay_free']:.4f}); {_NOT_PROOF}")
    return Outcome(UNDECIDED, ours, numbers, reason=why)


def _star_ok(x: dict[str, Any], printed: int) -> bool:
    return x["tau_star"] == printed and not x["tau_star_isolated"]


def check_lcsys_tau_star(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """LCSYS2022 Section IV, tau* = 10 (Theorem 1), on the calibrated instances."""
    p_star = printed["tau_star"]
    m, c = _lcsys_pair(context)
    rho, star = _ours_lcsys(context)
    numbers = {"rho_delay_free": rounded(rho), "tau_star": star,
               "calibrated": {RHO_TAU: m["tau_star"], CLOSEST: c["tau_star"]}}
    ours = f"our instance: rho(A-hat) = {rho:.4f}, tau* = {_star_text(star)}"
    for name, x in ((RHO_TAU, m), (CLOSEST, c)):
        if x["all_properties"] and _star_ok(x, p_star):
            return _attained(name, x, f"tau* = {x['tau_star']} (printed {p_star}; "
                             f"rho((I-KD_C)(P kron A^(tau+1))) < 1 for tau = 0..10, not for "
                             "11..30)", ours, numbers)
    why = (f"no calibrated instance has tau* = {p_star} ({RHO_TAU}: "
           f"{_star_text(m['tau_star'])}, {CLOSEST}: {_star_text(c['tau_star'])}); "
           f"{_NOT_PROOF}")
    return Outcome(UNDECIDED, ours, numbers, reason=why)


def check_lcsys_eq26(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """LCSYS2022 Section IV, eq. (26) = 0.74, 0.94, 1.45 at tau = 3, 8, 19: each value on
    the calibrated instances, with the root (as printed) and without (Theorem 1's
    quantity)."""
    from netsim.models.augmented import delay_bound_lcsys
    from netsim.papers._consensus import lcsys_instance

    p_eq26 = dict(printed["eq26"])
    inst = lcsys_instance(context)
    P, A, C, L = inst["P"], inst["A"], inst["C"], inst["L"]
    ours_v = {t: float(delay_bound_lcsys(P, A, C, L, t)) for t in p_eq26}
    numbers: dict[str, Any] = {str(t): rounded(v) for t, v in ours_v.items()}
    cal: dict[str, Any] = {}
    reached: dict[int, list[str]] = {t: [] for t in p_eq26}
    for name, x in zip((RHO_TAU, CLOSEST), _lcsys_pair(context), strict=True):
        cal[name] = {"as_printed": {str(t): rounded(x[f"eq26_tau{t}"]) for t in p_eq26},
                     "no_root": {str(t): rounded(x[f"theorem1_tau{t}"]) for t in p_eq26},
                     "all_properties": x["all_properties"]}
        for t, value in p_eq26.items():
            for reading, key in (("with the root", "eq26"), ("without the root", "theorem1")):
                if x["all_properties"] and _matches(x[f"{key}_tau{t}"], value):
                    reached[t].append(f"{name} {reading}")
    numbers["calibrated"] = cal
    numbers["reached"] = {str(t): v for t, v in reached.items()}

    def values(name: str, reading: str) -> str:
        return " / ".join(f"{v:.4f}" for v in cal[name][reading].values())

    ours = (f"ours: {', '.join(f'tau {t}: {v:.3f}' for t, v in ours_v.items())} on our "
            f"instance; calibrated at tau = 3 / 8 / 19, with the root (as printed) and without: "
            f"{RHO_TAU} {values(RHO_TAU, 'as_printed')} and {values(RHO_TAU, 'no_root')}, "
            f"{CLOSEST} {values(CLOSEST, 'as_printed')} and {values(CLOSEST, 'no_root')}")
    missed = [t for t in p_eq26 if not reached[t]]
    met = "; ".join(f"{p_eq26[t]:g} at tau = {t} by {', '.join(reached[t])}"
                    for t in p_eq26 if reached[t])
    if not missed:
        return Outcome(PROVED, f"attainable: every printed value is reached on a calibrated "
                       f"instance with every stated property ({met}); {_ATTAINABLE}; "
                       + ours, numbers)
    why = ("no calibrated instance reaches " + ", ".join(
        f"{p_eq26[t]:g} at tau = {t}" for t in missed) + " under either reading"
        + _pair_met(_lcsys_pair(context)[0], printed) + (f" (reached: {met})" if met else "")
        + f"; {_NOT_PROOF}")
    return Outcome(UNDECIDED, ours, numbers, reason=why)


def check_lcsys_hom19(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """LCSYS2022 Fig. 1 / Section IV, homogeneous tau = 19 at rho(A-bar) = 1, on the
    calibrated instances (exact rho of the augmented closed loop (9))."""
    from netsim.claims.checks import exact_rho
    from netsim.papers._consensus import lcsys_instance

    p_hom19 = printed["hom19_rho"]
    inst = lcsys_instance(context)
    r = exact_rho(inst["P"], inst["A"], inst["C"], inst["L"], 19)
    m, c = _lcsys_pair(context)
    numbers = {"exact_rho_19": rounded(r),
               "calibrated": {RHO_TAU: {"homogeneous": rounded(m["homogeneous_tau19"]),
                                        "heterogeneous": rounded(m["heterogeneous_tau19"])},
                              CLOSEST: {"homogeneous": rounded(c["homogeneous_tau19"]),
                                        "heterogeneous": rounded(c["heterogeneous_tau19"])}}}
    ours = (f"ours: exact rho at homogeneous tau = 19 is {r:.4f} on our instance; calibrated: "
            f"{RHO_TAU} {m['homogeneous_tau19']:.4f} (heterogeneous "
            f"{m['heterogeneous_tau19']:.4f}), "
            f"{CLOSEST} {c['homogeneous_tau19']:.4f} (heterogeneous "
            f"{c['heterogeneous_tau19']:.4f})")
    for name, x in ((RHO_TAU, m), (CLOSEST, c)):
        if x["all_properties"] and _matches(x["homogeneous_tau19"], p_hom19):
            return _attained(name, x, f"exact rho at homogeneous tau = 19 is "
                             f"{x['homogeneous_tau19']:.4f} (printed {p_hom19:g})",
                             ours, numbers)
    above = all(x["homogeneous_tau19"] > 1 for x in (m, c))
    why = (f"no calibrated instance has rho = {p_hom19:g} at homogeneous tau = 19 "
           f"(within {half_unit(p_hom19):g})"
           + ("; both are a little above 1: the MSE grows slowly, unstable rather than "
              "exactly marginal" if above else "")
           + _pair_met(m, printed) + f"; {_NOT_PROOF}")
    return Outcome(UNDECIDED, ours, numbers, reason=why)


def _ours_tolerant(context: Context) -> tuple[str, float]:
    rho, _ = _ours_lcsys(context)
    return (f"our instance: rho(A-hat) = {rho:.4f}, rho^(1/11) = {rho ** (1 / 11):.3f}, "
            f"rho^(1/26) = {rho ** (1 / 26):.3f}"), rho


def check_tolerant_rho(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """Delay-tolerant Section V, rho(A-hat) = 0.64, on ``delay-tolerant-calibrated``."""
    p_rho = printed["rho_delay_free"]
    m = calibrated_numbers(context, TOLERANT_CALIBRATED)
    ours, rho = _ours_tolerant(context)
    numbers = {"rho_delay_free": rounded(rho),
               "calibrated": {TOLERANT_CALIBRATED: rounded(m["rho_delay_free"])}}
    if m["all_properties"] and _matches(m["rho_delay_free"], p_rho):
        return _attained(TOLERANT_CALIBRATED, m, f"rho(A-hat) = {m['rho_delay_free']:.4f} (printed "
                         f"{p_rho:g})", ours, numbers)
    why = (f"the calibrated instance has rho(A-hat) = {m['rho_delay_free']:.4f} "
           f"({_props_words(m)}), not {p_rho:g}")
    return Outcome(UNDECIDED, ours, numbers, reason=why)


def check_tolerant_bounds(context: Context, printed: Mapping[str, Any]) -> Outcome:
    """Delay-tolerant Section V, bounds rho(A-hat)^(1/11) = 0.96 and rho(A-hat)^(1/26) =
    0.983, on ``delay-tolerant-calibrated``, with the exact rho of the uncompensated loop
    (11) under homogeneous and the scenario's heterogeneous delays below them."""
    p_bounds = dict(printed["bounds"])
    m = calibrated_numbers(context, TOLERANT_CALIBRATED)
    ours, rho = _ours_tolerant(context)
    cal = {str(t): {"bound": rounded(m[f"bound_tau{t}"]),
                    "exact_homogeneous": rounded(m[f"exact_hom{t}"]),
                    "exact_heterogeneous": rounded(m[f"exact_het{t}"])}
           for t in p_bounds}
    numbers = {"rho_delay_free": rounded(rho), "calibrated": {TOLERANT_CALIBRATED: cal}}
    ok = m["all_properties"] and all(_matches(m[f"bound_tau{t}"], v)
                                     for t, v in p_bounds.items())
    what = ", ".join(f"rho(A-hat)^(1/{t + 1}) = {m[f'bound_tau{t}']:.4f} (printed {v:g}; "
                     f"exact rho of (11) homogeneous / heterogeneous {m[f'exact_hom{t}']:.4f}"
                     f" / {m[f'exact_het{t}']:.4f}, below it)"
                     if m[f"exact_hom{t}"] <= m[f"bound_tau{t}"]
                     and m[f"exact_het{t}"] <= m[f"bound_tau{t}"] else
                     f"rho(A-hat)^(1/{t + 1}) = {m[f'bound_tau{t}']:.4f} (printed {v:g}; "
                     f"exact rho of (11) homogeneous / heterogeneous {m[f'exact_hom{t}']:.4f}"
                     f" / {m[f'exact_het{t}']:.4f}, ABOVE it)"
                     for t, v in p_bounds.items())
    if ok:
        return _attained(TOLERANT_CALIBRATED, m, what, ours, numbers)
    return Outcome(UNDECIDED, ours, numbers, reason=f"the calibrated instance misses the "
                   f"printed bounds: {what} ({_props_words(m)})")


# -- LCSYS2022 Fig. 1 on the calibrated instance ------------------------------------------


def _quick(ctx: BuildContext) -> bool:
    return ctx.trials < FULL_TRIALS


def fig1_run(ctx: BuildContext, scenario_name: str) -> dict[str, Any]:
    """LCSYS2022 Fig. 1's cells (:data:`FIG1_FAMILY` at :data:`FIG1_TAUS` in
    :data:`FIG1_SETTINGS`) on one scenario, by ``netsim bench delay-tolerance`` with the
    run's trials and the ``lcsys2022-fig1`` preset's steps (:data:`QUICK_STEPS` with fewer
    than :data:`FULL_TRIALS` trials); cached per scenario.

    Returns
    -------
    dict
        The benchmark report (:func:`netsim.bench.delay_tolerance.run_delay_tolerance`).
    """
    def make() -> dict[str, Any]:
        from netsim.bench.delay_tolerance import run_delay_tolerance
        from netsim.bench.presets import presets
        from netsim.models.scenario import resolve_scenario

        preset = presets()["lcsys2022-fig1"]
        scenario = resolve_scenario(scenario_name)
        return run_delay_tolerance(
            scenario, taus=FIG1_TAUS, delays=FIG1_SETTINGS, trials=ctx.trials,
            steps=QUICK_STEPS if _quick(ctx) else preset.steps, seed=scenario.seed,
            families=[FIG1_FAMILY], workers=ctx.workers,
            executor="serial" if ctx.workers == 1 else "local", progress=False)

    return ctx.cached(f"fig1-calibrated:{scenario_name}", make)


def _cells(data: dict[str, Any]) -> dict[tuple[str, int], dict[str, Any]]:
    """Fig. 1's cells by (setting, tau); the tau = 0 cell under both settings."""
    out: dict[tuple[str, int], dict[str, Any]] = {}
    for c in data["cells"]:
        if c["family"] != FIG1_FAMILY:
            continue
        for s in (FIG1_SETTINGS if c["tau"] == 0 else (c["setting"],)):
            out[(s, int(c["tau"]))] = c
    return out


def fig1_contrast(data: dict[str, Any]) -> dict[str, Any]:
    """Whether Fig. 1's caption shows in a report: tau-bar = 0, 3, 8 stable in both
    settings, homogeneous 19 not stable and heterogeneous 19 stable.

    Returns
    -------
    dict
        ``stable_038`` and ``contrast`` (bools), ``verdicts`` (``"<setting> <tau>"`` ->
        verdict), ``measured`` (the same keys -> the Monte Carlo growth verdict alone,
        ``measured_growth_verdict``) and ``exact`` (the same keys -> exact rho of the loop
        (9)).
    """
    cells = _cells(data)
    verdicts = {f"{s} {t}": c["measured"]["verdict"] for (s, t), c in cells.items()}
    measured = {f"{s} {t}": c["measured"].get("measured_growth_verdict")
                for (s, t), c in cells.items()}
    exact = {f"{s} {t}": (c.get("analytics") or {}).get("exact") for (s, t), c in cells.items()}
    stable = all(verdicts.get(f"{s} {t}") == "stable" for s in FIG1_SETTINGS
                 for t in FIG1_TAUS if t != 19)
    hom, het = verdicts.get("homogeneous 19"), verdicts.get("heterogeneous 19")
    return {"stable_038": stable,
            "contrast": stable and hom is not None and hom != "stable" and het == "stable",
            "verdicts": verdicts, "measured": measured, "exact": exact}


def _words(data: dict[str, Any]) -> str:
    cells = _cells(data)
    parts = []
    for s in FIG1_SETTINGS:
        for t in FIG1_TAUS:
            c = cells.get((s, t))
            if c is None:
                continue
            m = c["measured"]
            parts.append(f"{s} {t}: {m['verdict']} by the {m.get('verdict_basis')} (exact "
                         f"rho {fmt((c.get('analytics') or {}).get('exact'))}; measured: "
                         f"{m.get('measured_growth_verdict')}, MSE "
                         f"x{fmt(m.get('growth_rate'))}/step)")
    return "; ".join(parts)


def build_fig1_calibrated(ctx: BuildContext, printed: Mapping[str, Any]) -> ItemResult:
    """LCSYS2022 Fig. 1 on ``lcsys2022-calibrated-rho-tau`` (top) beside our instance
    ``lcsys2022-heterogeneous`` (bottom), the same settings for both."""
    p_rho, p_star = printed["rho_delay_free"], printed["tau_star"]
    runs = {RHO_TAU: fig1_run(ctx, RHO_TAU), OURS: fig1_run(ctx, OURS)}
    fig = figure(figsize=(11, 8.2))
    axes = fig.subplots(2, 2, sharey="row")
    colours = {0: "k", 3: "tab:blue", 8: "tab:green", 19: "tab:red"}
    rows = []
    for row, (name, data) in enumerate(runs.items()):
        cells = _cells(data)
        for col, setting in enumerate(FIG1_SETTINGS):
            ax = axes[row][col]
            for t in FIG1_TAUS:
                c = cells.get((setting, t))
                curve = None if c is None else c["measured"].get("curve")
                if c is None or not curve:
                    continue
                mse = [math.nan if v is None else float(v) for v in curve["mse"]]
                label = ("no delay" if t == 0 else rf"$\bar\tau$ = {t}") + (
                    f" ({c['measured']['verdict']})")
                ax.plot(curve["steps"], positive(mse), color=colours[t], lw=1.3, label=label)
                rows += [(name, setting, t, int(k), v)
                         for k, v in zip(curve["steps"], mse, strict=True)]
            g = data.get("gains") or {}
            star = (data.get("analysis") or {}).get("tau_star")
            mse_axes(ax, f"{name}: {setting} delays\n(rho(A-hat) = "
                     f"{fmt(g.get('rho_delay_free'))}, tau* = {star})")
        axes[row][1].set_ylabel("")
    steps, trials = runs[OURS]["steps"], runs[OURS]["trials"]
    fig.suptitle("LCSYS2022 Fig. 1 on the calibrated instance (top) and on ours (bottom): "
                 f"MSE of the compensating estimator (4)-(5), {trials} trials x {steps} steps",
                 fontsize=11)
    cal, ours = fig1_contrast(runs[RHO_TAU]), fig1_contrast(runs[OURS])

    def summary(name: str, data: dict[str, Any]) -> str:
        g, scan = data.get("gains") or {}, data.get("analysis") or {}
        return (f"{name}: rho(A-hat) = {fmt(g.get('rho_delay_free'))} (paper "
                f"{p_rho:g}), tau* = {scan.get('tau_star')} (paper {p_star}), "
                f"stable in the exact analysis up to homogeneous tau = "
                f"{scan.get('exact_tolerance_compensated')}; " + _words(data) + ".")

    lines = [f"Monte Carlo: {trials} trials x {steps} steps per curve (vectorised engine), "
             f"the compensating estimator only, netsim bench delay-tolerance on each "
             f"scenario with its own seed; heterogeneous delays drawn once per link from "
             f"the scenario's delay seed.",
             summary("Calibrated instance " + RHO_TAU, runs[RHO_TAU]),
             summary("Our instance " + OURS, runs[OURS])]
    if _quick(ctx):
        lines.append(f"A quick run (fewer than {FULL_TRIALS} trials): {QUICK_STEPS} steps "
                     "instead of the lcsys2022-fig1 preset's 500.")
    hom = cal["exact"].get("homogeneous 19")
    if cal["contrast"]:
        seen = cal["measured"]
        lines.append("On the calibrated instance the caption's contrast shows: MSE bounded "
                     "for tau-bar = 0, 3, 8 in both settings; at tau-bar = 19 > tau* the "
                     f"homogeneous case is {cal['verdicts']['homogeneous 19']} (exact rho "
                     f"{fmt(hom)}: a little above 1, so the MSE grows slowly, by "
                     f"{fmt((hom or 0.0) ** 2)} per step, rather than sitting at the paper's "
                     "rho = 1) while the heterogeneous case is stable (exact rho "
                     f"{fmt(cal['exact'].get('heterogeneous 19'))}). The verdicts are the "
                     "exact analysis's; the Monte Carlo growth alone says homogeneous 19 "
                     f"{seen.get('homogeneous 19')}, heterogeneous 19 "
                     f"{seen.get('heterogeneous 19')} in this run"
                     + (" (undecided: the band of the MSE growth over the second half "
                        "straddles the thresholds)" if "undecided" in (seen.get("homogeneous 19"),
                                                 seen.get("heterogeneous 19")) else "")
                     + ".")
    else:
        lines.append("On the calibrated instance the caption's contrast does NOT show in "
                     "this run: " + ", ".join(f"{k}: {v}" for k, v in cal["verdicts"].items())
                     + ".")
    lines.append("On our instance it " + ("shows too." if ours["contrast"] else
                 "does not: homogeneous tau-bar = 19 is "
                 f"{ours['verdicts'].get('homogeneous 19')} (exact rho "
                 f"{fmt(ours['exact'].get('homogeneous 19'))} < 1)."))
    differs = ["The paper prints no A, C, P or K: the calibrated instance "
               f"({RHO_TAU}) has every stated property and its rho(A-hat) and tau*, not "
               "its eq. (26) values or rho = 1 at homogeneous tau-bar = 19 (docs: "
               "Calibrating an instance); it shows the figure is attainable, not the "
               "paper's own system. The paper's heterogeneous draw is unknown."]
    files = [write_csv(ctx.out / "lcsys2022-fig1-calibrated.csv",
                       ("scenario", "delay_setting", "tau_bar", "step", "mse"), rows),
             write_json(ctx.out / "lcsys2022-fig1-calibrated.json",
                        {"contrast": {RHO_TAU: cal, OURS: ours}, "reports": runs})]
    return ItemResult(fig, files, lines, differs, [],
                      {"contrast_calibrated": cal["contrast"],
                       "contrast_ours": ours["contrast"]})
