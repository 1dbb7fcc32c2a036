"""Continuous-time plant and its exact discretisation over any interval.

The plant between two events is dx = A_c x dt + dw with E[dw dw^T] = Q_c dt. Over an
interval of true length h its exact discretisation is (Van Loan, "Computing integrals
involving the matrix exponential", IEEE TAC 23(3), 1978, eq. (2.13)-(2.14))

    x(t + h) = Phi(h) x(t) + nu,   Phi(h) = expm(A_c h),
    nu ~ N(0, Q_d(h)),   Q_d(h) = int_0^h expm(A_c s) Q_c expm(A_c s)^T ds,

with Q_d(h) read off the exponential of the block matrix
M = [[-A_c, Q_c], [0, A_c^T]] h:  expm(M) = [[., F12], [0, F22]],
Phi(h) = F22^T, Q_d(h) = Phi(h) F12.

A plant given as its discretisation (A, Q) at a period T (the papers' form) has the
continuous model A_c = logm(A) / T and the Q_c that Van Loan's integral maps to Q
(a linear equation in Q_c, solved in vectorised form). Intervals that are whole
multiples m T of the base period use A^m (products of the given A, as the step
kernel does) and, for m = 1, the given Q itself: a run on the base grid is then bit
for bit the step kernel's run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["ContinuousModel", "van_loan", "continuous_from_discrete", "whole_periods"]

#: Relative tolerance within which an interval counts as a whole number of periods.
PERIOD_TOLERANCE = 1e-12


def van_loan(Ac: np.ndarray, Qc: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation (Phi(h), Q_d(h)) of (A_c, Q_c) over an interval h.

    Parameters
    ----------
    Ac : numpy.ndarray, shape (n, n)
        Continuous-time system matrix.
    Qc : numpy.ndarray, shape (n, n)
        Continuous-time process noise intensity (symmetric PSD).
    h : float
        Interval length (true time); may be negative for Phi (Q_d is then not a
        covariance and should not be used).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray), shapes (n, n) and (n, n)
        The transition expm(A_c h) and the noise covariance over h (symmetrised).
    """
    from scipy.linalg import expm

    n = Ac.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -Ac
    M[:n, n:] = Qc
    M[n:, n:] = Ac.T
    F = expm(M * h)
    Phi = F[n:, n:].T.copy()
    Qd = Phi @ F[:n, n:]
    return Phi, 0.5 * (Qd + Qd.T)


def continuous_from_discrete(A: np.ndarray, Q: np.ndarray, period: float
                             ) -> tuple[np.ndarray, np.ndarray]:
    """The continuous model (A_c, Q_c) whose discretisation at ``period`` is (A, Q).

    A_c = logm(A) / T (the principal logarithm; it must be real: A may have no
    eigenvalue on the closed negative real axis), and Q_c solves
    vec(Q) = G vec(Q_c), G = int_0^T expm((A_c (+) A_c) s) ds (Kronecker sum), G from
    the exponential of [[A_c (+) A_c, I], [0, 0]] T.

    Raises
    ------
    ValueError
        When A has no real logarithm.
    """
    from scipy.linalg import expm, logm

    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    eig = np.linalg.eigvals(A)
    if np.any((np.abs(eig.imag) <= 1e-12 * max(1.0, float(np.abs(eig).max())))
              & (eig.real <= 0)):
        raise ValueError("plant.A has an eigenvalue on the closed negative real axis: it "
                         "is the discretisation of no real continuous-time plant; give "
                         "time.Ac and time.Qc instead")
    L = logm(A)
    if np.iscomplexobj(L):
        if np.abs(L.imag).max(initial=0.0) > 1e-9 * max(1.0, float(np.abs(L).max())):
            raise ValueError("plant.A has no real matrix logarithm; give time.Ac and "
                             "time.Qc instead")
        L = L.real
    Ac = L / period
    kron_sum = np.kron(Ac, np.eye(n)) + np.kron(np.eye(n), Ac)
    big = np.zeros((2 * n * n, 2 * n * n))
    big[:n * n, :n * n] = kron_sum
    big[:n * n, n * n:] = np.eye(n * n)
    G = expm(big * period)[:n * n, n * n:]
    # row-major vec: vec(X Y Z) = (X kron Z^T) vec(Y); for Y -> e^{As} Y e^{A^T s}
    # that is expm(s (A kron I + I kron A)) on the row-major vec
    Qc = np.linalg.solve(G, np.asarray(Q, dtype=float).reshape(-1)).reshape(n, n)
    return Ac, 0.5 * (Qc + Qc.T)


def whole_periods(h: float, period: float) -> int | None:
    """``m`` when ``h`` is a whole number m >= 0 of ``period`` (to PERIOD_TOLERANCE), else None."""
    if h < 0:
        return None
    m = round(h / period)
    if abs(h - m * period) <= PERIOD_TOLERANCE * max(1.0, abs(h)):
        return int(m)
    return None


@dataclass
class ContinuousModel:
    """A continuous-time plant with its discretisation at a base period.

    Parameters
    ----------
    Ac, Qc : numpy.ndarray, shape (n, n)
        Continuous-time system matrix and noise intensity.
    A, Q : numpy.ndarray, shape (n, n)
        Discretisation at ``period`` (given, or computed by :func:`van_loan`).
    period : float
        Base period T (the scenario's ``run.sample_period``).

    Notes
    -----
    :meth:`transition` and :meth:`noise` cache by interval; whole multiples m T use
    powers of the given ``A`` (m >= 0) and the given ``Q`` (m = 1), so that the
    synchronous case reproduces the step kernel exactly.
    """

    Ac: np.ndarray
    Qc: np.ndarray
    A: np.ndarray
    Q: np.ndarray
    period: float
    _powers: list[np.ndarray] = field(default_factory=list, repr=False)
    _phi: dict[float, np.ndarray] = field(default_factory=dict, repr=False)
    _qd: dict[float, np.ndarray] = field(default_factory=dict, repr=False)

    @classmethod
    def from_continuous(cls, Ac: np.ndarray, Qc: np.ndarray, period: float) -> ContinuousModel:
        """The model of (A_c, Q_c), with A, Q its discretisation at ``period``."""
        Ac = np.asarray(Ac, dtype=float)
        Qc = np.asarray(Qc, dtype=float)
        A, Q = van_loan(Ac, Qc, period)
        return cls(Ac, Qc, A, Q, float(period))

    @classmethod
    def from_discrete(cls, A: np.ndarray, Q: np.ndarray, period: float) -> ContinuousModel:
        """The model whose discretisation at ``period`` is the given (A, Q)."""
        Ac, Qc = continuous_from_discrete(A, Q, period)
        return cls(Ac, Qc, np.asarray(A, dtype=float), np.asarray(Q, dtype=float),
                   float(period))

    @property
    def n_states(self) -> int:
        """n."""
        return int(self.A.shape[0])

    def power(self, m: int) -> np.ndarray:
        """A^m of the base-period A (m >= 0), cached; A^1 is ``A`` itself."""
        if not self._powers:
            self._powers.extend([np.eye(self.n_states), self.A])
        while len(self._powers) <= m:
            self._powers.append(self.A @ self._powers[-1])
        return self._powers[m]

    def transition(self, h: float) -> np.ndarray:
        """Phi(h) = expm(A_c h), shape (n, n); A^m for h = m T (m >= 0)."""
        m = whole_periods(h, self.period)
        if m is not None:
            return self.power(m)
        phi = self._phi.get(h)
        if phi is None:
            from scipy.linalg import expm

            phi = expm(self.Ac * h)
            if len(self._phi) < 4096:
                self._phi[h] = phi
        return phi

    def noise(self, h: float) -> np.ndarray:
        """Q_d(h), shape (n, n), for h >= 0 (the given Q for h = T)."""
        if h < 0 or not math.isfinite(h):
            raise ValueError(f"noise covariance over a negative or non-finite interval {h}")
        if whole_periods(h, self.period) == 1:
            return self.Q
        qd = self._qd.get(h)
        if qd is None:
            qd = van_loan(self.Ac, self.Qc, h)[1]
            if len(self._qd) < 4096:
                self._qd[h] = qd
        return qd

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (the continuous matrices)."""
        return {"Ac": self.Ac.tolist(), "Qc": self.Qc.tolist(), "period": self.period}
