"""Formats 1 and 2 read alike; format 2's time origin and bit-reproducibility.

The format-1 files in tests/fixtures were written by the format-1 recorder (netsim before
format 2) with the commands below; the same commands today write format 2. Everything the
reader derives (arrays, link events) and every report (inspect, replay, analyze) must be
the same for both files, apart from topic names, path and format fields.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from netsim.traces.reader import read_trace
from netsim.traces.schemas import DEFAULT_TIME_ORIGIN_NS, parse_time_origin

from netsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
#: fixture -> the netsim run arguments that wrote it (format 1) / write it (format 2)
RUNS = {
    "format1-consensus.mcap": ["lcsys2022-heterogeneous", "--tau", "3", "--trials", "1",
                               "--steps", "30", "--estimators", "compensated"],
    # synchronous delays: drawn alike in seed layouts 1 and 2 (asynchronous ones are not)
    "format1-aoi-lossy-synchronous.mcap": [
        str(FIXTURES / "aoi-lossy-synchronous.toml"),
        "--trials", "1", "--steps", "20", "--estimators", "aoi"],
}


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("formats")
    out = {}
    for name, args in RUNS.items():
        path = folder / name.replace("format1", "format2")
        assert main(["run", *args, "--engine", "events", "--trace", str(path),
                     "--no-progress", "--json"]) == 0
        out[name] = (FIXTURES / name, path)
    return out


def _report(capsys, command: str, path: Path) -> dict:
    assert main([command, str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    for key in ("path", "topics", "trace_format", "time_origin"):
        data.pop(key, None)
    return data


@pytest.mark.parametrize("name", list(RUNS))
def test_format1_and_format2_read_the_same(pairs, name, capsys):
    old_path, new_path = pairs[name]
    old, new = read_trace(old_path), read_trace(new_path)
    assert (old.format, new.format) == (1, 2)
    assert old.library.startswith("netsim-trace/1 ") and new.library.startswith(
        "netsim-trace/2 ")
    assert (old.time_origin_ns, new.time_origin_ns) == (0, DEFAULT_TIME_ORIGIN_NS)
    assert old.agents == new.agents and old.links == new.links and old.sensors == new.sensors
    assert old.steps == new.steps and old.n_states == new.n_states
    for method in ("states", "estimates", "squared_errors", "effective_delays", "freshness"):
        np.testing.assert_allclose(getattr(old, method)(), getattr(new, method)(),
                                   rtol=1e-12, atol=0, err_msg=method)
    for i in old.sensors:
        np.testing.assert_allclose(old.measurements(i), new.measurements(i), rtol=1e-12)
    for link in old.links:
        a, b = old.link_events(*link), new.link_events(*link)
        assert len(a) == len(b) > 0
        for x, y in zip(a, b, strict=True):
            assert x._replace(log_time=0, payload=[]) == y._replace(log_time=0, payload=[])
            assert old.sim_time_ns(x.log_time) == new.sim_time_ns(y.log_time)
            np.testing.assert_allclose(x.payload, y.payload, rtol=1e-12)
    for command in ("inspect", "replay", "analyze"):
        assert _report(capsys, command, old_path) == _report(capsys, command, new_path), command


def test_lossy_fixture_has_drops_and_freshness(pairs):
    old, new = (read_trace(p) for p in pairs["format1-aoi-lossy-synchronous.mcap"])
    drops = [e for link in new.links for e in new.link_events(*link, "dropped")]
    assert drops and {e.reason for e in drops} == {"link down"}
    assert set(new.drop_reasons.values()) == {"link down"}
    assert (new.freshness() >= -1).all() and (old.freshness() >= -1).all()


def test_trace_driven_delays_read_both_formats(pairs, tmp_path, capsys):
    """A scenario whose links replay a trace (delay model ``trace``) runs the same from
    the format-1 file and from the format-2 file of the same run."""
    results = []
    base = (ROOT / "models" / "scenarios" / "lcsys2022-heterogeneous.toml").read_text()
    for source in pairs["format1-consensus.mcap"]:
        scenario = tmp_path / f"replay-{source.stem}.toml"
        scenario.write_text(base + f'\n[links]\ndelay = {{ distribution = "trace", '
                            f'file = "{source}" }}\n')
        assert main(["run", str(scenario), "--estimators", "compensated", "--steps", "25",
                     "--trials", "1", "--json", "--no-progress"]) == 0, capsys.readouterr().err
        data = json.loads(capsys.readouterr().out)
        results.append(data["estimators"]["compensated"])
    assert results[0] == results[1]


def test_time_origin_and_bit_reproducible_files(tmp_path):
    args = ["run", "lcsys2022-heterogeneous", "--trials", "1", "--steps", "8",
            "--estimators", "compensated", "--no-progress", "--json"]
    a, b, c = tmp_path / "a.mcap", tmp_path / "b.mcap", tmp_path / "c.mcap"
    assert main([*args, "--trace", str(a)]) == 0
    assert main([*args, "--trace", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()  # the default origin is fixed
    when = "2026-05-01T12:00:00Z"
    assert main([*args, "--trace", str(c), "--time-origin", when]) == 0
    origin = parse_time_origin(when)
    assert origin == 1_777_636_800 * 10**9  # seconds from 1970-01-01 to that instant
    trace = read_trace(c)
    assert trace.time_origin_ns == origin and trace.run["time_origin"] == when
    ts = trace.sample_period
    for k, record in enumerate(trace.records["/plant/state"]):
        assert record.log_time == origin + round(k * ts * 1e9)
    with open(c, "rb") as f:  # the plain reader sees the same times
        reader = make_reader(f)
        stats = reader.get_summary().statistics
        assert stats.message_start_time == origin
        assert reader.get_header().library.startswith("netsim-trace/2 ")
    np.testing.assert_array_equal(trace.estimates(), read_trace(a).estimates())


def test_plot_draws_both_formats_alike(pairs, tmp_path):
    old = [str(pairs[name][0]) for name in RUNS]
    new = [str(pairs[name][1]) for name in RUNS]
    assert main(["plot", *old, "-o", str(tmp_path / "old.png")]) == 0
    assert main(["plot", *new, "-o", str(tmp_path / "new.png")]) == 0
    assert (tmp_path / "old.png").read_bytes() == (tmp_path / "new.png").read_bytes()
