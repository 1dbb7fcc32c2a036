"""Validation of the system matrices shared by the analytics and the gain design.

Each function returns the input as float arrays or raises ValueError with one message
naming the argument and what is wrong with it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["as_square", "as_outputs", "check_system"]


def as_square(name: str, M: ArrayLike) -> np.ndarray:
    """Return ``M`` as a 2-D square float array or raise ValueError."""
    arr = np.asarray(M, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name} must be a square 2-D array, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite entries")
    return arr


def as_outputs(C: Sequence[ArrayLike], n: int | None = None) -> list[np.ndarray]:
    """Return the output matrices as a list of 2-D ``(m_i, n)`` float arrays."""
    out: list[np.ndarray] = []
    for i, Ci in enumerate(C):
        arr = np.asarray(Ci, dtype=float)
        if arr.ndim == 1:
            arr = arr.reshape(1, -1)
        if arr.ndim != 2:
            raise ValueError(f"C[{i}] must be a 1-D or 2-D array, got shape {arr.shape}")
        if n is None:
            n = arr.shape[1]
        if arr.shape[1] != n:
            raise ValueError(f"C[{i}] has {arr.shape[1]} columns, expected n={n}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"C[{i}] contains non-finite entries")
        out.append(arr)
    if not out:
        raise ValueError("C must contain at least one output matrix")
    return out


def check_system(
    P: ArrayLike, A: ArrayLike, C: Sequence[ArrayLike]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Validate ``P``, ``A`` and ``C`` together and return them as arrays.

    Returns
    -------
    P : numpy.ndarray, shape (N, N)
    A : numpy.ndarray, shape (n, n)
    C : list of numpy.ndarray, N arrays of shape (m_i, n)
    """
    P_arr = as_square("P", P)
    A_arr = as_square("A", A)
    C_list = as_outputs(C, A_arr.shape[0])
    if len(C_list) != P_arr.shape[0]:
        raise ValueError(
            f"C has {len(C_list)} output matrices but P is {P_arr.shape[0]}x{P_arr.shape[0]}"
        )
    return P_arr, A_arr, C_list
