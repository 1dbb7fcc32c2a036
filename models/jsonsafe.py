"""JSON-safe numbers: one convention for every report's ``to_dict()``.

NaN becomes ``None`` (null) and +-inf the strings ``"inf"`` / ``"-inf"``, so every
command's ``--json`` output is strict JSON (``allow_nan=False``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["json_number", "json_tree"]


def json_number(value: Any) -> float | str | None:
    """Return a JSON-safe float for a number (None for NaN, "inf"/"-inf" for infinities)."""
    if value is None:
        return None
    value = float(value)
    if math.isnan(value):
        return None
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def json_tree(value: Any) -> Any:
    """Apply :func:`json_number` to every float (and numpy scalar) inside dicts and lists."""
    if isinstance(value, dict):
        return {k: json_tree(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_tree(v) for v in value]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return json_number(value)
    return value
