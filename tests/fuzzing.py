"""The fuzz test's machinery (not a test module): a TOML writer, and a worker process
that runs ``netsim`` commands in-process under a memory limit and reports, per
request, the exit code, stderr, time and any exception that escaped.

The worker is ``python tests/fuzzing.py`` (started by the test under
``RLIMIT_AS``); it reads one JSON request per line on stdin ``{"argv": [...],
"files": {name: base64}}`` and answers one JSON line on stdout.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import math
import os
import re
import signal
import sys
import tempfile
import time
import traceback
from typing import Any

__all__ = ["to_toml", "worker_main", "TIME_LIMIT_S", "WALL_LIMIT_S", "PRELOAD"]

#: A request that uses more CPU time than this (seconds, the worker's user + system time,
#: which another job on the machine does not inflate) is a failure: refuse, do not hang.
TIME_LIMIT_S = 10
#: A request still running after this many seconds of wall time is a hang (a blocking
#: read uses no CPU); generous, so that a loaded machine never reaches it otherwise.
WALL_LIMIT_S = 180
#: Modules every request may import, imported before the first request: a time limit
#: that fired inside a first import would leave a half-imported module behind (seen:
#: "module 'cvxpy' has no attribute 'promote'").
PRELOAD = ("numpy", "scipy.linalg", "scipy.sparse", "scipy.optimize", "networkx", "cvxpy",
           "simpy", "mcap", "netsim.cli", "netsim.runner", "netsim.vectorised",
           "netsim.kernel", "netsim.estimators.gains", "netsim.estimators.consensus",
           "netsim.fusion", "netsim.aoi")

_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(key: str) -> str:
    return key if _BARE.match(key) else json.dumps(key)


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string for the characters used here
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def to_toml(data: dict[str, Any]) -> str:
    """Write a dict of the TOML scenario's shape (tables of scalars, lists and inline
    tables; ``options`` as a table of tables)."""
    lines = []
    for key, value in data.items():
        if not isinstance(value, dict):
            lines.append(f"{_key(key)} = {_value(value)}")
    for key, value in data.items():
        if isinstance(value, dict):
            plain = {k: v for k, v in value.items() if not isinstance(v, dict)}
            nested = {k: v for k, v in value.items() if isinstance(v, dict)}
            lines.append(f"\n[{_key(key)}]")
            lines += [f"{_key(k)} = {_value(v)}" for k, v in plain.items()]
            for sub, table in nested.items():
                if key == "options":
                    lines.append(f"\n[{_key(key)}.{_key(sub)}]")
                    lines += [f"{_key(k)} = {_value(v)}" for k, v in table.items()]
                else:
                    lines.append(f"{_key(sub)} = {_value(table)}")
    return "\n".join(lines) + "\n"


class _Timeout(Exception):
    pass


def _alarm(signum: int, frame: Any) -> None:
    raise _Timeout()


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _run(argv: list[str]) -> dict[str, Any]:
    from netsim.cli import main

    out, err = io.StringIO(), io.StringIO()
    started, cpu0 = time.perf_counter(), _cpu()
    escaped = None
    signal.signal(signal.SIGALRM, _alarm)
    signal.signal(signal.SIGPROF, _alarm)
    signal.setitimer(signal.ITIMER_PROF, TIME_LIMIT_S)  # CPU time of this process
    signal.alarm(WALL_LIMIT_S)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except _Timeout:
        code = None
        escaped = (f"timeout after {TIME_LIMIT_S} s of CPU time" if _cpu() - cpu0
                   >= TIME_LIMIT_S * 0.9 else f"hang: {WALL_LIMIT_S} s of wall time")
    except BaseException as exc:  # noqa: BLE001 - the point: nothing may escape
        code, escaped = None, "".join(traceback.format_exception(exc))[-3000:]
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.alarm(0)
    return {"code": code, "stderr": err.getvalue()[-4000:], "stdout_bytes": len(out.getvalue()),
            "seconds": time.perf_counter() - started, "cpu_seconds": _cpu() - cpu0,
            "escaped": escaped,
            # an interrupted request may leave state behind: the test starts a new worker
            "restart": escaped is not None}


def worker_main() -> None:
    """Serve requests until stdin closes (see the module docstring)."""
    import importlib
    import warnings

    for name in PRELOAD:
        importlib.import_module(name)
    warnings.simplefilter("default")
    folder = tempfile.mkdtemp(prefix="netsim-fuzz-")
    os.chdir(folder)
    for line in sys.stdin:
        request = json.loads(line)
        for name, content in request.get("files", {}).items():
            with open(os.path.join(folder, name), "wb") as handle:
                handle.write(base64.b64decode(content))
        reply = _run(request["argv"])
        sys.stdout.write(json.dumps(reply) + "\n")
        sys.stdout.flush()


if __name__ == "__main__":
    worker_main()
