"""A user's estimator plugged into netsim: the consensus-on-information filter.

This file is *not* part of netsim: it is what a researcher writes to test their own
estimator against delays. It implements the per-agent contract of
:mod:`netsim.estimators.contract` (``message_arrived``, ``step``, ``estimate``,
``outgoing``, ``last_delays``), knows nothing of SimPy, and is named in a scenario as
``"consensus_on_information:ConsensusOnInformation"`` (the scenario's folder is on the
import path; see ``examples/consensus-on-information.toml``).

The algorithm is the CI ("consensus on information") distributed Kalman filter of
G. Battistelli and L. Chisci, "Kullback-Leibler average, consensus on probability
densities, and distributed state estimation with guaranteed stability", Automatica
50(3):707-718, 2014, with L = 1 consensus step per sample. In information form
(Omega = P^-1, q = Omega x), agent i at step k:

1. correction with its own measurement (eq. for the local update):
   Omega_i = Omega_i(k|k-1) + C_i^T R_i^-1 C_i,  q_i = q_i(k|k-1) + C_i^T R_i^-1 y_i;
2. consensus (one step): Omega_i(k|k) = sum_j pi_ij Omega_j,  q_i(k|k) = sum_j pi_ij q_j,
   with pi_ij the scenario's consensus weights p_ij (row-stochastic);
3. prediction: Omega_i(k+1|k) = (A Omega_i(k|k)^-1 A^T + Q)^-1,
   q_i(k+1|k) = Omega_i(k+1|k) A Omega_i(k|k)^-1 q_i(k|k).

The paper exchanges the neighbours' *current* corrected pairs within one sampling
interval. In a network whose messages take at least one step (a message sent at step
s is usable at s + 1 + d), that is not possible; this plugin's adaptation, stated
here so that nobody mistakes it for the paper's: a neighbour's message carries its
fused estimate and covariance (x-hat_j(s|s), P_j(s|s)) time-stamped s, the receiver
keeps the freshest one and predicts it to step k with the model (k - s prediction
steps, x <- A x, P <- A P A^T + Q) before the consensus step; before anything has
arrived from j, agent i uses its own corrected pair in j's place (DESIGN.md). The
paper's stability theorem (collective observability, strong connectivity) is for its
own timing; netsim shows what the delays do to it.

netsim now ships the same paper's algorithm as the built-in family ``ci``
(:class:`netsim.estimators.baselines.ConsensusOnInformationFilter`, ``--estimators ci``),
with the paper's timing kept exact: the neighbours' *corrected* pairs of step k are
fused at step k + 1 (one consensus step per sample), then predicted and corrected with
the new measurement. This file stays what it was written as, an example of a user's
plugin (it runs as ``ci-filter``), with its own adaptation described above.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ConsensusOnInformation"]


class ConsensusOnInformation:
    """Agent i's consensus-on-information filter (Battistelli & Chisci 2014, L = 1).

    Parameters
    ----------
    setup : netsim.estimators.registry.AgentSetup
        What agent i may know: ``weights`` (row i of P, shape (N,)), ``A`` (n, n),
        ``C`` (m_i, n), ``Q`` (n, n), ``R`` (m_i, m_i), ``prior_mean`` (n,),
        ``prior_cov`` (n, n), ``in_neighbours``.
    """

    #: The family's name in results and traces.
    name = "ci-filter"
    description = "consensus-on-information Kalman filter (Battistelli & Chisci 2014), L = 1"
    paper = "Automatica 50(3), 2014, CI algorithm; neighbours' pairs predicted from time-stamps"
    #: It reads messages' time-stamps to predict a neighbour's estimate to step k.
    timestamps = True

    def __init__(self, setup) -> None:
        self.agent = setup.agent
        self.A = np.asarray(setup.A, dtype=float)
        self.Q = np.asarray(setup.Q, dtype=float)
        C = np.asarray(setup.C, dtype=float)
        R = np.asarray(setup.R, dtype=float).reshape(C.shape[0], C.shape[0])
        n = self.A.shape[0]
        self.n = n
        # C_i^T R_i^-1 C_i and C_i^T R_i^-1 (the information of one measurement)
        self._CtRinv = C.T @ np.linalg.inv(R) if C.shape[0] else np.zeros((n, 0))
        self._info = self._CtRinv @ C
        self.weights = {j: float(setup.weights[j]) for j in setup.in_neighbours
                        if setup.weights[j] != 0}
        self.own_weight = float(setup.weights[setup.agent])
        prior_info = np.linalg.inv(np.asarray(setup.prior_cov, dtype=float))
        self._Omega = prior_info  # Omega_i(k|k-1)
        self._q = prior_info @ np.asarray(setup.prior_mean, dtype=float)
        self._estimate = np.asarray(setup.prior_mean, dtype=float).copy()
        self._covariance = np.asarray(setup.prior_cov, dtype=float).copy()
        self._held: dict[int, tuple[int, np.ndarray]] = {}  # j -> (s, payload)
        self.last_delays: dict[int, int] = {}

    # -- the contract ---------------------------------------------------------------

    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        """Keep the freshest message of each in-neighbour (largest time-stamp)."""
        if sender not in self.weights:
            return False
        held = self._held.get(sender)
        if held is not None and held[0] >= sent_step:
            return False
        self._held[sender] = (int(sent_step), np.array(payload, dtype=float))
        return True

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Correct with y^i_k, fuse with the neighbours' predicted pairs, predict."""
        # 1. correction with the own measurement
        Omega = self._Omega + self._info
        q = self._q + self._CtRinv @ np.asarray(y, dtype=float)
        # 2. one consensus step on the information pairs
        fused_Omega = self.own_weight * Omega
        fused_q = self.own_weight * q
        delays = {}
        for j, weight in self.weights.items():
            held = self._held.get(j)
            if held is None:  # nothing from j yet: its weight stays on the own term
                fused_Omega += weight * Omega
                fused_q += weight * q
                delays[j] = -1
                continue
            s, payload = held
            x_j, P_j = self._predict(payload, k - s)
            Omega_j = np.linalg.inv(P_j)
            fused_Omega += weight * Omega_j
            fused_q += weight * (Omega_j @ x_j)
            delays[j] = k - 1 - s
        self.last_delays = delays
        P = np.linalg.inv(fused_Omega)
        P = 0.5 * (P + P.T)
        x = P @ fused_q
        self._estimate, self._covariance = x, P
        # 3. prediction to k + 1
        P_next = self.A @ P @ self.A.T + self.Q
        self._Omega = np.linalg.inv(P_next)
        self._q = self._Omega @ (self.A @ x)
        return x

    @property
    def estimate(self) -> np.ndarray:
        """x-hat_i(k|k), shape (n,)."""
        return self._estimate

    def outgoing(self, k: int) -> np.ndarray:
        """The fused estimate and covariance of step k, as [x (n), P (n*n) row-major]."""
        return np.concatenate([self._estimate, self._covariance.reshape(-1)])

    # -- helpers --------------------------------------------------------------------

    def _predict(self, payload: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
        n = self.n
        x = payload[:n]
        P = payload[n:].reshape(n, n)
        for _ in range(steps):
            x = self.A @ x
            P = self.A @ P @ self.A.T + self.Q
        return x, P
