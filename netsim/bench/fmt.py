"""Number and cell formatting shared by the report, the paper checks and the sweep text."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["describe_cell", "exact_name", "fmt_value"]


def fmt_value(value: Any, digits: int = 4) -> str:
    """A number as table text: ``-`` for None / NaN, fixed ``digits`` or ``.3e``."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, str):
        return value
    if value == 0 or 1e-3 <= abs(value) < 1e4:
        return f"{value:.{digits}f}"
    return f"{value:.3e}"


def describe_cell(c: dict[str, Any]) -> str:
    """One cell in words: verdict, steady MSE (stable runs) or last trusted MSE (any
    other verdict), MSE growth, what the exact value is and the joint-system verdict."""
    m, a = c["measured"], c["analytics"]
    exact = a.get("exact")
    parts = [f"{m['verdict']}"]
    if "steady_state_mse" in m:
        parts.append(f"steady MSE {fmt_value(m['steady_state_mse'])}")
    elif m.get("last_trusted_mse") is not None:
        parts.append(f"last trusted MSE {fmt_value(m['last_trusted_mse'])}"
                     + (f" at step {m['last_trusted_step']}"
                        if m.get("last_trusted_step") is not None else ""))
    parts.append(f"measured MSE growth {fmt_value(m['growth_rate'])}/step")
    if exact is not None:
        parts.append(f"{exact_name(a)} {fmt_value(exact)}")
    joint = a.get("joint")
    if joint:
        parts.append(f"joint system of state and error: {joint['verdict']} "
                     f"(rho {fmt_value(joint['rho'])}"
                     + (f", MSE x{fmt_value(joint['mse_growth_factor'])}/step"
                        if joint.get("growth") == "geometric" else "") + ")")
    return ", ".join(parts)


def exact_name(a: dict[str, Any]) -> str:
    """Short words for what a cell's ``exact`` value is (``analytics.exact_kind``)."""
    kind = a.get("exact_kind") or ""
    if kind.startswith("realised") and "eq. (11)" in kind:
        return "realised growth of the eq. (11) error recursion (moving-state forcing ignored)"
    if "eq. (11)" in kind or "eq. 11" in kind:
        return "eq. (11) error-recursion rho (moving-state forcing ignored)"
    if kind.startswith("augmented rho"):
        return "exact rho (eq. 9)"
    if kind.startswith("block"):
        return "block rate"
    if kind.startswith("realised"):
        return "realised growth"
    return "exact"
