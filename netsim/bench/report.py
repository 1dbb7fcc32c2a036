"""The delay-tolerance report as text."""

from __future__ import annotations

from typing import Any

from netsim.bench.cells import ROUNDOFF_WARNING
from netsim.bench.cells import find_cell as _cell
from netsim.bench.fmt import fmt_value as _f
from netsim.bench.presets import DELAY_MODELS
from netsim.cliutil import tau_star_text

__all__ = ["format_report"]


def format_report(data: dict[str, Any]) -> str:
    """The benchmark as text: per-setting tables, tolerance, the papers' statements (the
    bounds' words are the papers' own, :func:`netsim.papers.delay_bounds`)."""
    from netsim.papers import delay_bounds

    bounds = delay_bounds()
    tau_star_label = next((b.tau_star_label for b in bounds if b.tau_star_label), "tau*")
    s = data["scenario"]
    lines = []
    if data["preset"]:
        p = data["preset"]
        lines.append(f"preset {p['name']}: {p['description']}")
        ran = {"trials": data["trials"], "steps": data["steps"],
               "taus": ",".join(map(str, data["taus"])), "delays": ",".join(data["settings"])}
        preset = {k: (",".join(map(str, p[k])) if isinstance(p.get(k), list) else p.get(k))
                  for k in ran}
        departs = [f"{k} {ran[k]} (preset {preset[k]})" for k in ran
                   if preset[k] is not None and ran[k] != preset[k]]
        lines.append("  this run departs from the preset: " + "; ".join(departs) if departs
                     else f"  as the preset: {ran['trials']} trials x {ran['steps']} steps")
    lines.append(f"scenario {s['name']} ({s['source']}): n = {s['n_states']}, "
                 f"N = {s['n_agents']}, {s.get('n_links', len(s.get('links', ())))} links")
    g = data["gains"]
    scan = data["analysis"] or {}
    if g:
        lines.append(f"gains: {g['method']} ({g['solver']}), rho(A-hat) delay-free = "
                     f"{_f(g['rho_delay_free'])}; {tau_star_label} = "
                     f"{tau_star_text(scan.get('tau_star'), data['analysis'] is not None)}"
                     + (f", isolated {scan['tau_star_isolated']}"
                        if scan.get("tau_star_isolated") else ""))
    r = data["run"]
    lines.append(f"run: {data['trials']} trials x {data['steps']} steps per cell, seed "
                 f"{data['seed']}; {r['cells_computed']} cells computed, {r['cells_reused']} "
                 f"reused, {r['executor']} executor ({r['workers']} workers), "
                 f"{r['elapsed_s']:.1f} s")
    header = (f"{'tau':>4}  {'estimator':<15}{'run':<11}{'steady MSE':>11}"
              f"{'MSE grow':>10}{'decay':>8}{'exact':>9}{'joint':>11}  {'bound':>7} "
              f"{'pred':<5} verdict")
    for setting, desc in data["settings"].items():
        lines += ["", f"delays: {setting} -- {desc}", header, "-" * len(header)]
        for tau in data["taus"]:
            for family in data["families"]:
                c = _cell(data, setting, tau, family)
                if c is None:
                    continue
                m, a = c["measured"], c["analytics"]
                measured = m["verdict"]
                if m["diverged_trials"]:
                    measured = f"div@{m['first_divergence']}"
                pred = {True: "yes", False: "no", None: ""}[a.get("predicted_stable")]
                centralised = data.get("family_traits", {}).get(family, {}).get("centralised")
                name = "kf (reference)" if centralised else family
                # a steady MSE for stable runs only; else the last trusted one, marked *
                mse = (_f(m["steady_state_mse"]) if "steady_state_mse" in m else
                       _f(m.get("last_trusted_mse")) + "*")
                joint = (a.get("joint") or {}).get("verdict", "-")
                lines.append(
                    f"{tau:>4}  {name:<15}{measured:<11}{mse:>11}"
                    f"{_f(m['growth_rate']):>10}{_f(m['decay_factor'], 3):>8}"
                    f"{_f(a.get('exact')):>9}{joint:>11}  {_f(a.get('bound')):>7} "
                    f"{pred:<5} {c['verdict']}")
        realised = []
        for tau in data["taus"]:
            c = _cell(data, setting, tau, "compensated") or _cell(data, setting, tau,
                                                                  "uncompensated")
            if c is not None and tau > 0 and c["analytics"].get("realised_delays") and \
                    DELAY_MODELS.get(setting) == "heterogeneous":
                realised.append(f"tau {tau}: " + " ".join(
                    f"{k}:{v}" for k, v in c["analytics"]["realised_delays"].items()))
        if realised:
            lines.append("realised link delays: " + "; ".join(realised))
    lines += ["", "columns: run = stable / diverging / unbounded / undecided / div@k (a "
              "trial blew up at step k), by the rule of netsim.verdicts (for fixed delays "
              "decided by the joint system of state and error, else by the measured "
              "growth); steady MSE = mean MSE over "
              "the last quarter, for stable runs only (other runs: the last trusted MSE, "
              "marked *); MSE grow = fitted MSE factor per step over the second half; "
              "decay = fitted per-step factor of the error norm over the transient; exact = "
              "augmented rho of the realised fixed delays (compensated eq. 9; uncompensated: "
              "eq. (11), the error recursion alone, which ignores the forcing of the error "
              "by a moving state, (A^(r+1) - A) x; block: its rate), or the realised growth "
              "factor along trial 0's delays (time-varying); joint = the verdict of the "
              "joint linear system of plant state and error (fixed delays; - where it does "
              "not apply); bound = " + " or ".join(b.legend for b in bounds) + "; pred = "
              "the bound predicts stability; "
              "verdict: bound violated = exact > bound, prediction contradicted = predicted "
              "stable but diverging/unbounded/diverged."]
    lines += ["", "largest tolerated delay (measured on this grid: every tau up to it stable) "
              "vs predicted"]
    head = (f"{'estimator':<15}{'delays':<20}{'measured':>9}{'predicted':>10}  "
            f"{'exact (homog.)':>14}  stable taus / unstable taus")
    lines += [head, "-" * len(head)]
    for t in data["tolerance"]:
        measured = "none" if t["measured_max"] is None else str(t["measured_max"])
        # None: no prediction / exact analysis for the family ("-"), or none tolerated
        predicted = ("-" if str(t.get("predicted_by", "")).startswith("no prediction")
                     else "none" if t["predicted"] is None else str(t["predicted"]))
        exact = ("-" if str(t.get("exact_by", "")).startswith("no exact")
                 else "none" if t["exact_homogeneous"] is None else str(t["exact_homogeneous"]))
        lines.append(f"{t['family']:<15}{t['setting']:<20}{measured:>9}"
                     f"{predicted:>10}  {exact:>14}  "
                     f"{t['stable_taus']} / {t['unstable_taus']}")
    lines.append("predicted: " + "; ".join(b.prediction_legend for b in bounds)
                 + "; none: no delay is tolerated "
                 "(rho(A-hat) >= 1); -: no prediction for the family. exact: largest tau "
                 "with every smaller homogeneous tau's exact rho < 1 (scanned to "
                 f"{scan.get('tau_max')}).")
    if data["claims"]:
        lines += ["", "the papers' statements:"]
        for c in data["claims"]:
            lines.append(f"  [{c['status']}] {c['paper']}: {c['claim']}")
            lines.append(f"      ours: {c['ours']}")
    flagged = [c for c in data["cells"] if c["measured"].get("roundoff_warning")
               and not c.get("computed_as")]
    if flagged:
        worst = max(c["measured"]["state_norm_max"] for c in flagged)
        lines += ["", f"WARNING: {len(flagged)} cells ran into double-precision round-off "
                  f"(the unstable plant's state reached {worst:.2e}; eps |x| > "
                  f"{ROUNDOFF_WARNING:g} x the RMS error): use fewer steps."]
    lines += [""]
    if data["disagreements"]:
        lines.append(f"DISAGREEMENTS with the papers ({len(data['disagreements'])}):")
        lines += [f"  - {d}" for d in data["disagreements"]]
    else:
        lines.append("no disagreement with the papers' statements in this run")
    return "\n".join(lines) + "\n"
