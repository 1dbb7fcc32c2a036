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
import os
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


# -- the attack cases of issue 29, each under the same limits -------------------------------


def _snapshot(folder: Path) -> dict[str, Any]:
    """Every entry under ``folder``: a link's target, a special file's kind, a regular
    file's bytes (so that a test can say no file changed)."""
    import stat as st_

    seen: dict[str, Any] = {}
    for path in sorted(folder.rglob("*")):
        mode = path.lstat().st_mode
        rel = str(path.relative_to(folder))
        if st_.S_ISLNK(mode):
            seen[rel] = ("link", str(path.readlink()))
        elif st_.S_ISREG(mode):
            seen[rel] = ("file", path.read_bytes())
        elif st_.S_ISDIR(mode):
            seen[rel] = ("dir",)
        else:
            seen[rel] = ("special", st_.S_IFMT(mode))
    return seen


def _nested_key(depth: int) -> str:
    return "a = 1\n" + ".".join(["k"] * depth) + " = 1\n"


def _nested_inline(depth: int) -> str:
    return "x = " + "{a = " * depth + "1" + "}" * depth + "\n"


ATTACKS: dict[str, tuple[list[str], str]] = {
    # name: (argv, the words the one line must have); {d} is the case's folder
    "sweep --out equal to --csv": (
        ["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "4", "--out", "{d}/r.jsonl",
         "--csv", "{d}/r.jsonl"], "another output"),
    "run --trace through a symlink": (
        ["run", "lcsys2022-heterogeneous", "--steps", "5", "--trials", "1", "--trace",
         "{d}/t.mcap", "--force", "--no-progress"], "symbolic link"),
    "layout -o through a symlink": (
        ["layout", "{d}/trace.mcap", "-o", "{d}/t.json", "--force"], "symbolic link"),
    "plot -o onto an existing file": (
        ["plot", "{d}/trace.mcap", "-o", "{d}/old.png"], "exists"),
    "run --trace onto its own scenario": (
        ["run", "{d}/s.toml", "--trace", "{d}/s.toml", "--force", "--estimators",
         "compensated", "--trials", "1", "--no-progress"], "input"),
    "run /dev/zero": (["run", "/dev/zero", "--no-progress"], "/dev/zero"),
    "empirical latency file /dev/zero": (
        ["run", "{d}/zero-latency.toml", "--no-progress"], "/dev/zero"),
    "bench sweep --out /dev/full": (
        ["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "4", "--out", "/dev/full"],
        "/dev/full"),
    "a FIFO as the scenario": (["run", "{d}/fifo.toml", "--no-progress"], "fifo"),
    "a FIFO as a latency trace": (["run", "{d}/fifo-latency.toml", "--no-progress"], "fifo"),
    "fusion run --trials 1e9": (
        ["fusion", "run", "dkfe-example1", "--trials", "1000000000"], "--trials"),
    "bench sweep --sizes 1e9": (
        ["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "1000000000", "--out",
         "{d}/big.jsonl"], "--sizes"),
    "1,000,000 agents": (["run", "{d}/million.toml", "--no-progress"], "1,000,000 agents"),
    "a key nested 20,000 deep": (["run", "{d}/deep-key.toml", "--no-progress"], "deep"),
    "5,000 nested inline tables": (["run", "{d}/deep-inline.toml", "--no-progress"],
                                   "deep"),
    "a 36 MB scenario": (["run", "{d}/huge.toml", "--no-progress"], "MiB"),
    "--tau 1e20": (["run", "lcsys2022-heterogeneous", "--tau", str(10 ** 20),
                    "--no-progress"], "--tau"),
    "delays.tau = 2^63": (["run", "{d}/tau63.toml", "--no-progress"], "delays.tau"),
    "--estimators os:system": (["run", "lcsys2022-heterogeneous", "--estimators",
                                "os:system", "--no-progress"], "os:system"),
    "--estimators builtins:print": (["run", "lcsys2022-heterogeneous", "--estimators",
                                     "builtins:print", "--no-progress"], "builtins:print"),
    "--estimators json:loads": (["run", "lcsys2022-heterogeneous", "--estimators",
                                 "json:loads", "--no-progress"], "json:loads"),
    "sweep --out into a missing folder": (
        ["bench", "sweep", "lcsys2022-heterogeneous", "--sizes", "4", "--out",
         "{d}/missing/r.jsonl"], "does not exist"),
    "analyze --tau-max 1e18": (["analyze", "lcsys2022-homogeneous", "--tau-max",
                                str(10 ** 18)], "--tau-max"),
}


@pytest.fixture(scope="module")
def attack_trace(worker, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("attack-trace")
    trace = folder / "trace.mcap"
    reply = worker.run(["run", "lcsys2022-heterogeneous", "--steps", "10", "--trials", "1",
                        "--estimators", "compensated", "--trace", str(trace),
                        "--no-progress"], {})
    assert reply["code"] == 0, reply
    return trace


def _attack_folder(d: Path, trace: Path) -> None:
    """The files the attacks name: victims behind links, special files, huge inputs."""
    import shutil

    (d / "victim.txt").write_text("victim")
    (d / "old.png").write_bytes(b"\x89PNG an earlier plot")
    (d / "t.mcap").symlink_to(d / "victim.txt")
    (d / "t.json").symlink_to(d / "victim.txt")
    shutil.copy(trace, d / "trace.mcap")
    lcsys = copy.deepcopy(BASES["lcsys"])
    (d / "s.toml").write_text(to_toml(lcsys))
    for name, source in (("zero-latency.toml", "/dev/zero"),
                         ("fifo-latency.toml", str(d / "fifo"))):
        data = copy.deepcopy(lcsys)
        data["links"] = {"delay": {"distribution": "empirical", "file": source}}
        (d / name).write_text(to_toml(data))
    os.mkfifo(d / "fifo")
    os.mkfifo(d / "fifo.toml")
    text = (ROOT / "examples" / "geometric-100k.toml").read_text()
    (d / "million.toml").write_text(
        text.replace("sensors = 100000", "sensors = 1000000")
        .replace("agents = 100000", "agents = 1000000")
        .replace("radius = 0.005641895835477563", "radius = 0.0017841241161527712"))
    (d / "deep-key.toml").write_text(_nested_key(20_000))
    (d / "deep-inline.toml").write_text(_nested_inline(5_000))
    with open(d / "huge.toml", "w") as f:
        f.write(to_toml(lcsys))
        line = "# " + "x" * 1022 + "\n"
        f.write(line * (36 * 1024))
    tau63 = copy.deepcopy(lcsys)
    tau63.setdefault("delays", {})["tau"] = 2 ** 63
    (d / "tau63.toml").write_text(to_toml(tau63))


@pytest.mark.parametrize("name", list(ATTACKS))
def test_the_attack_cases_are_refused_in_one_line_and_change_no_file(
        name, worker, attack_trace, tmp_path):
    """Each case of issue 29, in the fuzz worker (4 GB address space, CPU-time limit):
    exit 2 with one line that names what is wrong, no traceback, and no file changed."""
    _attack_folder(tmp_path, attack_trace)
    before = _snapshot(tmp_path)
    argv_template, words = ATTACKS[name]
    argv = [a.replace("{d}", str(tmp_path)) for a in argv_template]
    reply = worker.run(argv, {})
    assert reply["escaped"] is None, reply["escaped"]
    err = reply["stderr"]
    assert "Traceback" not in err, err
    assert reply["cpu_seconds"] < TIME_LIMIT_S, reply
    assert reply["code"] == 2, (reply["code"], err)
    lines = [line for line in err.splitlines()
             if not line.startswith(("netsim run: note:", "netsim run: warning:"))]
    assert len(lines) == 1, err
    assert words.lower() in lines[0].lower(), lines[0]
    assert _snapshot(tmp_path) == before, "a file changed"
