"""Resource guards: every request runs within this machine or is refused in one line.

Each command runs as a subprocess under a 4 GB address-space limit (``ulimit -v``)
with a timeout: a request that cannot fit must be refused (exit 2, one line on stderr
naming the parameter, the estimate and the limit, no traceback); one whose delays reach
past the last step is capped, runs and says what it capped. A hang fails a case by the
timeout; no case asserts how fast the machine is (it must pass on a loaded machine).
"""

from __future__ import annotations

import os
import resource
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from netsim import budget

LIMIT_BYTES = 4_000_000 * 1024  # ulimit -v 4000000
TIMEOUT = 120  # a hang fails the case; nothing asserts how fast a machine is

# Run `netsim ARGS` on lcsys2022-homogeneous with its plant replaced by an n-state one
# (a TOML file with a 2000 x 2000 A takes longer to parse than the guard to answer).
BIG_PLANT = textwrap.dedent("""
    import dataclasses, sys
    import numpy as np
    import netsim.models.scenario as sc
    from netsim.cli import main
    from netsim.models.plant import LinearPlant
    n = int(sys.argv[1])
    base = sc.resolve_scenario("lcsys2022-homogeneous")
    N = base.n_agents
    A = 0.9 * np.eye(n) + 0.05 * np.eye(n, k=1)
    C = tuple(np.eye(n)[[i * (n // N)]] for i in range(N))
    plant = LinearPlant(A, C, 0.004 * np.eye(n), tuple(0.004 * np.eye(1) for _ in C),
                        np.zeros(n), np.eye(n))
    big = dataclasses.replace(base, name=f"big{n}", plant=plant)
    sc.resolve_scenario = lambda name, precheck=None: big
    sys.exit(main(sys.argv[2:]))
""")

SMALL = """
name = "guard-small"
[run]
steps = {steps}
trials = 2
estimators = ["compensated", "uncompensated", "block"]
[plant]
A = [[1.01, 0.1], [0.0, 0.95]]
C = [[[1.0, 0.0]], [[0.0, 1.0]], [[1.0, 1.0]]]
Q = 0.004
R = 0.004
[network]
topology = "cycle"
agents = 3
weights = "uniform"
{extra}
"""


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_BYTES, LIMIT_BYTES))


def _netsim(*args: str, script: str | None = None) -> tuple[subprocess.CompletedProcess, float]:
    cmd = ([sys.executable, "-c", script, *args] if script is not None
           else [sys.executable, "-m", "netsim.cli", *args])
    env = {k: v for k, v in os.environ.items() if not k.startswith("NETSIM_")}
    start = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT,
                          preexec_fn=_limit, env=env)
    return proc, time.monotonic() - start


def _refused(proc: subprocess.CompletedProcess, seconds: float, *needles: str) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    line = lines[0]
    assert "needs about" in line or "would take about" in line, line
    assert "this machine can give" in line or "NETSIM_TIME_LIMIT" in line, line
    for needle in needles:
        assert needle in line, line
    return line


def _capped_run(proc: subprocess.CompletedProcess, seconds: float) -> None:
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert "never arrives" in proc.stderr and "A^r only up to r =" in proc.stderr
    assert "estimator" in proc.stdout and "block" in proc.stdout


def _scenario(tmp_path: Path, steps: int = 60, extra: str = "") -> str:
    path = tmp_path / "s.toml"
    path.write_text(SMALL.format(steps=steps, extra=extra))
    return str(path)


# -- delays beyond the steps: capped, runs, says so -------------------------------------


def test_cli_tau_1e9_is_capped_and_runs():
    proc, seconds = _netsim("run", "lcsys2022-heterogeneous", "--tau", "1000000000",
                            "--trials", "4", "--no-progress")
    _capped_run(proc, seconds)


@pytest.mark.parametrize("delays", [
    '[delays]\nmodel = "heterogeneous"\ntau = 1e9',
    '[delays]\nmodel = "homogeneous"\ntau = 1000000000',
    '[links]\ndelay = { distribution = "constant", value = 1e9 }',
], ids=["tau-float", "tau-int", "links-constant"])
def test_scenario_delays_beyond_steps_are_capped(tmp_path, delays):
    proc, seconds = _netsim("run", _scenario(tmp_path, extra=delays), "--no-progress")
    if proc.returncode == 2:  # the loader may refuse a float tau: one line naming it
        assert proc.stderr.count("\n") == 1 and "delays.tau" in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
        return
    _capped_run(proc, seconds)


def test_empirical_latency_1e12_is_capped(tmp_path):
    (tmp_path / "lat.csv").write_text("latency\n1e12\n2e12\n")
    extra = '[links]\ndelay = { distribution = "empirical", file = "lat.csv" }'
    proc, seconds = _netsim("run", _scenario(tmp_path, extra=extra), "--no-progress")
    _capped_run(proc, seconds)


# -- requests too large for memory: refused in one line ----------------------------------


def test_steps_1e12_in_scenario_refused(tmp_path):
    proc, seconds = _netsim("run", _scenario(tmp_path, steps=10**12), "--no-progress")
    _refused(proc, seconds, "run.steps = 1000000000000", "TiB")


def test_cli_steps_refused():
    proc, seconds = _netsim("run", "lcsys2022-heterogeneous", "--steps", "100000000",
                            "--no-progress")
    _refused(proc, seconds, "--steps = 100000000", "lower --steps")


def test_cli_trials_refused():
    proc, seconds = _netsim("run", "lcsys2022-heterogeneous", "--trials", "100000000",
                            "--no-progress")
    _refused(proc, seconds, "--trials = 100000000", "lower --trials")


def test_events_engine_steps_refused():
    proc, seconds = _netsim("run", "lcsys2022-heterogeneous", "--steps", "100000000",
                            "--engine", "events", "--no-progress")
    _refused(proc, seconds, "--steps = 100000000", "events engine")


@pytest.mark.parametrize("command", ["design", "run", "analyze"])
def test_plant_n2000_refused(command):
    args = [command, "big"] + (["--no-progress"] if command == "run" else [])
    proc, seconds = _netsim("2000", *args, script=BIG_PLANT)
    _refused(proc, seconds, "plant.A = 2000 x 2000", "N n = 8000")


def test_analyze_huge_tau_max_refused():
    proc, seconds = _netsim("analyze", "lcsys2022-homogeneous", "--tau-max", "100000")
    _refused(proc, seconds, "--tau-max = 100000")


def test_analyze_scenario_delays_refused(tmp_path):
    # the scenario's own fixed delays give an augmented loop of dimension N n 1e9
    path = _scenario(tmp_path, extra='[delays]\nmodel = "homogeneous"\ntau = 1000000000')
    proc, seconds = _netsim("analyze", path, "--tau-max", "2")
    _refused(proc, seconds, "the scenario's delays = max 1000000000 steps")


# -- long computations: Ctrl-C ------------------------------------------------------------


def _busy(pid: int) -> bool:
    """The process and its workers have spent 3 CPU seconds: past their imports
    and computing (/proc, Linux)."""
    ticks = os.sysconf("SC_CLK_TCK")
    pids = [pid]
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        pids += [int(c) for c in children]
    except OSError:
        pass
    total = 0
    for p in pids:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime + stime
        except (OSError, IndexError, ValueError):
            pass
    return total >= 3 * ticks


def test_analyze_long_range_is_interruptible():
    """Ctrl-C during a long analysis ends it with exit 130 and one line. The process runs
    in its own session, and whatever happens the test kills that whole group, workers
    included, so a failure never leaves processes running."""
    proc = subprocess.Popen([sys.executable, "-m", "netsim.cli", "analyze",
                             "lcsys2022-homogeneous", "--tau-max", "100"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_limit, start_new_session=True)
    try:
        deadline = time.monotonic() + TIMEOUT
        while not _busy(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert proc.poll() is None, "--tau-max 100 should still be running"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=TIMEOUT)
        assert proc.returncode == 130, err
        assert err.strip().splitlines() == ["netsim analyze: interrupted"], err
    finally:  # the session's group: the command and its worker processes
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=TIMEOUT)


# -- in-process: the cap does not change results, the estimates -------------------------


def test_vectorised_powers_capped_and_equal_to_kernel(monkeypatch):
    from netsim.models.scenario import resolve_scenario
    from netsim.models.seeding import child_sequence

    import netsim.vectorised as vec
    from netsim.runner import run_trial, scenario_gains

    scenario = resolve_scenario("lcsys2022-heterogeneous").with_tau(10**9)
    gains = scenario_gains(scenario)
    steps = 25
    counts = []
    real = vec._powers

    def spy(A, count):
        counts.append(count)
        return real(A, count)

    monkeypatch.setattr(vec, "_powers", spy)
    seeds = [child_sequence(7, "trial", t) for t in range(2)]
    for family in ("compensated", "block"):
        results = vec.run_vectorised(scenario, family, gains, seeds, steps)
        for seed, res in zip(seeds, results, strict=True):
            ref = run_trial(scenario, family, gains, seed, steps)
            np.testing.assert_allclose(res.estimates, ref.estimates, rtol=1e-9, atol=1e-9)
    assert counts and max(counts) <= steps + 1


def test_analyze_progress_counts_every_tau():
    from netsim.models.scenario import resolve_scenario

    from netsim.analysis import analyze
    from netsim.runner import scenario_gains

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    ticks = []
    report = analyze(scenario, scenario_gains(scenario), 3, progress=ticks.append)
    assert len(report.rows) == 4
    # one tick per tau, one for the scenario's own fixed delays
    assert sum(ticks) == 4 + (report.realised is not None)


def test_delay_horizon_rule():
    # a message sent at s with delay d is usable at s + 1 + d: within steps 0..K no
    # delay above K matters
    assert budget.delay_horizon(10**12, 300) == 300
    assert budget.delay_horizon(3, 300) == 3
    assert budget.delay_horizon(float("inf"), 5) == 5


def test_memory_limit_follows_rlimit_and_override(monkeypatch):
    monkeypatch.setenv("NETSIM_MEMORY_LIMIT", "1G")
    assert budget.memory_limit() == (1 << 30, "NETSIM_MEMORY_LIMIT")
    with pytest.raises(budget.ResourceError, match=r"^steps = 9: x needs about 2\.0 GiB, "
                       r"more than the 1\.0 GiB"):
        budget.check_memory(2 << 30, "steps", "x", 9)
    monkeypatch.delenv("NETSIM_MEMORY_LIMIT")
    limit, source = budget.memory_limit()
    assert 0 < limit and source.startswith(f"{budget.SAFETY:g} x ")


def test_estimate_scales_with_request():
    from netsim.models.scenario import resolve_scenario

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    one, _ = budget.run_bytes(scenario, 300, 1, "events")
    ten, _ = budget.run_bytes(scenario, 300, 10, "events")
    assert ten > one
    # kept per trial: (K+1) (n + m + N + N n) doubles, independent of this module
    n, N, m = 6, 4, 4
    assert ten - one == pytest.approx(9 * (8 * 301 * (n + m + N + N * n) + 8 * 301))


def test_traced_steps_beyond_the_bulk_writers_memory_refused(tmp_path):
    """Tracing a trial the machine can run but whose trace the bulk writer could not
    build in memory (about 600 bytes per step here) is refused before it runs, and the
    event kernel, which writes as it runs, is pointed to (a memory limit between the
    two set with NETSIM_MEMORY_LIMIT)."""
    from netsim.models.scenario import resolve_scenario

    scenario = resolve_scenario("lcsys2022-heterogeneous")
    steps = 1_000_000
    _, one = budget.run_bytes(scenario, steps, 1, "vectorised", keep_estimates=True)
    traced = one + budget.trace_write_bytes(scenario, steps)
    limit = (one + traced) // 2
    trace = tmp_path / "t.mcap"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NETSIM_")}
    env["NETSIM_MEMORY_LIMIT"] = str(limit)
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "netsim.cli", "run", "lcsys2022-heterogeneous", "--steps",
         str(steps), "--trials", "1", "--estimators", "compensated", "--trace", str(trace),
         "--no-progress"], capture_output=True, text=True, timeout=TIMEOUT, env=env)
    line = _refused(proc, time.monotonic() - start, "--steps = 1000000", "--engine events")
    assert "writing the trace of one trial" in line
    assert not trace.exists()


def test_trace_write_bytes_is_an_upper_bound_of_what_writing_takes():
    """The estimate bounds the measured peak of the bulk writer (a run of 300 steps at
    N = 32 traced and untraced in subprocesses: their peak RSS differ by less)."""
    code = textwrap.dedent("""
        import resource, sys, warnings
        sys.path.insert(0, "benchmarks")
        import trace_throughput as tt
        from netsim.runner import run_monte_carlo, scenario_gains
        from netsim import budget
        warnings.simplefilter("ignore")
        s = tt.run_scenario(32)
        g = scenario_gains(s)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        trace = sys.argv[1] if len(sys.argv) > 1 else None
        run_monte_carlo(s, steps=3000, trials=1, gains=g, trace=trace, engine="vectorised")
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        print(after - before, budget.trace_write_bytes(s, 3000))
    """)
    root = Path(__file__).resolve().parents[1]
    grown = {}
    for name, extra in (("untraced", []), ("traced", [str(Path(os.environ.get(
            "TMPDIR", "/tmp")) / f"netsim-guard-{os.getpid()}.mcap")])):
        done = subprocess.run([sys.executable, "-c", code, *extra], cwd=root,
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        grown[name], estimate = map(int, done.stdout.split())
        for path in extra:
            Path(path).unlink(missing_ok=True)
    assert grown["traced"] - grown["untraced"] < estimate
