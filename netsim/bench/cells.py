"""One delay-tolerance cell: a Monte Carlo run or the exact scan, measured and analysed.

A cell (:func:`delay_tolerance_cell`, a sweep function for :func:`netsim.sweep.run_sweep`)
runs M trials of one estimator family at one delay setting and bound tau and returns the
measured summary, the exact value and the papers' bounds, a verdict and notes; the
``scan`` cell is the exact homogeneous analysis up to tau_max. :func:`find_cell` looks a
cell up in the finished report.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from netsim.bench.fmt import exact_name
from netsim.bench.variants import delay_variant
from netsim.estimators.registry import (
    RECURSION_BLOCK,
    RECURSION_COMPENSATED,
    RECURSION_UNCOMPENSATED,
    EstimatorFamily,
)
from netsim.models.scenario import Scenario
from netsim.models.seeding import child_sequence

__all__ = ["BOUND_SLACK", "CURVE_POINTS", "ROUNDOFF_WARNING", "delay_tolerance_cell",
           "find_cell"]


#: An exact value above a bound by more than this counts as a violation.
BOUND_SLACK = 1e-9


#: MSE curves kept per cell (for the plot), at most this many points.
CURVE_POINTS = 240


#: Relative double-precision round-off of the state: eps |x_K|.
_EPS = float(np.finfo(float).eps)


#: A cell is flagged when eps |x_K| exceeds this fraction of its RMS steady error.
ROUNDOFF_WARNING = 1e-3


def _curve(mse: np.ndarray) -> dict[str, list]:
    k = len(mse) - 1
    idx = np.unique(np.round(np.linspace(0, k, min(CURVE_POINTS, k + 1))).astype(int))
    return {"steps": idx.tolist(), "mse": [float(v) for v in mse[idx]]}


def _measure(results: list, steps: int, fraction: float,
             analysis: Any = None) -> dict[str, Any]:
    """Monte Carlo summary with ``netsim run``'s definitions (the verdict rule of
    :mod:`netsim.verdicts`, decided by the joint-system ``analysis`` where one applies),
    plus the decay fit. ``steady_state_mse`` only for a stable run; every run has
    ``last_trusted_mse`` (at ``last_trusted_step``)."""
    from netsim.traces.analysis import decay_fit
    from netsim.verdicts import has_steady_state, judge, steady_slice

    per_trial = [r.squared_errors.mean(axis=1) for r in results]
    judgement = judge(np.array(per_trial) if per_trial else np.zeros((0, steps + 1)),
                      states=[r.states for r in results] if results else None,
                      diverged_at=[r.diverged_at for r in results], analysis=analysis)
    horizon = judgement.precision_horizon
    diverged = [(t, int(r.diverged_at)) for t, r in enumerate(results)
                if r.diverged_at is not None and (horizon is None or r.diverged_at < horizon)]
    gone = {t for t, _ in diverged}
    good = [m for t, m in enumerate(per_trial) if t not in gone]
    if good:
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mse = np.nanmean(good, axis=0)
    else:
        mse = np.full(steps + 1, np.nan)
    trusted = mse if horizon is None else mse[:horizon]
    window = steady_slice(len(mse), fraction, horizon)
    steady = float(np.mean(mse[window])) if good else math.nan
    last = window.stop - 1
    fit = decay_fit(trusted) if good and len(trusted) >= 4 else None
    with np.errstate(invalid="ignore"):
        state_max = max((float(np.nanmax(np.abs(r.states))) for r in results), default=0.0)
    rms = math.sqrt(steady) if math.isfinite(steady) and steady > 0 else math.nan
    roundoff = _EPS * state_max
    return {
        "verdict": judgement.verdict,
        "verdict_basis": judgement.basis,
        "verdict_reason": judgement.reason,
        "measured_growth_verdict": judgement.measured,
        "growth": judgement.growth.to_dict(),
        "precision_horizon": horizon,
        # a steady MSE belongs to stable runs only (netsim.verdicts.has_steady_state)
        **({"steady_state_mse": steady} if has_steady_state(judgement.verdict) else {}),
        "last_trusted_mse": float(mse[last]) if good else math.nan,
        "last_trusted_step": last if good else None,
        "growth_rate": judgement.growth.rate,
        "decay_factor": fit.factor if fit is not None and fit.transient else math.nan,
        "excess_decay_factor": (fit.excess_factor if fit is not None and fit.transient
                                else math.nan),
        "tail_factor": fit.tail_factor if fit is not None else math.nan,
        "transient_steps": fit.end if fit is not None and fit.transient else None,
        "diverged_trials": len(diverged),
        "first_divergence": min((s for _, s in diverged), default=None),
        "messages": {
            "sent": int(sum(r.messages_sent for r in results)),
            "delivered": int(sum(r.messages_delivered for r in results)),
            "discarded_stale": int(sum(r.messages_discarded for r in results)),
            "dropped": int(sum(r.messages_dropped for r in results)),
        },
        "curve": _curve(mse) if good else None,
        "state_norm_max": state_max,
        "roundoff_floor": roundoff,
        "roundoff_warning": bool(math.isfinite(rms) and roundoff > ROUNDOFF_WARNING * rms),
    }


def _analytics(variant: Scenario, gains: Any, family: EstimatorFamily, tau: int,
               first: Any) -> tuple[dict[str, Any], Any]:
    """Exact rho (fixed delays) or realised growth (time-varying), bounds, prediction,
    for the families that declare an augmented error recursion (the registry's
    ``error_recursion``); the others get no bound and no prediction. The bounds are the
    papers' (:func:`netsim.papers.delay_bounds`): every one at ``tau`` under its key, and
    the one of the family's recursion as ``bound``. For fixed delays
    also ``joint``: the analysis of the joint system of plant state and error
    (:mod:`netsim.models.jointsystem`), returned as well (it decides the verdict)."""
    from netsim.models.augmented import augmented_spectral_radius
    from netsim.papers import delay_bounds
    from netsim.runner import fixed_delay_matrix

    out: dict[str, Any] = {"exact_kind": None, "exact": None}
    recursion = family.error_recursion
    if recursion is None or gains is None:
        out.update(bound_name=None, bound=None, predicted_stable=None)
        return out, None
    compensated = recursion == RECURSION_COMPENSATED
    plant = variant.plant
    P, A, C, L = variant.weights, plant.A, plant.C, gains.L
    bounds = delay_bounds()
    for b in bounds:
        out[b.key] = float(b.compute(P, A, C, L, tau))
    mine = next((b for b in bounds if recursion in b.recursions), None)
    if mine is None:
        out.update(bound_name=None, bound=None)
    else:
        out.update(bound_name=mine.name, bound=out[mine.key])
    exact_kinds = {} if mine is None else mine.exact_kinds
    out["predicted_stable"] = None if out["bound"] is None else bool(out["bound"] < 1.0)
    delays = fixed_delay_matrix(variant) if variant.topology is None else None
    analysis = None
    noise = {"Q": plant.Q, "x0_mean": plant.x0_mean, "x0_cov": plant.x0_cov}
    if recursion == RECURSION_BLOCK:
        out.update(exact_kind="block rate (eq. 26 expression, exact for eqs. 15-16)",
                   exact=out["bound"])
        edge = (np.asarray(P) != 0) & ~np.eye(variant.n_agents, dtype=bool)
        if delays is not None and (not np.any(edge) or int(delays[edge].max()) <= tau):
            from netsim.models.jointsystem import block_joint_analysis

            analysis = block_joint_analysis(P, A, C, L, tau, **noise)
    elif delays is not None:
        from netsim.models.jointsystem import joint_analysis

        out["realised_delays"] = {f"{j}->{i}": int(delays[i, j]) for j, i in variant.links}
        with np.errstate(over="ignore", invalid="ignore"):
            rho = float(augmented_spectral_radius(P, A, C, L, delays, None,
                                                  compensated=compensated))
        out.update(exact_kind=exact_kinds.get(recursion), exact=rho)
        analysis = joint_analysis(P, A, C, L, delays, compensated=compensated,
                                  rho_error=rho, **noise)
    elif first is not None and first.effective_delays is not None:
        out.update(_realised_growth(P, A, C, L, first.effective_delays, compensated))
    if analysis is not None:
        from netsim.verdicts import analysis_verdict

        out["joint"] = {**analysis.to_dict(), "verdict": analysis_verdict(analysis)}
    exact = out["exact"]
    out["exact_violates_bound"] = bool(exact is not None and math.isfinite(exact)
                                       and out["bound"] is not None
                                       and exact > out["bound"] + BOUND_SLACK)
    return out, analysis


def _realised_growth(P: np.ndarray, A: np.ndarray, C: Sequence[np.ndarray],
                     L: Sequence[np.ndarray], D: np.ndarray, compensated: bool
                     ) -> dict[str, Any]:
    """Realised growth factor of A-hat[k] ... A-hat[h] over the second half of the steps
    after start-up (every neighbour heard from), from one trial's effective delays.

    ``netsim.models.augmented.closed_loop_sequence_growth`` (matrix-free; exact up to rounding
    for augmented dimension <= 600, a random 8-vector block above): exp of
    (1/m) log ||A-hat[K] ... A-hat[h]||, h = the middle of the post-start-up steps.
    """
    from netsim.kernel import NOT_USED
    from netsim.models.augmented import closed_loop_sequence_growth

    edge = (P != 0) & ~np.eye(P.shape[0], dtype=bool)
    seq: list[np.ndarray] = []
    for k in range(1, D.shape[0]):
        d = D[k]
        if np.any(edge & (d == NOT_USED)):
            break  # the run stopped (diverged)
        if np.any(edge & (d < 0)):
            if seq:
                break
            continue  # start-up: an own estimate substituted
        seq.append(np.where(edge, d, 0).astype(np.int64))
    half = seq[len(seq) // 2:]
    if len(half) < 4:
        return {"realised_steps": len(seq)}
    depth = max(0, int(max(int(d[edge].max()) for d in half)))
    with np.errstate(over="ignore", invalid="ignore"):
        rate = closed_loop_sequence_growth(P, A, C, L, half, depth, compensated)
    return {
        "exact_kind": ("realised growth factor (trial 0, second half)" if compensated else
                       "realised growth factor of the eq. (11) error recursion alone, "
                       "moving-state forcing ignored (trial 0, second half)"),
        "exact": _exp(rate),
        "realised_steps": len(half),
        "realised_max_delay": depth,
    }


def _exp(value: float) -> float:
    if value is None or math.isnan(value):
        return math.nan
    return math.inf if value > 700 else math.exp(value)


def _verdict(family: Any, measured: dict[str, Any], analytics: dict[str, Any]) -> str:
    """The cell's verdict. ``family`` is unused: the verdict follows from the cell's own
    prediction (None for families that declare no recursion, e.g. the reference Kalman
    filter).

    ``bound violated``: the exact value exceeds the bound (the only meaning, as in
    ``netsim analyze``); ``prediction contradicted``: the bound predicts stability and
    the run is diverging, unbounded or diverged; ``bound conservative``: the run is
    stable although the bound does not predict it; else the run's verdict (``stable``,
    ``diverging``, ``unbounded``, ``undecided``, ``diverged``)."""
    verdict = measured["verdict"]
    if analytics.get("predicted_stable") is None:
        return verdict
    if analytics.get("exact_violates_bound"):
        return "bound violated"
    if analytics["predicted_stable"] and verdict in ("diverging", "unbounded", "diverged"):
        return "prediction contradicted"
    if verdict == "stable" and not analytics["predicted_stable"]:
        return "bound conservative"
    return verdict


def _notes(family: EstimatorFamily, measured: dict[str, Any], analytics: dict[str, Any]
           ) -> list[str]:
    notes = []
    exact = analytics.get("exact")
    stable = measured["verdict"] == "stable"
    joint = analytics.get("joint") or {}
    name = exact_name(analytics)
    if exact is not None and math.isfinite(exact):
        if exact < 1 and not stable:
            notes.append(f"the {name} {exact:.4f} < 1 predicts decay, the run is "
                         f"{measured['verdict']}")
            if family.error_recursion == RECURSION_UNCOMPENSATED:
                notes.append(f"the joint system of state and error: {joint['verdict']}: "
                             f"{joint['reason']}" if joint else
                             "eq. (11) leaves out the (A^(r+1) - A) x term of a moving state")
        elif exact >= 1 and stable:
            notes.append(f"the {name} {exact:.4f} >= 1, yet the run stays bounded over "
                         "its steps")
    if analytics.get("exact_violates_bound"):
        notes.append(f"exact {exact:.6f} > bound {analytics['bound']:.6f}")
    if measured.get("roundoff_warning"):
        notes.append(f"round-off regime: the state reached {measured['state_norm_max']:.2e}, "
                     f"double precision leaves ~{measured['roundoff_floor']:.1e} absolute "
                     "error in every estimate (use fewer steps)")
    return notes


def delay_tolerance_cell(params: dict[str, Any], seed: Any, context: dict[str, Any]
                         ) -> dict[str, Any]:
    """Compute one benchmark cell (a sweep function, see :func:`netsim.sweep.run_sweep`).

    ``params``: ``kind`` = ``mc`` (``setting``, ``tau``, ``family``, ``trials``, ``steps``,
    ``seed``) or ``scan`` (``tau_max``); ``context``: ``{"scenario", "gains"}``.
    """
    scenario: Scenario = context["scenario"]
    gains = context["gains"]
    if params["kind"] == "scan":
        return _scan(scenario, gains, int(params["tau_max"]))
    from netsim.runner import engines_for, family_of, run_trials

    setting, tau = params["setting"], int(params["tau"])
    # a plugin is resolved by its reference (module:attribute, entry point) in workers
    # (or shipped by value in context["plugins"]: a worker elsewhere lacks its file)
    ref = params.get("family_ref") or params["family"]
    shipped = context.get("plugins")
    shipped = (shipped.value if shipped is not None else None) or {}
    family = shipped[ref] if ref in shipped else family_of(ref, scenario)
    trials, steps, root = int(params["trials"]), int(params["steps"]), int(params["seed"])
    variant = delay_variant(scenario, setting, tau)
    time_varying = not variant.delay_model(0).time_invariant
    keep = time_varying and family.error_recursion in (RECURSION_COMPENSATED,
                                                        RECURSION_UNCOMPENSATED)
    seeds = [child_sequence(root, "trial", t) for t in range(trials)]
    engine = params.get("engine", "events")
    if engine == "vectorised" and (not family.vectorised or variant.timing is not None):
        # (a [time] variant: the timed lockstep where it expresses it, else the kernel)
        engine = engines_for("auto", [family], variant)[family.name]
    # trial 0's effective delays feed the realised growth rate
    results = run_trials(variant, family, gains if family.needs_gains else None,
                         seeds, steps, engine=engine,
                         record_delays=[0] if keep else False, record_estimates=False)
    analytics, analysis = _analytics(variant, gains, family, tau,
                                     results[0] if results else None)
    measured = _measure(results, steps, variant.steady_state_fraction, analysis)
    return {
        "measured": measured,
        "analytics": analytics,
        "verdict": _verdict(family, measured, analytics),
        "notes": _notes(family, measured, analytics),
    }


def _scan(scenario: Scenario, gains: Any, tau_max: int) -> dict[str, Any]:
    from netsim.analysis import analyze
    from netsim.papers import delay_bounds

    bounds = delay_bounds()
    report = analyze(scenario.with_tau(0) if scenario.delays.model not in ("fixed", "latency")
                     else scenario, gains, tau_max)

    def tolerance(values: list[float]) -> int | None:
        last = None
        for tau, v in enumerate(values):
            if not v < 1.0:
                break
            last = tau
        return last

    rows = report.rows
    comp = tolerance([r.rho_compensated for r in rows])
    uncomp = tolerance([r.rho_uncompensated for r in rows])
    return {
        "rho_delay_free": report.rho_delay_free,
        "tau_star": report.tau_star,
        "tau_star_isolated": list(report.tau_star_isolated),
        "tau_max": tau_max,
        "homogeneous": [{"tau": r.tau, "rho_compensated": r.rho_compensated,
                         "rho_uncompensated": r.rho_uncompensated,
                         **{b.key: getattr(r, b.key, None) for b in bounds}} for r in rows],
        "exact_tolerance_compensated": comp,
        "exact_tolerance_uncompensated_eq11": uncomp,
        "exact_tolerance_censored": {"compensated": comp == tau_max,
                                     "uncompensated_eq11": uncomp == tau_max},
        "eq26_violations": [r.tau for r in rows if r.verdict_eq26 == "violated"],
    }


def find_cell(data: dict[str, Any], setting: str, tau: int, family: str
              ) -> dict[str, Any] | None:
    """Return the cell of a delay-tolerance report at (setting, tau, family), or None."""
    for c in data["cells"]:
        if c["setting"] == setting and c["tau"] == tau and c["family"] == family:
            return c
    return None
