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
  implementation; we could not reproduce (94) with other delay pairs or with
  independent Bernoulli selections (the claim after (22)). Our steady traces:
  tr P = 1.5318 (DKFE), tr Xi_11 = 2.0802, tr Xi_22 = 2.6639, ODKFE tr P_o = 0.5720,
  centralised Kalman filter 0.1350.
- Q_w (86) has rank one (Q_w = q q^T, q = (0.2, 0.5, 0.3, 0.4)); (58) still holds.

Example 1 with delays (not in the paper): for d_1 = 1 or 2 the compensating estimate
is mean-square unstable for every gamma_11 in {0.1, 0.3, 0.5, 0.7, 0.9} (exact radius
>= 1.02), although (77) holds for some of them (e.g. 0.78 at d_1 = 1, gamma_11 = 0.5):
(77) alone is not sufficient, as Theorem 3 (which also asks for (71)-(72)) implies.

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
