"""The field's standard distributed Kalman filters as netsim families: KCF, CI, diffusion KF.

Three baselines beside the papers' consensus estimators (DESIGN.md, "Estimators",
Baselines), each implemented from its paper's algorithm, step by step:

* ``kcf`` -- :class:`KalmanConsensusFilter`: R. Olfati-Saber, "Kalman-Consensus Filter:
  Optimality, Stability, and Performance", Proc. 48th IEEE CDC, 2009, Algorithm 1 (the
  discrete-time KCF, steps 1-7: information vector/matrix, fusion over the
  neighbourhood, M_i = (P_i^-1 + S_i)^-1, x-hat_i = x-bar_i + M_i (y_i - S_i x-bar_i)
  + gamma M_i sum_j (x-bar_j - x-bar_i), gamma = eps / (1 + ||M_i||_F), prediction).
* ``ci`` -- :class:`ConsensusOnInformationFilter`: G. Battistelli and L. Chisci,
  "Kullback-Leibler average, consensus on probability densities, and distributed state
  estimation with guaranteed stability", Automatica 50(3):707-718, 2014, the CI
  algorithm (Section 4, Table/Algorithm "CI": local correction of the information pair,
  L consensus steps Omega_i <- sum_j pi_ij Omega_j, q_i <- sum_j pi_ij q_j, prediction
  in information form), with L = 1.
* ``diffkf`` -- :class:`DiffusionKalmanFilter`: F. S. Cattivelli and A. H. Sayed,
  "Diffusion Strategies for Distributed Kalman Filtering and Smoothing", IEEE TAC
  55(9):2069-2084, 2010, Algorithm 1 (diffusion KF: incremental update with the
  neighbourhood's measurements, then the diffusion update x-hat_{k,i|i} = sum_l c_{l,k}
  psi_{l,i}), in the information form of its Algorithm 2.

The papers' texts were not at hand when this module was written (they are not among
``../shared/papers``): the steps above are cited by algorithm and step, as the papers
print them in their algorithm boxes; equation numbers inside those papers are not
cited, so as not to cite numbers we could not check.

Timing over netsim's network (the adaptation, the same for the three)
-----------------------------------------------------------------------
Each paper exchanges data *within* one sampling interval (KCF: measurements and priors
of time t are fused at time t; CI: L exchanges per sample; diffusion KF: two exchanges
per sample, measurements then intermediate estimates). In netsim a message sent at step
s is usable at step s + 1 + d (DESIGN.md), one exchange per step. So each family runs
its paper's recursion *exactly*, but late: agent i completes paper time t when the
neighbours' data of time t can have arrived --

* KCF and CI: at step k the agent completes paper time t = k - 1 (fusion and consensus
  of time k - 1), predicts to k, and corrects with its own y^i_k only;
* diffusion KF: at step k it completes the diffusion of time k - 2 and the incremental
  update of time k - 1, predicts to k, and corrects with its own y^i_k only.

The estimate a family reports at step k (x-hat^i_{k|k}, what netsim's MSE measures) is
that last local correction: the paper's prior for time k (from the completed recursion)
updated with agent i's own measurement, in information form. For CI this is exactly the
paper's corrected pair (Omega_i^0, q_i^0) of time k; for KCF and the diffusion KF it is
the local correction of the paper's prior (no neighbour data of time k exists yet).
With zero link delay every message of time t arrives in time, and the paper's recursion
runs unchanged: tests/test_baselines.py checks each against an independent
implementation of the paper's algorithm (one consensus or diffusion round per step).

Late, lost and reordered messages (stated rules, tested)
--------------------------------------------------------
1. Freshest by time-stamp: per in-neighbour the agent holds the message with the
   largest time-stamp; an arrival stamped at or before the held one (reordered, or a
   duplicate) is discarded (``message_arrived`` returns False, counted in
   ``discarded``).
2. Estimates are predicted: a neighbour's estimate that refers to an earlier time than
   the one the recursion needs (a late or lost newer message) is predicted to that
   time with the model: x <- A x (KCF's x-bar_j, the diffusion KF's psi_j) and, for CI's
   information pair, P <- A P A^T + Q (the paper's prediction, applied per step).
3. Measurements are fused only at their own time: a neighbour's measurement
   information (KCF, diffusion KF) enters the fusion of time t only if its message is
   stamped t; a late or lost one is never fused (no out-of-sequence processing) and no
   measurement is fused twice. With every link delayed by d >= 1 steps KCF and the
   diffusion KF therefore fuse only the agent's own measurement.
4. Never heard from: before anything has arrived from j, KCF leaves j out of its sums
   (the consensus term and the fusion); CI and the diffusion KF put j's weight p_ij on
   agent i's own term (DESIGN.md's rule), so their weights still sum to one.

``last_delays`` reports r_ij[k] = k - 1 - s_j of the message held from j at step k
(-1 before anything arrived), as DESIGN.md defines it. The families declare no
augmented error recursion (the analytics and replay of LCSYS2022 eq. (9) do not apply)
and no batched form: they run in the event kernel.

Information pairs need R_i invertible; a singular R_i is a ValueError naming
``plant.R[i]``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "KCF_OPTIONS",
    "KalmanConsensusFilter",
    "ConsensusOnInformationFilter",
    "DiffusionKalmanFilter",
    "kcf_options",
]

#: Effective delay reported before anything has arrived from a neighbour.
NO_MESSAGE = -1
#: Settings of ``[options.kcf]`` and their defaults: ``epsilon``, the consensus speed
#: factor eps of gamma = eps / (1 + ||M_i||_F) (Olfati-Saber 2009, Algorithm 1, step 6).
#: The paper leaves eps to the designer; 0.1 is netsim's choice.
KCF_OPTIONS: dict[str, Any] = {"epsilon": 0.1}


def _information(C: np.ndarray, R: np.ndarray, agent: int) -> tuple[np.ndarray, np.ndarray]:
    """C^T R^-1 and C^T R^-1 C of agent ``agent`` (ValueError for a singular R)."""
    m, n = C.shape
    if m == 0:
        return np.zeros((n, 0)), np.zeros((n, n))
    try:
        Rinv = np.linalg.inv(R.reshape(m, m))
    except np.linalg.LinAlgError:
        raise ValueError(f"plant.R[{agent}]: the information-form baselines (kcf, ci, "
                         "diffkf) need R_i invertible; give R positive definite") from None
    CtRinv = C.T @ Rinv
    return CtRinv, CtRinv @ C


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


class _Baseline:
    """Held messages (freshest by time-stamp), own information and the model.

    Parameters
    ----------
    setup : netsim.estimators.registry.AgentSetup
        Agent i's weights, neighbours and plant model.
    """

    def __init__(self, setup: Any) -> None:
        self.agent = int(setup.agent)
        self.A = np.asarray(setup.A, dtype=float)
        self.Q = np.asarray(setup.Q, dtype=float)
        self.n = self.A.shape[0]
        C = np.asarray(setup.C, dtype=float).reshape(-1, self.n)
        R = np.asarray(setup.R, dtype=float)
        self._CtRinv, self._U = _information(C, R, self.agent)
        self.neighbours = tuple(int(j) for j in setup.in_neighbours if j != self.agent)
        weights = np.asarray(setup.weights, dtype=float)
        self.own_weight = float(weights[self.agent])
        self.weights = {j: float(weights[j]) for j in self.neighbours}
        self.prior_mean = np.asarray(setup.prior_mean, dtype=float).copy()
        self.prior_cov = np.asarray(setup.prior_cov, dtype=float).copy()
        self._held: dict[int, tuple[int, np.ndarray]] = {}
        self._estimate = self.prior_mean.copy()
        self._started = False
        self.last_delays: dict[int, int] = {}
        #: Messages discarded on arrival (rule 1: not fresher than the held one).
        self.discarded = 0

    # -- the contract -----------------------------------------------------------
    def message_arrived(self, sender: int, sent_step: int, payload: np.ndarray) -> bool:
        """Hold the freshest message of each in-neighbour (rule 1); False: discarded."""
        if sender not in self.weights:
            return False
        held = self._held.get(sender)
        if held is not None and int(sent_step) <= held[0]:
            self.discarded += 1
            return False
        self._held[sender] = (int(sent_step), np.array(payload, dtype=float))
        return True

    @property
    def estimate(self) -> np.ndarray:
        """x-hat^i_{k|k}, shape (n,)."""
        return self._estimate

    # -- helpers ----------------------------------------------------------------
    def _own_information(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u_i, U_i) = (C_i^T R_i^-1 y, C_i^T R_i^-1 C_i)."""
        return self._CtRinv @ np.asarray(y, dtype=float).reshape(-1), self._U

    def _record_delays(self, k: int) -> None:
        self.last_delays = {j: (k - 1 - self._held[j][0]) if j in self._held else NO_MESSAGE
                            for j in self.neighbours}

    @staticmethod
    def _correct(x: np.ndarray, P: np.ndarray, u: np.ndarray, U: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Information-form update: M = (P^-1 + U)^-1, x + M (u - U x)."""
        M = _symmetric(np.linalg.inv(np.linalg.inv(P) + U))
        return x + M @ (u - U @ x), M

    def _power(self, x: np.ndarray, steps: int) -> np.ndarray:
        for _ in range(steps):
            x = self.A @ x
        return x


class KalmanConsensusFilter(_Baseline):
    """Agent i's Kalman-consensus filter (Olfati-Saber, CDC 2009, Algorithm 1).

    Paper time t (completed at netsim step k = t + 1, see the module docstring):

    - step 2: u_i = H_i^T R_i^-1 z_i, U_i = H_i^T R_i^-1 H_i;
    - step 5: y_i = sum_{j in J_i} u_j, S_i = sum_{j in J_i} U_j, J_i = N_i + {i}
      (a neighbour's pair only if its message is stamped t: rule 3);
    - step 6: M_i = (P_i^-1 + S_i)^-1,
      x-hat_i = x-bar_i + M_i (y_i - S_i x-bar_i) + gamma M_i sum_{j in N_i}
      (x-bar_j - x-bar_i), gamma = eps / (1 + ||M_i||_F)
      (x-bar_j predicted to t with A^(t - s) when its message is older: rule 2; a
      neighbour never heard from is left out: rule 4);
    - step 7: P_i <- A M_i A^T + Q, x-bar_i <- A x-hat_i.

    The message m_i = (u_i, U_i, x-bar_i) of time k (step 3) is sent after step k as
    ``[x-bar_i (n), u_i (n), U_i (n*n, row-major)]``. The reported estimate at step k is
    x-bar_i(k) corrected with agent i's own (u_i, U_i) of step k.

    Parameters
    ----------
    setup : netsim.estimators.registry.AgentSetup
    epsilon : float
        The consensus speed factor eps of step 6.
    """

    def __init__(self, setup: Any, epsilon: float = KCF_OPTIONS["epsilon"]) -> None:
        super().__init__(setup)
        self.epsilon = float(epsilon)
        self._xbar = self.prior_mean.copy()  # x-bar_i of paper time t
        self._Pbar = self.prior_cov.copy()
        self._u = np.zeros(self.n)  # own (u_i, U_i) of paper time t
        self._Uown = self._U
        #: The paper's x-hat_i of the last completed paper time (None before step 1).
        self.paper_estimate: np.ndarray | None = None

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Complete paper time k - 1, predict to k, correct with y^i_k (see the class)."""
        if self._started:
            self._fuse(k - 1)
        self._started = True
        self._record_delays(k)
        self._u, self._Uown = self._own_information(y)
        self._estimate, _ = self._correct(self._xbar, self._Pbar, self._u, self._Uown)
        return self._estimate

    def _fuse(self, t: int) -> None:
        n = self.n
        y, S = self._u.copy(), self._Uown.copy()
        consensus = np.zeros(n)
        for j in self.neighbours:
            held = self._held.get(j)
            if held is None:  # rule 4: left out
                continue
            s, payload = held
            if s == t:  # rule 3: measurements only at their own time
                y = y + payload[n:2 * n]
                S = S + payload[2 * n:].reshape(n, n)
            consensus += self._power(payload[:n], t - s) - self._xbar  # rule 2
        M = _symmetric(np.linalg.inv(np.linalg.inv(self._Pbar) + S))
        gamma = self.epsilon / (1.0 + np.linalg.norm(M, "fro"))
        xhat = self._xbar + M @ (y - S @ self._xbar) + gamma * (M @ consensus)
        self.paper_estimate = xhat
        self._Pbar = _symmetric(self.A @ M @ self.A.T + self.Q)
        self._xbar = self.A @ xhat

    def outgoing(self, k: int) -> np.ndarray:
        """m_i of time k: ``[x-bar_i(k), u_i(k), U_i(k) row-major]``."""
        return np.concatenate([self._xbar, self._u, self._Uown.reshape(-1)])


class ConsensusOnInformationFilter(_Baseline):
    """Agent i's consensus-on-information filter (Battistelli & Chisci 2014, CI, L = 1).

    Paper time t:

    - correction: Omega_i^0 = Omega_i(t|t-1) + C_i^T R_i^-1 C_i,
      q_i^0 = q_i(t|t-1) + C_i^T R_i^-1 y_i(t);
    - consensus, one step (L = 1, one exchange per netsim step):
      Omega_i(t) = sum_{j in N_i + {i}} pi_ij Omega_j^0, q_i(t) = sum_j pi_ij q_j^0,
      pi_ij = p_ij (the scenario's row-stochastic weights);
    - prediction: Omega_i(t+1|t) = (A Omega_i(t)^-1 A^T + Q)^-1,
      q_i(t+1|t) = Omega_i(t+1|t) A Omega_i(t)^-1 q_i(t).

    The corrected pair of step k is computed at step k, reported (x = Omega^-1 q) and sent
    as ``[q_i^0 (n), Omega_i^0 (n*n, row-major)]``; the consensus of time k runs at step
    k + 1. A neighbour's pair stamped s < t is predicted to t (rule 2: P <- A P A^T + Q,
    x <- A x per step); a neighbour never heard from is replaced by agent i's own pair
    (rule 4). With pi = P this is the example plugin's algorithm
    (examples/consensus_on_information.py) with the paper's timing: the plugin fuses
    the neighbours' *fused* pairs predicted to k with its own corrected pair of k.

    Parameters
    ----------
    setup : netsim.estimators.registry.AgentSetup
    """

    def __init__(self, setup: Any) -> None:
        super().__init__(setup)
        self._Omega_prior = np.linalg.inv(self.prior_cov)  # Omega_i(t|t-1)
        self._q_prior = self._Omega_prior @ self.prior_mean
        self._Omega0 = self._Omega_prior.copy()  # the corrected pair of the last step
        self._q0 = self._q_prior.copy()
        #: The paper's fused (consensus) estimate of the last completed time.
        self.paper_estimate: np.ndarray | None = None

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Consensus of time k - 1, prediction to k, correction with y^i_k."""
        if self._started:
            self._consensus(k - 1)
        self._started = True
        self._record_delays(k)
        u, U = self._own_information(y)
        self._Omega0 = self._Omega_prior + U
        self._q0 = self._q_prior + u
        self._estimate = np.linalg.solve(self._Omega0, self._q0)
        return self._estimate

    def _consensus(self, t: int) -> None:
        n = self.n
        own_weight = self.own_weight
        Omega = np.zeros((n, n))
        q = np.zeros(n)
        for j, weight in self.weights.items():
            held = self._held.get(j)
            if held is None:  # rule 4: the own pair in j's place
                own_weight += weight
                continue
            s, payload = held
            q_j, Omega_j = payload[:n], payload[n:].reshape(n, n)
            if s < t:  # rule 2: predict the pair to t
                P_j = np.linalg.inv(Omega_j)
                x_j = P_j @ q_j
                for _ in range(t - s):
                    x_j, P_j = self.A @ x_j, self.A @ P_j @ self.A.T + self.Q
                Omega_j = np.linalg.inv(P_j)
                q_j = Omega_j @ x_j
            Omega += weight * Omega_j
            q += weight * q_j
        Omega += own_weight * self._Omega0
        q += own_weight * self._q0
        P = _symmetric(np.linalg.inv(Omega))
        self.paper_estimate = P @ q
        P_next = _symmetric(self.A @ P @ self.A.T + self.Q)
        self._Omega_prior = _symmetric(np.linalg.inv(P_next))
        self._q_prior = self._Omega_prior @ (self.A @ (P @ q))

    def outgoing(self, k: int) -> np.ndarray:
        """The corrected pair of step k: ``[q_i^0 (n), Omega_i^0 (n*n row-major)]``."""
        return np.concatenate([self._q0, self._Omega0.reshape(-1)])


class DiffusionKalmanFilter(_Baseline):
    """Agent i's diffusion Kalman filter (Cattivelli & Sayed, IEEE TAC 2010, Algorithm 1).

    Paper time t, with prior (x-hat_{i,t|t-1}, P_{i,t|t-1}):

    - incremental update (Algorithm 1, step 1, in the information form of Algorithm 2):
      S_i = sum_{l in N_i + {i}} H_l^T R_l^-1 H_l, q_i = sum_l H_l^T R_l^-1 y_l,
      P_{i,t} = (P_{i,t|t-1}^-1 + S_i)^-1,
      psi_{i,t} = x-hat_{i,t|t-1} + P_{i,t} (q_i - S_i x-hat_{i,t|t-1})
      (a neighbour's measurement only if its message is stamped t: rule 3);
    - diffusion update (step 2): x-hat_{i,t|t} = sum_{l in N_i + {i}} c_{l,i} psi_{l,t},
      c_{l,i} = p_il (column i of C sums to one as row i of P does), P_{i,t|t} = P_{i,t};
      a neighbour's psi of an earlier time predicted with A (rule 2); one never heard
      from replaced by agent i's own psi (rule 4);
    - prediction: x-hat_{i,t+1|t} = A x-hat_{i,t|t}, P_{i,t+1|t} = A P_{i,t|t} A^T + Q.

    The paper exchanges twice per sample (measurements, then the psi's); netsim once per
    step, so the recursion runs two steps behind for the diffusion and one step behind
    for the incremental update: the message sent after step k is
    ``[psi_i(k-1) (n), u_i(k) (n), U_i(k) (n*n row-major)]`` (psi_i(-1) is the prior
    mean, never used). At step k the agent diffuses time k - 2, predicts to k - 1, runs
    the incremental update of time k - 1 and reports A psi_i(k-1) (covariance
    A P_i(k-1) A^T + Q) corrected with its own y^i_k.

    Parameters
    ----------
    setup : netsim.estimators.registry.AgentSetup
    """

    def __init__(self, setup: Any) -> None:
        super().__init__(setup)
        self._psi = self.prior_mean.copy()  # psi_i of the last incremental update
        self._P = self.prior_cov.copy()  # P_i of the last incremental update
        self._u = np.zeros(self.n)
        self._Uown = self._U
        self._step: int | None = None
        #: The paper's diffused x-hat_{i,t|t} of the last completed time t.
        self.paper_estimate: np.ndarray | None = None

    def step(self, k: int, y: np.ndarray) -> np.ndarray:
        """Diffusion of k - 2, incremental update of k - 1, local correction with y^i_k."""
        if self._started:
            t = k - 1
            if t >= 1:  # diffusion of time t - 1, then prediction to t
                x = self._diffuse(t - 1)
                self.paper_estimate = x
                prior = (self.A @ x, _symmetric(self.A @ self._P @ self.A.T + self.Q))
            else:  # paper time 0: the prior itself
                prior = (self.prior_mean, self.prior_cov)
            self._psi, self._P = self._incremental(t, *prior)
            local = (self.A @ self._psi, _symmetric(self.A @ self._P @ self.A.T + self.Q))
        else:
            local = (self.prior_mean, self.prior_cov)
        self._started = True
        self._record_delays(k)
        self._u, self._Uown = self._own_information(y)
        self._estimate, _ = self._correct(*local, self._u, self._Uown)
        return self._estimate

    def _incremental(self, t: int, x: np.ndarray, P: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
        n = self.n
        q, S = self._u.copy(), self._Uown.copy()
        for j in self.neighbours:
            held = self._held.get(j)
            if held is not None and held[0] == t:  # rule 3
                q = q + held[1][n:2 * n]
                S = S + held[1][2 * n:].reshape(n, n)
        return self._correct(x, P, q, S)

    def _diffuse(self, t: int) -> np.ndarray:
        n = self.n
        own_weight = self.own_weight
        x = np.zeros(n)
        for j, weight in self.weights.items():
            held = self._held.get(j)
            # psi_j(s - 1) rides on the message stamped s (none on stamp 0)
            if held is None or held[0] < 1:  # rule 4: own psi in j's place
                own_weight += weight
                continue
            s, payload = held
            x += weight * self._power(payload[:n], t - (s - 1))  # rule 2
        return x + own_weight * self._psi

    def outgoing(self, k: int) -> np.ndarray:
        """``[psi_i(k-1), u_i(k), U_i(k) row-major]`` (see the class)."""
        return np.concatenate([self._psi, self._u, self._Uown.reshape(-1)])


# -- the families this module declares (netsim.estimators.registry) --------------------

from netsim.estimators.registry import (  # noqa: E402  (declared after the classes)
    AgentPlan,
    EstimatorFamily,
    FamilyContext,
    FamilyError,
    register,
)


def kcf_options(scenario: Any) -> dict[str, Any]:
    """The scenario's ``[options.kcf]`` over :data:`KCF_OPTIONS`, checked (FamilyError)."""
    given = dict(getattr(scenario, "options", {}).get("kcf", {}))
    unknown = sorted(set(given) - set(KCF_OPTIONS))
    if unknown:
        raise FamilyError(f"options.kcf.{unknown[0]}",
                          f"unknown key; allowed: {', '.join(KCF_OPTIONS)}")
    options = {**KCF_OPTIONS, **given}
    eps = options["epsilon"]
    if isinstance(eps, bool) or not isinstance(eps, int | float) or not eps >= 0:
        raise FamilyError("options.kcf.epsilon", f"must be a number >= 0, got {eps!r}")
    return options


def _kcf(context: FamilyContext) -> list[AgentPlan]:
    epsilon = float(kcf_options(context.scenario)["epsilon"])
    return [AgentPlan(KalmanConsensusFilter(context.agent_setup(i), epsilon), (i,),
                      tuple(context.out_neighbours(i)))
            for i in range(context.scenario.n_agents)]


def _ci(context: FamilyContext) -> list[AgentPlan]:
    return [AgentPlan(ConsensusOnInformationFilter(context.agent_setup(i)), (i,),
                      tuple(context.out_neighbours(i)))
            for i in range(context.scenario.n_agents)]


def _diffkf(context: FamilyContext) -> list[AgentPlan]:
    return [AgentPlan(DiffusionKalmanFilter(context.agent_setup(i)), (i,),
                      tuple(context.out_neighbours(i)))
            for i in range(context.scenario.n_agents)]


register(EstimatorFamily(
    name="kcf", build=_kcf,
    description="Kalman-consensus filter: neighbourhood information fusion plus "
    "gamma M_i sum_j (x-bar_j - x-bar_i), one exchange per step",
    paper="Olfati-Saber, CDC 2009, Algorithm 1 (steps 1-7); [options.kcf] epsilon",
    timestamps=True, source="builtin",
))
register(EstimatorFamily(
    name="ci", build=_ci,
    description="consensus on information: CI pairs (Omega_i, q_i), L = 1 consensus step "
    "per sampling step",
    paper="Battistelli & Chisci, Automatica 50(3) 2014, CI algorithm (correction, "
    "consensus, prediction)",
    timestamps=True, source="builtin",
))
register(EstimatorFamily(
    name="diffkf", build=_diffkf,
    description="diffusion Kalman filter: incremental update with the neighbours' "
    "measurements, diffusion of the intermediate estimates with weights c_li = p_il",
    paper="Cattivelli & Sayed, IEEE TAC 55(9) 2010, Algorithms 1-2 (incremental and "
    "diffusion updates)",
    timestamps=True, source="builtin",
))
