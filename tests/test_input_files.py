"""One rule for input files (issue 29): regular files only, a size cap checked before a
byte is read, TOML depth checked before parsing.

Each case runs ``netsim run`` in a subprocess under a 4 GB address-space limit and a
generous timeout (a hang or a memory blow-up fails the test; the timeout is far above
the fraction of a second each case takes) and asserts exit 2, one line naming the file,
no traceback.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from netsim.models.inputfiles import InputFileError, check_toml_depth, read_input_bytes

LIMIT = 4 * 1024 ** 3
TIMEOUT = 120


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def netsim(*args: str, env: dict[str, str] | None = None, cwd: Path | None = None
           ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "netsim.cli", *args], capture_output=True,
                          text=True, timeout=TIMEOUT, preexec_fn=_limit, cwd=cwd,
                          env={**os.environ, **(env or {})}, stdin=subprocess.DEVNULL)


def one_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("netsim run: error:"), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


def test_special_files_are_refused_before_reading(tmp_path):
    fifo = tmp_path / "s.toml"
    os.mkfifo(fifo)
    assert "named pipe" in one_line(netsim("run", str(fifo)))
    assert "character device" in one_line(netsim("run", "/dev/zero"))


def test_deep_toml_is_refused_before_parsing(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text("a" + ".a" * 20000 + " = 1\n")
    nested = tmp_path / "nested.toml"
    nested.write_text("x = " + "{a = " * 5000 + "1" + "}" * 5000 + "\n")
    arrays = tmp_path / "arrays.toml"
    arrays.write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
    for path in (deep, nested, arrays):
        line = one_line(netsim("run", str(path)))
        assert str(path) in line and "nested deeper than" in line


def test_a_scenario_over_the_size_cap_is_refused_naming_the_cap(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * 2000)
    line = one_line(netsim("run", str(big), env={"NETSIM_MAX_SCENARIO_BYTES": "1000"}))
    assert str(big) in line and "MiB" in line and "NETSIM_MAX_SCENARIO_BYTES" in line


def test_a_latency_file_must_be_a_regular_file(tmp_path):
    scenario = Path(__file__).resolve().parents[1] / "models" / "scenarios" / \
        "lcsys2022-heterogeneous.toml"
    text = scenario.read_text()
    for name, target in (("zero", "/dev/zero"), ("pipe", str(tmp_path / "lat.csv"))):
        if name == "pipe":
            os.mkfifo(target)
        s = tmp_path / f"{name}.toml"
        s.write_text(text + '\n[links]\ndelay = { distribution = "empirical", file = "'
                     + target + '" }\n')
        line = one_line(netsim("run", str(s), "--steps", "5", "--trials", "1"))
        assert target in line and "not a regular file" in line


def test_the_rule_in_isolation(tmp_path):
    ok = tmp_path / "ok.txt"
    ok.write_bytes(b"12345")
    assert read_input_bytes(ok, "file", 5) == b"12345"
    with pytest.raises(InputFileError, match="more than"):
        read_input_bytes(ok, "file", 4)
    with pytest.raises(InputFileError, match="cannot read"):
        read_input_bytes(tmp_path / "missing", "file", 4)
    # ordinary documents pass: long arrays of floats, dotted headers, inline tables
    check_toml_depth("A = [" + ", ".join(["[" + ", ".join(["0.5"] * 300) + "]"] * 3)
                     + "]\n[t.u.v]\nk = 'a.b.c.d.e'\n[[x.y]]\nz = {a.b = 1, c = 2}\n", "ok")
    with pytest.raises(InputFileError, match="line 2"):
        check_toml_depth("a = 1\nb" + ".b" * 70 + " = 2\n", "doc", max_depth=64)


def test_a_gain_cache_entry_that_is_a_pipe_is_ignored_not_waited_for(tmp_path):
    cache = tmp_path / "cache"
    env = {"NETSIM_CACHE_DIR": str(cache)}
    first = netsim("design", "lcsys2022-heterogeneous", "--json", env=env)
    assert first.returncode == 0, first.stderr
    (entry,) = cache.glob("*.npz")
    entry.unlink()
    os.mkfifo(entry)
    again = netsim("design", "lcsys2022-heterogeneous", "--json", env=env)
    assert again.returncode == 0, again.stderr
    warn = [ln for ln in again.stderr.splitlines() if ln.strip()]
    assert len(warn) == 1 and "not a regular file" in warn[0] and str(entry) in warn[0]
    assert json.loads(again.stdout)["design"]["L"] == json.loads(first.stdout)["design"]["L"]
    assert entry.is_file()  # rewritten as a regular file
