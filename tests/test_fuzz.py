"""Fuzz: mutated scenario files and command lines either run or are refused in one line.

Hypothesis mutates valid scenarios (values of other types and shapes, huge and
non-finite numbers, missing and unknown keys, damaged encodings) and ``netsim run``
arguments. Every mutant runs in a worker process under a 4 GB address-space limit
(``RLIMIT_AS``, as ``ulimit -v 4000000``) and must end within ``TIME_LIMIT_S`` of CPU
time (not wall time: another job on the machine must not fail it; a blocking hang is
caught by a generous wall-time limit) with
exit 0 (a result on stdout) or exit 2/3 with exactly one line on stderr, and never
let an exception escape. The default run tries 300 mutants; ``-m slow`` 3,000 more.
"""

from __future__ import annotations

import base64
import copy
import json
import resource
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import pytest
from fuzzing import TIME_LIMIT_S, to_toml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "models" / "scenarios"
MEMORY_LIMIT = 4_000_000 * 1024  # bytes, as ulimit -v 4000000


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


class Worker:
    """One long-lived worker process (imports once; a fresh process costs seconds)."""

    def __init__(self) -> None:
        self.process = None
        self.start()

    def start(self) -> None:
        self.process = subprocess.Popen(
            [sys.executable, str(Path(__file__).with_name("fuzzing.py"))],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, preexec_fn=_limit_memory, cwd=ROOT)

    def run(self, argv: list[str], files: dict[str, bytes]) -> dict[str, Any]:
        request = {"argv": argv, "files": {k: base64.b64encode(v).decode()
                                           for k, v in files.items()}}
        self.process.stdin.write(json.dumps(request) + "\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        if not line:  # the worker died (a crash the in-process guard could not catch)
            err = self.process.stderr.read()[-3000:]
            self.start()
            return {"code": None, "stderr": "", "seconds": 0.0,
                    "escaped": f"worker died: {err}"}
        reply = json.loads(line)
        if reply.get("restart"):  # an interrupted request may have left state behind
            self.close()
            self.start()
        return reply

    def close(self) -> None:
        self.process.stdin.close()
        try:
            self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


@pytest.fixture(scope="module")
def worker():
    w = Worker()
    yield w
    w.close()


def _base(name: str, **run: Any) -> dict[str, Any]:
    data = tomllib.loads((SCENARIOS / f"{name}.toml").read_text())
    data.setdefault("run", {}).update(run)
    return data


def _bases() -> dict[str, dict[str, Any]]:
    # small runs; the consensus scenario with given gains (no LMI solve per mutant)
    from netsim.models.scenario import resolve_scenario

    from netsim.runner import scenario_gains

    lcsys = _base("lcsys2022-heterogeneous", steps=20, trials=2)
    gains = scenario_gains(resolve_scenario("lcsys2022-heterogeneous"))
    lcsys["gains"] = {"method": "given", "K": [K.tolist() for K in gains.K]}
    links = _base("lcsys2022-time-varying", steps=20, trials=2)
    links["gains"] = copy.deepcopy(lcsys["gains"])
    links["links"] = {"loss": {"model": "gilbert-elliott", "p": 0.05, "r": 0.3},
                      "buffer": {"capacity": "tau+1", "policy": "drop-oldest"},
                      "outages": [[5, 8]]}
    return {"lcsys": lcsys, "links": links,
            "aoi": _base("aoi-example", steps=15),
            "dkfe": _base("dkfe-example1", steps=10, trials=2)}


BASES = _bases()


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value[:4]):
            out += _paths(v, (*prefix, i))
    return out


def _set(data: Any, path: tuple, value: Any, delete: bool = False) -> None:
    for key in path[:-1]:
        data = data[key]
    if delete:
        del data[path[-1]]
    else:
        data[path[-1]] = value


ODD = st.one_of(
    st.integers(-10**15, 10**15),
    st.sampled_from([0, -1, 1, 2, 10**9, 10**12, -10**9]),
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, 1e9, -1e-9]),
    st.text(alphabet="abcxyz-_:.é ", max_size=6),
    st.sampled_from(["", "none", "random", "given", "tau+1", "fixed", "compensated"]),
    st.booleans(),
    st.lists(st.integers(-2, 5), max_size=4),
    st.lists(st.lists(st.floats(-2, 2, width=32), min_size=0, max_size=3), max_size=3),
    st.just([]), st.just({}), st.just([[]]),
    st.dictionaries(st.sampled_from(["distribution", "model", "p", "value", "x"]),
                    st.one_of(st.integers(-3, 3), st.text(max_size=3)), max_size=2),
)

CLI = st.lists(st.sampled_from([
    ["--steps", "0"], ["--steps", "-3"], ["--steps", "100000000"], ["--steps", "7"],
    ["--trials", "0"], ["--trials", "100000000"], ["--trials", "3"], ["--seed", "-1"],
    ["--seed", "5"], ["--tau", "-1"], ["--tau", "2"], ["--tau", "1000000000"],
    ["--estimators", "compensated"], ["--estimators", ","], ["--estimators", "nope"],
    ["--estimators", "local-kf,centralized-kf"], ["--estimators", "x:y"],
    ["--engine", "events"], ["--engine", "vectorised"], ["--noise", "-1"],
    ["--noise", "0.01"], ["--rho", "0.5"], ["--gains", "rate"], ["--delayed", "age"],
    ["--json"],
]), max_size=3)


@st.composite
def mutants(draw) -> tuple[str, list[str], dict[str, bytes]]:
    name = draw(st.sampled_from(sorted(BASES)))
    data = copy.deepcopy(BASES[name])
    kind = draw(st.sampled_from(["value", "value", "value", "delete", "add", "encoding",
                                 "cli", "cli"]))
    text = None
    paths = _paths(data)
    if kind == "value":
        path = draw(st.sampled_from(paths))
        value = draw(ODD)
        if path in (("run", "steps"), ("run", "trials")) and isinstance(value, int) \
                and not isinstance(value, bool) and 2000 < value < 10**8:
            # a long but legitimate run is not a fuzz failure; an absurd one must be
            # refused at once: push the middle of the range to the absurd end
            value += 10**8
        _set(data, path, value)
    elif kind == "delete":
        path = draw(st.sampled_from(paths))
        _set(data, path, None, delete=True)
    elif kind == "add":
        tables = [p for p in paths if isinstance(_get(data, p), dict)] or [()]
        table = draw(st.sampled_from(tables))
        target = _get(data, table) if table else data
        target[draw(st.sampled_from(["extra", "tau", "seed", "P", "links", "weights"]))] = \
            draw(ODD)
    text = to_toml(data)
    raw = text.encode()
    if kind == "encoding":
        how = draw(st.sampled_from(["bom", "truncate", "flip", "latin1", "nul"]))
        if how == "bom":
            raw = b"\xef\xbb\xbf" + raw
        elif how == "truncate":
            raw = raw[: draw(st.integers(0, len(raw)))]
        elif how == "flip":
            i = draw(st.integers(0, len(raw) - 1))
            raw = raw[:i] + bytes([draw(st.integers(0, 255))]) + raw[i + 1:]
        elif how == "latin1":
            raw = raw.replace(b'name = "', 'name = "\xe9'.encode("latin-1"), 1)
        else:
            raw = raw[:20] + b"\x00" + raw[20:]
    args = [a for pair in (draw(CLI) if kind == "cli" else []) for a in pair]
    return name, ["run", "scenario.toml", "--no-progress", *args], {"scenario.toml": raw}


def _get(data: Any, path: tuple) -> Any:
    for key in path:
        data = data[key]
    return data


def check(reply: dict[str, Any], argv: list[str], raw: bytes) -> None:
    where = f"argv {argv}, scenario:\n{raw[:1500].decode(errors='replace')}"
    assert reply["escaped"] is None, f"{reply['escaped']}\n{where}"
    err = reply["stderr"]
    assert "Traceback" not in err, f"{err}\n{where}"
    assert "Warning:" not in err, f"a raw warning reached stderr: {err}\n{where}"
    assert reply["cpu_seconds"] < TIME_LIMIT_S, f"{reply['cpu_seconds']:.1f} s CPU\n{where}"
    if reply["code"] == 0:
        assert reply["stdout_bytes"] > 0, f"exit 0 without a result\n{where}"
    else:
        assert reply["code"] in (2, 3), f"exit {reply['code']}: {err}\n{where}"
        lines = [line for line in err.splitlines() if not line.startswith(
            ("netsim run: note:", "netsim run: warning:"))]
        assert len(lines) == 1, f"not one line: {err!r}\n{where}"


FUZZ = settings(max_examples=300, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


@FUZZ
@given(mutants())
def test_mutated_scenarios_run_or_are_refused_in_one_line(worker, mutant):
    _, argv, files = mutant
    check(worker.run(argv, files), argv, files["scenario.toml"])


@pytest.mark.slow
@settings(FUZZ, max_examples=3000, derandomize=False)
@given(mutants())
def test_mutated_scenarios_many(worker, mutant):
    _, argv, files = mutant
    check(worker.run(argv, files), argv, files["scenario.toml"])


def test_the_bases_run(worker):
    # the unmutated scenarios succeed: the fuzz starts from valid inputs
    for name, data in BASES.items():
        raw = to_toml(data).encode()
        reply = worker.run(["run", "scenario.toml", "--no-progress"], {"scenario.toml": raw})
        assert reply["code"] == 0 and reply["escaped"] is None, (name, reply)
