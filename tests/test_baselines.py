"""The standard distributed filters (issue 31): kcf, ci and diffkf.

Each family (netsim.estimators.baselines) is checked against an independent
implementation of its paper's algorithm written here in plain numpy (covariance-form
Kalman updates where the family uses the information form, the diffusion KF's
incremental update as the paper's sequential loop over the neighbourhood), run on the
same measurements as the event kernel with zero link delay; then the rules for late,
lost and reordered messages, in the kernel and on single agents. No family has a
batched form, so there is no engine comparison.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from netsim.estimators.registry import AgentSetup, ObserverTap, get_family

import netsim

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("kcf", "ci", "diffkf")

_SMALL = """
name = "baselines-small"
[run]
steps = {steps}
trials = 1
seed = 5
estimators = ["kcf", "ci", "diffkf"]
[plant]
# a damped rotation, three agents each measuring one direction (none observes alone
# through the rotation's period: each does, but the network shares the work)
A = [[0.9553364891, -0.2955202067, 0.1], [0.2955202067, 0.9553364891, 0.0],
     [0.0, 0.0, 1.02]]
C = [[[1.0, 0.0, 0.0]], [[0.5, 0.8660254038, 0.0]], [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]]
Q = 0.01
R = [[[0.02]], [[0.03]], [[0.05, 0.01], [0.01, 0.04]]]
x0_cov = 2.0
[network]
topology = "edges"
edges = [[0, 1], [1, 2], [2, 0], [1, 0]]
weights = "random"
seed = 3
{delays}
"""
_ZERO_DELAY = '[delays]\nmodel = "homogeneous"\ntau = 0'
# reordering (each message its own delay, 0..3 steps) and Bernoulli loss
_LOSSY = ('[links]\n'
          'delay = { distribution = "uniform", low = 0, high = 3, unit = "steps", '
          'mode = "asynchronous" }\nloss = { model = "bernoulli", p = 0.3 }')


def _scenario(tmp_path: Path, delays: str, steps: int = 40):
    path = tmp_path / "small.toml"
    path.write_text(_SMALL.format(steps=steps, delays=delays))
    return netsim.load_scenario(path)


class _Recorder(ObserverTap):
    """Keeps the kernel's measurements and delivery decisions."""

    def __init__(self) -> None:
        super().__init__(None)
        self.measurements: list[list[np.ndarray]] = []
        self.deliveries: list[tuple[int, int, int, bool]] = []

    def on_plant(self, k, state, measurements):
        self.measurements.append([np.array(y, dtype=float) for y in measurements])

    def on_delivered(self, message, accepted):
        self.deliveries.append((int(message.sender), int(message.receiver),
                                int(message.sent_step), bool(accepted)))


def _kernel(scenario, family: str):
    recorder = _Recorder()
    result = netsim.run_one(scenario, family, trial=0, observer=recorder)
    return result, recorder


# -- independent implementations of the papers' algorithms (plain numpy) -------------


def _model(scenario):
    p = scenario.plant
    A, Q = np.asarray(p.A, float), np.asarray(p.Q, float)
    C = [np.asarray(c, float) for c in p.C]
    R = [np.asarray(r, float).reshape(len(c), len(c)) for r, c in zip(p.R, C, strict=True)]
    W = np.asarray(scenario.weights.toarray() if hasattr(scenario.weights, "toarray")
                   else scenario.weights, float)
    N = scenario.n_agents
    nbrs = [sorted(j for j in scenario.graph.predecessors(i) if j != i) for i in range(N)]
    return A, Q, C, R, W, nbrs, np.asarray(p.x0_mean, float), np.asarray(p.x0_cov, float)


def _kalman(x, P, C, R, y):
    """Covariance-form measurement update (the Kalman gain P C^T (C P C^T + R)^-1)."""
    S = C @ P @ C.T + R
    K = np.linalg.solve(S, C @ P).T
    return x + K @ (y - C @ x), P - K @ C @ P


def _reference_kcf(scenario, ys, eps=0.1):
    """Olfati-Saber 2009, Algorithm 1, every node synchronous; netsim reports at step t
    the local update of x-bar_i(t) with the own z_i(t)."""
    A, Q, C, R, _W, nbrs, x0, P0 = _model(scenario)
    N = len(C)
    xbar = [x0.copy() for _ in range(N)]
    Pbar = [P0.copy() for _ in range(N)]
    out = []
    for t in range(len(ys)):
        u = [C[i].T @ np.linalg.inv(R[i]) @ ys[t][i] for i in range(N)]
        U = [C[i].T @ np.linalg.inv(R[i]) @ C[i] for i in range(N)]
        out.append([_kalman(xbar[i], Pbar[i], C[i], R[i], ys[t][i])[0] for i in range(N)])
        new = []
        for i in range(N):
            J = [i, *nbrs[i]]
            y = sum(u[j] for j in J)
            S = sum(U[j] for j in J)
            M = np.linalg.inv(np.linalg.inv(Pbar[i]) + S)
            gamma = eps / (1 + np.sqrt(np.trace(M.T @ M)))
            xhat = xbar[i] + M @ (y - S @ xbar[i]) + gamma * M @ sum(
                (xbar[j] - xbar[i] for j in nbrs[i]), np.zeros(len(x0)))
            new.append((A @ xhat, A @ M @ A.T + Q))
        xbar = [x for x, _ in new]
        Pbar = [P for _, P in new]
    return np.array(out)


def _reference_ci(scenario, ys):
    """Battistelli & Chisci 2014, CI with L = 1; netsim reports the corrected pair."""
    A, Q, C, R, W, nbrs, x0, P0 = _model(scenario)
    N = len(C)
    Om = [np.linalg.inv(P0) for _ in range(N)]
    q = [o @ x0 for o in Om]
    out = []
    for t in range(len(ys)):
        Om0 = [Om[i] + C[i].T @ np.linalg.inv(R[i]) @ C[i] for i in range(N)]
        q0 = [q[i] + C[i].T @ np.linalg.inv(R[i]) @ ys[t][i] for i in range(N)]
        out.append([np.linalg.solve(Om0[i], q0[i]) for i in range(N)])
        for i in range(N):
            Omf = sum(W[i, j] * Om0[j] for j in [i, *nbrs[i]])
            qf = sum(W[i, j] * q0[j] for j in [i, *nbrs[i]])
            Om[i] = np.linalg.inv(A @ np.linalg.inv(Omf) @ A.T + Q)
            q[i] = Om[i] @ A @ np.linalg.inv(Omf) @ qf
    return np.array(out)


def _reference_diffkf(scenario, ys):
    """Cattivelli & Sayed 2010, Algorithm 1 (sequential incremental update over the
    neighbourhood, diffusion with c_li = p_il); netsim reports at step t the local update
    of (A psi_i(t-1), A P_i(t-1) A^T + Q) with the own y_i(t)."""
    A, Q, C, R, W, nbrs, x0, P0 = _model(scenario)
    N = len(C)
    xp = [x0.copy() for _ in range(N)]
    Pp = [P0.copy() for _ in range(N)]
    local = [(x0.copy(), P0.copy()) for _ in range(N)]
    out = []
    for t in range(len(ys)):
        out.append([_kalman(*local[i], C[i], R[i], ys[t][i])[0] for i in range(N)])
        psi, P = [], []
        for i in range(N):
            x, Pi = xp[i], Pp[i]
            for j in [*nbrs[i][::-1], i]:  # any order: the paper's loop over N_k
                x, Pi = _kalman(x, Pi, C[j], R[j], ys[t][j])
            psi.append(x)
            P.append(Pi)
        for i in range(N):
            xhat = sum(W[i, j] * psi[j] for j in [i, *nbrs[i]])
            xp[i], Pp[i] = A @ xhat, A @ P[i] @ A.T + Q
            local[i] = (A @ psi[i], A @ P[i] @ A.T + Q)
    return np.array(out)


_REFERENCES = {"kcf": _reference_kcf, "ci": _reference_ci, "diffkf": _reference_diffkf}


@pytest.mark.parametrize("family", FAMILIES)
def test_kernel_matches_the_papers_algorithm_without_delay(tmp_path, family):
    scenario = _scenario(tmp_path, _ZERO_DELAY)
    result, recorder = _kernel(scenario, family)
    assert len(recorder.measurements) == 41
    expected = _REFERENCES[family](scenario, recorder.measurements)
    np.testing.assert_allclose(result.estimates, expected, rtol=1e-9, atol=1e-9)
    # every message arrived in time and none was refused
    assert recorder.deliveries and all(ok for *_, ok in recorder.deliveries)


def test_the_reference_implementations_are_not_all_the_same(tmp_path):
    # the comparisons above could pass vacuously if the families ignored the network:
    # the three references differ from each other and from isolated Kalman filters
    scenario = _scenario(tmp_path, _ZERO_DELAY)
    _, recorder = _kernel(scenario, "ci")
    ys = recorder.measurements
    refs = {name: f(scenario, ys) for name, f in _REFERENCES.items()}
    local = netsim.run_one(scenario, "local-kf", trial=0).estimates
    for a in FAMILIES:
        assert np.max(np.abs(refs[a] - local)) > 1e-3, a
        for b in FAMILIES:
            if a < b:
                assert np.max(np.abs(refs[a] - refs[b])) > 1e-3, (a, b)


# -- late, lost and reordered messages --------------------------------------------


@pytest.mark.parametrize("family", FAMILIES)
def test_lossy_reordering_links_freshest_rule_and_bounded(tmp_path, family):
    scenario = _scenario(tmp_path, _LOSSY, steps=150)
    result, recorder = _kernel(scenario, family)
    # rule 1 in the kernel: a delivery is kept iff its stamp is above every stamp kept
    # before from the same sender (reordered and duplicate messages are refused)
    held: dict[tuple[int, int], int] = {}
    refused = 0
    for sender, receiver, stamp, accepted in recorder.deliveries:
        fresher = stamp > held.get((sender, receiver), -1)
        assert accepted == fresher, (sender, receiver, stamp)
        if accepted:
            held[(sender, receiver)] = stamp
        refused += not accepted
    assert refused > 0  # the links did reorder
    assert result.messages_dropped > 0  # and lose
    assert result.messages_discarded == refused
    # a stable plant (rho(A) = 1.02 observed by agent 2, the rest damped): bounded
    errors = result.squared_errors
    assert np.all(np.isfinite(errors))
    local = netsim.run_one(scenario, "local-kf", trial=0).squared_errors
    assert errors[75:].mean() < local[75:].mean()  # (0.13-0.18 against 0.44)


def _setup(n_agents=2, C=None, R=None, weights=(0.6, 0.4)):
    n = 2
    A = np.array([[1.0, 0.1], [0.0, 0.95]])
    C = np.zeros((0, n)) if C is None else C
    R = np.zeros((0, 0)) if R is None else R
    return AgentSetup(agent=0, n_agents=n_agents, in_neighbours=(1,), out_neighbours=(1,),
                      weights=np.array(weights), A=A, C=C, Q=0.02 * np.eye(n), R=R,
                      prior_mean=np.array([0.5, -0.2]), prior_cov=np.diag([1.0, 2.0]),
                      L=None, rng=np.random.default_rng(0), delay_bound=3,
                      sample_period=1.0)


def _classes():
    from netsim.estimators.baselines import (
        ConsensusOnInformationFilter,
        DiffusionKalmanFilter,
        KalmanConsensusFilter,
    )

    return {"kcf": KalmanConsensusFilter, "ci": ConsensusOnInformationFilter,
            "diffkf": DiffusionKalmanFilter}


@pytest.mark.parametrize("family", FAMILIES)
def test_never_heard_from_is_a_local_kalman_filter(family):
    # rule 4: with nothing received, each family is agent 0's own Kalman filter
    from netsim.estimators.kalman import LocalKalmanFilter

    C, R = np.array([[1.0, 0.5]]), np.array([[0.1]])
    setup = _setup(C=C, R=R)
    agent = _classes()[family](setup)
    kf = LocalKalmanFilter(setup.A, C, setup.Q, R, setup.prior_mean, setup.prior_cov)
    rng = np.random.default_rng(1)
    for k in range(25):
        y = rng.standard_normal(1)
        np.testing.assert_allclose(agent.step(k, y), kf.step(k, y), rtol=1e-9, atol=1e-12)
    assert agent.last_delays == {1: -1}


@pytest.mark.parametrize("family", FAMILIES)
def test_older_or_equal_stamps_are_discarded(family):
    agent = _classes()[family](_setup())
    agent.step(0, np.zeros(0))
    payload = agent.outgoing(0)
    assert agent.message_arrived(1, 2, payload)
    assert not agent.message_arrived(1, 2, payload)  # duplicate
    assert not agent.message_arrived(1, 1, payload)  # reordered: older
    assert not agent.message_arrived(7, 3, payload)  # not an in-neighbour
    assert agent.discarded == 2


def _payload(family, n, x, P):
    """A neighbour's message with estimate x (and covariance P for CI), no measurement."""
    if family == "ci":
        Omega = np.linalg.inv(P)
        return np.concatenate([Omega @ x, Omega.ravel()])
    return np.concatenate([x, np.zeros(n), np.zeros(n * n)])


@pytest.mark.parametrize("family", FAMILIES)
def test_a_late_estimate_is_predicted_with_the_model(family):
    # rule 2: a message stamped s, held when the recursion needs time t > s, acts as
    # the same estimate predicted to t (x <- A x, P <- A P A^T + Q per step) stamped t
    s_late, k = 1, 5
    need = k - 1  # the stamp whose estimate the recursion wants at step k
    late, fresh = _classes()[family](_setup()), _classes()[family](_setup())
    setup = _setup()
    x, P = np.array([1.0, -2.0]), np.diag([0.5, 0.25])
    xp, Pp = x.copy(), P.copy()
    for _ in range(need - s_late):
        xp, Pp = setup.A @ xp, setup.A @ Pp @ setup.A.T + setup.Q
    for step in range(k):
        late.step(step, np.zeros(0))
        fresh.step(step, np.zeros(0))
    assert late.message_arrived(1, s_late, _payload(family, 2, x, P))
    assert fresh.message_arrived(1, need, _payload(family, 2, xp, Pp))
    np.testing.assert_allclose(late.step(k, np.zeros(0)), fresh.step(k, np.zeros(0)),
                               rtol=1e-10, atol=1e-12)
    assert late.last_delays == {1: k - 1 - s_late} and fresh.last_delays == {1: k - 1 - need}
    # and the late estimate did move agent 0 (it is used, not dropped)
    alone = _classes()[family](_setup())
    for step in range(k + 1):
        last = alone.step(step, np.zeros(0))
    assert np.max(np.abs(last - late.estimate)) > 1e-6


@pytest.mark.parametrize("family", ["kcf", "diffkf"])
def test_a_late_measurement_is_never_fused(family):
    # rule 3: measurement information stamped before the time being fused is dropped:
    # a message carrying a huge information matrix changes nothing once it is late
    n, k = 2, 4
    quiet = np.concatenate([np.zeros(n), np.zeros(n), np.zeros(n * n)])
    loud = np.concatenate([np.zeros(n), 1e3 * np.ones(n), 1e4 * np.eye(n).ravel()])
    a, b = _classes()[family](_setup()), _classes()[family](_setup())
    for step in range(k):
        a.step(step, np.zeros(0))
        b.step(step, np.zeros(0))
    assert a.message_arrived(1, k - 2, quiet) and b.message_arrived(1, k - 2, loud)
    np.testing.assert_allclose(a.step(k, np.zeros(0)), b.step(k, np.zeros(0)),
                               rtol=1e-12, atol=1e-12)
    # in time (stamped k - 1 at step k) the same information is fused
    a2, b2 = _classes()[family](_setup()), _classes()[family](_setup())
    for step in range(k):
        a2.step(step, np.zeros(0))
        b2.step(step, np.zeros(0))
    a2.message_arrived(1, k - 1, quiet)
    b2.message_arrived(1, k - 1, loud)
    if family == "kcf":
        assert np.max(np.abs(a2.step(k, np.zeros(0)) - b2.step(k, np.zeros(0)))) > 1e-3
    else:  # the diffusion KF's incremental update of k - 1 shows in its psi
        a2.step(k, np.zeros(0))
        b2.step(k, np.zeros(0))
        assert np.max(np.abs(a2.outgoing(k)[:n] - b2.outgoing(k)[:n])) > 1e-3


# -- every consensus scenario, and the registry ---------------------------------------


_CONSENSUS_SCENARIOS = [
    "lcsys2022-homogeneous", "lcsys2022-heterogeneous", "lcsys2022-time-varying",
    str(ROOT / "examples" / "consensus-on-information.toml"),
    str(ROOT / "examples" / "rotation-uncompensated.toml"),
]


@pytest.mark.parametrize("scenario", _CONSENSUS_SCENARIOS)
def test_runs_on_every_consensus_scenario(scenario):
    result = netsim.run(scenario, steps=30, trials=1, estimators=list(FAMILIES),
                        engine="events")
    for family in FAMILIES:
        assert np.all(np.isfinite(result[family].squared_errors)), family


def test_families_are_declared_builtin():
    for name in FAMILIES:
        family = get_family(name)
        assert family.source == "builtin" and family.paper and not family.vectorised
        assert family.build.__module__ == "netsim.estimators.baselines"


def test_kcf_epsilon_option(tmp_path):
    from netsim.estimators.registry import FamilyContext, FamilyError

    scenario = _scenario(tmp_path, _ZERO_DELAY)
    plans = get_family("kcf").agents(FamilyContext(scenario.with_options("kcf", epsilon=0.5),
                                                   None, 0))
    assert plans[0].estimator.epsilon == 0.5
    with pytest.raises(FamilyError, match="options.kcf.eps"):
        get_family("kcf").agents(FamilyContext(scenario.with_options("kcf", eps=1), None, 0))
