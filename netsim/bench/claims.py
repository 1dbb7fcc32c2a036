"""The papers' statements checked against a delay-tolerance report (its claim rows).

Each ``_c_*`` function puts one registry claim of LCSYS2022 or of the delay-tolerant
paper next to a bench report's numbers (the papers' numbers come from
:mod:`netsim.papers`); :data:`CLAIMS` maps a claim id to its check (``CLAIMS[id](data)``,
a bench row; a preset lists the ids it checks) and :func:`disagreements` lists the
statements and cells where they disagree. The claim registry (:mod:`netsim.claims`) names
the same functions as its claims' ``bench`` form; this module never imports
:mod:`netsim.claims`, so the bench sits below the claims in the layering.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from netsim import papers as _p
from netsim.bench.cells import find_cell as _cell
from netsim.bench.fmt import describe_cell as _describe
from netsim.bench.fmt import fmt_value as _f
from netsim.cliutil import tau_star_text

__all__ = ["CLAIMS", "disagreements"]


def _claim(cid: str, paper: str, text: str, ours: str, agrees: bool | None,
           kind: str = "claim") -> dict[str, Any]:
    """A paper's statement next to ours. ``kind``: ``claim`` (a qualitative result that
    should hold for any instance satisfying the paper's assumptions) or ``instance`` (a
    number of the paper's own, unprinted system; ours differs by construction)."""
    status = {True: "agrees", False: "DISAGREES" if kind == "claim" else "differs",
              None: "not checked"}[agrees]
    return {"id": cid, "paper": paper, "kind": kind, "claim": text, "ours": ours,
            "agrees": agrees, "status": status}


_LCSYS = _p.LCSYS


_TOL = _p.TOLERANT
_FIG1 = ", ".join(str(t) for t in _p.LCSYS_FIG1_TAUS)
_TF1 = _p.TOLERANT_FIG1_TAUS


def _c_rho(data: dict[str, Any], paper: str, cid: str) -> dict[str, Any]:
    rho = (data["gains"] or {}).get("rho_delay_free")
    printed = _p.LCSYS_RHO if paper == _LCSYS else _p.TOLERANT_RHO
    agrees = None if rho is None else abs(rho - printed) < 0.01
    return _claim(cid, paper, f"LMI gains give rho(A-hat) = {printed:g}",
                  f"rho(A-hat) = {_f(rho)} with our LMI design on our instance of the "
                  "unprinted A, C, P (a different system, not a contradiction of the theory)",
                  agrees, kind="instance")


def _c_tau_star(data: dict[str, Any]) -> dict[str, Any]:
    scan = data["analysis"] or {}
    t = scan.get("tau_star")
    return _claim("L-tau-star", _LCSYS, f"tau* = {_p.LCSYS_TAU_STAR} (Theorem 1)",
                  f"tau* = {tau_star_text(t, data['analysis'] is not None)}"
                  + (f" (isolated passing values {scan.get('tau_star_isolated')})"
                                   if scan.get("tau_star_isolated") else "")
                  + " for our gains and instance",
                  None if t is None else t == _p.LCSYS_TAU_STAR,
                  kind="instance")


def _c_eq26(data: dict[str, Any]) -> dict[str, Any]:
    claimed = _p.LCSYS_EQ26
    ours = []
    agrees = True
    checked = False
    for tau, value in claimed.items():
        c = _cell(data, "homogeneous", tau, "compensated") or _cell(
            data, "heterogeneous", tau, "compensated")
        if c is None:
            continue
        b = c["analytics"]["bound_eq26"]
        checked = True
        ours.append(f"tau {tau}: {_f(b, 3)} (paper {value})")
        agrees = agrees and abs(b - value) < 0.01
    return _claim("L-eq26", _LCSYS, "eq. (26) bounds " + ", ".join(
                      f"{v:g}" for v in claimed.values()) + " at tau = " + ", ".join(
                      str(t) for t in claimed),
                  "; ".join(ours) or "-", agrees if checked else None, kind="instance")


def _c_stable_038(data: dict[str, Any]) -> dict[str, Any]:
    bad, seen = [], []
    for setting in ("homogeneous", "heterogeneous"):
        for tau in _p.LCSYS_FIG1_TAUS:
            c = _cell(data, setting, tau, "compensated")
            if c is None:
                continue
            seen.append(f"{setting} {tau}: {c['measured']['verdict']}")
            if c["measured"]["verdict"] != "stable":
                bad.append(f"{setting} tau {tau}: {_describe(c)}")
    if not seen:
        return _claim("L-stable-0-3-8", _LCSYS, "compensated MSE bounded, steady-state stable "
                      f"for tau = {_FIG1} (homogeneous and heterogeneous)", "-", None)
    return _claim("L-stable-0-3-8", _LCSYS, "compensated MSE bounded, steady-state stable for "
                  f"tau = {_FIG1} (homogeneous and heterogeneous)",
                  "; ".join(bad) if bad else "all stable (" + ", ".join(seen) + ")", not bad)


def _c_hom19(data: dict[str, Any]) -> dict[str, Any]:
    c = _cell(data, "homogeneous", 19, "compensated")
    text = (f"homogeneous tau = 19 (> tau* = {_p.LCSYS_TAU_STAR}): the MSE is marginally "
            f"unstable, rho(A-bar) = {_p.LCSYS_HOM19_RHO:g}")
    if c is None:
        return _claim("L-hom-19", _LCSYS, text, "-", None)
    exact = c["analytics"].get("exact")
    marginal = (exact is not None and exact >= 0.999) or c["measured"]["verdict"] != "stable"
    return _claim("L-hom-19", _LCSYS, text,
                  f"{_describe(c)}; exact augmented rho = {_f(exact)} "
                  f"({'not ' if exact is not None and exact < 0.999 else ''}marginal; on our "
                  "instance, the paper's rho = 1 is for its own unprinted system)",
                  marginal)


def _c_het19(data: dict[str, Any]) -> dict[str, Any]:
    c = _cell(data, "heterogeneous", 19, "compensated")
    text = "heterogeneous tau = 19: the MSE is stable"
    if c is None:
        return _claim("L-het-19", _LCSYS, text, "-", None)
    return _claim("L-het-19", _LCSYS, text, _describe(c), c["measured"]["verdict"] == "stable")


def _decay_claim(data: dict[str, Any], cid: str, paper: str, family: str,
                 settings: Sequence[str], limit: int | None, text: str) -> dict[str, Any]:
    parts, agrees, checked = [], True, False
    for setting in settings:
        series = []
        for tau in data["taus"]:
            if limit is not None and tau > limit:
                continue
            c = _cell(data, setting, tau, family)
            if c is None or c["measured"]["verdict"] != "stable":
                continue
            f = c["measured"]["decay_factor"]
            if f is None or (isinstance(f, float) and math.isnan(f)):
                continue
            series.append((tau, f))
        if len(series) < 2:
            continue
        checked = True
        monotone = all(b[1] >= a[1] - 0.005 for a, b in zip(series, series[1:], strict=False))
        agrees = agrees and monotone
        parts.append(f"{setting}: decay factor per step " + ", ".join(
            f"tau {t}: {_f(f)}" for t, f in series)
            + ("" if monotone else " (NOT monotone)"))
    return _claim(cid, paper, text, "; ".join(parts) or "-", agrees if checked else None)


def _c_decay_l(data: dict[str, Any]) -> dict[str, Any]:
    limit = (data["analysis"] or {}).get("tau_star")
    return _decay_claim(data, "L-decay", _LCSYS, "compensated",
                        ("homogeneous", "heterogeneous"), limit,
                        "longer delays decrease the MSE decay rate for tau <= tau* (eq. 14): "
                        "the per-step error factor grows with tau")


def _c_decay_t(data: dict[str, Any]) -> dict[str, Any]:
    return _decay_claim(data, "T-decay", _TOL, "uncompensated", ("time-varying",), None,
                        "longer delays result in a lower MSE decay rate (eq. 17)")


def _c_bounds_t(data: dict[str, Any]) -> dict[str, Any]:
    claimed = _p.TOLERANT_BOUNDS
    ours, agrees, checked = [], True, False
    rho = (data["gains"] or {}).get("rho_delay_free")
    for tau, value in claimed.items():
        if rho is None:
            continue
        b = rho ** (1.0 / (tau + 1))
        checked = True
        ours.append(f"tau {tau}: {_f(b, 3)} (paper {value})")
        agrees = agrees and abs(b - value) < 0.005
    return _claim("T-bounds", _TOL, "bounds " + ", ".join(
                      f"rho(A-hat)^(1/{t + 1}) = {v:g}" for t, v in claimed.items()),
                  "; ".join(ours) + " (follow from our rho(A-hat))" if ours else "-",
                  agrees if checked else None, kind="instance")


def _stable_claim(data: dict[str, Any], cid: str, text: str, settings: Sequence[str],
                  taus: Sequence[int] | None) -> dict[str, Any]:
    bad, ok = [], []
    for setting in settings:
        for tau in data["taus"] if taus is None else taus:
            c = _cell(data, setting, tau, "uncompensated")
            if c is None:
                continue
            if c["measured"]["verdict"] == "stable":
                ok.append(f"{setting} tau {tau}")
            else:
                bad.append(f"{setting} tau {tau}: {_describe(c)}")
    if not bad and not ok:
        return _claim(cid, _TOL, text, "-", None)
    return _claim(cid, _TOL, text,
                  "; ".join(bad) if bad else "stable: " + ", ".join(ok), not bad)


def _c_fig1_t(data: dict[str, Any]) -> dict[str, Any]:
    return _stable_claim(data, "T-fig1-stable", "uncompensated MSE bounded, steady-state stable "
                         f"without delay and with tau-bar = {_TF1[1]} and {_TF1[2]} "
                         "(random delays)",
                         ("time-varying",), _p.TOLERANT_FIG1_TAUS)


def _c_fig2_t(data: dict[str, Any]) -> dict[str, Any]:
    return _stable_claim(data, "T-fig2-stable", "uncompensated MSE bounded, steady-state stable "
                         "for asynchronous varying, synchronous varying and asynchronous fixed "
                         f"delays, tau-bar = {_p.TOLERANT_FIG2_TAU}",
                         ("time-varying", "synchronous", "asynchronous-fixed"),
                         (_p.TOLERANT_FIG2_TAU,))


def _c_theorem1_t(data: dict[str, Any]) -> dict[str, Any]:
    return _stable_claim(data, "T-theorem1", "Theorem 1: with rho(A-hat) < 1 the uncompensated "
                         "estimator tracks the system with bounded error for any bounded delay",
                         tuple(data["settings"]), None)


def _c_theorem1_l(data: dict[str, Any]) -> dict[str, Any]:
    scan = data["analysis"] or {}
    star = scan.get("tau_star")
    bad, ok = [], []
    for setting in data["settings"]:
        for tau in data["taus"]:
            c = _cell(data, setting, tau, "compensated")
            if c is None or star is None or tau > star:
                continue
            if c["measured"]["verdict"] == "stable":
                ok.append(f"{setting} tau {tau}")
            else:
                bad.append(f"{setting} tau {tau}: {_describe(c)}")
    if not bad and not ok:
        return _claim("L-theorem1", _LCSYS, "Theorem 1: stable for tau <= tau* = "
                      f"{tau_star_text(star, data['analysis'] is not None)}", "-",
                      None)
    return _claim("L-theorem1", _LCSYS, f"Theorem 1: compensated estimator stable for every "
                  f"tau <= tau* = {tau_star_text(star)}",
                  "; ".join(bad) if bad else "stable: " + ", ".join(ok), not bad)


#: The bench checks by claim id: ``CLAIMS[id](report) -> dict`` (a bench row).
CLAIMS = {
    "L-rho": lambda d: _c_rho(d, _LCSYS, "L-rho"),
    "T-rho": lambda d: _c_rho(d, _TOL, "T-rho"),
    "L-tau-star": _c_tau_star,
    "L-eq26": _c_eq26,
    "L-stable-0-3-8": _c_stable_038,
    "L-hom-19": _c_hom19,
    "L-het-19": _c_het19,
    "L-decay": _c_decay_l,
    "L-theorem1": _c_theorem1_l,
    "T-bounds": _c_bounds_t,
    "T-fig1-stable": _c_fig1_t,
    "T-fig2-stable": _c_fig2_t,
    "T-decay": _c_decay_t,
    "T-theorem1": _c_theorem1_t,
}


def disagreements(data: dict[str, Any]) -> list[str]:
    """The report's disagreements: failed ``claim`` checks and ``bound violated`` cells."""
    out = [f"{c['paper']}: \"{c['claim']}\" -- ours: {c['ours']}"
           for c in data["claims"] if c["agrees"] is False and c["kind"] == "claim"]
    for c in data["cells"]:
        if c["verdict"] == "bound violated" and not c.get("computed_as"):
            a = c["analytics"]
            why = []
            if a["predicted_stable"] and c["measured"]["verdict"] != "stable":
                why.append(f"{a['bound_name']} = {_f(a['bound'])} < 1 predicts stability, "
                           f"measured {_describe(c)}")
            if a.get("exact_violates_bound"):
                why.append(f"{a['exact_kind']} {_f(a['exact'], 6)} > {a['bound_name']} "
                           f"{_f(a['bound'], 6)}")
            out.append(f"{c['family']}, {c['setting']}, tau {c['tau']}: " + "; ".join(why))
    return out
