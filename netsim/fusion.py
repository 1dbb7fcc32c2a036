"""Fusion-centre runs in the SimPy kernel (dkfe paper) and the ``netsim fusion`` commands.

Agents of one trial (in this order, which is the order of their updates at each step):

- ``0 .. L-1``: the sink nodes (:class:`netsim.estimators.fusion.SinkNode`), each measuring its
  own sensor (the plant's C_i), running its local Kalman filter and choosing the r_i
  components to send;
- ``L``: the fusion centre (:class:`netsim.estimators.fusion.FusionCentre`) with the example's
  delays d_i; its estimate is the DKFE, and it also computes the SDKFE;
- ``L + 1``: the ODKFE centre (the same sinks' selections with d_i = 0);
- ``L + 2``: the centralised Kalman filter on all measurements.

Delays. The paper's centre uses at time t the selection sent at t - d_i (eq. 9). A
kernel link delivers a message sent at step s with delay d for the update at step
s + 1 + d, so sink i's link to the centre has delay d_i - 1 (:func:`fusion_delay_model`).
A sink with d_i = 0 has no link: the centre reads its payload directly at the same step
(the sinks update first). With ``time_varying=True`` each message on sink i's link gets
a uniform random delay in 0..d_i - 1 (:class:`netsim.models.dkfe.UniformLinkDelays`, messages
may be reordered) and the centre pads it back to d_i with its buffer (Remark 1): the
fused estimates are then identical to the constant-delay run with the same seed.

Randomness: trial t uses ``child_sequence(seed, "trial", t)``; the plant draws from its
stream ``"plant"``, sink i's selections from ``("sink", i, "selection")``, random link
delays from ``"delays/dkfe-link/<i>-<L>"``.

Example 2's steady-state weights differ from the printed (94) by up to 0.1326; the
comparison with every printed number is in the docstring of :mod:`netsim.models.dkfe`.
Issue 31: :func:`eq94_transient` (Algorithm 1's weights at finite t against (94)),
:func:`theorem4_check` (Theorem 4 on the exact covariance recursion),
:func:`remark1_check` (time-varying delays buffered to the bound against the constant
bound) and :func:`readings_report` (with the readings of (94), the gamma x d table and
the r_i sweep of :mod:`netsim.models.dkfe`).
Traces (``--trace``) are not supported for these runs: the payloads are selections, not
estimates.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from typing import Any, cast

import numpy as np
import scipy.linalg as sla

from netsim.estimators.fusion import (
    FusionCentre,
    FusionCovariance,
    LocalGains,
    SinkNode,
    SteadyState,
    covariances_for,
    run_lockstep,
    weights_as_printed_79,
)
from netsim.estimators.kalman import CentralizedKalmanFilter
from netsim.kernel import AgentSpec, Simulation, TrialResult
from netsim.models import dkfe as dk
from netsim.models.delays import DelayModel, FixedDelays
from netsim.models.jsonsafe import json_tree
from netsim.models.seeding import SeedLike, child_sequence, stream
from netsim.threads import single_threaded_blas

__all__ = [
    "fusion_delay_model",
    "build_fusion_agents",
    "FusionTrial",
    "run_fusion_trial",
    "FusionRunResult",
    "run_fusion",
    "check_fusion_run",
    "fusion_run_bytes",
    "FUSION_SECONDS_PER_TRIAL_STEP",
    "table1",
    "example2",
    "conditions",
    "example_setup",
    "mse_curves",
    "exact_trace_curves",
    "xi11_trace_curves",
    "covariance_norm_curves",
    "FusionTrajectories",
    "fusion_trajectories",
    "eq94_transient",
    "Theorem4Case",
    "Theorem4Check",
    "two_sink_example1",
    "theorem4_check",
    "Remark1Check",
    "remark1_check",
    "readings_report",
]

ESTIMATOR_NAMES = ("local", "cse", "dkfe", "sdkfe", "odkfe", "centralized-kf")



def _radius_parts(c: dict[str, Any]) -> str:
    """What sets a sink's mean-square radius (:func:`netsim.models.dkfe.second_moment_parts`)."""
    p = c["second_moment_parts"]
    return (f"{p['set_by']} (selection chain {_f(p['selection_chain'])}, local filter "
            f"{_f(p['local_filter'])})")

def _no_measurement(ys: Sequence[np.ndarray]) -> None:
    return None


def fusion_delay_model(setup: dk.DkfeSetup, trial_seed: SeedLike,
                       time_varying: bool = False) -> DelayModel:
    """Link delays sink i -> centre (agent L): d_i - 1, or uniform in 0..d_i - 1."""
    centre = setup.n_sinks
    links = {(i, centre): d - 1 for i, d in enumerate(setup.delays) if d >= 1}
    if time_varying:
        return dk.UniformLinkDelays(links, trial_seed)
    return FixedDelays(links, default=0)


@dataclass
class _Handles:
    sinks: list[SinkNode]
    centre: FusionCentre
    odkfe: FusionCentre
    ckf: CentralizedKalmanFilter


def build_fusion_agents(setup: dk.DkfeSetup, trial_seed: SeedLike, *,
                        covariance: FusionCovariance, odkfe_covariance: FusionCovariance,
                        gains: Sequence[LocalGains],
                        steady_weights: Sequence[np.ndarray] | None = None,
                        ) -> tuple[list[AgentSpec], _Handles]:
    """Agents of one trial (see the module docstring for ids and order)."""
    L = setup.n_sinks
    sinks = [SinkNode(i, setup.A, setup.C[i], gains[i], setup.selections[i], setup.x0_mean,
                      rng=stream(trial_seed, "sink", i, "selection")) for i in range(L)]
    direct = {i: sinks[i] for i in range(L) if setup.delays[i] == 0}
    centre = FusionCentre(setup.A, setup.delays, setup.selections, setup.x0_mean, covariance,
                          direct=direct, steady_weights=steady_weights)
    odkfe = FusionCentre(setup.A, [0] * L, setup.selections, setup.x0_mean, odkfe_covariance,
                         direct=dict(enumerate(sinks)))
    ckf = CentralizedKalmanFilter(setup.A, np.vstack(setup.C), setup.Q,
                                  sla.block_diag(*setup.R), setup.x0_mean, setup.x0_cov)
    agents = [AgentSpec(s, itemgetter(i), [L] if setup.delays[i] >= 1 else [])
              for i, s in enumerate(sinks)]
    agents.append(AgentSpec(centre, _no_measurement, ()))
    agents.append(AgentSpec(odkfe, _no_measurement, ()))
    agents.append(AgentSpec(ckf, np.concatenate, ()))
    return agents, _Handles(sinks, centre, odkfe, ckf)


@dataclass
class FusionTrial:
    """One kernel trial: the kernel's result and every estimate, (K+1, ...) arrays."""

    result: TrialResult
    states: np.ndarray
    local: np.ndarray  # (K+1, L, n)
    cse: np.ndarray  # (K+1, L, n)
    dkfe: np.ndarray
    sdkfe: np.ndarray | None
    odkfe: np.ndarray
    ckf: np.ndarray
    selections: np.ndarray  # (K+1, L)
    arrivals: dict[tuple[int, int], int]
    measurements: list[np.ndarray] = field(default_factory=list)


def run_fusion_trial(setup: dk.DkfeSetup, trial_seed: SeedLike, steps: int, *,
                     covariances: tuple[FusionCovariance, FusionCovariance,
                                        list[LocalGains]] | None = None,
                     steady_weights: Sequence[np.ndarray] | None = None,
                     time_varying: bool = False) -> FusionTrial:
    """Run one trial of the sinks, both centres and the centralised filter."""
    cov, ocov, gains = covariances if covariances is not None else covariances_for(setup)
    agents, h = build_fusion_agents(setup, trial_seed, covariance=cov, odkfe_covariance=ocov,
                                    gains=gains, steady_weights=steady_weights)
    sim = Simulation(setup.plant(), agents, fusion_delay_model(setup, trial_seed, time_varying),
                     stream(trial_seed, "plant"), record_delays=False)
    result = sim.run(steps)
    L = setup.n_sinks
    last = len(h.centre.history["dkfe"])
    return FusionTrial(
        result=result,
        states=result.states[:last],
        local=result.estimates[:last, :L],
        cse=np.stack(h.centre.history["cse"])[:, :, 0],
        dkfe=np.stack(h.centre.history["dkfe"])[:, 0],
        sdkfe=np.stack(h.centre.history["sdkfe"])[:, 0] if steady_weights is not None else None,
        odkfe=np.stack(h.odkfe.history["dkfe"])[:, 0],
        ckf=result.estimates[:last, L + 2],
        selections=np.stack([np.concatenate(s.selections) for s in h.sinks], axis=1),
        arrivals=dict(h.centre.arrivals),
        measurements=result.measurements,
    )


# ---------------------------------------------------------------------------
# analytics shared by the commands
# ---------------------------------------------------------------------------


def conditions(setup: dk.DkfeSetup, lmis: bool = True) -> list[dict[str, Any]]:
    """Per sink: (58), (77), (74), (76) (d_i = 0), the exact radius, (75), (71)-(72)
    (:func:`netsim.models.dkfe.sink_conditions`)."""
    return dk.sink_conditions(setup, lmis)


def _mat(M: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(M)]


def _f(v: Any, digits: int = 4) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "True" if v else "False"
    v = float(v)
    if not math.isfinite(v):
        return str(v)
    if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
        return f"{v:.3e}"
    return f"{v:.{digits}f}"


def _fmt_matrix(M: np.ndarray, indent: str = "    ") -> list[str]:
    return [indent + "[" + ", ".join(f"{v:8.4f}" for v in row) + "]" for row in np.asarray(M)]


# ---------------------------------------------------------------------------
# Monte Carlo
# ---------------------------------------------------------------------------


@dataclass
class FusionRunResult:
    """Monte Carlo of one example: empirical MSE and exact traces per estimator."""

    setup: dk.DkfeSetup
    steps: int
    trials: int
    seed: int
    engine: str
    time_varying: bool
    marks: list[int]
    empirical: dict[str, list[float]]  # name -> MSE at each mark
    standard_error: dict[str, list[float]]
    theory: dict[str, list[float]]  # name -> trace of the exact covariance at each mark
    steady: SteadyState
    odkfe_steady: SteadyState
    fused_gap: list[float]  # mean |x-hat(t) - x-hat_s(t)| (Er, Fig. 8) at each mark
    conditions: list[dict[str, Any]]
    diverged_trials: int = 0
    #: With ``curves=True``: per estimator the Monte Carlo MSE at every step 0..K.
    curves: dict[str, list[float]] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "example": self.setup.summary(),
            "steps": self.steps,
            "trials": self.trials,
            "seed": self.seed,
            "engine": self.engine,
            "time_varying_delays": self.time_varying,
            "marks": self.marks,
            "mse": json_tree(self.empirical),
            "mse_standard_error": json_tree(self.standard_error),
            "exact_trace": json_tree(self.theory),
            "steady_state": json_tree({
                "converged": self.steady.converged,
                "steps": self.steady.steps,
                "trace_P": float(np.trace(self.steady.P)),
                "trace_P_odkfe": float(np.trace(self.odkfe_steady.P)),
                "weights": [_mat(w) for w in self.steady.weights],
            }),
            "dkfe_minus_sdkfe_mean_abs": json_tree(self.fused_gap),
            "conditions": json_tree(self.conditions),
            "diverged_trials": self.diverged_trials,
            **({"mse_curves": json_tree(self.curves)} if self.curves is not None else {}),
        }

    def format_text(self) -> str:
        s = self.setup
        delays = ("time-varying delays padded to d_i" if self.time_varying
                  else "constant delays")
        conv = "converged" if self.steady.converged else "NOT converged"
        lines = [
            f"{s.name}: n = {s.n}, L = {s.n_sinks} sinks, delays d = {list(s.delays)}, "
            f"components sent r = {[x.r for x in s.selections]}",
            f"run: {self.steps} steps x {self.trials} trials, seed {self.seed}, engine "
            f"{self.engine}, {delays}",
            f"steady state (Theorem 3): {conv} "
            f"after {self.steady.steps} steps; tr P = {_f(np.trace(self.steady.P))}, "
            f"ODKFE tr P_o = {_f(np.trace(self.odkfe_steady.P))}",
            "",
            "stability per sink:",
        ]
        for c in self.conditions:
            lines.append(
                f"  sink {c['sink']} (d = {c['delay']}): (58) {_f(c['c58']['holds'])}; "
                f"(77) rho = {_f(c['c77_rho'])}; (74) zeta_inf = {_f(c['c74']['zeta_inf'])}, "
                f"zeta_2 = {_f(c['c74']['zeta_2'])}; exact MS radius of the error chain "
                f"(65) = {_f(c['second_moment_radius'])}"
                + (" = " + _radius_parts(c) if "second_moment_parts" in c else "")
                + (f"; LMI (71)-(72) {'feasible' if c['lmi71_72']['feasible'] else 'infeasible'}"
                   if "lmi71_72" in c else "")
            )
        lines.append("")
        head = f"{'estimator':<20}" + "".join(f"{'t=' + str(m):>22}" for m in self.marks)
        lines += ["MSE E||x - xhat||^2: Monte Carlo (exact trace of the covariance)", head,
                  "-" * len(head)]
        for name in self.empirical:
            row = f"{name:<20}"
            for e, t in zip(self.empirical[name], self.theory.get(name, []), strict=False):
                row += f"{_f(e):>12} ({_f(t)})".rjust(22)
            lines.append(row)
        lines.append("")
        lines.append("mean |DKFE - SDKFE| (Er_i, Fig. 8): "
                     + ", ".join(f"t={m}: {_f(g)}" for m, g in zip(self.marks, self.fused_gap,
                                                                   strict=True)))
        if self.diverged_trials:
            lines.append(f"{self.diverged_trials} trials diverged and are left out")
        lines.append("Monte Carlo standard errors are in --json (mse_standard_error).")
        return "\n".join(lines) + "\n"


def _exact_traces(setup: dk.DkfeSetup, cov: FusionCovariance, ocov: FusionCovariance,
                  steady: SteadyState, marks: Sequence[int]) -> dict[str, list[float]]:
    n, L = setup.n, setup.n_sinks
    ckf = LocalGains(setup.A, np.vstack(setup.C), setup.Q, sla.block_diag(*setup.R),
                     setup.x0_cov)
    out: dict[str, list[float]] = {}
    for i in range(L):
        out[f"sink {i + 1} local KF"] = [
            float(np.trace(cov.at(t).P_local[i * n:(i + 1) * n, i * n:(i + 1) * n]))
            for t in marks]
    for i in range(L):
        out[f"CSE {i + 1} (d={setup.delays[i]})"] = [
            float(np.trace(cov.at(t).Xi_block(i, i))) for t in marks]
    out["DKFE"] = [float(np.trace(cov.at(t).P)) for t in marks]
    out["SDKFE"] = [float(np.trace(cov.fused_covariance(t, steady.weights))) for t in marks]
    out["ODKFE (d=0)"] = [float(np.trace(ocov.at(t).P)) for t in marks]
    out["centralized KF"] = [float(np.trace(ckf.at(t)[2])) for t in marks]
    return out


def example_setup(example: str | dk.DkfeSetup, gamma11: float | None = None) -> dk.DkfeSetup:
    """The setup of an example name (or the setup itself), with Example 1's gamma_11.

    ``gamma11`` (Example 1 only, in [0, 1]; default 0.5) is the probability that the sink
    sends component 1 (eq. 84). ValueError for another example or a value out of range.
    """
    if isinstance(example, dk.DkfeSetup):
        if gamma11 is not None:
            raise ValueError("gamma11 applies to the named example dkfe-example1 only")
        return example
    setup = dk.get_example(example)
    if gamma11 is None:
        return setup
    if setup.name != "dkfe-example1":
        raise ValueError(f"gamma11 applies to dkfe-example1 only, not {setup.name}")
    g = float(gamma11)
    if not (math.isfinite(g) and 0.0 <= g <= 1.0):
        raise ValueError(f"gamma11 must be in [0, 1], got {gamma11}")
    return dk.example1(g)


def _lockstep_series(setup: dk.DkfeSetup, run: Any) -> dict[str, np.ndarray]:
    """Every estimator of a lock-step run by its report name, (K+1, B, n) arrays."""
    L = setup.n_sinks
    out = {**{f"sink {i + 1} local KF": run.local[:, i] for i in range(L)},
           **{f"CSE {i + 1} (d={setup.delays[i]})": run.cse[:, i] for i in range(L)},
           "DKFE": run.dkfe}
    if run.sdkfe is not None:
        out["SDKFE"] = run.sdkfe
    out["ODKFE (d=0)"] = run.odkfe
    out["centralized KF"] = run.ckf
    return out


def mse_curves(example: str | dk.DkfeSetup, steps: int, trials: int, seed: int = 0, *,
               gamma11: float | None = None) -> dict[str, list[float]]:
    """Monte Carlo MSE E||x(t) - x-hat(t)||^2 of every estimator at t = 0..steps.

    The lock-step engine (:func:`netsim.estimators.fusion.run_lockstep`, the same
    estimator objects as the kernel) without the SDKFE and without the stability
    conditions of :func:`run_fusion` (no LMIs): cheap enough for a sweep over gamma_11.
    Keys as in :attr:`FusionRunResult.empirical` (without ``SDKFE``).
    """
    setup = example_setup(example, gamma11)
    if steps < 1 or trials < 1:
        raise ValueError("steps and trials must be positive")
    with np.errstate(over="ignore", invalid="ignore"):
        run = run_lockstep(setup, int(steps), int(trials), seed)
        return {name: [float(v) for v in np.sum((run.states - est) ** 2, axis=-1).mean(axis=1)]
                for name, est in _lockstep_series(setup, run).items()}


#: Seconds per trial-step of a fusion run (measured 0.25 ms on the kernel engine and
#: 0.1 ms in lockstep for Example 2 on the reference machine; rounded up), for refusing
#: runs that would take longer than the time limit.
FUSION_SECONDS_PER_TRIAL_STEP = {"kernel": 5e-4, "lockstep": 2e-4}


def fusion_run_bytes(setup: dk.DkfeSetup, steps: int, trials: int) -> int:
    """Bytes a fusion run holds: the true states and every estimator's series
    ((K+1) x trials x n each: L local filters, L CSEs, DKFE, SDKFE, ODKFE, centralised
    KF), twice for the squared errors computed from them."""
    series = 2 * setup.n_sinks + 5
    return 2 * (steps + 1) * trials * setup.n * 8 * series


def check_fusion_run(setup: dk.DkfeSetup, steps: int, trials: int, engine: str) -> None:
    """Refuse a fusion run this machine cannot hold or finish within the time limit
    (:class:`netsim.budget.ResourceError`, one line naming ``--trials``), from the counts
    alone, before anything is allocated."""
    from netsim.budget import check_duration, check_memory

    check_memory(fusion_run_bytes(setup, steps, trials), "--trials",
                 f"the fusion run ({steps} steps, n = {setup.n}, {setup.n_sinks} sinks)",
                 trials, "lower --trials or --steps")
    check_duration(FUSION_SECONDS_PER_TRIAL_STEP[engine] * steps * trials, "--trials", trials,
                   f"the fusion run ({steps} steps, {engine} engine)",
                   "lower --trials or --steps")


@single_threaded_blas()
def run_fusion(example: str | dk.DkfeSetup = "dkfe-example2", steps: int = 100,
               trials: int = 50, seed: int = 0, *, engine: str = "kernel",
               time_varying: bool = False,
               progress: Callable[[int], None] | None = None,
               gamma11: float | None = None, curves: bool = False) -> FusionRunResult:
    """Monte Carlo of an example: sinks, DKFE, SDKFE, ODKFE and centralised KF.

    Parameters
    ----------
    example : name (``dkfe-example1``, ``dkfe-example2``) or a DkfeSetup
    gamma11 : float, optional
        Example 1's selection probability gamma_11 (eq. 84; default 0.5), see
        :func:`example_setup`.
    curves : bool
        Also keep every estimator's Monte Carlo MSE at every step (``curves``).
    steps, trials, seed : int
    engine : ``kernel`` (every trial in the SimPy kernel) or ``lockstep``
        (all trials at once, vectorised, the same estimator objects; constant delays).
    time_varying : bool
        Kernel only: random link delays in 0..d_i - 1, padded to d_i (Remark 1).
    progress : callable(int), optional
        Called with 1 after each kernel trial.
    """
    setup = example_setup(example, gamma11)
    if steps < 1 or trials < 1:
        raise ValueError("steps and trials must be positive")
    if engine not in ("kernel", "lockstep"):
        raise ValueError(f"engine must be 'kernel' or 'lockstep', got {engine!r}")
    if engine == "lockstep" and time_varying:
        raise ValueError("time-varying delays need the kernel engine")
    check_fusion_run(setup, steps, trials, engine)
    covs = covariances_for(setup)
    cov, ocov, _ = covs
    steady = cov.steady_state()
    osteady = ocov.steady_state()
    L = setup.n_sinks
    if engine == "lockstep":
        run = run_lockstep(setup, steps, trials, seed, steady_weights=steady.weights,
                           covariances=covs)
        states = run.states  # (K+1, B, n)
        series = _lockstep_series(setup, run)
        diverged = 0
    else:
        per: dict[str, list[np.ndarray]] = {}
        st: list[np.ndarray] = []
        diverged = 0
        for t in range(trials):
            tr = run_fusion_trial(setup, child_sequence(seed, "trial", t), steps,
                                  covariances=covs, steady_weights=steady.weights,
                                  time_varying=time_varying)
            if progress is not None:
                progress(1)
            if tr.result.diverged_at is not None:
                diverged += 1
                continue
            st.append(tr.states)
            for i in range(L):
                per.setdefault(f"sink {i + 1} local KF", []).append(tr.local[:, i])
            for i in range(L):
                per.setdefault(f"CSE {i + 1} (d={setup.delays[i]})", []).append(tr.cse[:, i])
            per.setdefault("DKFE", []).append(tr.dkfe)
            # steady weights given: the SDKFE is recorded
            per.setdefault("SDKFE", []).append(cast(np.ndarray, tr.sdkfe))
            per.setdefault("ODKFE (d=0)", []).append(tr.odkfe)
            per.setdefault("centralized KF", []).append(tr.ckf)
        if not st:
            raise RuntimeError("every trial diverged")
        states = np.stack(st, axis=1)
        series = {k: np.stack(v, axis=1) for k, v in per.items()}
    marks = sorted({0, 1, 2, steps // 10, steps // 4, steps // 2, steps})
    emp, se = {}, {}
    full: dict[str, list[float]] | None = {} if curves else None
    for name, est in series.items():
        sq = np.sum((states - est) ** 2, axis=-1)  # (K+1, B)
        if full is not None:
            full[name] = [float(v) for v in sq.mean(axis=1)]
        emp[name] = [float(sq[m].mean()) for m in marks]
        se[name] = [float(sq[m].std(ddof=1) / math.sqrt(sq.shape[1])) if sq.shape[1] > 1
                    else math.nan for m in marks]
    gap = np.sum(np.abs(series["DKFE"] - series["SDKFE"]), axis=-1)
    return FusionRunResult(
        setup=setup, steps=steps, trials=trials, seed=seed, engine=engine,
        time_varying=time_varying, marks=marks, empirical=emp, standard_error=se,
        theory=_exact_traces(setup, cov, ocov, steady, marks), steady=steady,
        odkfe_steady=osteady, fused_gap=[float(gap[m].mean()) for m in marks],
        conditions=conditions(setup), diverged_trials=diverged, curves=full,
    )


# ---------------------------------------------------------------------------
# curves of the exact covariances and one trial's trajectories (the paper's figures)
# ---------------------------------------------------------------------------


def exact_trace_curves(setup: dk.DkfeSetup, steps: int) -> dict[str, list[float]]:
    """Trace of every estimator's exact error covariance at t = 0..steps (Fig. 6).

    Keys as in :attr:`FusionRunResult.theory` (``CSE i (d=..)``, ``DKFE``, ``SDKFE``,
    ``ODKFE (d=0)``, local and centralised Kalman filters); each a list of steps + 1.
    """
    cov, ocov, _ = covariances_for(setup)
    return _exact_traces(setup, cov, ocov, cov.steady_state(), range(int(steps) + 1))


def xi11_trace_curves(gammas: Sequence[float], steps: int, delay: int = 0
                      ) -> dict[float, list[float]]:
    """Example 1: Tr Xi_11(t), t = 0..steps, of the compensating estimate per gamma_11.

    The exact covariance recursion (:class:`netsim.estimators.fusion.FusionCovariance`)
    of :func:`netsim.models.dkfe.example1` (Figs. 3-4 of the dkfe paper); values may
    grow without bound (to inf) for the gamma_11 where (75) fails.
    """
    out: dict[float, list[float]] = {}
    with np.errstate(over="ignore", invalid="ignore"):
        for g in gammas:
            cov, _, _ = covariances_for(dk.example1(float(g), delay))
            out[float(g)] = [float(np.trace(cov.at(t).Xi_block(0, 0)))
                             for t in range(int(steps) + 1)]
    return out


def covariance_norm_curves(setup: dk.DkfeSetup, steps: int,
                           initial_covariances: Sequence[np.ndarray]
                           ) -> list[dict[str, list[float]]]:
    """||P(t)||_2 and ||Omega_i(t)||_2, t = 0..steps, for each initial covariance of x(0).

    Fig. 7 of the dkfe paper (Theorem 3: the same limits from every initial value).
    Returns one dict per initial covariance with keys ``P`` and ``Omega_1``..``Omega_L``.
    """
    from dataclasses import replace

    out = []
    for P0 in initial_covariances:
        P0 = np.asarray(P0, dtype=float)
        cov, _, _ = covariances_for(replace(setup, x0_cov=P0))
        row: dict[str, list[float]] = {"P": []}
        for i in range(setup.n_sinks):
            row[f"Omega_{i + 1}"] = []
        for t in range(int(steps) + 1):
            snap = cov.at(t)
            row["P"].append(float(np.linalg.norm(snap.P, 2)))
            for i, w in enumerate(snap.weights):
                row[f"Omega_{i + 1}"].append(float(np.linalg.norm(w, 2)))
        out.append(row)
    return out


@dataclass
class FusionTrajectories:
    """One trial's state and fused estimates, (K+1, n) arrays (Figs. 5 and 8)."""

    states: np.ndarray
    dkfe: np.ndarray
    sdkfe: np.ndarray
    odkfe: np.ndarray
    cse: np.ndarray  # (K+1, L, n)


def fusion_trajectories(setup: dk.DkfeSetup, steps: int, seed: int = 0,
                        trial: int = 0) -> FusionTrajectories:
    """Trial ``trial`` of :func:`run_fusion` (same seed, kernel engine): x(t), the DKFE,
    the SDKFE with the steady-state weights (79), the ODKFE and the CSEs."""
    covs = covariances_for(setup)
    steady = covs[0].steady_state()
    tr = run_fusion_trial(setup, child_sequence(seed, "trial", trial), steps,
                          covariances=covs, steady_weights=steady.weights)
    assert tr.sdkfe is not None
    return FusionTrajectories(tr.states, tr.dkfe, tr.sdkfe, tr.odkfe, tr.cse)


# ---------------------------------------------------------------------------
# commands: Table I and Example 2
# ---------------------------------------------------------------------------


def table1(json: bool = False) -> tuple[dict[str, Any], str]:
    """Example 1's Table I: conditions (75), (76), (74) for gamma_11 = 0, 0.1, ..., 1.

    Returns (data, text); ``json`` is accepted for symmetry with the other commands
    (both are always built).
    """
    rows = dk.table1_rows()
    d1 = dk.example1_paper_d1_check()
    setup = dk.example1()
    ss = dk.steady_state_local_filter(setup.A, setup.C[0], setup.Q, setup.R[0])
    data = {
        "example": "dkfe-example1",
        "delay": 0,
        "rows": json_tree(rows),
        "all_agree_with_paper": all(r["agrees"] for r in rows),
        "paper_D1_check": d1,
        "G_K1": _mat(ss.G),
        "Phi_K1": _mat(ss.Phi),
        "paper_eq83": _mat(dk.PAPER_EX1_GK),
        "paper_eq83_minus_Phi_K1_max_abs": float(np.max(np.abs(dk.PAPER_EX1_GK - ss.Phi))),
    }
    head = (f"{'gamma11':>7} | {'(75) LMI':>9} {'MS radius':>10} | {'(76) lmax':>10} {'ok':>5} | "
            f"{'zeta_inf':>9} {'zeta_2':>7} {'(74)':>5} | {'paper (75)/(76)/(74)':>21} | agree")
    lines = [
        "Table I (dkfe paper, Example 1, d_1 = 0): stability conditions over gamma_11",
        "(75): LMI f(D) - D < 0 solved with cvxpy and verified with numpy; MS radius: "
        "rho(E{A_1(t) kron A_1(t)}) (exact test, ours);",
        "(76): lambda_max(A^T (I - H_1) A) < 1; (74): zeta_inf < 1 and zeta_2 < 1",
        "",
        head,
        "-" * len(head),
    ]
    for r in rows:
        p = r["paper"]
        ptxt = "-" if p is None else f"{p['c75']}/{p['c76']}/{p['c74']}"
        lines.append(
            f"{r['gamma11']:>7.1f} | {_f(r['c75']):>9} {_f(r['second_moment_radius']):>10} | "
            f"{_f(r['c76_value']):>10} {_f(r['c76']):>5} | {_f(r['c74']['zeta_inf']):>9} "
            f"{_f(r['c74']['zeta_2']):>7} {_f(r['c74']['holds']):>5} | {ptxt:>21} | "
            f"{'yes' if r['agrees'] else 'NO'}"
        )
    lines += [
        "",
        f"all entries agree with the paper's Table I: {data['all_agree_with_paper']}",
        f"paper's printed D_1 (gamma_11 = 0.5): min eig D_1 = {_f(d1['min_eig_D'])}, "
        f"lambda_max(f(D_1) - D_1) = {_f(d1['max_eig_f_minus_D'])} -> "
        f"{'a valid certificate' if d1['certificate'] else 'NOT a certificate'}",
        "eq. (83) printed as G_K1 is Phi_K1 = G_K1 A with digit swaps: ours Phi_K1 =",
        *_fmt_matrix(ss.Phi),
        f"  (largest difference to the printed matrix "
        f"{_f(data['paper_eq83_minus_Phi_K1_max_abs'])}); G_K1 = I - K_1 C_1 =",
        *_fmt_matrix(ss.G),
    ]
    return data, "\n".join(lines) + "\n"


def example2(json: bool = False) -> tuple[dict[str, Any], str]:
    """Example 2: steady-state weights (79), condition (77) and the other checks.

    Returns (data, text) comparing with the printed (88), (93), (94), (95).
    """
    setup = dk.example2()
    n, L = setup.n, setup.n_sinks
    cov, ocov, _ = covariances_for(setup)
    steady = cov.steady_state()
    osteady = ocov.steady_state()
    conds = conditions(setup)
    phis = [dk.steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i]).Phi
            for i in range(L)]
    omega_diff = [np.asarray(steady.weights[i]) - dk.PAPER_EX2_OMEGA[i] for i in range(L)]
    printed79 = weights_as_printed_79(steady.Xi, steady.P, L, n)
    ckf = LocalGains(setup.A, np.vstack(setup.C), setup.Q, sla.block_diag(*setup.R),
                     setup.x0_cov)
    ckf_P = ckf.at(2000)[2]
    data = {
        "example": "dkfe-example2",
        "delays": list(setup.delays),
        "steady_state": {"converged": steady.converged, "steps": steady.steps,
                         "trace_P": float(np.trace(steady.P)),
                         "trace_Xi": [float(np.trace(steady.Xi[i * n:(i + 1) * n,
                                                              i * n:(i + 1) * n]))
                                      for i in range(L)],
                         "trace_P_odkfe": float(np.trace(osteady.P)),
                         "trace_P_centralized_kf": float(np.trace(ckf_P))},
        "weights": [_mat(w) for w in steady.weights],
        "paper_weights_eq94": [_mat(w) for w in dk.PAPER_EX2_OMEGA],
        "weights_minus_paper_max_abs": [float(np.max(np.abs(d))) for d in omega_diff],
        "weights_sum_minus_I_max_abs": float(np.max(np.abs(sum(steady.weights) - np.eye(n)))),
        "eq79_as_printed_sum_minus_I_max_abs": float(np.max(np.abs(sum(printed79) - np.eye(n)))),
        "c77_rho": [c["c77_rho"] for c in conds],
        "paper_c77_rho_eq93": list(dk.PAPER_EX2_RHO77),
        "zeta_inf": [c["c74"]["zeta_inf"] for c in conds],
        "paper_zeta_inf_eq95": list(dk.PAPER_EX2_ZETA_INF),
        "Phi_K": [_mat(p) for p in phis],
        "Phi_K_minus_paper_eq88_max_abs": [float(np.max(np.abs(p - q)))
                                           for p, q in zip(phis, dk.PAPER_EX2_PHI_K,
                                                           strict=True)],
        "conditions": json_tree(conds),
    }
    lines = [
        "Example 2 (dkfe paper, 4-bus grid, d_1 = 1, d_2 = 2): steady-state fusion",
        f"Xi(t) {'converged' if steady.converged else 'did NOT converge'} after {steady.steps} "
        f"steps; tr P = {_f(np.trace(steady.P))}, tr Xi_11 = "
        f"{_f(data['steady_state']['trace_Xi'][0])}, tr Xi_22 = "
        f"{_f(data['steady_state']['trace_Xi'][1])}; ODKFE (no delay) tr P_o = "
        f"{_f(np.trace(osteady.P))}; centralised KF tr P = {_f(np.trace(ckf_P))}",
        "",
    ]
    for i in range(L):
        lines.append(f"Omega_{i + 1} (ours, eq. 79 with P, i.e. the limit of eq. 31):")
        lines += _fmt_matrix(steady.weights[i])
        lines.append(f"Omega_{i + 1} printed (94):")
        lines += _fmt_matrix(dk.PAPER_EX2_OMEGA[i])
        lines.append(f"  largest difference {_f(data['weights_minus_paper_max_abs'][i])}")
    lines += [
        f"sum of our weights - I: {_f(data['weights_sum_minus_I_max_abs'])}; eq. (79) as "
        f"printed (P^-1 I_a^T Xi^-1) sums to I only up to "
        f"{_f(data['eq79_as_printed_sum_minus_I_max_abs'])} (typo: P, not P^-1)",
        "",
        "condition (77) rho(A^d_i (I - H_i) A) < 1:",
    ]
    for i in range(L):
        c = conds[i]
        lines.append(
            f"  sink {i + 1} (d = {setup.delays[i]}): {_f(c['c77_rho'])} (printed (93): "
            f"{dk.PAPER_EX2_RHO77[i]}, difference "
            f"{_f(abs(c['c77_rho'] - dk.PAPER_EX2_RHO77[i]))}) -> "
            f"{'holds' if c['c77_rho'] < 1 else 'fails'}")
    lines.append("condition (74) zeta_inf (printed (95)), zeta_2:")
    for i in range(L):
        c = conds[i]["c74"]
        lines.append(
            f"  sink {i + 1}: zeta_inf = {_f(c['zeta_inf'])} (printed "
            f"{dk.PAPER_EX2_ZETA_INF[i]}), zeta_2 = {_f(c['zeta_2'])} -> (74) "
            f"{'holds' if c['holds'] else 'fails'}")
    lines.append("Theorem 2 LMIs (71)-(72) (M(1,1) read from (121)), LMI (75) with general d, "
                 "and the exact mean-square radius:")
    for i in range(L):
        c = conds[i]
        lines.append(
            f"  sink {i + 1}: (71)-(72) {'feasible' if c['lmi71_72']['feasible'] else 'infeasible'}"
            f" ({c['lmi71_72']['status']}), (75) "
            f"{'feasible' if c['lmi75']['feasible'] else 'infeasible'}, mean-square radius "
            f"of the centre's error chain (65) {_f(c['second_moment_radius'])} = "
            + _radius_parts(c) + f"; (58) {_f(c['c58']['holds'])}")
    lines.append("Phi_K (88): largest difference to the printed matrices "
                 + ", ".join(_f(v) for v in data["Phi_K_minus_paper_eq88_max_abs"]))
    return data, "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------
# (94) from finite-horizon weights; Theorem 4; Remark 1 (issue 31)
# ---------------------------------------------------------------------------


def eq94_transient(scales: Sequence[float] = (0.01, 1.0, 100.0), steps: int = 300
                   ) -> list[dict[str, Any]]:
    """Could (94) be Algorithm 1's Omega_i(t) at a finite t rather than the limit?

    For x(0) ~ N(0, s I) with each s in ``scales``, the exact weights Omega_i(t) of
    Example 2 (:class:`netsim.estimators.fusion.FusionCovariance`, time-varying gains)
    for t = 0..steps; returns per scale the t with the smallest max |ours - printed|
    and that distance.
    """
    from dataclasses import replace

    setup = dk.example2()
    out = []
    for s in scales:
        cov, _, _ = covariances_for(replace(setup, x0_cov=float(s) * np.eye(setup.n)))
        dist = [max(float(np.max(np.abs(w - p)))
                    for w, p in zip(cov.at(t).weights, dk.PAPER_EX2_OMEGA, strict=True))
                for t in range(int(steps) + 1)]
        k = int(np.argmin(dist))
        out.append({"x0_cov_scale": float(s), "steps": int(steps), "closest_t": k,
                    "distance": dist[k], "distance_at_end": dist[-1]})
    return out


@dataclass
class Theorem4Case:
    """One instance of Theorem 4: which sinks satisfy (71)-(72) and what P(t) does."""

    name: str
    claim: str
    example: str
    delays: tuple[int, ...]
    radius: list[float]
    lmi71_72: list[bool]
    c77: list[float]
    trace_P: list[float]  # exact tr P(t), t = 0..steps
    trace_Xi: list[list[float]]  # per sink, exact tr Xi_ii(t)
    growth: float  # max tr P over the last quarter / max over the second quarter
    # below a convergent tr Xi_ii(t) (57), or growth < 1.001
    bounded: bool
    eq57_holds: bool  # tr P(t) <= tr Xi_ii(t) for every sink with a finite Xi_ii
    cse_limits: list[float | None] = field(default_factory=list)  # steady tr Xi_ii alone
    limit_gap: float | None = None  # |tr P(T) from two initial covariances|
    stationary_gap: float | None = None  # |tr P(T) - tr P of stationary_fusion|
    monte_carlo: dict[str, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return json_tree({k: getattr(self, k) for k in (
            "name", "claim", "example", "delays", "radius", "lmi71_72", "c77", "growth", "bounded",
            "eq57_holds", "cse_limits", "limit_gap", "stationary_gap", "monte_carlo")}
            | {"trace_P_end": self.trace_P[-1],
               "trace_Xi_end": [x[-1] for x in self.trace_Xi]})


@dataclass
class Theorem4Check:
    """Theorem 4 (C.1), (C.2) on Example 2 with chosen delays, plus a control."""

    steps: int
    cases: list[Theorem4Case]

    def case(self, name: str) -> Theorem4Case:
        return next(c for c in self.cases if c.name == name)

    @property
    def c1_holds(self) -> bool:
        c = self.case("C.1")
        return bool(c.bounded and c.eq57_holds)

    @property
    def c2_holds(self) -> bool:
        c = self.case("C.2")
        tol = 1e-5 * abs(c.trace_P[-1])
        return bool(c.bounded and c.limit_gap is not None and c.limit_gap < tol
                    and c.stationary_gap is not None and c.stationary_gap < tol)

    def to_dict(self) -> dict[str, Any]:
        return {"steps": self.steps, "c1_holds": self.c1_holds, "c2_holds": self.c2_holds,
                "cases": [c.to_dict() for c in self.cases]}

    def format_text(self) -> str:
        lines = [f"Theorem 4 (exact covariance recursion, {self.steps} steps)", ""]
        for c in self.cases:
            lines.append(f"{c.name} {c.example}, delays {list(c.delays)}: {c.claim}")
            lines.append("  (71)-(72) per sink: " + ", ".join(
                f"sink {i + 1} {'holds' if ok else 'fails'} (radius {r:.4f}, (77) {q:.4f})"
                for i, (ok, r, q) in enumerate(zip(c.lmi71_72, c.radius, c.c77,
                                                   strict=True))))
            lines.append(f"  tr P(T) = {_f(c.trace_P[-1])}, growth over the last quarter "
                         f"{_f(c.growth)} -> {'bounded' if c.bounded else 'UNBOUNDED'}; "
                         "tr Xi_ii(T) = " + ", ".join(_f(x[-1]) for x in c.trace_Xi)
                         + f"; (57) tr P <= tr Xi_ii: {c.eq57_holds}; steady tr Xi_ii of "
                         "each sink satisfying (71)-(72) alone: "
                         + ", ".join(_f(v) for v in c.cse_limits))
            if c.limit_gap is not None:
                lines.append(f"  two initial covariances: |tr P_a(T) - tr P_b(T)| = "
                             f"{_f(c.limit_gap)}; steady state (stationary_fusion) gap "
                             f"{_f(c.stationary_gap)}")
            if c.monte_carlo:
                m = c.monte_carlo
                lines.append(f"  Monte Carlo at T: MSE {_f(m['mse'])} +- {_f(m['se'])} "
                             f"(exact {_f(m['exact'])}, z = {_f(m['z'], 2)})")
        lines += ["", f"(C.1) holds: {self.c1_holds}; (C.2) holds: {self.c2_holds}"]
        return "\n".join(lines) + "\n"


def two_sink_example1(gammas: tuple[float, float], delays: tuple[int, int] = (0, 0)
                      ) -> dk.DkfeSetup:
    """Example 1's plant (81) watched by two sinks with the sensor (82), independent
    noises, selection probabilities gamma_11 = ``gammas[i]`` (84) and delays ``delays``
    (a small instance for Theorem 4; not in the paper)."""
    from dataclasses import replace

    one = dk.example1(gammas[0], delays[0])
    two = dk.example1(gammas[1], delays[1])
    return replace(one, name="dkfe-example1-two-sinks",
                   description=(f"Example 1's plant with two sinks sending one component, "
                                f"gamma_11 = {list(gammas)}, d = {list(delays)}"),
                   C=one.C + two.C, R=one.R + two.R, delays=(delays[0], delays[1]),
                   selections=one.selections + two.selections)


def _theorem4_case(name: str, claim: str, setup: dk.DkfeSetup, steps: int,
                   trials: int, seed: int, two_starts: bool) -> Theorem4Case:
    from dataclasses import replace

    n, L, delays = setup.n, setup.n_sinks, setup.delays
    phis = [dk.steady_state_local_filter(setup.A, setup.C[i], setup.Q, setup.R[i]).Phi
            for i in range(L)]
    radius = [dk.second_moment_radius(setup.A, phis[i], setup.selections[i], delays[i])
              for i in range(L)]
    lmi = [dk.lmi_theorem2(setup.A, phis[i], setup.selections[i], delays[i]).feasible
           for i in range(L)]
    c77 = [dk.condition_77(setup.A, setup.selections[i], delays[i]) for i in range(L)]
    with np.errstate(over="ignore", invalid="ignore"):
        cov, _, _ = covariances_for(setup)
        trP = [float(np.trace(cov.at(t).P)) for t in range(steps + 1)]
        trXi = [[float(np.trace(cov.at(t).Xi_block(i, i))) for t in range(steps + 1)]
                for i in range(L)]
    q = max(steps // 4, 1)
    growth = max(trP[-q:]) / max(max(trP[q:2 * q]), 1e-300)
    eq57 = all(trP[t] <= x[t] * (1 + 1e-9) + 1e-12 for x in trXi for t in range(steps + 1)
               if math.isfinite(x[t]))
    # the bound of (C.1): each sink satisfying (71)-(72) alone has a steady CSE
    # (stationary_fusion of that sink alone); tr P(t) <= tr Xi_ii(t) -> that limit
    limits: list[float | None] = []
    for i in range(L):
        if not lmi[i]:
            limits.append(None)
            continue
        alone = replace(setup, C=(setup.C[i],), R=(setup.R[i],), delays=(delays[i],),
                        selections=(setup.selections[i],))
        st = dk.stationary_fusion(alone, tol=1e-10)
        limits.append(float(np.trace(st.Xi)) if st.converged else None)
    converging = [i for i in range(L) if limits[i] is not None
                  and abs(trXi[i][-1] - cast(float, limits[i])) <= 1e-3 * cast(float, limits[i])]
    bounded = bool(eq57 and converging) or bool(math.isfinite(growth) and growth < 1.001)
    case = Theorem4Case(name, claim, setup.name, delays, radius, lmi, c77, trP, trXi, float(growth),
                        bounded, bool(eq57))
    case.cse_limits = limits
    if two_starts:
        cov_b, _, _ = covariances_for(replace(setup, x0_cov=100.0 * np.eye(n)))
        case.limit_gap = abs(float(np.trace(cov_b.at(steps).P)) - trP[-1])
        st = dk.stationary_fusion(setup)
        case.stationary_gap = (abs(float(np.trace(st.P)) - trP[-1]) if st.converged
                               else math.inf)
    if trials > 1:
        with np.errstate(over="ignore", invalid="ignore"):
            run = run_lockstep(setup, steps, trials, seed)
        sq = np.sum((run.states[steps] - run.dkfe[steps]) ** 2, axis=-1)
        mse, se = float(sq.mean()), float(sq.std(ddof=1) / math.sqrt(len(sq)))
        case.monte_carlo = {"trials": trials, "mse": mse, "se": se, "exact": trP[-1],
                            "z": (mse - trP[-1]) / se if se > 0 else math.inf}
    return case


def theorem4_check(steps: int = 200, trials: int = 0, seed: int = 0,
                   c1: dk.DkfeSetup | None = None, c2: dk.DkfeSetup | None = None,
                   control: dk.DkfeSetup | None = None, with_control: bool = True
                   ) -> Theorem4Check:
    """Theorem 4 (C.1), (C.2) checked with the exact covariance recursion.

    (C.1): the DKFE's MSE is bounded once one sink's selection probabilities satisfy
    (71)-(72). Default instance ``c1``: Example 1's plant with two sinks, gamma_11 = 0.5
    for both, delays (0, 1) (:func:`two_sink_example1`): the same probabilities satisfy
    (71)-(72) at d = 0 and fail them at d = 1 (:func:`netsim.models.dkfe.gamma_delay_table`).
    (Example 2 with d = (1, 14) is such an instance too, but ten times as costly.)
    Checked: (57) tr P(t) <= tr Xi_ii(t) at every step, and the CSE of a sink
    satisfying (71)-(72) converges to its own steady state
    (:func:`netsim.models.dkfe.stationary_fusion` of that sink alone, within 0.1 %), so
    tr P(t) stays below a convergent sequence while the other CSE grows.
    (C.2): every sink satisfies (71)-(72) and (77) (default ``c2``: Example 2 as
    printed, d = (1, 2)): P(t) converges to one limit from x(0) ~ N(0, I) and
    N(0, 100 I), equal to the steady state computed independently. The control
    (default: the two-sink instance with d = (1, 1), no sink satisfies (71)-(72);
    outside the theorem) shows that the test sees growth. ``trials`` > 1 adds the
    lock-step Monte Carlo MSE of the DKFE at the last step beside the exact tr P.
    """
    if steps < 8:
        raise ValueError("steps must be at least 8")
    cases = [_theorem4_case("C.1", "one sink satisfies (71)-(72): the DKFE's MSE is bounded",
                            c1 if c1 is not None else two_sink_example1((0.5, 0.5), (0, 1)),
                            steps,
                            trials, seed, False),
             _theorem4_case("C.2", "every sink satisfies (71)-(72) and (77): P(t) converges "
                            "to a unique limit", c2 if c2 is not None else dk.example2(),
                            steps, trials, seed, True)]
    if with_control:
        cases.append(_theorem4_case(
            "control", "no sink satisfies (71)-(72) (outside the theorem)",
            control if control is not None else two_sink_example1((0.5, 0.5), (1, 1)), steps,
            0, seed, False))
    return Theorem4Check(int(steps), cases)


@dataclass
class Remark1Check:
    """Remark 1: time-varying delays d_i(t) <= d_i^u buffered to the bound.

    Per trial the kernel run with random link delays (uniform in 0..d_i - 1 steps,
    padded by the centre to d_i) against the constant-delay run with the same seed.
    """

    delays: tuple[int, ...]
    steps: int
    trials: int
    max_abs_difference: float  # over trials, steps, DKFE and CSEs
    buffered: int  # selections that arrived before their slot and waited
    reordered: int  # selections overtaken by a later one on the same link
    messages: int
    #: per sink (1-based): {arrival lag (usable step - sent step): count}
    arrival_lags: dict[int, dict[int, int]] = field(default_factory=dict)

    @property
    def identical(self) -> bool:
        return self.max_abs_difference == 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"delays": list(self.delays), "steps": self.steps, "trials": self.trials,
                "max_abs_difference": self.max_abs_difference, "buffered": self.buffered,
                "reordered": self.reordered, "messages": self.messages,
                "arrival_lags": {str(k): {str(a): b for a, b in v.items()}
                                 for k, v in self.arrival_lags.items()},
                "identical": self.identical}

    def format_text(self) -> str:
        return (f"Remark 1 (Example 2, bounds d = {list(self.delays)}, {self.trials} trials x "
                f"{self.steps} steps): {self.messages} selections, {self.buffered} arrived "
                f"early and waited in the centre's buffer, {self.reordered} were overtaken; "
                f"max |time-varying - constant| over the DKFE and CSEs = "
                f"{self.max_abs_difference:g} -> "
                f"{'identical' if self.identical else 'DIFFERENT'}\n")


def remark1_check(delays: tuple[int, ...] = (3, 2), steps: int = 40, trials: int = 3,
                  seed: int = 0) -> Remark1Check:
    """Run Example 2 with time-varying delays buffered to their bound and compare with
    the run at the constant bound (same seed): Remark 1 says they are the same model."""
    setup = dk.example2(delays=delays)
    covs = covariances_for(setup)
    worst, buffered, reordered, messages = 0.0, 0, 0, 0
    lags: dict[int, dict[int, int]] = {i + 1: {} for i in range(setup.n_sinks)}
    for t in range(int(trials)):
        s = child_sequence(seed, "trial", t)
        fixed = run_fusion_trial(setup, s, steps, covariances=covs)
        varying = run_fusion_trial(setup, s, steps, covariances=covs, time_varying=True)
        for a, b in ((fixed.dkfe, varying.dkfe), (fixed.cse, varying.cse)):
            worst = max(worst, float(np.max(np.abs(a - b))))
        messages += len(varying.arrivals)
        buffered += sum(1 for (i, sent), usable in varying.arrivals.items()
                        if usable < sent + setup.delays[i])
        for (i, sent), usable in varying.arrivals.items():
            lags[i + 1][usable - sent] = lags[i + 1].get(usable - sent, 0) + 1
        for i in range(setup.n_sinks):
            order = sorted((u, s_) for (j, s_), u in varying.arrivals.items() if j == i)
            sent_order = [s_ for _, s_ in order]
            reordered += sum(1 for k in range(1, len(sent_order))
                             if sent_order[k] < max(sent_order[:k]))
    return Remark1Check(tuple(int(d) for d in delays), int(steps), int(trials), worst,
                        buffered, reordered, messages,
                        {k: dict(sorted(v.items())) for k, v in lags.items()})


def readings_report(quick: bool = False) -> tuple[dict[str, Any], str]:
    """(94) readings, the gamma x d table, the r_i sweep, Theorem 4 and Remark 1.

    ``quick``: small settings (for tests); otherwise the reproduce settings. Returns
    (data, text).
    """
    if quick:
        readings = dk.eq94_readings(("categorical", "independent-bernoulli"), (),
                                    delay_readings=(), marginal_search=False)
        table = dk.gamma_delay_table((0.3, 0.6), (0, 1))
        sweep = dk.dimension_sweep(r_values=(2, 4), same_r=True)
        thm4 = theorem4_check(steps=60, c1=two_sink_example1((0.5, 0.2)),
                              c2=two_sink_example1((0.5, 0.6)), with_control=False)
        rem1 = remark1_check(steps=20, trials=1)
        transient: list[dict[str, Any]] = []
    else:
        readings = dk.eq94_readings()
        table = dk.gamma_delay_table()
        sweep = dk.dimension_sweep()
        thm4 = theorem4_check()
        rem1 = remark1_check()
        transient = eq94_transient()
    data = {"eq94_readings": readings.to_dict(), "eq94_transient": transient,
            "gamma_delay_table": table.to_dict(), "dimension_sweep": sweep.to_dict(),
            "theorem4": thm4.to_dict(), "remark1": rem1.to_dict()}
    text = "\n".join([readings.format_text(), *(
        [("finite-time weights Omega_i(t) of Algorithm 1: " + "; ".join(
            f"x(0) ~ N(0, {r['x0_cov_scale']:g} I): closest at t = {r['closest_t']}, "
            f"{r['distance']:.4f}" for r in transient))] if transient else []),
        table.format_text(), sweep.format_text(), thm4.format_text(), rem1.format_text()])
    return data, text
