"""The ``netsim`` command's entry point runs its whole process with one BLAS thread
(netsim.console, issue 34), and leaves a user's thread settings alone."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PROBE = textwrap.dedent("""
    import io, json, os, sys, contextlib
    from netsim.console import THREAD_VARIABLES, main
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["run", "lcsys2022-heterogeneous", "--steps", "6", "--trials", "2",
                     "--no-progress"])
    used_threadpoolctl = "threadpoolctl" in sys.modules
    from threadpoolctl import threadpool_info
    blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    print(json.dumps({"code": code, "threadpoolctl": used_threadpoolctl, "blas": blas,
                      "env": {k: os.environ.get(k) for k in THREAD_VARIABLES}}))
""")


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if not k.endswith("_NUM_THREADS") and k != "VECLIB_MAXIMUM_THREADS"}
    env.update(extra)
    return env


def _probe(env: dict[str, str]) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_command_runs_with_one_blas_thread_without_threadpoolctl():
    got = _probe(_env())
    assert got["code"] == 0
    assert got["blas"] and set(got["blas"]) == {1}
    assert got["threadpoolctl"] is False  # the limit came from the variables, for free
    assert set(got["env"].values()) == {"1"}


def test_a_users_thread_setting_is_kept_and_the_work_still_limited():
    got = _probe(_env(OPENBLAS_NUM_THREADS="2"))
    assert got["code"] == 0
    assert got["env"]["OPENBLAS_NUM_THREADS"] == "2"
    assert got["env"]["OMP_NUM_THREADS"] is None  # nothing else set either
    # the run limited its BLAS with threadpoolctl around the work, as a library call does
    assert got["threadpoolctl"] is True


def test_importing_the_cli_changes_no_environment_variable():
    script = ("import json, os; before = dict(os.environ); import netsim.cli, netsim.console; "
              "print(json.dumps(dict(os.environ) == before))")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         cwd=ROOT, env=_env(), timeout=300, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) is True


def test_python_dash_m_netsim_is_the_command():
    out = subprocess.run([sys.executable, "-m", "netsim", "--help"], capture_output=True,
                         text=True, cwd=ROOT, env=_env(), timeout=300)
    assert out.returncode == 0 and "usage: netsim" in out.stdout
