"""Centralised Kalman filter on all sensors' measurements: the reference optimum."""

from __future__ import annotations

import numpy as np

__all__ = ["CentralizedKalmanFilter", "LocalKalmanFilter", "kalman_gain"]


def kalman_gain(S: np.ndarray, CP: np.ndarray, key: str, step: int) -> np.ndarray:
    """The Kalman gain P C^T S^-1 from the innovation covariance S = C P C^T + R and
    C P; a singular S is a ValueError naming ``key`` (the scenario's ``plant.R`` entry)."""
    try:
        return np.linalg.solve(S, CP).T
    except np.linalg.LinAlgError:
        raise ValueError(
            f"{key}: the Kalman filter's innovation covariance C P C^T + R is singular at "
            f"step {step} (R is singular where C P C^T is: noise-free dependent rows of C, "
            "or a singular P); give R positive definite"
        ) from None


class CentralizedKalmanFilter:
    """Kalman filter with every sensor's measurement, undelayed.

    Step 0 is the measurement update of the prior N(x0_mean, x0_cov); every later
    step is predict (x = A x, P = A P A^T + Q) then update with the stacked
    measurement y_k = C x_k + zeta_k (Joseph form for the covariance).

    Parameters
    ----------
    A : numpy.ndarray, shape (n, n)
    C : numpy.ndarray, shape (m, n)
        All sensors' output matrices stacked.
    Q : numpy.ndarray, shape (n, n)
    R : numpy.ndarray, shape (m, m)
        Block-diagonal measurement covariance.
    prior_mean : numpy.ndarray, shape (n,)
    prior_cov : numpy.ndarray, shape (n, n)
    """

    family = "centralized-kf"

    def __init__(
        self,
        A: np.ndarray,
        C: np.ndarray,
        Q: np.ndarray,
        R: np.ndarray,
        prior_mean: np.ndarray,
        prior_cov: np.ndarray,
        key: str = "plant.R",
    ) -> None:
        self._A, self._C, self._Q, self._R = A, C, Q, R
        self._key = key
        self._estimate = np.asarray(prior_mean, dtype=float).copy()
        self._cov = np.asarray(prior_cov, dtype=float).copy()
        self._started = False
        self.last_step: int | None = None

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        """The centralised filter receives no messages; refuse any."""
        return False

    @property
    def estimate(self) -> np.ndarray:
        """Current estimate x-hat_{k|k}, shape (n,)."""
        return self._estimate

    @property
    def covariance(self) -> np.ndarray:
        """Current error covariance P_{k|k}, shape (n, n)."""
        return self._cov

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Run step ``k`` with the stacked measurement y_k, shape (m,)."""
        A, C, Q, R = self._A, self._C, self._Q, self._R
        if self._started:
            x = A @ self._estimate
            P = A @ self._cov @ A.T + Q
        else:
            x, P = self._estimate, self._cov
            self._started = True
        S = C @ P @ C.T + R
        G = kalman_gain(S, C @ P, self._key, k)  # P C^T S^-1 (S symmetric)
        x = x + G @ (y - C @ x)
        I_GC = np.eye(len(x)) - G @ C
        P = I_GC @ P @ I_GC.T + G @ R @ G.T
        self._estimate, self._cov = x, 0.5 * (P + P.T)
        self.last_step = k
        return self._estimate


class LocalKalmanFilter(CentralizedKalmanFilter):
    """Agent i's Kalman filter on its own measurement only, with no communication.

    The baseline of a network without links: the filter of (A, C_i, Q, R_i). Where
    (A, C_i) is not detectable (the papers' setting: no agent observes the system on
    its own), its error grows with the unobservable unstable modes.

    Parameters
    ----------
    A : numpy.ndarray, shape (n, n)
    C : numpy.ndarray, shape (m_i, n)
    Q : numpy.ndarray, shape (n, n)
    R : numpy.ndarray, shape (m_i, m_i)
    prior_mean : numpy.ndarray, shape (n,)
    prior_cov : numpy.ndarray, shape (n, n)
    """

    family = "local-kf"

    def outgoing(self, step: int) -> None:
        """A local filter sends nothing."""
        return None


# -- the families this module declares (netsim.estimators.registry) --------------------

from netsim.estimators.registry import (  # noqa: E402  (declared after the classes)
    AgentPlan,
    EstimatorFamily,
    FamilyContext,
    register,
)


def _centralised(context: FamilyContext) -> list[AgentPlan]:
    p = context.scenario.plant
    kf = CentralizedKalmanFilter(p.A, p.C_stacked, p.Q, p.R_stacked, p.x0_mean, p.x0_cov)
    return [AgentPlan(kf, tuple(range(p.n_sensors)), ())]


def _local(context: FamilyContext) -> list[AgentPlan]:
    p = context.scenario.plant
    return [AgentPlan(LocalKalmanFilter(p.A, p.C[i], p.Q, p.R[i], p.x0_mean, p.x0_cov,
                                        f"plant.R[{i}]"), (i,), ())
            for i in range(p.n_sensors)]


register(EstimatorFamily(
    name="centralized-kf",
    build=_centralised,
    description="centralised Kalman filter on every sensor's measurement (the optimum)",
    paper="reference baseline (DESIGN.md)",
    centralised=True, delay_free=True,
    batched="netsim.vectorised:run_vectorised",
    batched_options={"rule": "kalman"},
    source="builtin",
))
register(EstimatorFamily(
    name="local-kf",
    build=_local,
    description="each agent's own Kalman filter on its measurement, no communication",
    paper="baseline (DESIGN.md): local filters without communication",
    delay_free=True,
    source="builtin",
))
