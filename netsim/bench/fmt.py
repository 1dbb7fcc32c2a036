"""Number and cell formatting shared by the report, the paper checks and the sweep text."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["describe_cell", "fmt_value"]


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
    """One cell in words: verdict, steady MSE, MSE growth and the exact value."""
    m, a = c["measured"], c["analytics"]
    exact = a.get("exact")
    parts = [f"{m['verdict']}", f"steady MSE {fmt_value(m['steady_state_mse'])}",
             f"MSE growth {fmt_value(m['growth_rate'])}/step"]
    if exact is not None:
        parts.append(f"exact {fmt_value(exact)}")
    return ", ".join(parts)
