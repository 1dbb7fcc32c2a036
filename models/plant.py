"""Linear time-invariant plant observed by N sensors.

x_k = A x_{k-1} + nu_k,   nu_k ~ N(0, Q)            (LCSYS2022 eq. 1)
y^i_k = C_i x_k + zeta^i_k, zeta^i_k ~ N(0, R_i)
with x_0 ~ N(x0_mean, x0_cov).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["LinearPlant", "PlantTrajectory"]


@dataclass(frozen=True)
class PlantTrajectory:
    """States and measurements of one or more realisations of the plant.

    Attributes
    ----------
    states : numpy.ndarray, shape (K+1, T, n)
        x_0..x_K of each of T realisations.
    measurements : numpy.ndarray, shape (K+1, T, M)
        All sensors' y^i_k stacked (sensor i in the rows of ``sensor_slices[i]``),
        M = sum of m_i.
    """

    states: np.ndarray
    measurements: np.ndarray


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
        # what scipy.linalg.block_diag returns, without importing scipy.linalg
        blocks = [np.atleast_2d(Ri) for Ri in self.R]
        if not blocks:
            return np.empty((1, 0))  # as scipy's block_diag()
        rows, cols = (sum(b.shape[axis] for b in blocks) for axis in (0, 1))
        out = np.zeros((rows, cols), dtype=np.result_type(*[b.dtype for b in blocks]))
        r = c = 0
        for b in blocks:
            out[r:r + b.shape[0], c:c + b.shape[1]] = b
            r, c = r + b.shape[0], c + b.shape[1]
        return out

    @cached_property
    def _factors(self) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
        # sensors often share one R object (``plant.sensors``): factor each once
        memo: dict[int, np.ndarray] = {}
        return (
            _factor(self.x0_cov),
            _factor(self.Q),
            tuple(memo[id(Ri)] if id(Ri) in memo else memo.setdefault(id(Ri), _factor(Ri))
                  for Ri in self.R),
        )

    def sample_initial(self, rng: np.random.Generator) -> np.ndarray:
        """Draw x_0 ~ N(x0_mean, x0_cov), shape (n,)."""
        return self.x0_mean + self._factors[0] @ rng.standard_normal(self.n_states)

    def step(self, x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Return x_k = A x_{k-1} + nu_k, shape (n,)."""
        return self.A @ x + self._factors[1] @ rng.standard_normal(self.n_states)

    @cached_property
    def _stacked_measurement(self) -> tuple[np.ndarray, np.ndarray, bool, tuple[slice, ...]]:
        """C stacked, the noise factor (diagonal as a vector if every m_i = 1, else
        block-diagonal), whether it is diagonal, and the sensors' row slices."""
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

    @property
    def noise_width(self) -> int:
        """Standard normals one step draws: n process noise, then sum m_i sensor noise."""
        return self.n_states + sum(map(len, self.C))  # len(C_i) = m_i

    def standard_noise(self, rng: np.random.Generator, steps: int,
                       out: np.ndarray | None = None) -> np.ndarray:
        """Draw the standard normals of steps 0..``steps``, shape (steps+1, n+M).

        Row k holds step k's draws in the order :meth:`step` (:meth:`sample_initial`
        at k = 0) and :meth:`measure_stacked` take them from ``rng``, so the rows are
        the numbers a step-by-step simulation with the same stream draws. ``out``, a
        C-contiguous float array of shape (steps+1, n+M), receives the same numbers
        (no temporary).
        """
        width = self.noise_width
        if out is not None:
            rng.standard_normal(out=out.reshape((steps + 1) * width))
            return out
        return rng.standard_normal((steps + 1) * width).reshape(steps + 1, width)

    def simulate(self, noise: np.ndarray) -> PlantTrajectory:
        """Simulate x_k = A x_{k-1} + nu_k and y^i_k = C_i x_k + zeta^i_k (eq. 1).

        Parameters
        ----------
        noise : numpy.ndarray, shape (K+1, T, n+M)
            Standard normals of T realisations, each laid out as by
            :meth:`standard_noise`: x_0 = x0_mean + F_0 z, nu_k = F_Q z, zeta = F_R z
            with F F^T the covariances.

        Returns
        -------
        PlantTrajectory
            States (K+1, T, n) and stacked measurements (K+1, T, M). The same
            numbers as :meth:`sample_initial`, :meth:`step` and
            :meth:`measure_stacked` step by step, up to the order of
            floating-point additions. A state that overflows becomes inf/NaN without a
            warning: the hosts report it as a divergence.
        """
        with np.errstate(over="ignore", invalid="ignore"):
            return self._simulate(noise)

    def _simulate(self, noise: np.ndarray) -> PlantTrajectory:
        n = self.n_states
        # fresh copies: matrices unpickled on a Dask worker are views into a receive
        # buffer (aligned to 16 rather than 32 bytes here), and products with them
        # rounded differently than in a local process; with copies the same seed gives
        # the same numbers on every executor (tests/test_sweep.py)
        F0, FQ, FR = self._factors
        F0_T, FQ_T, A_T = (np.array(F.T, order="C") for F in (F0, FQ, self.A))
        C_T = np.array(self.C_stacked.T, order="C")
        # any layout (a trial-major block seen as (K+1, T, n+M) is not copied)
        noise = np.require(noise, dtype=float, requirements=["A"])
        K1, T, _ = noise.shape
        states = np.empty((K1, T, n))
        states[0] = np.array(self.x0_mean, dtype=float) + noise[0, :, :n] @ F0_T
        process = np.matmul(noise[1:, :, :n], FQ_T)  # (K, T, n)
        # x_k = x_{k-1} A^T + nu_k row by row, written in place; ndarray.dot is the
        # same BLAS product as ``@`` (bit for bit) at under half its call overhead
        previous = states[0]
        for current, nu in zip(states[1:], process, strict=True):
            previous.dot(A_T, current)
            current += nu
            previous = current
        M = C_T.shape[1]
        z = noise[:, :, n:]
        _, factor, diagonal, _ = self._stacked_measurement
        if diagonal:  # one output per sensor: the factor is a vector
            # C x_k + F_R z a block of steps at a time, into the output: the
            # temporaries stay in cache
            measurements = np.empty((K1, T, M))
            rows = max(1, 32768 // max(1, T * M))
            scaled = np.empty((min(rows, K1), T, M))
            for k in range(0, K1, rows):
                part = measurements[k:k + rows]
                np.matmul(states[k:k + rows].reshape(-1, n), C_T, out=part.reshape(-1, M))
                part += np.multiply(z[k:k + rows], factor, out=scaled[:len(part)])
            return PlantTrajectory(states, measurements)
        measurements = (states.reshape(-1, n) @ C_T).reshape(K1, T, M)
        if M:
            import scipy.sparse as sp  # only here: it costs 0.2 s CPU to import

            # the block-diagonal noise factor as a sparse matrix: M can be thousands
            z = z.reshape(K1 * T, M)
            measurements += (sp.block_diag(FR, format="csr") @ z.T).T.reshape(K1, T, M)
        return PlantTrajectory(states, measurements)

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
