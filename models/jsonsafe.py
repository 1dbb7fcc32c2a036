"""JSON-safe numbers: one convention for every report's ``to_dict()``.

NaN becomes ``None`` (null) and +-inf the strings ``"inf"`` / ``"-inf"``, so every
command's ``--json`` output is strict JSON (``allow_nan=False``). :func:`json_tree`
applies that to a whole tree of dicts, lists and numpy values; :func:`json_default`
is the ``default=`` hook of :func:`json.dumps` for numpy values met while encoding.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["json_default", "json_number", "json_tree"]


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


def json_tree(value: Any, *, str_keys: bool = False) -> Any:
    """Apply :func:`json_number` to every float (and numpy scalar) inside mappings and lists.

    Parameters
    ----------
    value : Any
        A number, or mappings, lists, tuples and numpy arrays of them, nested.
    str_keys : bool, optional
        Convert every mapping key with ``str`` (so that a ``sort_keys=True`` dump sorts
        integer keys as the strings it writes). Default: keys are kept.

    Returns
    -------
    Any
        The same tree with dicts for mappings, lists for tuples and arrays, Python
        ``bool`` / ``int`` for numpy booleans and integers and JSON-safe floats.
    """
    if isinstance(value, Mapping):
        return {(str(k) if str_keys else k): json_tree(v, str_keys=str_keys)
                for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_tree(v, str_keys=str_keys) for v in value]
    if isinstance(value, np.ndarray):
        return json_tree(value.tolist(), str_keys=str_keys)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return json_number(value)
    return value


def json_default(value: Any, fallback: Callable[[Any], Any] | None = None) -> Any:
    """``default=`` hook of :func:`json.dumps`: numpy arrays and scalars as Python values.

    Floats are not made JSON-safe here (:func:`json.dumps` never calls the hook for a
    float); use :func:`json_tree` for that.

    Parameters
    ----------
    value : Any
        The object :func:`json.dumps` cannot encode.
    fallback : callable, optional
        Applied to anything that is not a numpy value (e.g. ``str`` for metadata that
        must always encode). Default: raise.

    Returns
    -------
    Any
        A list for an array, a Python scalar for a numpy scalar, else ``fallback(value)``.

    Raises
    ------
    TypeError
        ``not JSON-able: <value>``, for a value that is not a numpy value and no fallback.
    """
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.generic):
        return value.item()
    if fallback is not None:
        return fallback(value)
    raise TypeError(f"not JSON-able: {value!r}")
