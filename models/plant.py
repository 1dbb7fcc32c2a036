"""Linear time-invariant plant observed by N sensors.

x_k = A x_{k-1} + nu_k,   nu_k ~ N(0, Q)            (LCSYS2022 eq. 1)
y^i_k = C_i x_k + zeta^i_k, zeta^i_k ~ N(0, R_i)
with x_0 ~ N(x0_mean, x0_cov).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["LinearPlant"]


@dataclass(frozen=True)
class LinearPlant:
    """LTI plant with one output matrix per sensor.

    Parameters
    ----------
    A : numpy.ndarray, shape (n, n)
        System matrix.
    C : tuple of numpy.ndarray, each shape (m_i, n)
        Output matrix of each sensor i = 0..N-1.
    Q : numpy.ndarray, shape (n, n)
        Process noise covariance.
    R : tuple of numpy.ndarray, each shape (m_i, m_i)
        Measurement noise covariance of each sensor.
    x0_mean : numpy.ndarray, shape (n,)
        Mean of the initial state; also every estimator's initial prior.
    x0_cov : numpy.ndarray, shape (n, n)
        Covariance of the initial state.
    """

    A: np.ndarray
    C: tuple[np.ndarray, ...]
    Q: np.ndarray
    R: tuple[np.ndarray, ...]
    x0_mean: np.ndarray
    x0_cov: np.ndarray

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    @property
    def n_sensors(self) -> int:
        return len(self.C)

    @property
    def C_stacked(self) -> np.ndarray:
        """All output matrices stacked, shape (sum m_i, n)."""
        return np.vstack(self.C)

    @property
    def R_stacked(self) -> np.ndarray:
        """Block-diagonal measurement covariance, shape (sum m_i, sum m_i)."""
        from scipy.linalg import block_diag

        return block_diag(*self.R)

    @cached_property
    def _factors(self) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
        return (
            _factor(self.x0_cov),
            _factor(self.Q),
            tuple(_factor(Ri) for Ri in self.R),
        )

    def sample_initial(self, rng: np.random.Generator) -> np.ndarray:
        """Draw x_0 ~ N(x0_mean, x0_cov), shape (n,)."""
        return self.x0_mean + self._factors[0] @ rng.standard_normal(self.n_states)

    def step(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return x_k = A x_{k-1} + nu_k, shape (n,)."""
        return self.A @ x + self._factors[1] @ rng.standard_normal(self.n_states)

    @cached_property
    def _stacked_measurement(self) -> tuple[np.ndarray, np.ndarray, bool, list[int]]:
        """C stacked, the noise factor (diagonal as a vector if every m_i = 1, else
        block-diagonal), whether it is diagonal, and the split points."""
        factors = self._factors[2]
        sizes = [C.shape[0] for C in self.C]
        if all(m == 1 for m in sizes):
            factor = np.array([float(F[0, 0]) for F in factors])
            diagonal = True
        else:
            from scipy.linalg import block_diag

            factor = block_diag(*factors)
            diagonal = False
        return self.C_stacked, factor, diagonal, self.sensor_slices

    @cached_property
    def sensor_slices(self) -> tuple[slice, ...]:
        """Each sensor's rows of the stacked measurement (of :meth:`measure_stacked`)."""
        ends = np.cumsum([0] + [C.shape[0] for C in self.C]).tolist()
        return tuple(slice(a, b) for a, b in zip(ends[:-1], ends[1:], strict=True))

    def measure_stacked(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return all sensors' y^i_k = C_i x_k + zeta^i_k stacked, shape (sum m_i,).

        The noise is one draw of sum m_i standard normals, in sensor order (the same
        numbers as one draw per sensor).
        """
        C, factor, diagonal, _ = self._stacked_measurement
        z = rng.standard_normal(C.shape[0])
        return C @ x + (factor * z if diagonal else factor @ z)

    def measure(self, x: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
        """Return each sensor's y^i_k = C_i x_k + zeta^i_k, shapes (m_i,).

        Views of :meth:`measure_stacked` (same draw, same numbers).
        """
        y = self.measure_stacked(x, rng)
        return [y[rows] for rows in self.sensor_slices]


def _factor(cov: np.ndarray) -> np.ndarray:
    """Return F with F F^T = cov for a PSD covariance (Cholesky, eigen fallback)."""
    try:
        return np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        w, v = np.linalg.eigh(cov)
        return v * np.sqrt(np.clip(w, 0.0, None))
