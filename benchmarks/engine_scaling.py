#!/usr/bin/env python
"""Vectorised lockstep engine vs SimPy event kernel, and how the vectorised engine scales.

Five measurements, all taken in one run and reported as measured (nothing is
asserted, except that the anchor's squared errors agree):

0. **Plain-numpy anchor** (:func:`numpy_anchor`, about 30 lines of numpy: the
   compensating estimator, LCSYS2022 eqs. 4-5, with homogeneous tau = 3 at N = 32,
   n = 6, 100 trials x 500 steps, drawing the same plant noise): its wall time beside
   ``run_trials(..., engine="vectorised")``, interleaved, best of ``--repeat`` (at
   least 3), and the largest difference of the squared errors relative to their
   round-off scale 2 ||e|| ||x|| (``agree`` below 1e-12). In the same rounds the
   engine runs the batch with asynchronous random delays too, a numba loop written
   from the same equations (:data:`NUMBA_SOURCE`, :func:`numba_anchor`; "numba not
   installed" when it is not) runs both batches, the engine runs both with its numpy
   step and (numba installed) its compiled step (``NETSIM_NUMBA=1``), every result is
   checked against the numpy step's, and all are set against the arithmetic floor
   (:func:`floor_flops_per_trial_step` at the DGEMM rate of this thread,
   :func:`dgemm_peak`).
1. **Engine ratio** (in this process): trial-steps per second of
   ``netsim.runner.run_trials(..., engine="vectorised")`` over ``engine="events"`` for
   the compensated estimator at N = 4, 32, 128 (random strongly-connected graph,
   default edge probability 0.1, tau = 3 homogeneous) and N = 1000 (random geometric
   graph, tau = 10 homogeneous), plus N = 32 with asynchronous random delays (tau = 3;
   one stream per trial, seed layout 2), on the LCSYS2022 n = 6 plant (agent i carries sensor
   i mod 4; ``netsim.bench.sweep_variant``), gains L_i = 0.3 C_i^T. The event kernel's
   cost per trial-step does not depend on the number of trials, so it is timed on a
   few trials (and fewer steps at N = 1000); the table says what was timed. One
   warm-up run of each engine precedes the timings; each timing is the best of
   ``--repeat`` (fewer for the slow cases, as stated).
2. **LCSYS2022 Fig. 1 preset** (``netsim.bench.run_delay_tolerance`` with the
   preset's 8 delay settings x 100 trials x 500 steps, all four estimator families,
   as ``netsim bench delay-tolerance lcsys2022-fig1`` runs it): wall time on the
   vectorised engine (serial and with 2 local worker processes) and on the event
   kernel (2 local workers; a few minutes; skipped by ``--quick``), their ratio, and
   the wall time of the CLI command itself (a subprocess, default engine).
3. **Scaling grid** (vectorised engine): vary one of N, n, tau, T around a base point
   (N = 32, n = 6, tau = 3, T = 100 trials, K = 500 steps) on a synthetic scenario (a
   random n x n plant scaled to spectral radius 1.0, one unit-norm output per agent,
   random strongly-connected graph with mean in-degree about 4 -- edge probability
   3.1 / (N - 1), which is the default 0.1 at N = 32 --, homogeneous delays tau,
   L_i = 0.3 C_i^T). Each configuration runs in a fresh subprocess; wall time is the
   best of two runs when one run is short (< 3 s), and memory is the child's peak
   resident set size during the timed runs (Linux: VmHWM of /proc/self/status, reset
   to the current RSS just before the runs by writing 5 to /proc/self/clear_refs; not
   ru_maxrss, which Linux carries over fork and exec from the parent), reported in
   total and as the increase over the RSS just before the runs (after imports,
   warm-up and scenario build). The script fits log-log slopes (time and memory
   increase vs the parameter; tau + 1 for tau) and writes a log-log plot (``--plot``).
4. **1,000 agents**: n = 6 (LCSYS2022 plant), random geometric graph, tau = 10
   homogeneous, 1,000 steps, one trial, vectorised, in a fresh subprocess: wall time
   and peak RSS.

Every run uses a divergence threshold of 1e150 so that no trial stops early (the
vectorised engine stops when every trial has diverged, which would make the
timings meaningless); divergences are counted and reported. (1e300 cannot be used:
both engines square the threshold as a Python float, which overflows.)

Usage::

    python benchmarks/engine_scaling.py                 # everything, ~6-8 min on 2 cores
    python benchmarks/engine_scaling.py --quick         # no event-kernel Fig. 1 run
    python benchmarks/engine_scaling.py --json > scaling.json
    python benchmarks/engine_scaling.py --plot /tmp/scaling.png

Progress goes to stderr; stdout holds the tables (or, with ``--json``, exactly one
JSON object).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from tables import format_table, si  # noqa: E402

#: Threshold high enough that nothing stops early, low enough that its square is finite.
NO_DIVERGENCE = 1e150
GAIN_SCALE = 0.3
BASE = {"agents": 32, "states": 6, "tau": 3, "trials": 100, "steps": 500}
GRID = {
    "agents": (8, 32, 128, 512),
    "states": (2, 6, 12, 24),
    "tau": (0, 3, 10, 30),
    "trials": (10, 100, 1000),
}
GRID_LABEL = {"agents": "N", "states": "n", "tau": "tau", "trials": "T"}
MEAN_IN_DEGREE_EXTRA = 3.1  # edge probability 3.1 / (N - 1): 0.1 at N = 32
BIG = {"agents": 1000, "states": 6, "tau": 10, "trials": 1, "steps": 1000,
       "topology": "geometric"}


def progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _proc_status(field: str) -> int | None:
    """A ``/proc/self/status`` memory field (VmHWM, VmRSS) in bytes, None if unavailable."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def peak_rss_bytes() -> tuple[int, str]:
    """Peak RSS of this process and where it was read.

    Linux: VmHWM of /proc/self/status, the high-water mark of this address space. Not
    ru_maxrss: Linux carries ru_maxrss over fork and exec, so a child started by a big
    parent reports the parent's peak. Elsewhere: ru_maxrss (KiB; bytes on macOS).
    """
    hwm = _proc_status("VmHWM")
    if hwm is not None:
        return hwm, "VmHWM"
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(rss if sys.platform == "darwin" else rss * 1024), "ru_maxrss"


def reset_peak_rss() -> bool:
    """Reset VmHWM to the current RSS (Linux >= 4.0: write 5 to clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


# -------------------------------------------------------------------------- scenarios


def lcsys_variant(agents: int, topology: str, tau: int, delays: str = "homogeneous"):
    """The LCSYS2022 n = 6 plant on N agents (sensor i mod 4), delays tau (a delay model
    of the scenario files: homogeneous, asynchronous, ...)."""
    from netsim.bench import _scenario_data, sweep_variant

    data, src = _scenario_data("lcsys2022-heterogeneous")
    scn = sweep_variant(data, src, {"agents": agents, "topology": topology,
                                    "delays": delays, "tau": tau})
    return dataclasses.replace(scn, divergence_threshold=NO_DIVERGENCE)


def synthetic_scenario(agents: int, states: int, tau: int, seed: int):
    """Random n x n plant (spectral radius 1.0), one unit-norm output per agent."""
    from netsim.models.scenario import parse_scenario

    rng = np.random.default_rng([seed, agents, states])
    A = rng.normal(size=(states, states))
    A /= np.max(np.abs(np.linalg.eigvals(A)))
    C = rng.normal(size=(agents, states))
    C /= np.linalg.norm(C, axis=1, keepdims=True)
    data = {
        "name": f"scaling-N{agents}-n{states}-tau{tau}",
        "run": {"seed": seed, "divergence_threshold": NO_DIVERGENCE},
        "plant": {"A": A.tolist(), "C": [[row.tolist()] for row in C], "Q": 0.004,
                  "R": 0.004, "x0_cov": 1.0},
        "network": {"topology": "random", "agents": agents, "seed": seed,
                    "weights": "random",
                    "edge_probability": min(1.0, MEAN_IN_DEGREE_EXTRA / (agents - 1))},
        "delays": {"model": "homogeneous" if tau > 0 else "none", "tau": tau, "seed": seed},
        "gains": {"method": "lmi"},
    }
    return parse_scenario(data, "engine_scaling")


def simple_gains(scenario) -> types.SimpleNamespace:
    return types.SimpleNamespace(L=[GAIN_SCALE * C.T for C in scenario.plant.C])


def trial_seeds(scenario, count: int) -> list:
    from netsim.models.seeding import child_sequence

    return [child_sequence(scenario.seed, "trial", t) for t in range(count)]


def timed_run(scenario, gains, seeds, steps: int, engine: str) -> tuple[float, int]:
    """Wall time of one run_trials call and the number of diverged trials."""
    from netsim.runner import run_trials

    gc.collect()
    t0 = time.perf_counter()
    results = run_trials(scenario, "compensated", gains, seeds, steps, engine=engine,
                         record_estimates=False)
    wall = time.perf_counter() - t0
    return wall, sum(r.diverged_at is not None for r in results)


# --------------------------------------------------------- 0. plain-numpy anchor


def numpy_anchor(A, C, L, P, tau, x0_mean, F0, FQ, FR, plant_seeds, steps):
    """Plain-numpy lockstep of the compensating estimator, homogeneous delay tau.

    What a user would write from LCSYS2022: eq. (1) for the plant (the standard normals
    of each trial drawn from its own stream, as netsim lays them out); eq. (4),
    x^i_{k|k-1} = p_ii A x^i_{k-1|k-1} + sum_j p_ij A^(tau+1) x^j_{k-1-tau|k-1-tau}
    (agent i's own prediction A x^i standing in for j before anything arrived); eq. (5),
    x^i_{k|k} = x^i_{k|k-1} + L_i (y^i_k - C_i x^i_{k|k-1}). C (N, m, n), L (N, n, m),
    FR (N, m, m) the measurement-noise factors. Returns the squared errors (K+1, T, N).
    """
    N, m, n = C.shape
    T, K1 = len(plant_seeds), steps + 1
    noise = np.stack([np.random.Generator(np.random.PCG64(s)).standard_normal(
        (K1, n + N * m)) for s in plant_seeds], axis=1)               # (K+1, T, n + N m)
    x = np.empty((K1, T, n))
    x[0] = x0_mean + noise[0, :, :n] @ F0.T
    for k in range(1, K1):
        x[k] = x[k - 1] @ A.T + noise[k, :, :n] @ FQ.T
    zeta = noise[:, :, n:].reshape(K1, T, N, m)
    y = ((x @ C.reshape(N * m, n).T).reshape(K1, T, N, m)
         + np.einsum("imr,ktir->ktim", FR, zeta)).transpose(0, 2, 1, 3)  # (K+1, N, T, m)
    A_d = np.linalg.matrix_power(A, tau + 1)
    own, rest = np.diag(P)[:, None, None], P - np.diag(np.diag(P))
    C_T, L_T = C.transpose(0, 2, 1), L.transpose(0, 2, 1)
    est = np.broadcast_to(x0_mean, (N, T, n))
    sq = np.empty((K1, T, N))
    history = []
    for k in range(K1):
        if k == 0:
            prior = est
        elif k <= tau:                                                # nothing arrived yet
            prior = P.sum(1)[:, None, None] * (est @ A.T)
        else:
            sent = history[k - 1 - tau]
            prior = own * (est @ A.T) + (rest @ sent.reshape(N, -1)).reshape(N, T, n) @ A_d.T
        est = prior + (y[k] - prior @ C_T) @ L_T
        history.append(est)
        sq[k] = ((est - x[k]) ** 2).sum(-1).T
    return sq


NUMBA_SOURCE = """
import numpy as np
from numba import njit


@njit(cache=False, error_model="numpy")
def numba_loop(A_pow, C, L, own_w, ptr, nbr, w, link, x0_mean, F0, FQ, FR, noise, delays,
               tau_bound):
    # One trial at a time, step by step, agent by agent, neighbour by neighbour:
    # LCSYS2022 eq. (1) for the plant, eq. (4) with the freshest message of each link
    # (x^i_{k|k-1} = p_ii A x^i_{k-1} + sum_j p_ij A^(k - s_j) x^j_{s_j}; the own
    # prediction A x^i_{k-1} stands in before anything arrived from j), eq. (5).
    # Receiver i's neighbours: nbr[ptr[i]:ptr[i+1]], weights w, link index link;
    # noise (T, K+1, n + N m); delays (T, K+1, links) int, the delay of the message
    # sent at step s on a link. Returns the squared errors (K+1, T, N).
    T, K1, _ = noise.shape
    N, m, n = C.shape
    D = tau_bound
    depth = D + 2
    sq = np.empty((K1, T, N))
    x = np.empty(n)
    xn = np.empty(n)
    y = np.empty((N, m))
    est = np.empty((depth, N, n))        # x^i(s) at slot s % depth
    held = np.empty(len(nbr), np.int64)  # freshest message of each term (send step)
    prior = np.empty(n)
    for t in range(T):
        z = noise[t]
        for a in range(n):
            v = x0_mean[a]
            for b in range(n):
                v += F0[a, b] * z[0, b]
            x[a] = v
        held[:] = -1
        for k in range(K1):
            if k > 0:                                  # eq. (1): the plant
                for a in range(n):
                    v = 0.0
                    for b in range(n):
                        v += A_pow[1, a, b] * x[b] + FQ[a, b] * z[k, b]
                    xn[a] = v
                x[:] = xn
            for i in range(N):
                for r in range(m):
                    v = 0.0
                    for b in range(n):
                        v += C[i, r, b] * x[b]
                    for q in range(m):
                        v += FR[i, r, q] * z[k, n + i * m + q]
                    y[i, r] = v
            cur, prev = k % depth, (k - 1) % depth
            for i in range(N):
                if k == 0:
                    prior[:] = x0_mean
                else:
                    for a in range(n):
                        v = 0.0
                        for b in range(n):
                            v += A_pow[1, a, b] * est[prev, i, b]
                        prior[a] = own_w[i] * v
                    for e in range(ptr[i], ptr[i + 1]):
                        # arrivals: message s is usable from s + 1 + d_s on
                        for r in range(D + 1):
                            s = k - 1 - r
                            if s > held[e] and delays[t, s, link[e]] == r:
                                held[e] = s
                        s = held[e]
                        lag = k - s if s >= 0 else 1
                        src = (s % depth) if s >= 0 else prev
                        who = nbr[e] if s >= 0 else i
                        for a in range(n):
                            v = 0.0
                            for b in range(n):
                                v += A_pow[lag, a, b] * est[src, who, b]
                            prior[a] += w[e] * v
                # eq. (5)
                for a in range(n):
                    est[cur, i, a] = prior[a]
                for r in range(m):
                    v = y[i, r]
                    for b in range(n):
                        v -= C[i, r, b] * prior[b]
                    for a in range(n):
                        est[cur, i, a] += L[i, a, r] * v
                e2 = 0.0
                for a in range(n):
                    diff = est[cur, i, a] - x[a]
                    e2 += diff * diff
                sq[k, t, i] = e2
    return sq
"""


def numba_anchor_function():
    """The compiled :data:`NUMBA_SOURCE` loop, or None when numba is not installed."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return None
    namespace: dict[str, Any] = {}
    exec(compile(NUMBA_SOURCE, "<numba anchor>", "exec"), namespace)
    return namespace["numba_loop"]


def numba_anchor(loop, A, C, L, P, tau, x0_mean, F0, FQ, FR, plant_seeds, steps, links,
                 delay_seeds=None):
    """The numba loop (:data:`NUMBA_SOURCE`) on the same noise and delays as netsim.

    The plant noise: each trial's standard normals from its own stream (as
    :func:`numpy_anchor`). Delays: tau on every link, or (``delay_seeds``) the
    asynchronous model's draws as netsim lays them out (seed layout 2: one stream
    ``delays/asynchronous`` per trial, blocks of rows x links int32 draws in 0..tau).
    Drawing the numbers is timed with the loop. Returns the squared errors (K+1, T, N).
    """
    from netsim.models.delays import BATCH_SIZE, BLOCK_ELEMENTS
    from netsim.models.seeding import stream

    N, m, n = C.shape
    T, K1 = len(plant_seeds), steps + 1
    noise = np.empty((T, K1, n + N * m))
    for t, s in enumerate(plant_seeds):
        np.random.Generator(np.random.PCG64(s)).standard_normal(out=noise[t])
    A_pow = np.stack([np.linalg.matrix_power(A, r) for r in range(tau + 2)])
    # receiver i's neighbours j (p_ij > 0, j != i) and the link j -> i of each
    link_of = {(int(j), int(i)): q for q, (j, i) in enumerate(links)}
    ptr, nbr, w, link = [0], [], [], []
    for i in range(N):
        for j in range(N):
            if j != i and P[i, j] != 0:
                nbr.append(j)
                w.append(P[i, j])
                link.append(link_of[(j, i)])
        ptr.append(len(nbr))
    if delay_seeds is None:
        delays = np.full((1, 1, 1), tau, dtype=np.int32)
        delays = np.broadcast_to(delays, (T, K1, len(links)))
    else:
        delays = np.empty((T, K1, len(links)), dtype=np.int32)
        rows = max(1, min(BATCH_SIZE, BLOCK_ELEMENTS // len(links)))
        blocks = -(-K1 // rows)
        for t, seed in enumerate(delay_seeds):
            g = stream(seed, "delays/asynchronous")
            draws = g.integers(0, tau + 1, size=blocks * rows * len(links), dtype=np.int32)
            delays[t] = draws.reshape(-1, len(links))[:K1]
    return loop(A_pow, C, L, np.diag(P).copy(), np.array(ptr), np.array(nbr), np.array(w),
                np.array(link), x0_mean, F0, FQ, FR, noise, delays, tau)


def floor_flops_per_trial_step(agents: int, states: int, outputs: int, links: int) -> int:
    """The arithmetic of one trial-step of the compensating estimator (eqs. 4-5) and its
    error record, in floating-point operations: per agent the own prediction A x and
    the sender's compensated A^(d+1) x (2 n^2 each), the innovation C x, y - C x and
    L (y - C x) plus the add (4 m n + m + n) and the squared error (3 n); per link the
    weighted sum (2 n). 7,640 at N = 32, n = 6, m = 1, 122 links (issue 34's 7.6 kFLOP).

    What the engine's numpy step does with one delay (``netsim.vectorised``, the
    state-major step) is this count and a little less: it forms A^(d+1) x and A x of
    every agent once (counted dense here; the step skips the structural zeros of A
    and A^(d+1) when at most half are nonzero: LCSYS2022's A has 11 nonzeros of 36,
    A^4 14), and C_i x over the nonzero entries of C_i; it also weights the own
    prediction, p_ii A x^i (2 n per agent, 384 FLOP at N = 32, not counted). The
    floor stays the dense count, a conservative reference.
    """
    n, m = states, outputs
    return agents * (4 * n * n + 4 * m * n + m + 4 * n) + 2 * n * links


def dgemm_peak(size: int = 768, repeat: int = 5) -> float:
    """FLOP/s of a size x size double matrix product on this thread (best of repeat)."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(size, size)), rng.normal(size=(size, size))
    out = np.empty((size, size))
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        np.matmul(a, b, out=out)
        best = min(best, time.process_time() - t0)
    return 2.0 * size ** 3 / max(best, 1e-9)


def _deviation(sq_a: np.ndarray, sq_b: np.ndarray, states: np.ndarray) -> tuple[float, float]:
    """Largest |sq_a - sq_b| relative to the round-off scale 2 ||e|| ||x||, and relative.

    The two differ only in the order of additions, so a squared error ||e||^2 differs
    by about 2 ||e|| eps ||x|| (the estimates are as large as x).
    """
    scale = 2 * np.sqrt(sq_b) * np.linalg.norm(states, axis=-1)[..., None] + 1e-300
    return (float(np.max(np.abs(sq_a - sq_b) / scale)),
            float(np.max(np.abs(sq_a - sq_b) / np.abs(sq_b))))


def measure_anchor(repeat: int) -> dict[str, Any]:
    """The vectorised engine against :func:`numpy_anchor` and :func:`numba_anchor`,
    interleaved in one run, with one delay on every link and asynchronous delays,
    the engine's numpy step and (numba installed) its compiled step."""
    from netsim.models.seeding import child_sequence

    from netsim.runner import run_trials
    from netsim.vectorised import KERNEL_ENV, numba_available

    progress("[0/4] anchors vs vectorised engine (N = 32, tau = 3, 100 x 500)")
    base = BASE
    scn = lcsys_variant(base["agents"], "random", base["tau"])
    gains = simple_gains(scn)
    seeds = trial_seeds(scn, base["trials"])
    plant = scn.plant
    if len({Ci.shape[0] for Ci in plant.C}) != 1:
        raise SystemExit("anchor: every agent needs the same number of outputs")
    F0, FQ, FR = plant._factors
    plant_seeds = [child_sequence(s, "plant") for s in seeds]
    args = (plant.A, np.stack(plant.C), np.stack([np.asarray(x) for x in gains.L]),
            np.asarray(scn.weights, dtype=float), base["tau"], plant.x0_mean, F0, FQ,
            np.stack(FR), plant_seeds, base["steps"])
    # the same batch with asynchronous random delays (tau = 3, an independent draw per
    # message), timed in the same rounds against the same floor
    scn_async = lcsys_variant(base["agents"], "random", base["tau"], "asynchronous")
    loop = numba_anchor_function()
    compiled = numba_available()

    def engine(scenario, kernel: str) -> list:
        saved = os.environ.get(KERNEL_ENV)
        os.environ[KERNEL_ENV] = "1" if kernel == "numba" else "0"  # as a user asks
        try:
            return run_trials(scenario, "compensated", gains, seeds, base["steps"],
                              engine="vectorised", record_estimates=False)
        finally:
            if saved is None:
                os.environ.pop(KERNEL_ENV, None)
            else:
                os.environ[KERNEL_ENV] = saved

    cases: dict[str, Any] = {
        "anchor": lambda: numpy_anchor(*args),
        "vectorised": lambda: engine(scn, "numpy"),
        "asynchronous": lambda: engine(scn_async, "numpy"),
    }
    if loop is not None:
        cases["numba_loop"] = lambda: numba_anchor(loop, *args, scn.links)
        cases["numba_loop_asynchronous"] = lambda: numba_anchor(
            loop, *args, scn_async.links, delay_seeds=seeds)
    if compiled:
        cases["vectorised_numba"] = lambda: engine(scn, "numba")
        cases["asynchronous_numba"] = lambda: engine(scn_async, "numba")
    walls: dict[str, list[float]] = {k: [] for k in cases}
    # CPU time of this process too: all run on one thread (OPENBLAS_NUM_THREADS=1),
    # so it is the work done, less sensitive than the wall time to other processes
    cpus: dict[str, list[float]] = {k: [] for k in cases}
    last: dict[str, Any] = {}
    for r in range(-1, repeat):  # round -1: warm-up (numba compiles), not timed
        for name, fn in cases.items():
            gc.collect()
            c0, t0 = time.process_time(), time.perf_counter()
            out = fn()
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            if r >= 0:
                walls[name].append(wall)
                cpus[name].append(cpu)
            if r == repeat - 1:
                last[name] = out if isinstance(out, np.ndarray) else (
                    np.stack([res.squared_errors for res in out], axis=1),
                    np.stack([res.states for res in out], axis=1))
            del out
        if r >= 0:
            progress(f"  run {r + 1}/{repeat}: " + ", ".join(
                f"{k} {walls[k][-1]:.3f} s" for k in cases))
    sq_netsim, states = last["vectorised"]
    sq_async, states_async = last["asynchronous"]
    checks: dict[str, dict[str, float]] = {}

    def check(name: str, sq: np.ndarray, ref: np.ndarray, st: np.ndarray) -> None:
        deviation, relative = _deviation(sq, ref, st)
        checks[name] = {"max_deviation": deviation, "max_relative_difference": relative}

    check("anchor", last["anchor"], sq_netsim, states)
    if loop is not None:
        check("numba_loop", last["numba_loop"], sq_netsim, states)
        check("numba_loop_asynchronous", last["numba_loop_asynchronous"], sq_async,
              states_async)
    if compiled:
        check("vectorised_numba", last["vectorised_numba"][0], sq_netsim, states)
        check("asynchronous_numba", last["asynchronous_numba"][0], sq_async, states_async)
    best = {k: min(v) for k, v in walls.items()}
    best_cpu = {k: min(v) for k, v in cpus.items()}
    # the arithmetic floor: the estimator's FLOPs at this thread's DGEMM rate
    peak = dgemm_peak()
    flops = floor_flops_per_trial_step(base["agents"], plant.n_states,
                                       max(Ci.shape[0] for Ci in plant.C), len(scn.links))
    floor_s = flops * base["trials"] * base["steps"] / peak
    engines = [k for k in ("vectorised", "asynchronous", "vectorised_numba",
                           "asynchronous_numba") if k in cases]
    ratios = {}
    for k in engines:
        homogeneous = not k.startswith("asynchronous")
        numba_ref = "numba_loop" if homogeneous else "numba_loop_asynchronous"
        ratios[k] = {
            "delays": "homogeneous" if homogeneous else "asynchronous",
            "step": "numba" if k.endswith("numba") else "numpy",
            "cpu_s": best_cpu[k],
            "numpy_anchor_over_engine_cpu": (best_cpu["anchor"] / best_cpu[k]
                                             if homogeneous else None),
            "numba_loop_over_engine_cpu": (best_cpu[numba_ref] / best_cpu[k]
                                           if numba_ref in best_cpu else None),
            "engine_over_floor_cpu": best_cpu[k] / floor_s,
        }
    worst = max(c["max_deviation"] for c in checks.values())
    return {"floor": {"flops_per_trial_step": flops, "dgemm_flops_per_s": peak,
                      "floor_s": floor_s,
                      "vectorised_over_floor_cpu": best_cpu["vectorised"] / floor_s,
                      "asynchronous_over_floor_cpu": best_cpu["asynchronous"] / floor_s},
            "agents": base["agents"], "states": plant.n_states, "tau": base["tau"],
            "trials": base["trials"], "steps": base["steps"], "links": len(scn.links),
            "repeat": repeat, "walls_s": walls, "best_s": best,
            "vectorised_over_anchor": best["anchor"] / best["vectorised"],
            "cpu_s": cpus, "best_cpu_s": best_cpu,
            "vectorised_over_anchor_cpu": best_cpu["anchor"] / best_cpu["vectorised"],
            "max_deviation": checks["anchor"]["max_deviation"],
            "max_relative_difference": checks["anchor"]["max_relative_difference"],
            "checks": checks, "engines": ratios,
            "numba_installed": loop is not None,
            "agree": worst < 1e-12}


# ------------------------------------------------------------------ 1. engine ratio


def engine_ratio_cases(quick: bool) -> list[dict[str, Any]]:
    """(N, topology, tau, vectorised T/K/repeat, events T/K/repeat) per size."""
    return [
        {"agents": 4, "topology": "random", "tau": 3,
         "vec": (100, 500, 3), "ev": (3, 500, 2)},
        {"agents": 32, "topology": "random", "tau": 3,
         "vec": (100, 500, 3), "ev": (3, 500, 2)},
        {"agents": 128, "topology": "random", "tau": 3,
         "vec": (100, 200, 2), "ev": (2, 100, 1)},
        {"agents": 1000, "topology": "geometric", "tau": 10,
         "vec": (1, 300, 1), "ev": (1 if quick else 2, 30, 1)},
        # the goal's second case: a random delay per message (one stream per trial)
        {"agents": 32, "topology": "random", "tau": 3, "delays": "asynchronous",
         "vec": (100, 500, 2), "ev": (3, 500, 2)},
    ]


def measure_engine_ratio(quick: bool, repeat: int) -> list[dict[str, Any]]:
    progress("[1/4] engine ratio: warm-up")
    warm = lcsys_variant(4, "random", 3)
    for engine in ("vectorised", "events"):
        timed_run(warm, simple_gains(warm), trial_seeds(warm, 2), 20, engine)
    rows = []
    for case in engine_ratio_cases(quick):
        delays = case.get("delays", "homogeneous")
        scn = lcsys_variant(case["agents"], case["topology"], case["tau"], delays)
        gains = simple_gains(scn)
        row: dict[str, Any] = {"agents": case["agents"], "topology": case["topology"],
                               "tau": case["tau"], "delays": delays, "links": len(scn.links),
                               "states": scn.plant.n_states}
        for engine, key in (("vectorised", "vec"), ("events", "ev")):
            trials, steps, rep = case[key]
            rep = min(rep, repeat)
            seeds = trial_seeds(scn, trials)
            walls, diverged = [], 0
            for r in range(rep):
                wall, div = timed_run(scn, gains, seeds, steps, engine)
                walls.append(wall)
                diverged = max(diverged, div)
                progress(f"  N={case['agents']:<5} {engine:<10} T={trials:<4} K={steps:<4} "
                         f"run {r + 1}/{rep}: {wall:.3f} s")
            best = min(walls)
            row[engine] = {"trials": trials, "steps": steps, "repeat": rep, "wall_s": best,
                           "walls_s": walls, "trial_steps_per_s": trials * steps / best,
                           "us_per_trial_step": best / (trials * steps) * 1e6,
                           "diverged_trials": diverged}
        row["ratio"] = (row["vectorised"]["trial_steps_per_s"]
                        / row["events"]["trial_steps_per_s"])
        rows.append(row)
    return rows


# ------------------------------------------------------------ 2. LCSYS2022 Fig. 1


def fig1_run(engine: str, executor: str, workers: int) -> dict[str, Any]:
    from netsim.models.scenario import resolve_scenario

    from netsim.bench import FAMILIES, PRESETS, run_delay_tolerance
    from netsim.runner import scenario_gains

    preset = PRESETS["lcsys2022-fig1"]
    scenario = resolve_scenario(preset.scenario)
    gains = scenario_gains(scenario)  # not timed: the CLI designs them before the sweep too
    t0 = time.perf_counter()
    data = run_delay_tolerance(
        scenario, taus=preset.taus, delays=preset.delays, trials=preset.trials,
        steps=preset.steps, seed=scenario.seed, families=list(FAMILIES), gains=gains,
        preset=preset, executor=executor, workers=workers, progress=False, engine=engine)
    wall = time.perf_counter() - t0
    cells = [c for c in data["cells"]]
    return {"engine": data["engine"], "executor": data["run"]["executor"],
            "workers": data["run"]["workers"], "wall_s": wall,
            "cells_computed": data["run"]["cells_computed"],
            "settings": len(preset.taus) * len(preset.delays), "trials": preset.trials,
            "steps": preset.steps, "families": list(FAMILIES), "table_rows": len(cells)}


def cli_run() -> dict[str, Any]:
    exe = shutil.which("netsim")
    cmd = ([exe] if exe else [sys.executable, "-m", "netsim.cli"]) + [
        "bench", "delay-tolerance", "lcsys2022-fig1", "--json", "--no-progress"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    out: dict[str, Any] = {"command": " ".join(["netsim", *cmd[-5:]]),
                           "wall_s": wall, "exit_code": proc.returncode}
    if proc.returncode == 0:
        data = json.loads(proc.stdout)
        out.update(engine=data.get("engine"), inner_elapsed_s=data["run"]["elapsed_s"],
                   executor=data["run"]["executor"], workers=data["run"]["workers"])
    else:
        out["stderr_tail"] = proc.stderr[-500:]
    return out


def measure_fig1(quick: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for label, engine, executor, workers in (
        ("vectorised_serial", "vectorised", "serial", 1),
        ("vectorised_local", "vectorised", "local", 2),
    ):
        progress(f"[2/4] Fig. 1 preset: {engine}, {executor} ({workers} worker(s))")
        out[label] = fig1_run(engine, executor, workers)
        progress(f"  {out[label]['wall_s']:.1f} s")
    if quick:
        out["events_local"] = None
        progress("[2/4] Fig. 1 preset on the event kernel: skipped (--quick)")
    else:
        progress("[2/4] Fig. 1 preset: events, local (2 workers) -- a few minutes")
        out["events_local"] = fig1_run("events", "local", 2)
        progress(f"  {out['events_local']['wall_s']:.1f} s")
        out["events_over_vectorised_local"] = (out["events_local"]["wall_s"]
                                               / out["vectorised_local"]["wall_s"])
        out["events_over_vectorised_serial"] = (out["events_local"]["wall_s"]
                                                / out["vectorised_serial"]["wall_s"])
    progress("[2/4] CLI: netsim bench delay-tolerance lcsys2022-fig1 --json --no-progress")
    out["cli"] = cli_run()
    progress(f"  {out['cli']['wall_s']:.1f} s (exit {out['cli']['exit_code']})")
    return out


# -------------------------------------------------------- 3./4. child measurements


def child_main(spec: dict[str, Any]) -> int:
    """Run one vectorised configuration; print one JSON line (wall, RSS)."""
    if spec.get("topology") == "geometric":
        scn = lcsys_variant(spec["agents"], "geometric", spec["tau"])
    else:
        scn = synthetic_scenario(spec["agents"], spec["states"], spec["tau"], spec["seed"])
    gains = simple_gains(scn)
    seeds = trial_seeds(scn, spec["trials"])
    timed_run(scn, gains, seeds[:1], 3, "vectorised")  # warm-up: imports, first calls
    gc.collect()
    process_peak, _ = peak_rss_bytes()
    reset = reset_peak_rss()
    baseline = _proc_status("VmRSS") if reset else process_peak
    walls, diverged = [], 0
    while True:
        wall, div = timed_run(scn, gains, seeds, spec["steps"], "vectorised")
        walls.append(wall)
        diverged = max(diverged, div)
        if len(walls) >= spec.get("repeat", 2) or wall >= spec.get("repeat_below_s", 3.0):
            break
    print(json.dumps({"walls_s": walls, "wall_s": min(walls), "diverged_trials": diverged,
                      "links": len(scn.links), "batch_trials": batch_trials(scn, spec),
                      "baseline_rss_bytes": baseline, "peak_rss_bytes": peak_rss_bytes()[0],
                      "peak_source": peak_rss_bytes()[1] + (" reset before the run" if reset
                                                            else " (whole process)"),
                      "setup_peak_rss_bytes": process_peak}))
    return 0


def batch_trials(scn, spec: dict[str, Any]) -> int:
    """Trials per lockstep batch, as netsim.vectorised.run_vectorised splits them."""
    import netsim.vectorised as vec

    limit = getattr(vec, "BATCH_ELEMENTS", None)
    if limit is None:
        return spec["trials"]
    per = max(1, limit // (max(1, len(scn.links)) * (spec["steps"] + 2)))
    return min(per, spec["trials"])


def engine_revision() -> dict[str, Any]:
    """The commit measured, and whether the engine's files differ from it."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                                  check=False).stdout.strip()
        except OSError:
            return ""

    return {"commit": git("rev-parse", "--short", "HEAD") or None,
            "dirty_files": git("status", "--porcelain", "--", "netsim", "models",
                               "estimators").splitlines()}


def run_child(spec: dict[str, Any]) -> dict[str, Any]:
    cmd = [sys.executable, os.path.abspath(__file__), "--child", json.dumps(spec)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"child {spec} failed ({proc.returncode}): {proc.stderr[-1000:]}")
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["process_elapsed_s"] = elapsed
    result["run_rss_bytes"] = result["peak_rss_bytes"] - result["baseline_rss_bytes"]
    return {**spec, **result}


def measure_grid(seed: int) -> dict[str, Any]:
    cache: dict[tuple, dict[str, Any]] = {}
    points: dict[str, list[dict[str, Any]]] = {}
    total = sum(len(v) for v in GRID.values()) - (len(GRID) - 1)
    done = 0
    for param, values in GRID.items():
        points[param] = []
        for value in values:
            spec = {**BASE, param: value, "seed": seed}
            key = tuple(spec[k] for k in BASE)
            if key not in cache:
                done += 1
                progress(f"[3/4] grid {done}/{total}: N={spec['agents']} n={spec['states']} "
                         f"tau={spec['tau']} T={spec['trials']} K={spec['steps']}")
                cache[key] = run_child(spec)
                r = cache[key]
                progress(f"  {r['wall_s']:.2f} s, peak RSS {r['peak_rss_bytes'] / 2**20:.0f} "
                         f"MiB")
            points[param].append(cache[key])
    slopes = {}
    for param, rows in points.items():
        x = np.array([r[param] + (1 if param == "tau" else 0) for r in rows], dtype=float)
        t = np.array([r["wall_s"] for r in rows])
        m = np.array([max(r["run_rss_bytes"], 1) for r in rows], dtype=float)
        slopes[param] = {"time": float(np.polyfit(np.log(x), np.log(t), 1)[0]),
                         "memory": float(np.polyfit(np.log(x), np.log(m), 1)[0])}
    return {"base": BASE, "points": points, "slopes": slopes}


def measure_big() -> dict[str, Any]:
    progress("[4/4] 1,000 agents: geometric, tau = 10, 1,000 steps, 1 trial (subprocess)")
    r = run_child({**BIG, "seed": 0, "repeat": 1})
    progress(f"  {r['wall_s']:.1f} s, peak RSS {r['peak_rss_bytes'] / 2**30:.2f} GiB")
    return r


# -------------------------------------------------------------------------- output


def plot_grid(grid: dict[str, Any], path: str) -> str:
    from matplotlib.figure import Figure
    from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

    def plain_ticks(ax: Any) -> None:
        # decade and 2, 5 ticks as plain numbers; no crowded minor labels
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(NullFormatter())

    fig = Figure(figsize=(4 * len(GRID), 7))
    axes = fig.subplots(2, len(GRID))
    for c, (param, rows) in enumerate(grid["points"].items()):
        x = np.array([r[param] + (1 if param == "tau" else 0) for r in rows], dtype=float)
        label = "tau + 1" if param == "tau" else GRID_LABEL[param]
        slope = grid["slopes"][param]
        ax = axes[0, c]
        ax.loglog(x, [r["wall_s"] for r in rows], "o-")
        ax.set_title(f"time vs {label} (slope {slope['time']:.2f})")
        ax.set_xlabel(label)
        ax.set_ylabel("wall s (best run)")
        ax.grid(True, which="both", alpha=0.3)
        plain_ticks(ax)
        ax = axes[1, c]
        ax.loglog(x, [r["peak_rss_bytes"] / 2**20 for r in rows], "o-", label="peak RSS")
        ax.loglog(x, [max(r["run_rss_bytes"], 1) / 2**20 for r in rows], "s--",
                  label="peak RSS - RSS before run")
        ax.set_title(f"memory vs {label} (slope {slope['memory']:.2f})")
        ax.set_xlabel(label)
        ax.set_ylabel("MiB")
        ax.grid(True, which="both", alpha=0.3)
        plain_ticks(ax)
        ax.legend(fontsize=8)
    base = ", ".join(f"{GRID_LABEL[k]}={v}" for k, v in BASE.items() if k in GRID_LABEL)
    fig.suptitle(f"vectorised engine, one parameter varied around {base}, "
                 f"K={BASE['steps']} (fresh subprocess per point)")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return str(path)


def _mib(b: float) -> str:
    return f"{b / 2**20:.0f}"


def render(report: dict[str, Any]) -> str:
    m = report["machine"]
    rev = report["revision"]
    out = [
        f"netsim engine scaling  (python {m['python']}, numpy {m['numpy']}, {m['cpus']} CPUs, "
        f"OPENBLAS_NUM_THREADS={m['openblas_threads']}; load average at start "
        f"{report['load_start']}, at end {report['load_end']})",
        f"revision {rev['commit']}; uncommitted changes under netsim/ models/ estimators/: "
        + (", ".join(rev["dirty_files"]) if rev["dirty_files"] else "none"),
        "",
    ]
    anchor = report.get("anchor")
    if anchor:
        b = anchor["best_s"]
        out += [
            f"0. Vectorised engine / plain-numpy anchor (numpy_anchor, ~30 lines): "
            f"compensated, N = {anchor['agents']} ({anchor['links']} links), "
            f"n = {anchor['states']}, tau = {anchor['tau']} homogeneous, "
            f"{anchor['trials']} trials x {anchor['steps']} steps, the same noise; "
            f"interleaved, best of {anchor['repeat']}; goal >= 3x (issue 34)",
            format_table(["anchor s", "vectorised s", "ratio", "anchor CPU s",
                          "vectorised CPU s", "CPU ratio", "max deviation",
                          "max rel. difference", "agree"],
                         [[f"{b['anchor']:.3f}", f"{b['vectorised']:.3f}",
                           f"{anchor['vectorised_over_anchor']:.2f}x",
                           f"{anchor['best_cpu_s']['anchor']:.3f}",
                           f"{anchor['best_cpu_s']['vectorised']:.3f}",
                           f"{anchor['vectorised_over_anchor_cpu']:.2f}x",
                           f"{anchor['max_deviation']:.1e}",
                           f"{anchor['max_relative_difference']:.1e}",
                           "yes" if anchor["agree"] else "NO"]]),
            "   (wall and CPU time of this process, each the best of the runs; "
            "deviation = |sq_anchor - sq_netsim| / (2 ||e|| ||x||), the round-off of a "
            "squared error whose estimate is as large as the state; the relative difference "
            "is larger where ||e|| << ||x||; agree: deviation < 1e-12)",
        ]
        fl = anchor.get("floor")
        if fl:
            def x(v: float | None, digits: int = 2) -> str:
                return "-" if v is None else f"{v:.{digits}f}x"

            rows = [[e["delays"], e["step"], f"{e['cpu_s']:.3f}",
                     x(e["numpy_anchor_over_engine_cpu"]),
                     x(e["numba_loop_over_engine_cpu"]),
                     x(e["engine_over_floor_cpu"], 1)]
                    for e in anchor.get("engines", {}).values()]
            cpu = anchor["best_cpu_s"]
            numba_note = (
                f"numba loop (NUMBA_SOURCE) CPU s: {cpu['numba_loop']:.3f} one delay, "
                f"{cpu['numba_loop_asynchronous']:.3f} asynchronous"
                if anchor.get("numba_installed") else
                "numba not installed: no numba loop, no compiled step "
                "(pip install 'netsim[numba]')")
            out += [
                f"   arithmetic floor: {fl['flops_per_trial_step']:,} FLOP per trial-step "
                f"at the DGEMM rate of this thread ({fl['dgemm_flops_per_s'] / 1e9:.1f} "
                f"GFLOP/s, 768 x 768, best CPU of 5) = {fl['floor_s'] * 1e3:.1f} ms for "
                f"{anchor['trials']} x {anchor['steps']}; goals (issue 34): numpy anchor / "
                "vectorised >= 3x with one delay, numba loop / vectorised >= 1x with "
                "asynchronous delays, vectorised within 8x of the floor",
                f"   numpy anchor CPU s: {cpu['anchor']:.3f}; {numba_note}",
                format_table(["delays", "engine step", "vectorised CPU s",
                              "numpy anchor / vectorised", "numba loop / vectorised",
                              "vectorised / floor"], rows),
                "   (CPU time, best of the runs; the step is chosen as a user does, "
                "NETSIM_NUMBA=1 for the compiled one; squared errors of every anchor and "
                "step agree with the numpy step's to: " + ", ".join(
                    f"{k} {v['max_deviation']:.1e}"
                    for k, v in anchor.get("checks", {}).items()) + ")",
            ]
        out += [""]
    ratio = report["engine_ratio"]
    if ratio:
        out += [
            "1. Vectorised engine / event kernel, trial-steps per second (compensated, "
            "LCSYS2022 n=6 plant, L_i = 0.3 C_i^T; wall = perf_counter around run_trials, "
            "best of the runs shown; goals >= 50x at N = 32 with 100 trials, homogeneous "
            "delays, and >= 30x with asynchronous delays)",
            format_table(
                ["N", "graph", "links", "delays", "tau", "vec T x K", "vec runs", "vec s",
                 "vec trial-steps/s", "ev T x K", "ev runs", "ev s", "ev trial-steps/s",
                 "ratio", "diverged"],
                [[str(r["agents"]), r["topology"], str(r["links"]),
                  r.get("delays", "homogeneous"), str(r["tau"]),
                  f"{r['vectorised']['trials']} x {r['vectorised']['steps']}",
                  str(r["vectorised"]["repeat"]), f"{r['vectorised']['wall_s']:.3f}",
                  si(r["vectorised"]["trial_steps_per_s"]),
                  f"{r['events']['trials']} x {r['events']['steps']}",
                  str(r["events"]["repeat"]), f"{r['events']['wall_s']:.3f}",
                  si(r["events"]["trial_steps_per_s"]), f"{r['ratio']:.1f}x",
                  f"{r['vectorised']['diverged_trials']}/{r['events']['diverged_trials']}"]
                 for r in ratio]),
            "   (diverged = trials that crossed the 1e150 threshold, vectorised/events; "
            "asynchronous: an independent random delay per message, drawn per trial as "
            "one (messages x links) block from one stream, seed layout 2)",
            "",
        ]
    fig1 = report["fig1"]
    if fig1:
        vs, vl, ev = fig1["vectorised_serial"], fig1["vectorised_local"], fig1["events_local"]
        rows = [["vectorised", "serial (1 process)", f"{vs['wall_s']:.1f}",
                 str(vs["cells_computed"])],
                ["vectorised", "local, 2 workers", f"{vl['wall_s']:.1f}",
                 str(vl["cells_computed"])]]
        if ev is not None:
            rows.append(["events", "local, 2 workers", f"{ev['wall_s']:.1f}",
                         str(ev["cells_computed"])])
        else:
            rows.append(["events", "local, 2 workers", "skipped (--quick)", "-"])
        cli = fig1["cli"]
        rows.append([f"CLI ({cli.get('engine', '?')})",
                     f"{cli.get('executor', '?')}, {cli.get('workers', '?')} workers",
                     f"{cli['wall_s']:.1f}", "-"])
        out += [
            f"2. LCSYS2022 Fig. 1 preset: run_delay_tolerance, {vs['settings']} delay settings "
            f"x {vs['trials']} trials x {vs['steps']} steps, families "
            f"{', '.join(vs['families'])}; gain design (cvxpy) not timed except in the CLI "
            "row; goal < 30 s on the vectorised engine",
            format_table(["engine", "executor", "wall s", "cells"], rows),
        ]
        if ev is not None:
            out.append(f"   events / vectorised: {fig1['events_over_vectorised_local']:.1f}x "
                       f"(both 2 workers), {fig1['events_over_vectorised_serial']:.1f}x "
                       "(events 2 workers / vectorised serial)")
        out.append(f"   CLI: `{cli['command']}` wall {cli['wall_s']:.1f} s including "
                   f"interpreter start, imports and gain design (exit {cli['exit_code']}"
                   + (f"; its own run.elapsed_s {cli['inner_elapsed_s']:.1f} s)"
                      if "inner_elapsed_s" in cli else ")"))
        out.append("")
    grid = report["grid"]
    if grid:
        rows = []
        for param, pts in grid["points"].items():
            for r in pts:
                rows.append([GRID_LABEL[param], str(r["agents"]), str(r["states"]),
                             str(r["tau"]), str(r["trials"]), str(r["steps"]), str(r["links"]),
                             str(r["batch_trials"]),
                             f"{r['wall_s']:.3f}", str(len(r["walls_s"])),
                             si(r["trials"] * r["steps"] / r["wall_s"]),
                             _mib(r["peak_rss_bytes"]), _mib(r["run_rss_bytes"]),
                             str(r["diverged_trials"])])
        out += [
            "3. Vectorised engine scaling (synthetic plant, spectral radius 1.0, one output "
            "per agent, random graph with mean in-degree ~4, homogeneous delays; one "
            "parameter varied around the base; each point a fresh subprocess; time = best "
            "of up to 2 runs; memory = the child's peak RSS during the timed runs "
            f"({grid['points']['agents'][0]['peak_source']}), and its increase over the "
            "RSS just before them, i.e. after imports, warm-up and scenario build)",
            format_table(["varied", "N", "n", "tau", "T", "K", "links", "batch T", "wall s", "runs",
                    "trial-steps/s", "peak RSS MiB", "run +MiB", "diverged"], rows),
            "   (batch T = trials per lockstep batch: run_vectorised splits the trials so "
            "that trials x links x (K + 2) <= netsim.vectorised.BATCH_ELEMENTS)",
            "   log-log slopes (tau + 1 for tau): "
            + "; ".join(f"{GRID_LABEL[p]}: time {s['time']:.2f}, memory {s['memory']:.2f}"
                        for p, s in grid["slopes"].items()),
            f"   plot: {report.get('plot')}",
            "",
        ]
    big = report["big"]
    if big:
        out += [
            f"4. {big['agents']} agents, n = {big['states']} (LCSYS2022 plant), random "
            f"geometric graph ({big['links']} links), tau = {big['tau']} homogeneous, "
            f"{big['steps']} steps, {big['trials']} trial (batch of {big['batch_trials']}), "
            "vectorised, fresh subprocess: "
            f"wall {big['wall_s']:.1f} s; peak RSS {big['peak_rss_bytes'] / 2**30:.2f} GiB "
            f"(run adds {big['run_rss_bytes'] / 2**30:.2f} GiB; goal within 16 GiB); "
            f"diverged trials {big['diverged_trials']}",
            "",
        ]
    out.append(f"total {report['total_wall_s']:.0f} s")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="engine_scaling.py",
        description="Vectorised lockstep engine vs the SimPy event kernel (trial-steps/s, "
                    "LCSYS2022 Fig. 1 preset time) and the vectorised engine's time and "
                    "memory vs N, n, tau and trials.")
    parser.add_argument("--quick", action="store_true",
                        help="skip the event-kernel run of the Fig. 1 preset (a few minutes) "
                             "and time the N = 1000 event kernel on 1 trial")
    parser.add_argument("--repeat", type=int, default=3,
                        help="max timed runs per engine-ratio case; best is kept (3)")
    parser.add_argument("--only", default="anchor,ratio,fig1,grid,big",
                        help="comma-separated parts to run: anchor, ratio, fig1, grid, big "
                             "(all)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic grid (0)")
    parser.add_argument("--plot", default=str(Path(__file__).with_name("engine_scaling.png")),
                        metavar="FILE.png", help="log-log plot of the scaling grid "
                        "(default benchmarks/engine_scaling.png)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object on stdout instead of the tables")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return child_main(json.loads(args.child))
    parts = {p.strip() for p in args.only.split(",") if p.strip()}
    known = {"anchor", "ratio", "fig1", "grid", "big"}
    if not parts <= known:
        parser.error(f"--only: unknown part(s) {sorted(parts - known)}")
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    if not args.plot.lower().endswith(".png"):
        parser.error("--plot must name a .png file")

    import netsim  # noqa: F401  (sets the OPENBLAS default for any child too)

    t0 = time.perf_counter()
    load_start = [round(x, 2) for x in os.getloadavg()]
    report: dict[str, Any] = {
        "benchmark": "engine_scaling",
        "command": " ".join([sys.argv[0], *(sys.argv[1:] if argv is None else argv)]),
        "machine": {"python": platform.python_version(), "numpy": np.__version__,
                    "platform": platform.platform(), "cpus": os.cpu_count(),
                    "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS")},
        "revision": engine_revision(),
        "quick": args.quick,
        "load_start": load_start,
    }
    report["anchor"] = measure_anchor(max(args.repeat, 3)) if "anchor" in parts else None
    if report["anchor"] is not None and not report["anchor"]["agree"]:
        progress("anchor: the vectorised engine's squared errors differ from the anchor's")
    report["engine_ratio"] = measure_engine_ratio(args.quick, args.repeat) \
        if "ratio" in parts else None
    report["fig1"] = measure_fig1(args.quick) if "fig1" in parts else None
    report["grid"] = measure_grid(args.seed) if "grid" in parts else None
    if report["grid"]:
        report["plot"] = plot_grid(report["grid"], args.plot)
    report["big"] = measure_big() if "big" in parts else None
    report["load_end"] = [round(x, 2) for x in os.getloadavg()]
    report["total_wall_s"] = time.perf_counter() - t0
    progress(f"total {report['total_wall_s']:.0f} s")
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(render(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
