"""Formats 1 and 2 read alike; format 2's time origin and bit-reproducibility.

The format-1 files in tests/fixtures were written by the format-1 recorder (netsim before
format 2) with the commands below. The format-2 file of the same run is written again by
the same command (consensus: with the fixture's gains, since an LMI solve repeats only to
the solver's tolerance), or transcoded from the fixture's recorded observer calls (AoI:
its errors reach 1e-19, where another numpy rounds differently). Everything the reader
derives (arrays, link events) and every report (inspect, replay, analyze) must be the
same for both files to round-off, apart from topic names, path and format fields.
"""

from __future__ import annotations

import json
from dataclasses import replace
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


def _fixture_gains(fixture: Path):
    """``scenario_gains`` giving the gains stored in ``fixture`` (and its design's
    metadata): an LMI solve is reproducible only to the solver's tolerance (about 1e-8
    between CLARABEL versions), so a fresh run designs them again differently."""
    from netsim import runner

    old = read_trace(fixture)
    design = runner.scenario_gains

    def gains(scenario):
        fresh = design(scenario)
        n = len(fresh.K)
        return replace(fresh, K=tuple(old.matrices[f"K_{i}"] for i in range(n)),
                       L=tuple(old.matrices[f"L_{i}"] for i in range(n)),
                       rho=float(old.run["rho_delay_free"]), method=old.run["gains_method"],
                       solver=old.run["gains_solver"],
                       certified=old.run["gains_certified"] == "True")
    return gains


def _transcode(fixture: Path, out: Path, trace_format: int = 2) -> None:
    """Write the run a format-1 file holds again through today's recorder: its recorded
    observer calls (plant, updates, freshness, link events), in the file's order."""
    from types import SimpleNamespace

    from netsim.traces.recorder import TraceRecorder
    from netsim.traces.schemas import parse_topic

    old = read_trace(fixture)
    keep = {k: v for k, v in old.run.items()
            if k.startswith(("family_", "gains_")) or k == "rho_delay_free"}
    recorder = TraceRecorder(out, scenario_metadata=old.scenario, matrices=old.matrices,
                             family=old.family, trial=old.trial, seed=old.seed,
                             sample_period=old.sample_period, steps=int(old.run["steps"]),
                             run_metadata=keep, trace_format=trace_format)
    with recorder:
        for record in old.messages:
            info, m = parse_topic(record.topic), record.message
            if info.kind == "plant":
                recorder.on_plant(int(m.step), np.array(m.state),
                                  [old.measurements(i)[int(m.step)] for i in old.sensors])
            elif info.kind == "estimate":
                estimate = np.array(m.estimate)
            elif info.kind == "update":
                recorder.on_update(int(m.agent), int(m.step), estimate,
                                   dict(zip(map(int, m.neighbours), map(int, m.effective_delay),
                                            strict=True)))
            elif info.kind == "freshness":
                recorder.on_freshness(int(m.agent), int(m.step), list(m.index),
                                      list(m.adopted_from), list(m.substate_dim))
            elif info.kind == "link":
                message = SimpleNamespace(
                    sender=int(m.sender), receiver=int(m.receiver), sent_step=int(m.sent_step),
                    sequence=int(m.sequence), payload=np.array(m.payload),
                    send_time=float(m.send_time), arrival_time=float(m.arrival_time),
                    delay_steps=int(m.delay_steps))
                if m.event == "sent":
                    recorder.on_sent(message)
                elif m.event == "delivered":
                    recorder.on_delivered(message, bool(m.accepted))
                else:
                    recorder.on_dropped(message, str(m.reason), float(m.event_time))


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """Each format-1 fixture and a format-2 file of the same run. The consensus run is
    run again (with the fixture's gains); the AoI run is transcoded: its deadbeat
    observer drives the errors to 1e-19, where each numpy and LAPACK build rounds
    differently, and the analytics of those errors (decay slopes, the plot) follow."""
    from netsim import runner

    folder = tmp_path_factory.mktemp("formats")
    out = {}
    for name, args in RUNS.items():
        path = folder / name.replace("format1", "format2")
        if "aoi" in name:
            _transcode(FIXTURES / name, path)
        else:
            with pytest.MonkeyPatch.context() as patch:
                patch.setattr(runner, "scenario_gains", _fixture_gains(FIXTURES / name))
                assert main(["run", *args, "--engine", "events", "--trace", str(path),
                             "--trace-format", "2", "--no-progress", "--json"]) == 0
        out[name] = (FIXTURES / name, path)
    return out


def _close(a, b, what: str) -> None:
    """Equal to round-off: relative 1e-12 of the values' scale (the AoI observer's
    deadbeat errors reach 1e-19, where its design's own round-off shows)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    finite = np.abs(a[np.isfinite(a)])
    scale = 1.0 + (finite.max() if finite.size else 0.0)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale**2, err_msg=what)


def _same_report(a, b, where: str = "") -> None:
    """Equal reports, numbers to round-off (relative 1e-9): the fixtures were written by
    another numpy and BLAS, whose sums differ in the last bits."""
    if isinstance(a, dict) and isinstance(b, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _same_report(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), where
        for n, (x, y) in enumerate(zip(a, b, strict=True)):
            _same_report(x, y, f"{where}[{n}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert a == b or (np.isnan(a) and np.isnan(b)) or np.isclose(
            a, b, rtol=1e-9, atol=1e-12), (where, a, b)
    else:
        assert a == b, (where, a, b)


def _report(capsys, command: str, path: Path) -> dict:
    assert main([command, str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    for key in ("path", "topics", "file_topics", "trace_format", "time_origin"):
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
        _close(getattr(old, method)(), getattr(new, method)(), method)
    for i in old.sensors:
        _close(old.measurements(i), new.measurements(i), f"sensor {i}")
    for link in old.links:
        a, b = old.link_events(*link), new.link_events(*link)
        assert len(a) == len(b) > 0
        for x, y in zip(a, b, strict=True):
            assert x._replace(log_time=0, payload=[]) == y._replace(log_time=0, payload=[])
            assert old.sim_time_ns(x.log_time) == new.sim_time_ns(y.log_time)
            np.testing.assert_allclose(x.payload, y.payload, rtol=1e-12)
    for command in ("inspect", "replay", "analyze"):
        _same_report(_report(capsys, command, old_path), _report(capsys, command, new_path),
                     command)


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
        assert reader.get_header().library.startswith("netsim-trace/3 ")  # the default
    np.testing.assert_array_equal(trace.estimates(), read_trace(a).estimates())


def test_plot_draws_both_formats_alike(pairs, tmp_path):
    old = [str(pairs[name][0]) for name in RUNS]
    new = [str(pairs[name][1]) for name in RUNS]
    assert main(["plot", *old, "-o", str(tmp_path / "old.png")]) == 0
    assert main(["plot", *new, "-o", str(tmp_path / "new.png")]) == 0
    from matplotlib.image import imread

    a, b = imread(tmp_path / "old.png"), imread(tmp_path / "new.png")
    assert a.shape == b.shape
    # the same picture: curves equal to round-off may move an antialiased edge pixel
    assert np.mean(np.any(a != b, axis=-1)) < 1e-3
