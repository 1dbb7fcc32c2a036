"""The dkfe paper's setting: sink nodes, random component selection, delays, examples.

Paper: B. Chen, D. W. C. Ho, G. Hu, L. Yu, "Delay-dependent distributed Kalman fusion
estimation with dimensionality reduction in cyber-physical systems"
(``../shared/papers/dkfe-dimensionality-reduction-delays.txt``).

What is here (numpy/cvxpy mathematics only; the estimators are in
:mod:`netsim.estimators.fusion`, the SimPy agents in :mod:`netsim.fusion`):

- :class:`SelectionScheme`: the categorical choice of which r_i of the n components
  sink i sends (eqs. 10-13, 16-17, 22), with its moments H_i = E{H_i(t)} (eq. 23) and
  Lambda_i, V_i, W_i (eq. 54).
- :class:`DkfeSetup` and the paper's Examples 1 and 2 transcribed exactly
  (:func:`example1`: eqs. 81-82, 84; :func:`example2`: eqs. 85-92, d_1 = 1, d_2 = 2).
  The paper gives no initial state statistics: we use x(0) ~ N(0, I) (our choice).
- Stability conditions: (58) per sink (:func:`condition_58`), (77)
  (:func:`condition_77`), the norm conditions (74) (:func:`condition_74`) and (76)
  (:func:`condition_76`), the LMI (75) of Remark 8 with cvxpy (:func:`lmi_75`), and
  Theorem 2's LMIs (71)-(72) (:func:`lmi_theorem2`, see below), beside the exact
  mean-square stability test :func:`second_moment_radius` (ours).
- :class:`UniformLinkDelays`: bounded time-varying link delays for Remark 1.
- Issue 31: :func:`stationary_fusion` (steady Xi, P, weights under any selection law,
  deterministic schedules or formula variant; an engine independent of
  :class:`netsim.estimators.fusion.FusionCovariance`), :func:`eq94_readings` (every
  reading of the selection model tried for (94); none gives the printed weights, see
  below), :func:`gamma_delay_table` and :func:`sink_delay_table` ((71)-(72) against the
  delay), :func:`dimension_sweep` (the transmitted dimension r_i).

Timing (how the paper's d_i maps onto the kernel)
-------------------------------------------------
In the paper the centre at time t uses the selection the sink made at time t - d_i
(eq. 9, 14, 15). In the kernel a message sent at step s with link delay d is usable at
step s + 1 + d, so the paper's d_i >= 1 is the link delay d_i - 1. The paper's
d_i = 0 (the centre uses the sink's time-t selection at time t) cannot be a link: the
centre then reads the sink's current payload directly at the same step, after the sink's
update (the agents run in order, sinks first). Time-varying delays d_i(t) <= d_i^u
(Remark 1) are padded at the centre: it holds every arrival in a buffer and uses the
selection sent at t - d_i^u, so a link whose delays are bounded by b_i gives the
paper's d_i = b_i + 1 (:func:`paper_delay_of_link_bound`).

Theorem 2's LMIs (71)-(72)
--------------------------
The extracted text prints (71) [[X_i, Y_i], [Y_i^T, Z_i]] >= 0 and (72)
M_i = [[M_i(1,1), -Y_i - d_i Z_i A_i], [-Y_i^T - d_i A_i^T Z_i, f(D_i) + d_i f(Z_i) - S_i]]
< 0 with A_i = E{A_i(t)}, but it never defines M_i(1,1). We read it from the proof's
bound (121): M_i(1,1) = -D_i + X_i + Y_i + Y_i^T + d_i Z_i + S_i (a Jensen-type
derivation would give d_i X_i in place of X_i). The verdict does not depend on that
choice: for any reading -D + c X + Y + Y^T + d Z + S with c >= 0,
(i) X = Y = Z = 0, S = (D + f(D)) / 2 satisfies (71)-(72) whenever f(D) < D; and
(ii) multiplying (72) by [I, I] on both sides gives
f(D) - D + c X + d (Z - Z A - A^T Z + f(Z)) < 0 where X >= 0 (from (71)) and
f(Z) >= A^T Z A, so f(D) < D. Hence (71)-(72) are feasible exactly when (75),
f(D) < D, is, and since the CSE error chain xi(t+1) = A_i(t) xi(t - d_i) (65) with
i.i.d. A_i(t) is mean-square stable iff some D > 0 has f(D) < D, both are equivalent to
rho(E{A_i(t) kron A_i(t)}) < 1 (:func:`second_moment_radius`), for every d_i. Theorem 2
is therefore neither conservative nor unsound, and condition (77) (the mean of the
same chain) is implied by it, so Theorem 3's extra (77) is redundant.
:func:`lmi_theorem2` solves (71)-(72) with our reading, and the tests check the
equivalence.

Comparison with the printed numbers (our values from ``netsim fusion table1`` and
``netsim fusion example2``; printed numbers contain typos, never tuned)
--------------------------------------------------------------------------------------
Example 1 (d_1 = 0):

- (83) printed "G_K1" = [[0.4760, -0.8573], [0.0314, 0.0376]]. The steady-state
  G_K1 = I - K_1 C_1 is [[1, -0.7794], [0, 0.0341]]; the printed matrix is
  Phi_K1 = G_K1 A = [[0.4706, -0.8573], [0.0341, 0.0376]] with two pairs of digits
  swapped (0.4706 -> 0.4760, 0.0341 -> 0.0314; differences 0.0054 and 0.0027).
- gamma_11 = 0.5: lambda_max(A^T (I - H_1) A) = 1.5887 and
  zeta_inf,1 = 2.3625, both as printed.
- The printed D_1 of the LMI (75) at gamma_11 = 0.5 is itself a valid certificate:
  D_1 > 0 and lambda_max(f(D_1) - D_1) = -0.0695 (``example1_paper_d1_check``).
- Table I: our (75) column (cvxpy, confirmed by the exact second-moment spectral
  radius max((1 - gamma) 1.5625, 1.21 gamma, rho(Phi_K)^2)) is True exactly for
  gamma_11 in {0.4, ..., 0.8}, and (76) and (74) are False for every gamma_11: all 33
  entries agree with Table I. (74) is read as the conjunction of its two lines; its
  second line alone, zeta_2 = ||Phi_K||_2 ||(I - H_1) A||_2 < 1, holds for
  gamma_11 in {0.2, ..., 0.6}, including 0.2 and 0.3 where the error covariance
  diverges (exact radius 1.25 and 1.094): that line alone is not a sufficient
  condition.

Example 2 (d_1 = 1, d_2 = 2):

- (88) Phi_K1 agrees to all printed digits; Phi_K2 differs in row 4:
  printed [-0.5093, -0.0291, -0.3937, 0.6284], ours [-0.5093, -0.0291, -0.3979,
  0.6248] (digit swaps, differences 0.0042 and 0.0036).
- (93): rho(A (I - H_1) A) = 0.5759 as printed; rho(A^2 (I - H_2) A) = 0.6613 against
  the printed 0.6631 (digit swap, difference 0.0018). Both < 1 either way.
- (95): zeta_inf,1 = 0.8657 as printed; zeta_inf,2 = 1.3554 as printed when computed
  with H_2 (the printed formula's "(I_n - H_1)" on the second line is a typo: with H_1
  it would be 1.0550).
- Theorem 2's LMIs (71)-(72) are feasible for both sinks, as the paper says (exact
  mean-square radii 0.9010 and 0.8147; the first is rho(Phi_K1)^4, the local filter's
  own error chain).
- (94) steady-state weights (Xi(t) converges after about 420 steps from x(0) ~ N(0, I)).
  Ours, Omega_2 = I - Omega_1:
  Omega_1 = [[0.6913, 0.1001, 0.3308, -0.0133], [0.1911, 0.8285, 0.3253, 0.1845],
             [0.1987, 0.0279, 0.6630, 0.2104], [0.0617, 0.0798, 0.2059, 0.5549]]
  printed:  [[0.6254, 0.0921, 0.3294, 0.0440], [0.0585, 0.7874, 0.2587, 0.2107],
             [0.1654, 0.0271, 0.6857, 0.2670], [0.0065, 0.0765, 0.2257, 0.6729]]
  Entry-wise differences (ours - printed): [[0.0659, 0.0080, 0.0014, -0.0573],
  [0.1326, 0.0411, 0.0666, -0.0262], [0.0333, 0.0008, -0.0227, -0.0566],
  [0.0552, 0.0033, -0.0198, -0.1180]]; largest 0.1326 (entry (2, 1)). The printed
  weights do sum to I. Our Xi (cross-covariances included) is confirmed by Monte Carlo
  (tests/test_fusion.py) and its diagonal blocks by the paper's own recursion (45),
  (55) to 1e-11, so the difference lies in the paper's cross-covariances (56) or its
  implementation. :func:`eq94_readings` enumerates 49 readings (eleven selection laws,
  seven formula variants, every delay pair (d_1, d_2) in 0..3 for the categorical and
  Bernoulli laws, relabellings, a search over the categorical laws with the printed
  marginals (92)): none comes within 0.01, none gets one entry of Omega_1 to four
  decimals; categorical 0.1326, uniform pair 0.1261, independent Bernoulli (the claim
  after (22)) 0.2241, the closest law with the marginals (92) found about 0.119, and
  Algorithm 1's Omega_i(t) at finite t at best 0.1132. Our steady traces:
  tr P = 1.5318 (DKFE), tr Xi_11 = 2.0802, tr Xi_22 = 2.6639, ODKFE tr P_o = 0.5720,
  centralised Kalman filter 0.1350.
- Q_w (86) has rank one (Q_w = q q^T, q = (0.2, 0.5, 0.3, 0.4)); (58) still holds.

Example 1 with delays (not in the paper, :func:`gamma_delay_table`): (71)-(72) hold for
gamma_11 in [0.3600, 0.8264] at d_1 = 0, only in [0.5904, 0.6830] at d_1 = 1 (e.g. not at
0.5, where the exact radius is 1.2207 although (77) gives 0.78), and for no gamma_11 at
d_1 = 2, 3 (smallest radius 1.2135, 1.5795): (77) alone is not sufficient, as Theorem 3
(which also asks for (71)-(72)) implies. Example 2's sinks keep (71)-(72) up to d_1 = 13
and d_2 = 12 with the printed probabilities (:func:`sink_delay_table`).

Other findings in the text: (64) has typos in the noise zeta^c_i (A^{d_i} H_i w where
(I - H_i) w belongs, and K_i missing in front of v_i; they do not enter any stability
condition); the sentence after (22) calls the gamma^i_l(t) "independent Bernoulli",
but within a step they are dependent (they sum to r_i), which (54) and Lemma 1
handle correctly (e.g. Lambda_1 in (84) has a zero off-diagonal); (79) prints
[Omega_1, ..., Omega_L] = P^{-1} I_a^T Xi^{-1}, which is the limit of (31) only with
P in place of P^{-1} (with P^{-1} the weights would sum to P^{-2}, not I); we use
P I_a^T Xi^{-1}.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.linalg as sla
from netsim.models.plant import LinearPlant
from netsim.models.seeding import SeedLike, stream

__all__ = [
    "SelectionScheme",
    "DkfeSetup",
    "LocalFilterSteadyState",
    "example1",
    "example2",
    "EXAMPLES",
    "get_example",
    "steady_state_local_filter",
    "condition_58",
    "chain_patterns",
    "lemma7_f",
    "second_moment_radius",
    "second_moment_parts",
    "condition_77",
    "condition_74",
    "condition_76",
    "LmiResult",
    "lmi_75",
    "lmi_theorem2",
    "sink_conditions",
    "UniformLinkDelays",
    "paper_delay_of_link_bound",
    "table1_rows",
    "example1_paper_d1_check",
    "PAPER_TABLE1",
    "PAPER_EX1_GK",
    "PAPER_EX1_D1",
    "PAPER_EX2_PHI_K",
    "PAPER_EX2_RHO77",
    "PAPER_EX2_OMEGA",
    "PAPER_EX2_ZETA_INF",
    "TABLE1_GAMMAS",
    "Moments",
    "selection_moments",
    "StationaryFusion",
    "stationary_fusion",
    "conditional_bernoulli",
    "sequential_without_replacement",
    "independent_indicators",
    "weighted_round_robin",
    "EQ94_PRINT_TOL",
    "EQ94_MATCH_TOL",
    "EQ94_MATCH_EXACT",
    "EQ94_SELECTION_READINGS",
    "EQ94_FORMULA_READINGS",
    "Eq94Reading",
    "Eq94Readings",
    "eq94_readings",
    "GammaDelayCell",
    "GammaDelayTable",
    "gamma_delay_table",
    "SinkDelayTable",
    "sink_delay_table",
    "DimensionSweep",
    "dimension_sweep",
]

# ---------------------------------------------------------------------------
# the paper's printed numbers (for comparison only; never used in a computation)
# ---------------------------------------------------------------------------

#: Table I: gamma_11 -> ((75), (76) derived by [32], (74) derived by [26]).
PAPER_TABLE1: dict[float, tuple[bool, bool, bool]] = {
    0.0: (False, False, False),
    0.1: (False, False, False),
    0.2: (False, False, False),
    0.3: (False, False, False),
    0.4: (True, False, False),
    0.5: (True, False, False),
    0.6: (True, False, False),
    0.7: (True, False, False),
    0.8: (True, False, False),
    0.9: (False, False, False),
    1.0: (False, False, False),
}
TABLE1_GAMMAS: tuple[float, ...] = tuple(round(0.1 * k, 1) for k in range(11))
#: Eq. (83), printed as "G_K1" (it is Phi_K1 = G_K1 A with two digit swaps).
PAPER_EX1_GK = np.array([[0.4760, -0.8573], [0.0314, 0.0376]])
#: The solution D_1 of (75) printed for gamma_11 = 0.5.
PAPER_EX1_D1 = np.array(
    [
        [1.3284, 0.1730, -0.0731, -0.0395],
        [0.1730, 0.3727, 0.0009, -0.0782],
        [-0.0731, 0.0009, 1.0315, -0.5204],
        [-0.0395, -0.0782, -0.5204, 1.9647],
    ]
)
#: Eq. (88): Phi_K1 stacked over Phi_K2 (8 x 4 as printed).
PAPER_EX2_PHI_K = (
    np.array(
        [
            [0.7915, -0.0778, -0.1333, 0.0886],
            [-0.3288, 0.6887, -0.4510, 0.0035],
            [-0.1573, -0.2237, 0.6459, -0.0659],
            [-0.2790, -0.2490, -0.4294, 0.9001],
        ]
    ),
    np.array(
        [
            [0.7324, 0.025, -0.0683, -0.0919],
            [-0.6848, 1.0244, -0.2209, -0.4579],
            [-0.4547, -0.0287, 0.5831, -0.1738],
            [-0.5093, -0.0291, -0.3937, 0.6284],
        ]
    ),
)
#: Eq. (93): rho(A^{d_i} (I - H_i) A), i = 1, 2.
PAPER_EX2_RHO77 = (0.5759, 0.6631)
#: Eq. (95): zeta_inf,i, i = 1, 2.
PAPER_EX2_ZETA_INF = (0.8657, 1.3554)
#: Eq. (94): steady-state weights Omega_1, Omega_2.
PAPER_EX2_OMEGA = (
    np.array(
        [
            [0.6254, 0.0921, 0.3294, 0.044],
            [0.0585, 0.7874, 0.2587, 0.2107],
            [0.1654, 0.0271, 0.6857, 0.2670],
            [0.0065, 0.0765, 0.2257, 0.6729],
        ]
    ),
    np.array(
        [
            [0.3746, -0.0921, -0.3294, -0.044],
            [-0.0585, 0.2126, -0.2587, -0.2107],
            [-0.1654, -0.0271, 0.3143, -0.2670],
            [-0.0065, -0.0765, -0.2257, 0.3271],
        ]
    ),
)


# ---------------------------------------------------------------------------
# selection and setup
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SelectionScheme:
    """Categorical choice of the components a sink sends (eqs. 10-13, 16-17, 22).

    Parameters
    ----------
    patterns : numpy.ndarray, shape (Delta_i, n), 0/1
        Row h is the diagonal of H^i_h (eq. 16): 1 for a component that is sent.
        Every row has the same number r_i of ones.
    probabilities : numpy.ndarray, shape (Delta_i,)
        pi^i_h >= 0, summing to 1 (eq. 22).
    """

    patterns: np.ndarray
    probabilities: np.ndarray

    def __post_init__(self) -> None:
        pat = np.asarray(self.patterns, dtype=float)
        pi = np.asarray(self.probabilities, dtype=float)
        if pat.ndim != 2 or pat.shape[0] < 1:
            raise ValueError("patterns must be a (Delta, n) array")
        if not np.all((pat == 0) | (pat == 1)):
            raise ValueError("patterns must contain only 0 and 1")
        r = pat.sum(axis=1)
        if np.any(r != r[0]) or r[0] < 1:
            raise ValueError("every pattern must select the same number r >= 1 of components")
        if pi.shape != (pat.shape[0],):
            raise ValueError(f"need one probability per pattern, got {pi.shape}")
        if np.any(pi < 0) or not math.isclose(float(pi.sum()), 1.0, abs_tol=1e-12):
            raise ValueError(f"probabilities must be >= 0 and sum to 1, got {pi.tolist()}")
        object.__setattr__(self, "patterns", pat)
        object.__setattr__(self, "probabilities", pi)

    @classmethod
    def all_subsets(cls, n: int, r: int, probabilities: Sequence[float]) -> SelectionScheme:
        """Every r-subset of n components in lexicographic order (the order of eq. 89)."""
        rows = []
        for subset in itertools.combinations(range(n), r):
            row = np.zeros(n)
            row[list(subset)] = 1.0
            rows.append(row)
        return cls(np.array(rows), np.asarray(probabilities, dtype=float))

    @property
    def n(self) -> int:
        return self.patterns.shape[1]

    @property
    def r(self) -> int:
        """Number of components sent per step."""
        return int(self.patterns[0].sum())

    @property
    def mean(self) -> np.ndarray:
        """Diagonal of H_i = E{H_i(t)} (eq. 23), shape (n,)."""
        return self.probabilities @ self.patterns

    @property
    def H(self) -> np.ndarray:
        """H_i = E{H_i(t)} = diag(gamma^i_1..gamma^i_n) (eq. 23)."""
        return np.diag(self.mean)

    @property
    def Lambda(self) -> np.ndarray:
        """Lambda_i = E{H_i(t) (.) H_i(t)} = E{h h^T} (eq. 54)."""
        return (self.patterns.T * self.probabilities) @ self.patterns

    @property
    def V(self) -> np.ndarray:
        """V_i = E{H_i(t) (.) [I - H_i(t)]} = E{h (1 - h)^T} (eq. 54)."""
        return (self.patterns.T * self.probabilities) @ (1.0 - self.patterns)

    @property
    def W(self) -> np.ndarray:
        """W_i = E{[I - H_i(t)] (.) [I - H_i(t)]} (eq. 54)."""
        return ((1.0 - self.patterns).T * self.probabilities) @ (1.0 - self.patterns)

    def draw(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray | int:
        """Draw pattern indices (categorical with the probabilities)."""
        return rng.choice(len(self.probabilities), size=size, p=self.probabilities)


@dataclass(frozen=True)
class DkfeSetup:
    """Plant, sink nodes, selections and delays of one fusion problem.

    x(t+1) = A x(t) + w(t) (eq. 1), y_i(t) = C_i x(t) + v_i(t) (eq. 2); sink i runs a
    Kalman filter (eqs. 5-7), sends r_i selected components (eq. 13) that the centre
    uses d_i steps later (eq. 9).

    Parameters
    ----------
    name, description : str
    A : (n, n); Q : (n, n) (Q_w)
    C, R : tuples of (q_i, n) and (q_i, q_i) (C_i, Q_{v_i})
    delays : tuple of int
        d_i >= 0 in the paper's sense (see the module docstring for the kernel mapping).
    selections : tuple of SelectionScheme
    x0_mean, x0_cov : initial state statistics (not in the paper; our choice).
    """

    name: str
    description: str
    A: np.ndarray
    Q: np.ndarray
    C: tuple[np.ndarray, ...]
    R: tuple[np.ndarray, ...]
    delays: tuple[int, ...]
    selections: tuple[SelectionScheme, ...]
    x0_mean: np.ndarray
    x0_cov: np.ndarray
    notes: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        A = np.atleast_2d(np.asarray(self.A, dtype=float))
        n = A.shape[0]
        if A.shape != (n, n):
            raise ValueError("A must be square")
        L = len(self.C)
        if not (len(self.R) == len(self.delays) == len(self.selections) == L) or L < 1:
            raise ValueError("C, R, delays and selections need one entry per sink")
        for d in self.delays:
            if int(d) != d or d < 0:
                raise ValueError(f"delays must be non-negative integers, got {self.delays}")
        for s in self.selections:
            if s.n != n:
                raise ValueError("selection patterns must have n columns")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "Q", np.asarray(self.Q, dtype=float))
        object.__setattr__(self, "C", tuple(np.atleast_2d(np.asarray(c, float)) for c in self.C))
        object.__setattr__(self, "R", tuple(np.atleast_2d(np.asarray(r, float)) for r in self.R))
        object.__setattr__(self, "delays", tuple(int(d) for d in self.delays))
        object.__setattr__(self, "x0_mean", np.asarray(self.x0_mean, dtype=float))
        object.__setattr__(self, "x0_cov", np.asarray(self.x0_cov, dtype=float))

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def n_sinks(self) -> int:
        return len(self.C)

    def plant(self) -> LinearPlant:
        """The plant for the event kernel (one sensor per sink)."""
        return LinearPlant(self.A, self.C, self.Q, self.R, self.x0_mean, self.x0_cov)

    def with_delays(self, delays: Sequence[int]) -> DkfeSetup:
        """The same setup with other delays d_i (e.g. zeros: the paper's ODKFE)."""
        from dataclasses import replace

        return replace(self, delays=tuple(int(d) for d in delays))

    def summary(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "n_states": self.n,
            "n_sinks": self.n_sinks,
            "delays": list(self.delays),
            "components_sent": [s.r for s in self.selections],
            "H": [s.mean.tolist() for s in self.selections],
        }


def example1(gamma11: float = 0.5, delay: int = 0) -> DkfeSetup:
    """Example 1 (eqs. 81-82, 84): n = 2, one sink sending one component.

    Component 1 is sent with probability gamma_11, component 2 otherwise, so
    H_1 = diag(gamma_11, 1 - gamma_11). The paper assumes no delay (d_1 = 0).
    """
    g = float(gamma11)
    if not 0.0 <= g <= 1.0:
        raise ValueError(f"gamma11 must be in [0, 1], got {gamma11}")
    sel = SelectionScheme(np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([g, 1.0 - g]))
    return DkfeSetup(
        name="dkfe-example1",
        description=(
            "dkfe paper Example 1 (eqs. 81-82): A = [[1.25, 0], [1, 1.1]], Q_w = 20 I, "
            f"C_1 = [0 1], Q_v1 = 2.5, one component sent, gamma_11 = {g}, d_1 = {delay}"
        ),
        A=np.array([[1.25, 0.0], [1.0, 1.1]]),
        Q=20.0 * np.eye(2),
        C=(np.array([[0.0, 1.0]]),),
        R=(np.array([[2.5]]),),
        delays=(int(delay),),
        selections=(sel,),
        x0_mean=np.zeros(2),
        x0_cov=np.eye(2),
        notes=("x(0) ~ N(0, I) is our choice; the paper gives no initial statistics",),
    )


def example2(delays: Sequence[int] = (1, 2)) -> DkfeSetup:
    """Example 2 (eqs. 85-92): the 4-bus grid, two sinks sending two components each."""
    A = np.array(
        [
            [1.0156, 0.0139, 0.0457, 0.0971],
            [-0.0353, 0.9997, -0.0008, -0.0017],
            [-0.0526, -0.0448, 0.9625, -0.0797],
            [-0.008, -0.0505, -0.0903, 0.9011],
        ]
    )
    Q = np.array(
        [
            [0.04, 0.1, 0.06, 0.08],
            [0.1, 0.25, 0.15, 0.2],
            [0.06, 0.15, 0.09, 0.12],
            [0.08, 0.2, 0.12, 0.16],
        ]
    )
    C1 = np.array([[1, 0, 1, 0], [0, 1, 0, 0], [0, 1, 1, 0], [1, 0, 1, 0]], dtype=float)
    C2 = np.array([[1, 0, 0, 1], [1, 0, 1, 0], [0, 0, 0, 1], [1, 0, 1, 0]], dtype=float)
    R1 = np.diag([0.9, 0.6, 0.9, 0.4])
    R2 = np.diag([0.3, 0.4, 0.5, 0.2])
    sel1 = SelectionScheme.all_subsets(4, 2, [0.3, 0.2, 0.1, 0.1, 0.1, 0.2])
    sel2 = SelectionScheme.all_subsets(4, 2, [0.2, 0.1, 0.2, 0.1, 0.3, 0.1])
    d = tuple(int(v) for v in delays)
    return DkfeSetup(
        name="dkfe-example2",
        description=(
            "dkfe paper Example 2 (eqs. 85-92): 4-bus smart grid, two sinks, r_1 = r_2 = 2 "
            f"of 4 components, selection probabilities (91), delays d = {list(d)}"
        ),
        A=A,
        Q=Q,
        C=(C1, C2),
        R=(R1, R2),
        delays=d,
        selections=(sel1, sel2),
        x0_mean=np.zeros(4),
        x0_cov=np.eye(4),
        notes=("x(0) ~ N(0, I) is our choice; the paper gives no initial statistics",),
    )


EXAMPLES: dict[str, Any] = {"dkfe-example1": example1, "dkfe-example2": example2}


def get_example(name: str) -> DkfeSetup:
    """Return a built-in example by name (``dkfe-example1``, ``dkfe-example2``, or 1/2)."""
    key = str(name).strip().lower()
    aliases = {"1": "dkfe-example1", "example1": "dkfe-example1",
               "2": "dkfe-example2", "example2": "dkfe-example2"}
    key = aliases.get(key, key)
    if key not in EXAMPLES:
        raise ValueError(f"unknown example {name!r}; choose one of {sorted(EXAMPLES)}")
    return EXAMPLES[key]()


# ---------------------------------------------------------------------------
# local filters and condition (58)
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class LocalFilterSteadyState:
    """Limits (59) of the local Kalman filter (7): P*, P, K, G_K = I - K C, Phi_K = G_K A."""

    P_pred: np.ndarray
    P: np.ndarray
    K: np.ndarray
    G: np.ndarray
    Phi: np.ndarray


def steady_state_local_filter(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray
) -> LocalFilterSteadyState:
    """Steady state of eq. (7) from the discrete algebraic Riccati equation."""
    n = A.shape[0]
    P_pred = sla.solve_discrete_are(A.T, C.T, Q, R)
    P_pred = 0.5 * (P_pred + P_pred.T)
    S = C @ P_pred @ C.T + R
    K = np.linalg.solve(S, C @ P_pred).T
    G = np.eye(n) - K @ C
    P = G @ P_pred
    return LocalFilterSteadyState(P_pred, 0.5 * (P + P.T), K, G, G @ A)


def _psd_sqrt(M: np.ndarray) -> np.ndarray:
    w, v = np.linalg.eigh(0.5 * (M + M.T))
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def condition_58(A: np.ndarray, Q: np.ndarray, C: np.ndarray, tol: float = 1e-9) -> dict[str, Any]:
    """(A, sqrt(Q_w)) stabilisable and (A, C_i) detectable (eq. 58), PBH tests.

    Also reports the paper's rank tests (controllability of (A, sqrt(Q_w)) and
    observability of (A, C_i)), which are sufficient.
    """
    n = A.shape[0]
    B = _psd_sqrt(Q)
    stabilisable = detectable = True
    for lam in np.linalg.eigvals(A):
        if abs(lam) < 1.0 - tol:
            continue
        M = A - lam * np.eye(n)
        if np.linalg.matrix_rank(np.hstack([M, B]), tol=1e-8) < n:
            stabilisable = False
        if np.linalg.matrix_rank(np.vstack([M, C]), tol=1e-8) < n:
            detectable = False
    ctrb = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(n)])
    obsv = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
    return {
        "holds": bool(stabilisable and detectable),
        "stabilisable": bool(stabilisable),
        "detectable": bool(detectable),
        "rank_controllability": int(np.linalg.matrix_rank(ctrb, tol=1e-8)),
        "rank_observability": int(np.linalg.matrix_rank(obsv, tol=1e-8)),
    }


# ---------------------------------------------------------------------------
# the CSE error chain (63)-(69) and its stability conditions
# ---------------------------------------------------------------------------


def chain_patterns(
    A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> list[np.ndarray]:
    """Realisations of A_i(t) (eq. 66), one per selection pattern.

    A_i(t) = [[A^d (I - H) A, A^d H Phi_K], [0, Phi_K^(d+1)]] with H the pattern's
    diagonal; the chain xi(t+1) = A_i(t) xi(t - d) (eq. 65) draws pattern h with
    probability pi_h independently at every step.
    """
    n = A.shape[0]
    Ad = np.linalg.matrix_power(A, d)
    Phid = np.linalg.matrix_power(Phi, d + 1)
    out = []
    for row in selection.patterns:
        H = np.diag(row)
        top = np.hstack([Ad @ (np.eye(n) - H) @ A, Ad @ H @ Phi])
        bottom = np.hstack([np.zeros((n, n)), Phid])
        out.append(np.vstack([top, bottom]))
    return out


def lemma7_f(
    B: np.ndarray, A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> np.ndarray:
    """f(B) = E{A_i^T(t) B A_i(t)}, transcribed from eq. (69) of Lemma 7.

    (The tests check it against the direct average over the selection patterns.)
    """
    n = A.shape[0]
    Ad = np.linalg.matrix_power(A, d)
    Phid = np.linalg.matrix_power(Phi, d + 1)
    H = selection.H
    eye = np.eye(n)
    B11, B12 = B[:n, :n], B[:n, n:]
    B21, B22 = B[n:, :n], B[n:, n:]
    X = Ad.T @ B11 @ Ad
    t11 = A.T @ (selection.W * X) @ A
    t12 = A.T @ (selection.V.T * X) @ Phi + A.T @ (eye - H) @ Ad.T @ B12 @ Phid
    t21 = Phi.T @ (selection.V * X) @ A + Phid.T @ B21 @ Ad @ (eye - H) @ A
    t22 = (
        Phi.T @ (selection.Lambda * X) @ Phi
        + Phid.T @ B21 @ Ad @ H @ Phi
        + Phid.T @ B22 @ Phid
        + Phi.T @ H @ Ad.T @ B12 @ Phid
    )
    return np.block([[t11, t12], [t21, t22]])


def second_moment_radius(
    A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> float:
    """rho(E{A_i(t) kron A_i(t)}): the exact mean-square stability test of (65).

    The chain xi(t+1) = A_i(t) xi(t - d) splits into d + 1 interleaved chains driven by
    i.i.d. A_i(t); each is mean-square stable iff this radius is < 1 (iff some D > 0
    has f(D) < D, i.e. (75)). Not in the paper; used to check (75) and (71)-(72).
    """
    mats = chain_patterns(A, Phi, selection, d)
    M = sum(p * np.kron(Ah, Ah) for p, Ah in zip(selection.probabilities, mats, strict=True))
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def second_moment_parts(
    A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> dict[str, float | str]:
    """Where :func:`second_moment_radius` comes from.

    A_i(t) (66) is block upper triangular, so E{A_i kron A_i} has the eigenvalues of its
    diagonal blocks: the selection chain's E{S kron S} with S = A^d (I - H(t)) A (the
    part the random selection governs), the local Kalman filter's Phi_K^(d+1) kron
    Phi_K^(d+1) (radius rho(Phi_K)^(2(d+1))), and the cross blocks E{S} kron
    Phi_K^(d+1). Returns the three radii and ``radius``, their maximum (equal to
    :func:`second_moment_radius`), and ``set_by``: which part attains it.
    """
    n = A.shape[0]
    Ad = np.linalg.matrix_power(A, d)
    S = [Ad @ (np.eye(n) - np.diag(row)) @ A for row in selection.patterns]
    probs = selection.probabilities
    ES2 = sum(p * np.kron(M, M) for p, M in zip(probs, S, strict=True))
    ES = sum(p * M for p, M in zip(probs, S, strict=True))
    rho_phi = float(np.max(np.abs(np.linalg.eigvals(Phi))))
    parts = {"selection_chain": float(np.max(np.abs(np.linalg.eigvals(ES2)))),
             "local_filter": rho_phi ** (2 * (d + 1)),
             "cross": float(np.max(np.abs(np.linalg.eigvals(ES)))) * rho_phi ** (d + 1)}
    top = max(parts, key=lambda k: parts[k])
    return {**parts, "radius": parts[top],
            "set_by": {"selection_chain": "the selection chain E{S kron S}",
                       "local_filter": "the local Kalman filter rho(Phi_K)^(2(d+1))",
                       "cross": "the cross term rho(E{S}) rho(Phi_K)^(d+1)"}[top]}


def condition_77(A: np.ndarray, selection: SelectionScheme, d: int) -> float:
    """rho(A^d (I - H_i) A) of eq. (77) (the condition is that it is < 1)."""
    n = A.shape[0]
    M = np.linalg.matrix_power(A, d) @ (np.eye(n) - selection.H) @ A
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def condition_74(
    A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> dict[str, Any]:
    """The norm conditions (74) (from [26]): zeta_inf,i < 1 and zeta_2,i < 1.

    zeta_inf = ||A^d||_1 ||(I - H)^(1/2) A||_1 ||A^d||_inf ||(I - H)^(1/2) A||_inf,
    zeta_2 = ||Phi_K^(d+1)||_2 ||A^d (I - H) A||_2. ``holds`` is the conjunction of the
    two lines of (74) (the reading that reproduces Table I).
    """
    n = A.shape[0]
    Ad = np.linalg.matrix_power(A, d)
    IH = np.eye(n) - selection.H
    S = np.sqrt(IH) @ A  # I - H is diagonal with entries in [0, 1]
    z_inf = (
        np.linalg.norm(Ad, 1) * np.linalg.norm(S, 1)
        * np.linalg.norm(Ad, np.inf) * np.linalg.norm(S, np.inf)
    )
    z_2 = np.linalg.norm(np.linalg.matrix_power(Phi, d + 1), 2) * np.linalg.norm(Ad @ IH @ A, 2)
    return {
        "zeta_inf": float(z_inf),
        "zeta_2": float(z_2),
        "zeta_inf_holds": bool(z_inf < 1.0),
        "zeta_2_holds": bool(z_2 < 1.0),
        "holds": bool(z_inf < 1.0 and z_2 < 1.0),
    }


def condition_76(A: np.ndarray, selection: SelectionScheme) -> float:
    """lambda_max(A^T (I - H_i) A) of eq. (76) (from [32], d_i = 0; holds if < 1)."""
    n = A.shape[0]
    M = A.T @ (np.eye(n) - selection.H) @ A
    return float(np.max(np.linalg.eigvalsh(0.5 * (M + M.T))))


@dataclass
class LmiResult:
    """Outcome of an LMI feasibility problem.

    ``feasible`` is True only if the solver returned a solution that numpy verifies
    (strict inequalities with the stated margins); ``status`` is the solver's.
    """

    feasible: bool
    status: str
    solver: str
    margin: float | None
    variables: dict[str, np.ndarray] = field(default_factory=dict)
    error: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {
            "feasible": self.feasible,
            "status": self.status,
            "solver": self.solver,
            "margin": self.margin,
            "error": self.error,
        }


def _solver() -> str:
    import cvxpy as cp

    installed = set(cp.installed_solvers())
    for name in ("CLARABEL", "SCS"):
        if name in installed:
            return name
    raise RuntimeError(f"no SDP solver installed (have {sorted(installed)})")


def _solve(problem: Any, solver: str) -> tuple[str, str]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            problem.solve(solver=solver)
    except Exception as exc:  # noqa: BLE001 - reported as not feasible
        return "solver_error", f"{type(exc).__name__}: {exc}"
    return str(problem.status), ""


def _f_expr(B: Any, mats: list[np.ndarray], probs: np.ndarray) -> Any:
    """f(B) = sum_h pi_h A_h^T B A_h as a cvxpy expression (equal to eq. 69)."""
    return sum(float(p) * (Ah.T @ B @ Ah) for p, Ah in zip(probs, mats, strict=True))


def _f_num(B: np.ndarray, mats: list[np.ndarray], probs: np.ndarray) -> np.ndarray:
    return sum(float(p) * (Ah.T @ B @ Ah) for p, Ah in zip(probs, mats, strict=True))


def _sym(M: Any) -> Any:
    return 0.5 * (M + M.T)


def lmi_75(A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int = 0) -> LmiResult:
    """Remark 8's LMI (75): find D > 0 with f(D) - D < 0 (cvxpy).

    Remark 8 states it for d_i = 0 (f-hat = f at d = 0); the same LMI with the
    general-d f of Lemma 7 is the exact test for every d. The problem is homogeneous,
    so we solve D >= I, f(D) - D <= -I and verify the returned D with numpy.
    """
    import cvxpy as cp

    mats = chain_patterns(A, Phi, selection, d)
    m = mats[0].shape[0]
    D = cp.Variable((m, m), symmetric=True)
    eye = np.eye(m)
    cons = [D >> eye, _sym(_f_expr(D, mats, selection.probabilities) - D) << -eye]
    problem = cp.Problem(cp.Minimize(0), cons)
    solver = _solver()
    status, error = _solve(problem, solver)
    if D.value is None or status not in ("optimal", "optimal_inaccurate"):
        return LmiResult(False, status, solver, None, error=error)
    Dv = _sym(np.asarray(D.value))
    lhs = _sym(_f_num(Dv, mats, selection.probabilities) - Dv)
    margin = float(np.max(np.linalg.eigvalsh(lhs)))
    ok = bool(np.min(np.linalg.eigvalsh(Dv)) > 0 and margin < 0)
    return LmiResult(ok, status, solver, margin, {"D": Dv}, error)


def lmi_theorem2(
    A: np.ndarray, Phi: np.ndarray, selection: SelectionScheme, d: int
) -> LmiResult:
    """Theorem 2's LMIs (71)-(72) with M_i(1,1) read from the proof's (121).

    M_i(1,1) = -D + X + Y + Y^T + d Z + S, A_i = E{A_i(t)}; variables D, S > 0,
    X, Z symmetric, Y. Homogeneous, so we solve D >= I, S >= I, (71) >= 0,
    (72) <= -I, and verify with numpy. See the module docstring: feasible exactly when
    (75) is (for any d).
    """
    import cvxpy as cp

    mats = chain_patterns(A, Phi, selection, d)
    probs = selection.probabilities
    m = mats[0].shape[0]
    Abar = sum(float(p) * Ah for p, Ah in zip(probs, mats, strict=True))
    D = cp.Variable((m, m), symmetric=True)
    S = cp.Variable((m, m), symmetric=True)
    X = cp.Variable((m, m), symmetric=True)
    Z = cp.Variable((m, m), symmetric=True)
    Y = cp.Variable((m, m))
    eye = np.eye(m)
    m11 = -D + X + Y + Y.T + d * Z + S
    m12 = -Y - d * (Z @ Abar)
    m22 = _f_expr(D, mats, probs) + d * _f_expr(Z, mats, probs) - S
    M = cp.bmat([[m11, m12], [m12.T, m22]])
    XYZ = cp.bmat([[X, Y], [Y.T, Z]])
    cons = [D >> eye, S >> eye, _sym(XYZ) >> 0, _sym(M) << -np.eye(2 * m)]
    problem = cp.Problem(cp.Minimize(0), cons)
    solver = _solver()
    status, error = _solve(problem, solver)
    if D.value is None or status not in ("optimal", "optimal_inaccurate"):
        return LmiResult(False, status, solver, None, error=error)
    v = {k: np.asarray(var.value) for k, var in {"D": D, "S": S, "X": X, "Y": Y, "Z": Z}.items()}
    Dv, Sv, Xv, Yv, Zv = (v[k] for k in "DSXYZ")
    n11 = -Dv + Xv + Yv + Yv.T + d * Zv + Sv
    n12 = -Yv - d * Zv @ Abar
    n22 = _f_num(Dv, mats, probs) + d * _f_num(Zv, mats, probs) - Sv
    Mv = _sym(np.block([[n11, n12], [n12.T, n22]]))
    margin = float(np.max(np.linalg.eigvalsh(Mv)))
    ok = bool(
        margin < 0
        and np.min(np.linalg.eigvalsh(_sym(Dv))) > 0
        and np.min(np.linalg.eigvalsh(_sym(Sv))) > 0
        and np.min(np.linalg.eigvalsh(_sym(np.block([[Xv, Yv], [Yv.T, Zv]])))) > -1e-7
    )
    return LmiResult(ok, status, solver, margin, v, error)


# ---------------------------------------------------------------------------
# Remark 1: bounded time-varying link delays
# ---------------------------------------------------------------------------


def sink_conditions(setup: DkfeSetup, lmis: bool = True) -> list[dict[str, Any]]:
    """Per sink: (58), (77), (74), (76) (d_i = 0), the exact radius, (75), (71)-(72)."""
    out = []
    for i in range(setup.n_sinks):
        A, sel, d = setup.A, setup.selections[i], setup.delays[i]
        ss = steady_state_local_filter(A, setup.C[i], setup.Q, setup.R[i])
        row: dict[str, Any] = {
            "sink": i + 1,
            "delay": d,
            "c58": condition_58(A, setup.Q, setup.C[i]),
            "c77_rho": condition_77(A, sel, d),
            "c74": condition_74(A, ss.Phi, sel, d),
            "c76_lambda_max": condition_76(A, sel) if d == 0 else None,
            "second_moment_radius": second_moment_radius(A, ss.Phi, sel, d),
            "second_moment_parts": second_moment_parts(A, ss.Phi, sel, d),
            "rho_phi_k": float(np.max(np.abs(np.linalg.eigvals(ss.Phi)))),
        }
        if lmis:
            row["lmi75"] = lmi_75(A, ss.Phi, sel, d).to_dict()
            row["lmi71_72"] = lmi_theorem2(A, ss.Phi, sel, d).to_dict()
        out.append(row)
    return out


class UniformLinkDelays:
    """Time-varying bounded step delays: uniform in 0..b_l per message on link l.

    The delay model of Remark 1 (d_i(t) <= d_i^u): each link has its own bound and
    its own stream ``"delays/dkfe-link/<sender>-<receiver>"`` of ``seed``; messages can
    be reordered. With link bound b the paper's padded delay is d^u = b + 1
    (:func:`paper_delay_of_link_bound`).
    """

    unit: Literal["steps", "time"] = "steps"
    time_invariant = False

    def __init__(self, bounds: Mapping[tuple[int, int], int], seed: SeedLike) -> None:
        for link, b in bounds.items():
            if int(b) != b or b < 0:
                raise ValueError(f"bound of link {link} must be a non-negative integer, got {b}")
        self.bounds = {tuple(k): int(v) for k, v in bounds.items()}
        self.max_delay = max(self.bounds.values(), default=0)
        self._seed = seed
        self._rngs: dict[tuple[int, int], np.random.Generator] = {}

    def draw(self, sender: int, receiver: int, send_step: int) -> int:
        bound = self.bounds.get((sender, receiver))
        if bound is None:
            raise KeyError(f"no delay bound for link {sender}->{receiver}")
        rng = self._rngs.get((sender, receiver))
        if rng is None:
            rng = self._rngs[(sender, receiver)] = stream(
                self._seed, f"delays/dkfe-link/{sender}-{receiver}"
            )
        return int(rng.integers(0, bound + 1))


def paper_delay_of_link_bound(bound: int) -> int:
    """The paper's d_i for a link whose step delays are at most ``bound``: bound + 1."""
    return int(bound) + 1


# ---------------------------------------------------------------------------
# Table I and the Example 1 check of the printed D_1
# ---------------------------------------------------------------------------


def table1_rows(gammas: Sequence[float] = TABLE1_GAMMAS) -> list[dict[str, Any]]:
    """Example 1, d_1 = 0: conditions (75), (76), (74) for each gamma_11 (Table I).

    Each row has the LMI (75) result, the exact second-moment radius (ours), the
    value and verdict of (76) and (74), and the paper's printed verdicts.
    """
    rows = []
    for g in gammas:
        setup = example1(g)
        A, C, Q, R = setup.A, setup.C[0], setup.Q, setup.R[0]
        sel, d = setup.selections[0], setup.delays[0]
        ss = steady_state_local_filter(A, C, Q, R)
        lmi = lmi_75(A, ss.Phi, sel, d)
        radius = second_moment_radius(A, ss.Phi, sel, d)
        c76 = condition_76(A, sel)
        c74 = condition_74(A, ss.Phi, sel, d)
        paper = PAPER_TABLE1.get(round(float(g), 1))
        ours = (lmi.feasible, c76 < 1.0, c74["holds"])
        rows.append({
            "gamma11": float(g),
            "lmi75": lmi.to_dict(),
            "c75": lmi.feasible,
            "second_moment_radius": radius,
            "c76_value": c76,
            "c76": bool(c76 < 1.0),
            "c74": c74,
            "paper": None if paper is None else {"c75": paper[0], "c76": paper[1],
                                                 "c74": paper[2]},
            "agrees": None if paper is None else bool(ours == paper),
        })
    return rows


def example1_paper_d1_check(gamma11: float = 0.5) -> dict[str, Any]:
    """Is the printed D_1 (Example 1, gamma_11 = 0.5) a certificate of (75)?"""
    setup = example1(gamma11)
    ss = steady_state_local_filter(setup.A, setup.C[0], setup.Q, setup.R[0])
    sel = setup.selections[0]
    D = PAPER_EX1_D1
    lhs = lemma7_f(D, setup.A, ss.Phi, sel, 0) - D
    return {
        "min_eig_D": float(np.min(np.linalg.eigvalsh(_sym(D)))),
        "max_eig_f_minus_D": float(np.max(np.linalg.eigvalsh(_sym(lhs)))),
        "certificate": bool(
            np.min(np.linalg.eigvalsh(_sym(D))) > 0 and np.max(np.linalg.eigvalsh(_sym(lhs))) < 0
        ),
    }


# ---------------------------------------------------------------------------
# stationary second moments for a general selection reading (an engine of its own)
# ---------------------------------------------------------------------------

#: A selection's first two moments for one sink: (E{h}, E{h h^T}), h the 0/1 (or, for a
#: reading that is not a probability model, real) diagonal of H_i(t); shapes (n,), (n, n).
Moments = tuple[np.ndarray, np.ndarray]


def selection_moments(selection: SelectionScheme) -> Moments:
    """(E{h}, E{h h^T}) of a categorical selection (eqs. 23, 54: H_i and Lambda_i)."""
    return selection.mean.copy(), selection.Lambda.copy()


@dataclass
class StationaryFusion:
    """Steady state of the compensating estimates' errors under one reading.

    Attributes
    ----------
    Xi : numpy.ndarray, shape (L n, L n)
        Xi_ij = E{x~^c_i x~^c_j^T} (eq. 33) in the steady state (for a periodic reading:
        at phase 0).
    P : numpy.ndarray, shape (n, n)
        Fused error covariance (32) with the optimal weights.
    weights : list of numpy.ndarray, each (n, n)
        Omega_i of (31) from ``Xi``.
    steps : int
        Iterations until the change fell below the tolerance.
    converged : bool
        False if the iteration diverged or ran out of steps.
    phases : list of (Xi, P, weights)
        For a periodic (scheduled) reading, one entry per phase of the period; otherwise
        the single steady state.
    """

    Xi: np.ndarray
    P: np.ndarray
    weights: list[np.ndarray]
    steps: int
    converged: bool
    phases: list[tuple[np.ndarray, np.ndarray, list[np.ndarray]]] = field(default_factory=list)


def _fusion_weights(Xi: np.ndarray, L: int, n: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Optimal weights (31) and P (32): (I_a^T Xi^-1 I_a)^-1 I_a^T Xi^-1."""
    Ia = np.tile(np.eye(n), (L, 1))
    XiIa = np.linalg.solve(0.5 * (Xi + Xi.T), Ia)
    P = np.linalg.inv(Ia.T @ XiIa)
    P = 0.5 * (P + P.T)
    row = P @ XiIa.T
    return [row[:, i * n:(i + 1) * n] for i in range(L)], P


class _StationaryModel:
    """Linear maps of the stacked error state with steady-state local gains.

    State at step t: per sink e_i(t), ..., e_i(t - D) (local errors, D = max d_i), the
    compensating errors c_i(t), ..., c_i(t - d_i), and w(t-1), ..., w(t-D); the step
    appends w(t) and v_i(t+1). Eq. (25) gives
    c_i(t+1) = A^d [b + h o (a - b)] + sum_{theta=1..d} A^(theta-1) w(t+1-theta) with a
    the transmitted error and b the predicted one.
    """

    def __init__(self, setup: DkfeSetup, send: str, compensation: str) -> None:
        A, n, L = setup.A, setup.n, setup.n_sinks
        delays = setup.delays
        D = max(delays)
        self.n, self.L, self.delays = n, L, delays
        self.filters = [steady_state_local_filter(A, setup.C[i], setup.Q, setup.R[i])
                        for i in range(L)]
        off = 0
        self.loc = []
        for _ in range(L):
            self.loc.append([off + m * n for m in range(D + 1)])
            off += (D + 1) * n
        self.cse = []
        for d in delays:
            self.cse.append([off + m * n for m in range(d + 1)])
            off += (d + 1) * n
        wl = [off + m * n for m in range(D)]
        off += D * n
        self.N = off
        wn = off
        off += n
        vs = []
        for C in setup.C:
            vs.append(off)
            off += C.shape[0]
        self.noise = sla.block_diag(setup.Q, *setup.R)
        eye = np.eye(n)

        def w_at(lag: int) -> int:  # column of w(t - lag), lag >= 0
            return wn if lag == 0 else wl[lag - 1]

        T = np.zeros((self.N, off))

        def put(M: np.ndarray, r: int, c: int, block: np.ndarray) -> None:
            M[r:r + block.shape[0], c:c + block.shape[1]] += block

        for m in range(1, D):
            put(T, wl[m], wl[m - 1], eye)
        if D:
            put(T, wl[0], wn, eye)
        self.random: list[tuple[int, np.ndarray, np.ndarray]] = []
        for i in range(L):
            f, d = self.filters[i], delays[i]
            new_e = np.zeros((n, off))
            put(new_e, 0, self.loc[i][0], f.Phi)
            put(new_e, 0, wn, f.G)
            put(new_e, 0, vs[i], -f.K)
            T[self.loc[i][0]:self.loc[i][0] + n] += new_e
            for m in range(1, D + 1):
                put(T, self.loc[i][m], self.loc[i][m - 1], eye)
            for m in range(1, d + 1):
                put(T, self.cse[i][m], self.cse[i][m - 1], eye)
            a = np.zeros((n, off))
            if send == "posterior":  # x~_i(t+1-d), eq. (15)
                if d == 0:
                    a = new_e.copy()
                else:
                    put(a, 0, self.loc[i][d - 1], eye)
            elif send == "prior":  # x_i(t+1-d) - A x-hat_i(t-d)
                put(a, 0, self.loc[i][d], A)
                put(a, 0, w_at(d), eye)
            else:
                raise ValueError(f"send must be 'posterior' or 'prior', got {send!r}")
            b = np.zeros((n, off))
            if compensation == "paper":  # A x~^c_i(t-d) + w(t-d), eq. (25)
                put(b, 0, self.cse[i][d], A)
                put(b, 0, w_at(d), eye)
            elif compensation == "same-time":  # x~^c_i(t+1-d), no prediction step
                if d == 0:
                    raise ValueError("compensation 'same-time' needs d_i >= 1")
                put(b, 0, self.cse[i][d - 1], eye)
            else:
                raise ValueError(f"compensation must be 'paper' or 'same-time', got "
                                 f"{compensation!r}")
            F = np.zeros((n, off))
            for theta in range(1, d + 1):
                put(F, 0, w_at(theta - 1), np.linalg.matrix_power(A, theta - 1))
            Ad = np.linalg.matrix_power(A, d)
            T[self.cse[i][0]:self.cse[i][0] + n] += Ad @ b + F
            self.random.append((self.cse[i][0], Ad, a - b))
        self.T = T

    def step(self, S: np.ndarray, moments: Sequence[Moments],
             printed_eq8: bool = False, A: np.ndarray | None = None,
             Q: np.ndarray | None = None) -> np.ndarray:
        """S' = E{e' e'^T} given E{e e^T} = S and each sink's selection moments."""
        n = self.n
        Sext = sla.block_diag(S, self.noise)
        Tbar = self.T.copy()
        for (row, Ad, Delta), (m, _) in zip(self.random, moments, strict=True):
            Tbar[row:row + n] += Ad @ (np.asarray(m)[:, None] * Delta)
        out = Tbar @ Sext @ Tbar.T
        for (row, Ad, Delta), (m, second) in zip(self.random, moments, strict=True):
            cov_h = np.asarray(second) - np.outer(m, m)
            if np.any(cov_h):
                out[row:row + n, row:row + n] += Ad @ (cov_h * (Delta @ Sext @ Delta.T)) @ Ad.T
        out = 0.5 * (out + out.T)
        if printed_eq8 and A is not None and Q is not None:
            # eq. (8) as printed: P_ij(t) = G_Ki [Q_w + A P_ij(t-1) A^T] G_Ki^T
            for i in range(self.L):
                for j in range(self.L):
                    if i != j:
                        ri, rj = self.loc[i][0], self.loc[j][0]
                        G = self.filters[i].G
                        out[ri:ri + n, rj:rj + n] = G @ (Q + A @ S[ri:ri + n, rj:rj + n]
                                                          @ A.T) @ G.T
        return out

    def xi(self, S: np.ndarray) -> np.ndarray:
        n = self.n
        return np.block([[S[r:r + n, c:c + n] for c in (x[0] for x in self.cse)]
                         for r in (x[0] for x in self.cse)])


def stationary_fusion(setup: DkfeSetup, moments: Sequence[Moments] | None = None, *,
                      schedules: Sequence[np.ndarray] | None = None,
                      send: str = "posterior", compensation: str = "paper",
                      printed_eq8: bool = False, tol: float = 1e-12,
                      max_steps: int = 20000, method: str = "auto") -> StationaryFusion:
    """Steady-state Xi, P and weights of the DKFE under one reading of the model.

    With the default arguments this is the paper's model, eqs. (5)-(7), (15), (21)-(23),
    with steady-state local gains (59): the limit Theorem 3 speaks of, computed here
    independently of :class:`netsim.estimators.fusion.FusionCovariance` (which iterates
    with the time-varying gains from x(0)).

    Parameters
    ----------
    setup : DkfeSetup
    moments : list of (E{h}, E{h h^T}), one per sink, optional
        The selection's moments (default: each sink's categorical scheme). The error
        recursion is linear in h with h independent of the errors, so any selection
        law enters only through these two moments.
    schedules : list of numpy.ndarray, shape (p_i, n), optional
        Deterministic periodic selections instead: sink i sends the pattern
        ``schedules[i][(t - d_i) mod p_i]`` at the centre's step t (round robin).
    send : ``posterior`` (the sink sends x-hat_i(t|t), eq. 15) or ``prior``
        (x-hat_i(t|t-1)).
    compensation : ``paper`` (A x-hat^c_i(t-d_i-1), eq. 15) or ``same-time``
        (x-hat^c_i(t-d_i), no prediction; an index shift of f_i(t) = t - d_i - 1).
    printed_eq8 : bool
        Replace the local cross-covariances by eq. (8) as printed,
        G_Ki [Q_w + A P_ij A^T] G_Ki^T (G_Ki on both sides).
    tol, max_steps : convergence test (relative max-entry change) and step limit.
    method : ``auto`` or ``iterate``
        ``auto`` solves a deterministic (scheduled, or zero-variance) selection exactly
        as a Stein equation over one period; ``iterate`` always iterates the second
        moment (for the random readings both are the iteration).
    """
    if method not in ("auto", "iterate"):
        raise ValueError(f"method must be 'auto' or 'iterate', got {method!r}")
    model = _StationaryModel(setup, send, compensation)
    L, n = setup.n_sinks, setup.n
    if schedules is not None:
        scheds = [np.atleast_2d(np.asarray(s, dtype=float)) for s in schedules]
        period = 1
        for s in scheds:
            period = period * len(s) // math.gcd(period, len(s))

        def moments_at(t: int) -> list[Moments]:
            out = []
            for i, s in enumerate(scheds):
                h = s[(t - setup.delays[i]) % len(s)]
                out.append((h, np.outer(h, h)))
            return out
    else:
        period = 1
        fixed = list(moments) if moments is not None else [selection_moments(s)
                                                           for s in setup.selections]
        if len(fixed) != L:
            raise ValueError(f"need moments for {L} sinks, got {len(fixed)}")

        def moments_at(t: int) -> list[Moments]:
            return fixed
    deterministic = schedules is not None or all(
        np.allclose(sec, np.outer(m, m)) for m, sec in moments_at(0))
    if deterministic and not printed_eq8 and method == "auto":
        return _stein_steady_state(model, moments_at, period, L, n)
    S = np.zeros((model.N, model.N))
    # a steady state is a few times the noise propagated over the slowest decay; far
    # beyond that the iteration is diverging
    blow_up = 1e14 * max(1.0, float(np.max(np.abs(model.noise))))
    history: list[np.ndarray] = []
    converged = False
    t = 0
    with np.errstate(over="ignore", invalid="ignore"):
        for t in range(1, max_steps + 1):
            S = model.step(S, moments_at(t), printed_eq8, setup.A, setup.Q)
            if not np.all(np.isfinite(S)) or np.max(np.abs(S)) > blow_up:
                break
            history.append(S)
            if len(history) > period:
                old = history.pop(0)
                change = float(np.max(np.abs(S - old)) / max(np.max(np.abs(S)), 1e-300))
                if change < tol and t > 2 * period + 10:
                    converged = True
                    break
    if not converged:
        nan = np.full((n, n), np.nan)
        return StationaryFusion(np.full((L * n, L * n), np.nan), nan, [nan] * L, t, False)
    # history holds the last `period` states, ending at step t; phase k = step t' mod period
    phases = []
    ordered = sorted(((t - (len(history) - 1 - k)) % period, S_k)
                     for k, S_k in enumerate(history))
    for _, S_k in ordered:
        Xi = model.xi(S_k)
        weights, P = _fusion_weights(Xi, L, n)
        phases.append((Xi, P, weights))
    Xi, P, weights = phases[0]
    return StationaryFusion(Xi, P, weights, t, True, phases)


def _stein_steady_state(model: _StationaryModel, moments_at: Any, period: int,
                        L: int, n: int) -> StationaryFusion:
    """Deterministic selections: the period map S -> M S M^T + C solved as a Stein
    equation (scipy.linalg.solve_discrete_lyapunov); no steady state if rho(M) >= 1."""
    N = model.N
    M = np.eye(N)
    C = np.zeros((N, N))
    for t in range(1, period + 1):
        mom = moments_at(t)
        Tbar = model.T.copy()
        for (row, Ad, Delta), (m, _) in zip(model.random, mom, strict=True):
            Tbar[row:row + n] += Ad @ (np.asarray(m)[:, None] * Delta)
        Tx, Tn = Tbar[:, :N], Tbar[:, N:]
        M = Tx @ M
        C = Tx @ C @ Tx.T + Tn @ model.noise @ Tn.T
    radius = float(np.max(np.abs(np.linalg.eigvals(M)))) if N else 0.0
    if radius >= 1.0:
        nan = np.full((n, n), np.nan)
        return StationaryFusion(np.full((L * n, L * n), np.nan), nan, [nan] * L, period,
                                False)
    S = sla.solve_discrete_lyapunov(M, C)
    phases = []
    for t in range(period):
        if t:
            S = model.step(S, moments_at(t))
        S = 0.5 * (S + S.T)
        Xi = model.xi(S)
        weights, P = _fusion_weights(Xi, L, n)
        phases.append((Xi, P, weights))
    Xi, P, weights = phases[0]
    return StationaryFusion(Xi, P, weights, period, True, phases)


# ---------------------------------------------------------------------------
# (94): the readings of the selection model and which one gives the printed weights
# ---------------------------------------------------------------------------

#: Ways the printed Omega_1, Omega_2 could be labelled relative to ours.
_LABELS: dict[str, Any] = {
    "as printed": lambda W: list(W),
    "transposed": lambda W: [w.T for w in W],
    "sinks swapped": lambda W: list(W)[::-1],
    "sinks swapped, transposed": lambda W: [w.T for w in list(W)[::-1]],
}
#: Print precision of (94): an entry agrees when within half a unit of the 4th decimal.
EQ94_PRINT_TOL = 5e-5
#: A reading "gives the printed numbers" when every entry of Omega_1 and Omega_2 is
#: within this distance (it allows for a few digit swaps as found elsewhere in the
#: paper, all <= 0.0054) and at least 12 of the 16 entries of Omega_1 agree to print
#: precision.
EQ94_MATCH_TOL = 0.01
EQ94_MATCH_EXACT = 12


def _bernoulli_moments(g: np.ndarray) -> Moments:
    return g.copy(), np.outer(g, g) + np.diag(g * (1.0 - g))


def _subset_law_moments(patterns: np.ndarray, probs: np.ndarray) -> Moments:
    return probs @ patterns, (patterns.T * probs) @ patterns


def conditional_bernoulli(g: Sequence[float] | np.ndarray, r: int
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Independent Bernoulli(g_l) components conditioned on exactly r being sent.

    Returns (patterns (C(n, r), n) in lexicographic order, probabilities).
    """
    gv = np.asarray(g, dtype=float)
    pats = SelectionScheme.all_subsets(len(gv), r,
                                       [1.0] + [0.0] * (math.comb(len(gv), r) - 1)).patterns
    w = np.array([np.prod(np.where(h == 1, gv, 1.0 - gv)) for h in pats])
    if w.sum() <= 0:
        raise ValueError("no r-subset has positive probability")
    return pats, w / w.sum()


def sequential_without_replacement(g: Sequence[float] | np.ndarray, r: int
                                   ) -> tuple[np.ndarray, np.ndarray]:
    """r successive draws without replacement, component l drawn with weight g_l.

    Returns (patterns (C(n, r), n) in lexicographic order, probabilities).
    """
    gv = np.asarray(g, dtype=float)
    n = len(gv)
    law: dict[frozenset[int], float] = {}
    for order in itertools.permutations(range(n), r):
        p, left = 1.0, set(range(n))
        for k in order:
            total = float(sum(gv[j] for j in left))
            p *= float(gv[k]) / total if total > 0 else 0.0
            left.discard(k)
        key = frozenset(order)
        law[key] = law.get(key, 0.0) + p
    pats = np.array([[1.0 if k in s else 0.0 for k in range(n)]
                     for s in itertools.combinations(range(n), r)])
    return pats, np.array([law[frozenset(np.flatnonzero(h).tolist())] for h in pats])


def independent_indicators(selection: SelectionScheme) -> Moments:
    """Every sigma_h an independent Bernoulli(pi_h) ((21)-(22) without (12)): the sink
    sends the union of the patterns drawn (possibly none, possibly all)."""
    pats, pi = selection.patterns, selection.probabilities
    n = selection.n
    m, second = np.zeros(n), np.zeros((n, n))
    for mask in itertools.product((0, 1), repeat=len(pi)):
        p = float(np.prod([pi[k] if b else 1.0 - pi[k] for k, b in enumerate(mask)]))
        h = np.zeros(n)
        for k, b in enumerate(mask):
            if b:
                h = np.maximum(h, pats[k])
        m += p * h
        second += p * np.outer(h, h)
    return m, second


def weighted_round_robin(selection: SelectionScheme, period: int = 10) -> np.ndarray:
    """A deterministic schedule sending pattern h round(period pi_h) times per period
    (in pattern order, interleaved by largest remaining share). Shape (period, n)."""
    counts = np.round(selection.probabilities * period).astype(int)
    if counts.sum() != period:
        raise ValueError(f"probabilities {selection.probabilities.tolist()} are not "
                         f"multiples of 1/{period}")
    rows, sent = [], np.zeros(len(counts))
    for k in range(period):
        h = int(np.argmax(counts * (k + 1) / period - sent))
        sent[h] += 1
        rows.append(selection.patterns[h])
    return np.array(rows)


@dataclass(frozen=True)
class Eq94Reading:
    """One reading of Example 2's model and the weights it gives.

    Attributes
    ----------
    name, axis, description : str
        ``axis`` is ``selection`` (how the components are chosen), ``formula`` (which
        covariance formula or estimate enters), ``delays`` (another d_1, d_2) or
        ``search`` (the closest categorical law with the printed marginals (92)).
    delays : tuple of int
    weights : list of numpy.ndarray, each (n, n)
        Omega_1, Omega_2 (for a periodic reading: the phase closest to (94)).
    distance : float
        max |ours - printed| over the entries of Omega_1 and Omega_2, labelled as printed.
    best_label, best_distance : str, float
        The labelling of :data:`_LABELS` with the smallest distance, and that distance.
    exact_entries : int
        Entries of Omega_1 (of 16) within print precision (5e-5) under ``best_label``.
    trace_P : float
        tr P of the fused estimate under the reading (nan if it has no steady state).
    converged : bool
    note : str
    """

    name: str
    axis: str
    description: str
    delays: tuple[int, ...]
    weights: list[np.ndarray]
    distance: float
    best_label: str
    best_distance: float
    exact_entries: int
    trace_P: float
    converged: bool
    note: str = ""

    @property
    def matches(self) -> bool:
        """Whether the reading gives the printed (94) (:data:`EQ94_MATCH_TOL`)."""
        return bool(self.converged and self.best_distance <= EQ94_MATCH_TOL
                    and self.exact_entries >= EQ94_MATCH_EXACT)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "axis": self.axis, "description": self.description,
                "delays": list(self.delays),
                "weights": [np.asarray(w).tolist() for w in self.weights],
                "distance": self.distance, "best_label": self.best_label,
                "best_distance": self.best_distance, "exact_entries": self.exact_entries,
                "trace_P": self.trace_P, "converged": self.converged,
                "matches": self.matches, "note": self.note}


@dataclass
class Eq94Readings:
    """Every reading tried for (94), with its distance to the printed weights."""

    rows: list[Eq94Reading]
    printed: tuple[np.ndarray, np.ndarray]

    @property
    def matching(self) -> list[Eq94Reading]:
        """The readings that give the printed numbers (empty: none does)."""
        return [r for r in self.rows if r.matches]

    @property
    def closest(self) -> Eq94Reading:
        """The reading with the smallest distance under its best labelling."""
        ok = [r for r in self.rows if r.converged]
        return min(ok, key=lambda r: r.best_distance)

    def row(self, name: str) -> Eq94Reading:
        """The reading called ``name`` (KeyError if absent)."""
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        c = self.closest
        return {"rows": [r.to_dict() for r in self.rows],
                "printed": [p.tolist() for p in self.printed],
                "match_tolerance": EQ94_MATCH_TOL, "match_exact_entries": EQ94_MATCH_EXACT,
                "matching": [r.name for r in self.matching],
                "closest": {"name": c.name, "distance": c.best_distance,
                            "label": c.best_label}}

    def format_text(self) -> str:
        head = (f"{'reading':<44} {'d':>5} {'as printed':>10} {'best':>7} "
                f"{'labelling':<26} {'exact':>5} {'tr P':>8}")
        lines = ["(94): readings of Example 2's selection model and the distance of their "
                 "steady weights to the printed Omega_1, Omega_2",
                 "(max |ours - printed| over all 32 entries; 'exact': entries of Omega_1 "
                 "agreeing to 4 decimals; a match needs <= "
                 f"{EQ94_MATCH_TOL} and >= {EQ94_MATCH_EXACT} exact)", "", head,
                 "-" * len(head)]
        for r in self.rows:
            d = ",".join(str(v) for v in r.delays)
            if not r.converged:
                lines.append(f"{r.name:<44} {d:>5} {'no steady state':>18}")
                continue
            lines.append(f"{r.name:<44} {d:>5} {r.distance:>10.4f} {r.best_distance:>7.4f} "
                         f"{r.best_label:<26} {r.exact_entries:>5} {r.trace_P:>8.4f}")
        c = self.closest
        lines += ["", f"closest: {c.name} (d = {list(c.delays)}, {c.best_label}): "
                  f"{c.best_distance:.4f}, {c.exact_entries} of 16 entries of Omega_1 exact",
                  "readings that give the printed numbers: "
                  + (", ".join(r.name for r in self.matching) or "none")]
        return "\n".join(lines) + "\n"


def _score(weights: Sequence[np.ndarray], printed: Sequence[np.ndarray]
           ) -> tuple[float, str, float, int]:
    """(distance as printed, best labelling, its distance, exact entries of Omega_1)."""
    dist = {}
    for label, f in _LABELS.items():
        V = f(weights)
        dist[label] = max(float(np.max(np.abs(V[k] - printed[k]))) for k in range(len(V)))
    best = min(dist, key=lambda k: dist[k])
    V = _LABELS[best](weights)
    exact = int(np.sum(np.abs(V[0] - printed[0]) <= EQ94_PRINT_TOL))
    return dist["as printed"], best, dist[best], exact


def _reading(name: str, axis: str, description: str, setup: DkfeSetup,
             printed: Sequence[np.ndarray], note: str = "", *,
             weights_from: Any = None, **kw: Any) -> Eq94Reading:
    kw.setdefault("tol", 1e-10)  # distances are reported to 4 decimals
    st = stationary_fusion(setup, **kw)
    n, L = setup.n, setup.n_sinks
    if not st.converged:
        nan = [np.full((n, n), np.nan)] * L
        return Eq94Reading(name, axis, description, setup.delays, nan, math.nan, "",
                           math.nan, 0, math.nan, False, note or "no steady state")
    candidates = [(P, W if weights_from is None else weights_from(Xi, P))
                  for Xi, P, W in st.phases]
    scored = [(_score(W, printed), P, W) for P, W in candidates]
    (dist, label, best, exact), P, W = min(scored, key=lambda x: x[0][2])
    if len(candidates) > 1:
        note = (note + "; " if note else "") + (
            f"periodic: phase closest of {len(candidates)} (distances "
            + ", ".join(f"{s[0][2]:.3f}" for s in scored) + ")")
    return Eq94Reading(name, axis, description, setup.delays, [np.asarray(w) for w in W],
                       dist, label, best, exact, float(np.trace(P)), True, note)


#: The selection readings of :func:`eq94_readings` (names in the order tried).
EQ94_SELECTION_READINGS = (
    "categorical", "independent-bernoulli", "conditional-bernoulli",
    "sequential-without-replacement", "uniform-r-of-n", "independent-indicators",
    "expected-selection", "diagonal-moments", "most-probable-pattern", "round-robin",
    "weighted-round-robin")
#: The formula readings (each with the categorical selection unless named otherwise).
EQ94_FORMULA_READINGS = (
    "sink-sends-prediction", "compensation-same-time", "eq8-as-printed",
    "cross-covariances-ignored", "fuse-one-step-predictions", "eq79-as-printed",
    "bernoulli+compensation-same-time")


def _block_diagonal(Xi: np.ndarray, L: int, n: int) -> np.ndarray:
    out = np.zeros_like(Xi)
    for i in range(L):
        out[i * n:(i + 1) * n, i * n:(i + 1) * n] = Xi[i * n:(i + 1) * n, i * n:(i + 1) * n]
    return out


def eq94_readings(selection_readings: Sequence[str] = EQ94_SELECTION_READINGS,
                  formula_readings: Sequence[str] = EQ94_FORMULA_READINGS,
                  delay_grid: Sequence[int] = (0, 1, 2, 3),
                  delay_readings: Sequence[str] = ("categorical", "independent-bernoulli"),
                  marginal_search: bool = True, search_evaluations: int = 60
                  ) -> Eq94Readings:
    """Enumerate readings of Example 2's selection model and compare with (94).

    Each reading is a complete model of how Example 2's weights could have been
    computed; its steady-state weights come from :func:`stationary_fusion` and are
    compared with the printed Omega_1, Omega_2 entry by entry, also under relabellings
    (transposed, sinks swapped). Axes:

    - selection (``selection_readings``): the categorical choice of one of the
      Delta_i = 6 patterns (89) with the printed pi (91) (eqs. 11-13, 21-22; netsim's
      reading); independent Bernoulli components with the printed marginals gamma^i_l
      (92) (the sentence after (22)); Bernoulli(gamma) conditioned on r_i = 2 sent;
      two successive draws without replacement weighted by gamma; the uniform choice
      of an r-subset (pi ignored); independent indicators sigma_h ~ Bernoulli(pi_h)
      without (12) (the union of the drawn patterns is sent); the expectation
      H_i = E{H_i(t)} in place of the realised H_i(t) (a deterministic fractional
      selection: E{h h^T} = H_i H_i); Lambda_i = diag(gamma) (the pattern of (84) carried
      over; not a probability law); always the most probable pattern; round robin over
      the six patterns; a weighted round robin with the printed pi as shares.
      Normalising is a no-op here (sum pi = 1, sum gamma = r_i = 2 for both sinks); the
      time index of H_i(t - d_i) does not matter (the draws are i.i.d.).
    - formula (``formula_readings``): the sink sends its prediction x-hat_i(t|t-1)
      (the prior covariance P* enters); the compensation uses x-hat^c_i(t - d_i) without
      the prediction step (f_i(t) = t - d_i - 1 read as t - d_i); eq. (8) as printed
      (G_Ki on both sides); the cross-covariances Xi_ij (i != j) ignored; the fusion of
      one-step predictions; (79) as printed (P^-1 I_a^T Xi^-1); and the Bernoulli reading
      with the same-time compensation.
    - delays: every (d_1, d_2) in ``delay_grid`` squared for each of ``delay_readings``
      (off-by-one readings of the delays).
    - search (``marginal_search``): the categorical laws with exactly the printed
      marginals (92) form a polygon per sink (pi + a (e_12 + e_34) + b (e_13 + e_24)
      + c (e_14 + e_23), a + b + c = 0, pi >= 0); SLSQP finds the law closest to (94)
      in least squares (``search_evaluations`` model evaluations at most).

    Returns
    -------
    Eq94Readings
        One row per reading; ``matching`` lists the readings that give the printed
        numbers and ``closest`` the nearest one.
    """
    base = example2()
    printed = (PAPER_EX2_OMEGA[0], PAPER_EX2_OMEGA[1])
    sels = base.selections
    gammas = [s.mean for s in sels]
    rows: list[Eq94Reading] = []

    def selection_kw(name: str) -> tuple[dict[str, Any], str]:
        if name == "categorical":
            return {"moments": [selection_moments(s) for s in sels]}, (
                "one of the 6 patterns (89) drawn with the printed pi (91) (netsim)")
        if name == "independent-bernoulli":
            return {"moments": [_bernoulli_moments(g) for g in gammas]}, (
                "components independent Bernoulli(gamma) of (92) (sentence after (22))")
        if name == "conditional-bernoulli":
            return {"moments": [_subset_law_moments(*conditional_bernoulli(g, s.r))
                                for g, s in zip(gammas, sels, strict=True)]}, (
                "Bernoulli(gamma) conditioned on exactly r_i = 2 sent")
        if name == "sequential-without-replacement":
            return {"moments": [_subset_law_moments(*sequential_without_replacement(g, s.r))
                                for g, s in zip(gammas, sels, strict=True)]}, (
                "r_i = 2 draws without replacement, weights gamma")
        if name == "uniform-r-of-n":
            return {"moments": [_subset_law_moments(s.patterns, np.full(len(s.patterns),
                                                                        1 / len(s.patterns)))
                                for s in sels]}, "uniform over the 6 patterns (pi ignored)"
        if name == "independent-indicators":
            return {"moments": [independent_indicators(s) for s in sels]}, (
                "sigma_h independent Bernoulli(pi_h), (12) dropped, union sent")
        if name == "expected-selection":
            return {"moments": [(g, np.outer(g, g)) for g in gammas]}, (
                "E{H_i(t)} = H_i in place of H_i(t) (deterministic, fractional)")
        if name == "diagonal-moments":
            return {"moments": [(g, np.diag(g)) for g in gammas]}, (
                "Lambda_i = diag(gamma) as in (84) (not a probability law for r = 2)")
        if name == "most-probable-pattern":
            return {"schedules": [s.patterns[[int(np.argmax(s.probabilities))]]
                                  for s in sels]}, "always the most probable pattern"
        if name == "round-robin":
            return {"schedules": [s.patterns for s in sels]}, (
                "the 6 patterns in turn (period 6)")
        if name == "weighted-round-robin":
            return {"schedules": [weighted_round_robin(s) for s in sels]}, (
                "deterministic, pattern h 10 pi_h times per 10 steps")
        raise ValueError(f"unknown selection reading {name!r}; choose from "
                         f"{list(EQ94_SELECTION_READINGS)}")

    for name in selection_readings:
        kw, desc = selection_kw(name)
        rows.append(_reading(name, "selection", desc, base, printed, **kw))

    cat = selection_kw("categorical")[0]
    n, L = base.n, base.n_sinks
    formulas: dict[str, tuple[str, dict[str, Any]]] = {
        "sink-sends-prediction": ("the sink sends x-hat_i(t|t-1): P* enters in place of P",
                                  {**cat, "send": "prior"}),
        "compensation-same-time": ("x-hat^c_i(t - d_i) in (15), no prediction step",
                                   {**cat, "compensation": "same-time"}),
        "eq8-as-printed": ("P_ij by (8) as printed, G_Ki on both sides",
                           {**cat, "printed_eq8": True}),
        "cross-covariances-ignored": (
            "Xi_ij = 0 for i != j in (31)",
            {**cat, "weights_from": lambda Xi, P: _fusion_weights(
                _block_diagonal(Xi, L, n), L, n)[0]}),
        "fuse-one-step-predictions": (
            "weights of the predictions A x-hat^c_i(t): Xi_ij -> A Xi_ij A^T + Q_w",
            {**cat, "weights_from": lambda Xi, P: _fusion_weights(
                np.kron(np.eye(L), base.A) @ Xi @ np.kron(np.eye(L), base.A).T
                + np.kron(np.ones((L, L)), base.Q), L, n)[0]}),
        "eq79-as-printed": (
            "(79) literally: P^-1 I_a^T Xi^-1 (sums to P^-2, not I)",
            {**cat, "weights_from": lambda Xi, P: [
                w for w in np.split(np.linalg.inv(P) @ np.linalg.solve(
                    Xi, np.tile(np.eye(n), (L, 1))).T, L, axis=1)]}),
        "bernoulli+compensation-same-time": (
            "independent Bernoulli and x-hat^c_i(t - d_i) in (15)",
            {**selection_kw("independent-bernoulli")[0], "compensation": "same-time"}),
    }
    for name in formula_readings:
        if name not in formulas:
            raise ValueError(f"unknown formula reading {name!r}; choose from {list(formulas)}")
        desc, kw = formulas[name]
        rows.append(_reading(name, "formula", desc, base, printed, **kw))

    for name in delay_readings:
        kw, desc = selection_kw(name)
        for d1 in delay_grid:
            for d2 in delay_grid:
                if (d1, d2) == base.delays:
                    continue
                rows.append(_reading(f"{name} d=({d1},{d2})", "delays",
                                     f"{desc}, delays d = ({d1}, {d2})",
                                     base.with_delays((d1, d2)), printed, **kw))

    if marginal_search:
        rows.append(_marginal_search(base, printed, search_evaluations))
    return Eq94Readings(rows, printed)


#: Pair patterns (lexicographic, eq. 89) moved by the polygon directions a, b, c.
_PAIR_DIRECTIONS = np.array([[1, 0, 0, 0, 0, 1],    # a: e_12 + e_34
                             [0, 1, 0, 0, 1, 0],    # b: e_13 + e_24
                             [0, 0, 1, 1, 0, 0]],   # c: e_14 + e_23
                            dtype=float)


def _marginal_search(base: DkfeSetup, printed: Sequence[np.ndarray],
                     evaluations: int) -> Eq94Reading:
    """Closest categorical law with the printed marginals (92) (see eq94_readings).

    SLSQP on the squared distance (smooth), then Nelder-Mead on the max-entry distance
    from there (a law outside the polygon is penalised); ``evaluations`` bounds each.
    """
    from scipy import optimize

    minimize: Any = optimize.minimize
    sels = base.selections
    if any(s.n != 4 or s.r != 2 for s in sels):
        raise ValueError("the marginal search is for n = 4, r = 2 (Example 2)")
    dirs = np.vstack([_PAIR_DIRECTIONS[0] - _PAIR_DIRECTIONS[2],
                      _PAIR_DIRECTIONS[1] - _PAIR_DIRECTIONS[2]]).T  # (6, 2), c = -a - b

    def laws(x: np.ndarray) -> list[np.ndarray]:
        return [s.probabilities + dirs @ x[2 * i:2 * i + 2] for i, s in enumerate(sels)]

    count = [0]

    def weights_of(x: np.ndarray) -> list[np.ndarray] | None:
        count[0] += 1
        moments = [_subset_law_moments(s.patterns, np.clip(p, 0.0, None))
                   for s, p in zip(sels, laws(x), strict=True)]
        st = stationary_fusion(base, moments, tol=1e-10)
        return st.weights if st.converged else None

    def squared(x: np.ndarray) -> float:
        W = weights_of(x)
        if W is None:
            return 1e3
        return float(sum(np.sum((w - p) ** 2) for w, p in zip(W, printed, strict=True)))

    def worst(x: np.ndarray) -> float:
        outside = float(sum(-np.minimum(p, 0.0).sum() for p in laws(x)))
        if outside > 0:
            return 10.0 + outside
        W = weights_of(x)
        if W is None:
            return 1e3
        return max(float(np.max(np.abs(w - p))) for w, p in zip(W, printed, strict=True))

    cons = [{"type": "ineq", "fun": (lambda x, i=i: laws(x)[i])} for i in range(len(sels))]
    res = minimize(squared, np.zeros(2 * len(sels)), method="SLSQP", constraints=cons,
                   options={"maxiter": max(1, evaluations // 5), "ftol": 1e-10})
    x_ls = np.asarray(res.x)
    if worst(x_ls) >= 10.0:
        x_ls = np.zeros(2 * len(sels))
    res2 = minimize(worst, x_ls, method="Nelder-Mead",
                    options={"maxfev": max(1, evaluations), "xatol": 1e-5, "fatol": 1e-6,
                             "initial_simplex": x_ls + np.vstack([np.zeros(len(x_ls)),
                                                                  0.02 * np.eye(len(x_ls))])})
    x = np.asarray(res2.x) if res2.fun <= worst(x_ls) else x_ls
    probs = [np.clip(p, 0.0, None) / np.clip(p, 0.0, None).sum() for p in laws(x)]
    moments = [_subset_law_moments(s.patterns, p) for s, p in zip(sels, probs, strict=True)]
    law = "; ".join(f"pi^{i + 1} = " + ", ".join(f"{v:.3f}" for v in p)
                    for i, p in enumerate(probs))
    return _reading("categorical-closest-with-marginals-92", "search",
                    "categorical law with the printed marginals (92) closest to (94)",
                    base, printed, f"{law} ({count[0]} evaluations)", moments=moments)


# ---------------------------------------------------------------------------
# (71)-(72) against the delay: gamma_11 x d for Example 1, d per sink for Example 2
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class GammaDelayCell:
    """Example 1 at one (gamma_11, d_1): Theorem 2's LMIs beside the exact test.

    ``lmi71_72`` / ``lmi75``: cvxpy feasibility verified with numpy (None when the LMIs
    were not solved); ``radius``: rho(E{A_1(t) kron A_1(t)}), feasible iff < 1;
    ``c77``: rho(A^d (I - H_1) A) of (77).
    """

    gamma: float
    d: int
    radius: float
    c77: float
    lmi71_72: bool | None
    lmi75: bool | None
    status: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"gamma11": self.gamma, "d": self.d, "radius": self.radius, "c77": self.c77,
                "lmi71_72": self.lmi71_72, "lmi75": self.lmi75, "status": self.status}


@dataclass
class GammaDelayTable:
    """Table I extended over the delay: which gamma_11 satisfy (71)-(72) at each d_1.

    ``intervals[d]``: the gamma_11 ranges where the exact radius is < 1 (located on a
    grid and refined by bisection to 1e-9); ``best[d]``: (gamma_11, radius) of the
    smallest radius on that grid.
    """

    gammas: tuple[float, ...]
    delays: tuple[int, ...]
    cells: list[GammaDelayCell]
    intervals: dict[int, list[tuple[float, float]]]
    best: dict[int, tuple[float, float]]

    def cell(self, gamma: float, d: int) -> GammaDelayCell:
        for c in self.cells:
            if c.d == d and abs(c.gamma - gamma) < 1e-12:
                return c
        raise KeyError((gamma, d))

    @property
    def lmi_agrees_with_radius(self) -> bool:
        """Every solved LMI (71)-(72) verdict equals radius < 1."""
        return all(c.lmi71_72 == (c.radius < 1.0) for c in self.cells if c.lmi71_72 is not None)

    def to_dict(self) -> dict[str, Any]:
        return {"example": "dkfe-example1", "gammas": list(self.gammas),
                "delays": list(self.delays), "cells": [c.to_dict() for c in self.cells],
                "feasible_gamma_intervals": {str(d): [list(iv) for iv in ivs]
                                             for d, ivs in self.intervals.items()},
                "smallest_radius": {str(d): {"gamma11": g, "radius": r}
                                    for d, (g, r) in self.best.items()},
                "lmi_agrees_with_radius": self.lmi_agrees_with_radius}

    def format_text(self) -> str:
        lines = ["(71)-(72) on Example 1 over gamma_11 and the delay d_1 (Table I is d_1 = 0)",
                 "cell: LMI (71)-(72) verdict (cvxpy, verified) / exact mean-square radius "
                 "rho(E{A_1 kron A_1}) (feasible iff < 1)", ""]
        head = f"{'gamma11':>7} | " + " | ".join(f"{'d=' + str(d):^16}" for d in self.delays)
        lines += [head, "-" * len(head)]
        for g in self.gammas:
            cells = []
            for d in self.delays:
                c = self.cell(g, d)
                v = "-" if c.lmi71_72 is None else ("True" if c.lmi71_72 else "False")
                cells.append(f"{v:>5} {c.radius:>10.4f}")
            lines.append(f"{g:>7.2f} | " + " | ".join(cells))
        lines.append("")
        for d in self.delays:
            ivs = self.intervals[d]
            g, r = self.best[d]
            txt = (", ".join(f"[{a:.4f}, {b:.4f}]" for a, b in ivs) if ivs
                   else "none (no gamma_11 satisfies (71)-(72))")
            lines.append(f"d_1 = {d}: feasible gamma_11 {txt}; smallest radius {r:.4f} "
                         f"at gamma_11 = {g:.3f}")
        lines.append("LMI verdicts agree with the exact radius: "
                     f"{self.lmi_agrees_with_radius}")
        return "\n".join(lines) + "\n"


def _example1_radius(gamma: float, d: int, Phi: np.ndarray, A: np.ndarray) -> float:
    sel = SelectionScheme(np.eye(2), np.array([gamma, 1.0 - gamma]))
    return second_moment_radius(A, Phi, sel, d)


def gamma_delay_table(gammas: Sequence[float] = TABLE1_GAMMAS,
                      delays: Sequence[int] = (0, 1, 2, 3), lmis: bool = True,
                      resolution: int = 200, lmi75: bool = True) -> GammaDelayTable:
    """Theorem 2's conditions (71)-(72) on Example 1 for each gamma_11 and delay d_1.

    Example 1 (eqs. 81-82, 84) with d_1 = d: for each cell, the LMIs (71)-(72)
    (:func:`lmi_theorem2`, real cvxpy solves, verified with numpy) and (75)
    (:func:`lmi_75`, unless ``lmi75`` is False) when ``lmis``, the exact radius
    (:func:`second_moment_radius`) and (77). Then, from the exact radius on
    ``resolution`` + 1 grid points in [0, 1] refined by bisection, the feasible
    gamma_11 intervals per d (the equivalence of (71)-(72) and radius < 1 is shown in
    the module docstring and checked cell by cell).
    """
    from scipy.optimize import brentq

    base = example1(0.5)
    A = base.A
    Phi = steady_state_local_filter(A, base.C[0], base.Q, base.R[0]).Phi
    cells = []
    for g in gammas:
        for d in delays:
            sel = example1(float(g), int(d)).selections[0]
            radius = second_moment_radius(A, Phi, sel, int(d))
            l72 = l75 = None
            status = ""
            if lmis:
                r72 = lmi_theorem2(A, Phi, sel, int(d))
                l72, status = r72.feasible, r72.status
                l75 = lmi_75(A, Phi, sel, int(d)).feasible if lmi75 else None
            cells.append(GammaDelayCell(float(g), int(d), radius, condition_77(A, sel, int(d)),
                                        l72, l75, status))
    grid = np.linspace(0.0, 1.0, int(resolution) + 1)
    intervals: dict[int, list[tuple[float, float]]] = {}
    best: dict[int, tuple[float, float]] = {}
    for d in delays:
        d = int(d)
        r = np.array([_example1_radius(float(g), d, Phi, A) for g in grid])
        k = int(np.argmin(r))
        best[d] = (float(grid[k]), float(r[k]))

        def excess(g: float, d: int = d) -> float:
            return _example1_radius(g, d, Phi, A) - 1.0

        ivs = []
        inside = r < 1.0
        k = 0
        while k < len(grid):
            if not inside[k]:
                k += 1
                continue
            j = k
            while j + 1 < len(grid) and inside[j + 1]:
                j += 1
            lo = grid[k] if k == 0 else brentq(excess, grid[k - 1], grid[k], xtol=1e-9)
            hi = grid[j] if j == len(grid) - 1 else brentq(excess, grid[j], grid[j + 1],
                                                           xtol=1e-9)
            ivs.append((float(lo), float(hi)))
            k = j + 1
        intervals[d] = ivs
    return GammaDelayTable(tuple(float(g) for g in gammas), tuple(int(d) for d in delays),
                           cells, intervals, best)


@dataclass
class SinkDelayTable:
    """Example 2 (or another setup) with its printed selections: (71)-(72) per sink and d.

    ``rows``: dicts with sink, d, radius, c77, lmi71_72 (None if not solved);
    ``largest_delay[i]``: the largest d in the range with radius < 1 for sink i + 1 below
    which every d also has it (None if d = 0 already fails).
    """

    name: str
    delays: tuple[int, ...]
    rows: list[dict[str, Any]]
    largest_delay: list[int | None]

    def to_dict(self) -> dict[str, Any]:
        return {"example": self.name, "delays": list(self.delays), "rows": self.rows,
                "largest_feasible_delay": self.largest_delay}

    def format_text(self) -> str:
        lines = [f"(71)-(72) per sink of {self.name} against the delay d_i (printed "
                 "selection probabilities)", "",
                 f"{'d':>3} | " + " | ".join(f"{'sink ' + str(i + 1):^24}"
                                            for i in range(len(self.largest_delay))),
                 f"{'':>3} | " + " | ".join(f"{'LMI   radius    (77)':^24}"
                                            for _ in self.largest_delay)]
        for d in self.delays:
            cells = []
            for r in (x for x in self.rows if x["d"] == d):
                v = "-" if r["lmi71_72"] is None else ("True" if r["lmi71_72"] else "False")
                cells.append(f"{v:>5} {r['radius']:>8.4f} {r['c77']:>8.4f}  ")
            lines.append(f"{d:>3} | " + " | ".join(cells))
        lines.append("")
        lines += [f"sink {i + 1}: (71)-(72) hold for every d_i <= {v}" if v is not None
                  else f"sink {i + 1}: (71)-(72) fail already at d_i = 0"
                  for i, v in enumerate(self.largest_delay)]
        return "\n".join(lines) + "\n"


def sink_delay_table(setup: DkfeSetup | None = None, delays: Sequence[int] = range(16),
                     lmis: bool = True) -> SinkDelayTable:
    """For each sink of ``setup`` (default Example 2) and each d: (71)-(72), radius, (77)."""
    setup = example2() if setup is None else setup
    rows = []
    largest: list[int | None] = []
    for i in range(setup.n_sinks):
        Phi = steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i]).Phi
        sel = setup.selections[i]
        ok_upto: int | None = None
        broken = False
        for d in delays:
            radius = second_moment_radius(setup.A, Phi, sel, int(d))
            lmi = lmi_theorem2(setup.A, Phi, sel, int(d)).feasible if lmis else None
            rows.append({"sink": i + 1, "d": int(d), "radius": radius,
                         "c77": condition_77(setup.A, sel, int(d)), "lmi71_72": lmi})
            if radius < 1.0 and not broken:
                ok_upto = int(d)
            else:
                broken = True
        largest.append(ok_upto)
    rows.sort(key=lambda r: (r["d"], r["sink"]))
    return SinkDelayTable(setup.name, tuple(int(d) for d in delays), rows, largest)


# ---------------------------------------------------------------------------
# the transmitted dimension r_i
# ---------------------------------------------------------------------------


@dataclass
class DimensionSweep:
    """Steady DKFE error against the number r_i of components each sink sends.

    ``rows``: dicts with r (tuple per sink), law (``uniform`` over the C(n, r) subsets
    or ``printed``), radius per sink, trace_P (steady tr P of the DKFE, None without a
    steady state), trace_Xi per sink (steady tr Xi_ii, None if that CSE diverges).
    """

    name: str
    delays: tuple[int, ...]
    rows: list[dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        return {"example": self.name, "delays": list(self.delays), "rows": self.rows}

    def format_text(self) -> str:
        lines = [f"steady DKFE error against the transmitted dimension r_i ({self.name}, "
                 f"delays {list(self.delays)}; uniform choice of the r-subsets unless "
                 "'printed')", "",
                 f"{'r':>8} {'law':>8} | {'tr P (DKFE)':>12} | "
                 + " | ".join(f"{'tr Xi_' + str(i + 1) + str(i + 1):>10} {'radius':>7}"
                              for i in range(len(self.delays)))]
        for r in self.rows:
            tp = "diverges" if r["trace_P"] is None else f"{r['trace_P']:.4f}"
            cells = " | ".join(
                f"{('diverges' if x is None else f'{x:.4f}'):>10} {rad:>7.4f}"
                for x, rad in zip(r["trace_Xi"], r["radius"], strict=True))
            lines.append(f"{str(tuple(r['r'])):>8} {r['law']:>8} | {tp:>12} | {cells}")
        return "\n".join(lines) + "\n"


def dimension_sweep(setup: DkfeSetup | None = None,
                    r_values: Sequence[int] | None = None,
                    same_r: bool = False) -> DimensionSweep:
    """Steady-state tr P and tr Xi_ii for every combination of r_1, ..., r_L.

    Each sink sends r_i of the n components, chosen uniformly among the C(n, r_i)
    subsets (the paper prints probabilities only for r_i = 2, eq. 91); r_i = n (no
    reduction) is the reference. For ``setup`` (default Example 2) its own selections
    are added as the ``printed`` row. ``same_r``: only r_1 = ... = r_L. Steady states
    from :func:`stationary_fusion`; a CSE whose error chain is not mean-square stable
    has no steady state (trace None).
    """
    setup = example2() if setup is None else setup
    n, L = setup.n, setup.n_sinks
    rs = list(range(1, n + 1)) if r_values is None else [int(r) for r in r_values]
    for r in rs:
        if not 1 <= r <= n:
            raise ValueError(f"r must be in 1..{n}, got {r}")
    combos = [(r,) * L for r in rs] if same_r else list(itertools.product(rs, repeat=L))
    phis = [steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i]).Phi
            for i in range(L)]

    def row(sels: Sequence[SelectionScheme], law: str) -> dict[str, Any]:
        from dataclasses import replace

        radius = [second_moment_radius(setup.A, phis[i], s, setup.delays[i])
                  for i, s in enumerate(sels)]
        st = stationary_fusion(replace(setup, selections=tuple(sels)), tol=1e-10)
        traces: list[float | None] = []
        for i in range(L):
            if st.converged:
                traces.append(float(np.trace(st.Xi[i * n:(i + 1) * n, i * n:(i + 1) * n])))
            else:
                traces.append(None)
        return {"r": [s.r for s in sels], "law": law, "radius": radius,
                "trace_P": float(np.trace(st.P)) if st.converged else None,
                "trace_Xi": traces, "converged": st.converged}

    rows = []
    for combo in combos:
        sels = [SelectionScheme.all_subsets(n, r, [1 / math.comb(n, r)] * math.comb(n, r))
                for r in combo]
        rows.append(row(sels, "uniform"))
    rows.append(row(list(setup.selections), "printed"))
    return DimensionSweep(setup.name, setup.delays, rows)
