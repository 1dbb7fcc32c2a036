"""Foxglove layouts (``netsim layout``, ``netsim run --trace --layout``): every message
path a layout references exists in the trace, checked against the file alone (its
channels, the FileDescriptorSet stored as schema data and the decoded messages, read
with the plain ``mcap`` reader), for a consensus trace and a lossy AoI trace, each in
trace format 2 (one topic per agent and link event) and format 3 (one message per step
and kind: indexed paths into the per-step arrays, the index within the array of a real
message of the topic and meaning what the ``trace_layout`` metadata says)."""

from __future__ import annotations

import json
import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from netsim.models.scenario import resolve_scenario
from netsim.traces.layout import (
    foxglove_layout,
    layout_paths,
    layout_source,
    message_path_series,
    render_layout,
    write_layout,
)
from netsim.traces.reader import read_trace

from netsim.cli import main
from netsim.runner import run_monte_carlo

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
_F = descriptor_pb2.FieldDescriptorProto
_NUMERIC = {_F.TYPE_DOUBLE, _F.TYPE_FLOAT, _F.TYPE_FIXED64, _F.TYPE_SFIXED64, _F.TYPE_FIXED32,
            _F.TYPE_SFIXED32, _F.TYPE_UINT64, _F.TYPE_INT64, _F.TYPE_UINT32, _F.TYPE_INT32,
            _F.TYPE_SINT64, _F.TYPE_SINT32, _F.TYPE_BOOL}


@pytest.fixture(scope="module")
def traces(tmp_path_factory):
    folder = tmp_path_factory.mktemp("layouts")
    consensus = folder / "consensus.mcap"
    assert main(["run", "lcsys2022-heterogeneous", "--tau", "3", "--trials", "1",
                 "--steps", "25", "--estimators", "compensated", "--trace", str(consensus),
                 "--layout", "--trace-format", "2", "--no-progress", "--json"]) == 0
    aoi = folder / "aoi.mcap"
    assert main(["run", str(ROOT / "examples" / "aoi-random-lossy.toml"), "--trials", "1",
                 "--steps", "20", "--estimators", "aoi", "--trace", str(aoi), "--layout",
                 "--trace-format", "2", "--no-progress", "--json"]) == 0
    out = {"consensus": consensus, "aoi": aoi}
    # format 3 through the API, then the layout --layout writes
    for kind, scenario, family, steps in (
            ("consensus3", "lcsys2022-heterogeneous", "compensated", 25),
            ("aoi3", str(ROOT / "examples" / "aoi-random-lossy.toml"), "aoi", 20)):
        path = folder / f"{kind}.mcap"
        run_monte_carlo(resolve_scenario(scenario), trials=1, steps=steps, families=[family],
                        trace=str(path), trace_options={"trace_format": 3})
        write_layout(path)
        out[kind] = path
    return out


def _file_contents(path: Path):
    """Topics -> (message descriptor, first decoded message, field -> the longest array
    of that field in any message of the topic), from the file alone."""
    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(
                log_time_order=False):
            if channel.topic not in out:
                schema = summary.schemas[channel.schema_id]
                fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                package, _, name = schema.name.rpartition(".")
                [message] = [m for fd in fds.file if fd.package == package
                             for m in fd.message_type if m.name == name]
                out[channel.topic] = (message, decoded, {})
            message, _first, longest = out[channel.topic]
            for fd in message.field:
                if fd.label == _F.LABEL_REPEATED:
                    size = len(getattr(decoded, fd.name))
                    longest[fd.name] = max(longest.get(fd.name, 0), size)
    return out


def _trace_layout(path: Path) -> dict:
    """The last ``trace_layout`` metadata record of a format-3 file, JSON-decoded."""
    with open(path, "rb") as f:
        records = [r for r in make_reader(f).iter_metadata() if r.name == "trace_layout"]
    assert records, f"{path.name}: no trace_layout metadata"
    return {key: json.loads(value) for key, value in records[-1].metadata.items()}


def _labels(layout: dict) -> dict[str, str]:
    return {p["value"]: p["label"] for key, config in layout["configById"].items()
            if key.startswith("Plot!") for p in config["paths"]}


def _titles(layout: dict, tab_leaves: list[str]) -> list[str]:
    return [layout["configById"][leaf]["title"] for leaf in tab_leaves]


def _check_paths(layout: dict, path: Path) -> list[str]:
    contents = _file_contents(path)
    paths = [p["value"] for key, config in layout["configById"].items()
             if key.startswith("Plot!") for p in config["paths"]]
    assert paths
    for value in paths:
        m = re.fullmatch(r"(/[A-Za-z0-9_/]+)\.(\w+)(?:\[(\d+)\])?", value)
        assert m, f"not a plain message path: {value}"
        topic, name, index = m.group(1), m.group(2), m.group(3)
        assert topic in contents, f"{value}: no topic {topic} in {path.name}"
        descriptor, _first, longest = contents[topic]
        [fd] = [f for f in descriptor.field if f.name == name] or [None]
        assert fd is not None, f"{value}: {descriptor.name} has no field {name}"
        assert fd.type in _NUMERIC, f"{value}: not a plottable field"
        if index is None:
            assert fd.label != _F.LABEL_REPEATED, f"{value}: an array needs an index"
        else:
            assert fd.label == _F.LABEL_REPEATED, f"{value}: not an array"
            # some message of the topic has that entry
            assert int(index) < longest[name], f"{value}: index out of range"
    return paths


def _leaves(tree):
    return [tree] if isinstance(tree, str) else _leaves(tree["first"]) + _leaves(tree["second"])


def _check_structure(layout: dict) -> dict[str, list[str]]:
    assert set(layout) >= {"configById", "globalVariables", "userNodes", "playbackConfig",
                           "layout"}
    config = layout["configById"]
    root = config[layout["layout"]]
    placed = []
    tabs = {}
    for tab in root["tabs"]:
        leaves = _leaves(tab["layout"])
        assert all(leaf in config for leaf in leaves)
        tabs[tab["title"]] = leaves
        placed += leaves
    plots = [key for key in config if key.startswith("Plot!")]
    assert sorted(placed) == sorted(plots)  # every panel placed once
    return tabs


@pytest.mark.parametrize("kind", ["consensus", "aoi"])
def test_layout_paths_exist_in_the_trace(traces, kind):
    """Format 2: one topic per agent and per link event."""
    path = traces[kind]
    layout = json.loads(path.with_name(f"{path.stem}.layout.json").read_text())
    tabs = _check_structure(layout)
    paths = _check_paths(layout, path)
    contents = _file_contents(path)
    agents = sorted(t for t in contents if re.fullmatch(r"/agent_\d+/estimate", t))
    # every agent's error norm and the state against every agent's estimate
    assert {f"{t}.error_norm" for t in agents} <= set(paths)
    assert "/plant/state.state[0]" in paths
    assert {f"{t}.estimate[0]" for t in agents} <= set(paths)
    delivered = [t for t in contents if t.endswith("/delivered")]
    assert {f"{t}.delay_steps" for t in delivered} <= set(paths)
    assert "Errors" in tabs and "State" in tabs and "Delays" in tabs
    if kind == "consensus":
        # effective delay of every link: one path per (receiver, in-neighbour)
        links = [t for t in contents if t.endswith("/sent")]
        effective = [p for p in paths if ".effective_delay[" in p]
        assert len(effective) == len(links) > 0
        assert "Age of information" not in tabs
    else:
        dropped = [t for t in contents if t.endswith("/dropped")]
        assert dropped and {f"{t}.sequence" for t in dropped} <= set(paths)
        fresh = [t for t in contents if t.endswith("/freshness")]
        assert {f"{t}.max_index" for t in fresh} <= set(paths) and fresh
        assert "Drops" in tabs and "Age of information" in tabs


@pytest.mark.parametrize("kind", ["consensus3", "aoi3"])
def test_format3_layout_paths_exist_and_mean_what_they_say(traces, kind):
    """Format 3: indexed paths into the per-step arrays, every index valid in a real
    message and naming the agent, link or update entry its label says."""
    path = traces[kind]
    layout = json.loads(path.with_name(f"{path.stem}.layout.json").read_text())
    assert layout == foxglove_layout(layout_source(path))
    tabs = _check_structure(layout)
    paths = _check_paths(layout, path)
    labels = _labels(layout)
    meta = _trace_layout(path)
    N, n = meta["agents"], meta["n_states"]
    links = [tuple(link) for link in meta["links"]]
    updates = [tuple(entry) for entry in meta["updates"]]
    assert {p.split(".")[0] for p in paths} <= {
        "/plant/state", "/agents/estimate", "/agents/update", "/agents/freshness",
        "/links/sent", "/links/dropped"}
    assert "Errors" in tabs and "State" in tabs and "Delays" in tabs
    # error norm and estimate entries of every agent, agent-major
    for i in range(N):
        assert labels[f"/agents/estimate.error_norm[{i}]"] == f"agent {i}"
        for s in range(min(n, 4)):
            assert labels[f"/agents/estimate.estimate[{i * n + s}]"] == f"agent {i}"
    assert {f"/plant/state.state[{s}]" for s in range(min(n, 4))} <= set(paths)
    # effective delay entry e is r_ij of updates[e]; sent delay l is links[l]
    effective = {p: label for p, label in labels.items() if ".effective_delay[" in p}
    # (entries that never hold a value are left out: test_shipped_layouts_...)
    assert effective.items() <= {f"/agents/update.effective_delay[{e}]": f"r {j}\u2192{i}"
                                 for e, (j, i) in enumerate(updates) if j != i}.items()
    assert len(effective) > 0
    sent = {p: label for p, label in labels.items() if p.startswith("/links/sent.")}
    assert sent.items() <= {f"/links/sent.delay_steps[{q}]": f"link {j}\u2192{i}"
                            for q, (j, i) in enumerate(links)}.items()
    assert sent
    # the -3 sentinel lies below the y axis: points, never joined into lines
    for leaf in tabs["Delays"]:
        config = layout["configById"][leaf]
        assert config["minYValue"] > -3
        assert not any(series["showLine"] for series in config["paths"])
    if kind == "consensus3":
        assert "Drops" not in tabs and "Age of information" not in tabs
    else:
        drops = {p: label for p, label in labels.items() if p.startswith("/links/dropped.")}
        assert drops and drops.items() <= {f"/links/dropped.link_reason[{q}]":
                                           f"link {j}\u2192{i}"
                                           for q, (j, i) in enumerate(links)}.items()
        assert any("link down" in t for t in _titles(layout, tabs["Drops"]))
        sizes = meta["freshness_sizes"]
        fresh = [i for i, size in enumerate(sizes) if size > 0]
        shown = {p for p in paths if p.startswith("/agents/freshness.max_index[")}
        assert shown and shown <= {f"/agents/freshness.max_index[{i}]" for i in fresh}
        start = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
        indexed = {p for p in paths if p.startswith("/agents/freshness.index[")}
        assert indexed and indexed <= {f"/agents/freshness.index[{start[i] + s}]"
                                       for i in fresh for s in range(sizes[i])}
        assert "Age of information" in tabs


def test_format3_path_series_are_the_messages(traces):
    """message_path_series (what render_layout draws) against the decoded messages:
    error_norm[i] is ||estimate[i*n : (i+1)*n] - state|| of the same step."""
    path = traces["consensus3"]
    n = _trace_layout(path)["n_states"]
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        state = {m.log_time: np.array(d.state) for _s, _c, m, d in
                 reader.iter_decoded_messages(topics=["/plant/state"])}
        estimates = [(m.log_time, d) for _s, _c, m, d in
                     reader.iter_decoded_messages(topics=["/agents/estimate"])]
    wanted = ["/agents/estimate.error_norm[1]", "/agents/estimate.estimate[7]",
              "/plant/state.state[2]", "/agents/estimate.error_norm[99]"]
    series = message_path_series(path, wanted)
    xs, norms = series["/agents/estimate.error_norm[1]"]
    assert xs == [float(k) for k in range(len(estimates))]  # seconds from time 0, Ts = 1
    for (t, d), norm in zip(estimates, norms, strict=True):
        error = np.array(d.estimate[n:2 * n]) - state[t]
        assert norm == pytest.approx(float(np.linalg.norm(error)))
    assert series["/agents/estimate.estimate[7]"][1] == [d.estimate[7] for _t, d in estimates]
    assert series["/plant/state.state[2]"][1] == [state[t][2] for t, _d in estimates]
    assert all(math.isnan(v) for v in series["/agents/estimate.error_norm[99]"][1])
    with pytest.raises(ValueError, match="array"):
        message_path_series(path, ["/agents/estimate.estimate"])
    with pytest.raises(ValueError, match="no field"):
        message_path_series(path, ["/agents/estimate.nothing[0]"])


def test_format3_render_and_a_file_without_summary(traces, tmp_path):
    """render_layout draws every format-3 panel from the file (every series has a
    value); a file cut before its summary (writer killed) gives the same layout."""
    for kind in ("consensus3", "aoi3"):
        path = traces[kind]
        layout = foxglove_layout(layout_source(path))
        series = message_path_series(path, layout_paths(layout))
        assert all(any(not math.isnan(v) for v in ys) for _xs, ys in series.values())
        png = render_layout(path, layout, tmp_path / f"{kind}.png", max_panels=20)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    path = traces["aoi3"]
    data = path.read_bytes()
    # the footer record (opcode, length, summary_start, ...) and the closing magic
    [summary_start] = struct.unpack("<Q", data[-28:-20])
    assert 0 < summary_start < len(data)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:summary_start])
    source = layout_source(cut)
    assert source.format == 3 and source.counts == layout_source(path).counts
    layout = foxglove_layout(source)
    assert layout == foxglove_layout(layout_source(path))
    assert message_path_series(cut, layout_paths(layout)) == message_path_series(
        path, layout_paths(layout))


def test_layout_command_and_figure(traces, tmp_path, capsys):
    out, png = tmp_path / "c.json", tmp_path / "c.png"
    assert main(["layout", str(traces["consensus"]), "-o", str(out), "--figure", str(png),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["layout"] == str(out) and data["figure"] == str(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    beside = traces["consensus"].with_name("consensus.layout.json")
    assert json.loads(out.read_text()) == json.loads(beside.read_text())  # same layout
    assert main(["layout", str(traces["consensus"]), "-o", str(out)]) == 2  # exists
    assert "exists" in capsys.readouterr().err
    # format 3: the same command; the figure evaluates its indexed paths
    out3, png3 = tmp_path / "a3.json", tmp_path / "a3.png"
    assert main(["layout", str(traces["aoi3"]), "-o", str(out3), "--figure", str(png3),
                 "--tabs", "Drops,Age of information", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["tabs"] == ["Errors", "State", "Delays", "Drops", "Age of information"]
    assert png3.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    beside = traces["aoi3"].with_name("aoi3.layout.json")
    assert json.loads(out3.read_text()) == json.loads(beside.read_text())
    assert foxglove_layout(read_trace(traces["aoi3"])) == json.loads(out3.read_text())


@pytest.mark.parametrize("args, message", [
    (["layout", str(FIXTURES / "format1-consensus.mcap"), "-o", "{tmp}/x.json"],
     "trace format 1"),
    (["layout", str(ROOT / "README.md"), "-o", "{tmp}/x.json"], "not an MCAP file"),
    (["layout", str(FIXTURES / "format1-consensus.mcap"), "-o", "{tmp}/x.txt"],
     "must be a .json file"),
    (["run", "lcsys2022-heterogeneous", "--layout"], "--layout needs --trace"),
    (["run", "lcsys2022-heterogeneous", "--time-origin", "0"], "--time-origin needs --trace"),
    (["run", "lcsys2022-heterogeneous", "--trace", "{tmp}/t.mcap", "--time-origin", "soon"],
     "--time-origin: time origin 'soon'"),
])
def test_bad_layout_requests(args, message, tmp_path, capsys):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


# -- issue 30: the layouts as Lichtblick shows them, on the shipped scenarios ----------

_SHIPPED = [  # (scenario, one estimator family): built-in and examples/*.toml
    ("lcsys2022-heterogeneous", "compensated"),
    ("aoi-example", "aoi"),
    (str(ROOT / "examples" / "aoi-random-lossy.toml"), "aoi"),
    (str(ROOT / "examples" / "rotation-uncompensated.toml"), "uncompensated"),
    (str(ROOT / "examples" / "consensus-on-information.toml"), "ci-filter"),
    (str(ROOT / "examples" / "dkfe-example2-lossy.toml"), "dkfe"),
]
_BACKGROUNDS = ("#ffffff", "#121217")  # the light and the dark theme


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    """Format-3 (default) traces and their layouts, written by netsim run --layout."""
    folder = tmp_path_factory.mktemp("shipped")
    out = {}
    for scenario, family in _SHIPPED:
        name = Path(scenario).stem
        path = folder / f"{name}.mcap"
        assert main(["run", scenario, "--trials", "1", "--steps", "15", "--estimators",
                     family, "--trace", str(path), "--layout", "--no-progress",
                     "--json"]) == 0, scenario
        out[name] = path
    return out


def _read_independently(path: Path):
    """(metadata records, topic -> [(log_time, decoded message)]) with the plain mcap
    reader."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        messages: dict[str, list] = {}
        for _s, channel, message, decoded in reader.iter_decoded_messages(
                log_time_order=False):
            messages.setdefault(channel.topic, []).append((message.log_time, decoded))
    return metadata, messages


def _values(messages: dict, path: str) -> list[float]:
    m = re.fullmatch(r"(/[A-Za-z0-9_/]+)\.(\w+)(?:\[(\d+)\])?", path)
    assert m, path
    topic, name, index = m.group(1), m.group(2), m.group(3)
    out = []
    for _t, decoded in messages.get(topic, []):
        value = getattr(decoded, name)
        if index is not None:
            if int(index) >= len(value):
                continue
            value = value[int(index)]
        out.append(float(value))
    return out


def _luminance(colour: str) -> float:
    assert re.fullmatch(r"#[0-9a-fA-F]{6}", colour), colour
    channels = [int(colour[q:q + 2], 16) / 255 for q in (1, 3, 5)]
    linear = [c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4 for c in channels]
    return 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2]


def _contrast(a: str, b: str) -> float:
    high, low = sorted((_luminance(a), _luminance(b)), reverse=True)
    return (high + 0.05) / (low + 0.05)


@pytest.mark.parametrize("name", [Path(s).stem for s, _ in _SHIPPED])
def test_shipped_layouts_read_well_in_lichtblick(shipped, name):
    path = shipped[name]
    layout = json.loads(path.with_name(f"{path.stem}.layout.json").read_text())
    _check_structure(layout)
    metadata, messages = _read_independently(path)
    [trace_layout] = [m for n, m in metadata if n == "trace_layout"][-1:]
    links = [tuple(x) for x in json.loads(trace_layout["links"])]
    panels = layout["configById"]
    for key, config in panels.items():  # a title under Foxglove's and Lichtblick's key
        for title_key in ("foxglovePanelTitle", "lichtblickPanelTitle"):
            assert isinstance(config.get(title_key), str) and config[title_key], (key,
                                                                                 title_key)
    dropped_links = set()
    for _t, drops in messages.get("/links/dropped", []):
        dropped_links.update(int(x) for x in drops.link)
    drop_series = {}
    for key, config in panels.items():
        if not key.startswith("Plot!"):
            continue
        y_min, y_max = config.get("minYValue", -math.inf), config.get("maxYValue", math.inf)
        for series in config["paths"]:
            value = series["value"]
            # colours visible on both themes (not white, near-white or near-black)
            for background in _BACKGROUNDS:
                assert _contrast(series["color"], background) >= 2.5, (value, background)
            # no series without data: a value the panel draws, in the trace
            values = _values(messages, value)
            drawn = [v for v in values if math.isfinite(v) and y_min <= v <= y_max]
            assert drawn, f"{name}: {value} ({series['label']}) has nothing to draw"
            # markers are not joined into lines: a line never holds an off-axis sentinel
            if series["showLine"]:
                assert all(math.isfinite(v) and v >= y_min for v in values), value
            if value.startswith("/links/dropped."):
                drop_series.setdefault(key, []).append(series)
    # drop series: one per link, named by the link, for every link that dropped
    per_link = []
    for key, group in drop_series.items():
        for series in group:
            m = re.fullmatch(r"/links/dropped\.link_reason\[(\d+)\]", series["value"])
            assert m, f"{key}: {series['value']} is not a per-link drop series"
            j, i = links[int(m.group(1))]
            assert series["label"] == f"link {j}\u2192{i}"
            assert not series["showLine"]
            per_link.append(int(m.group(1)))
    assert sorted(per_link) == sorted(dropped_links)
    # one complete drop_reasons record when the run dropped messages
    records = [m for n, m in metadata if n == "drop_reasons"]
    assert len(records) == (1 if dropped_links else 0), records
    if dropped_links:
        codes = {int(c) for _t, drops in messages["/links/dropped"] for c in drops.reason}
        assert codes <= {int(c) for c in records[0]}
        titles = " ".join(c["lichtblickPanelTitle"] for c in panels.values())
        for code, text in records[0].items():  # the codes are explained in a title
            assert f"{code} = {text}" in titles


def test_the_aoi_example_has_per_link_drops(shipped):
    """aoi-example: its links go down (the time-varying graph): a Drops tab."""
    path = shipped["aoi-example"]
    layout = json.loads(path.with_name(f"{path.stem}.layout.json").read_text())
    tabs = {t["title"] for t in layout["configById"]["Tab!netsim"]["tabs"]}
    assert "Drops" in tabs
    assert any(v.startswith("/links/dropped.link_reason[") for v in layout_paths(layout))


def test_format2_drop_series_per_link(traces):
    """Format 2: a dropped topic per link; its series named by the link."""
    path = traces["aoi"]
    layout = json.loads(path.with_name(f"{path.stem}.layout.json").read_text())
    for config in layout["configById"].values():
        for series in config.get("paths", []):
            m = re.fullmatch(r"/link_(\d+)_(\d+)/dropped\.\w+", series["value"])
            if m:
                assert series["label"] == f"link {m.group(1)}\u2192{m.group(2)}"
                assert not series["showLine"]
        assert config.get("lichtblickPanelTitle") == config.get("foxglovePanelTitle")


def test_old_traces_with_two_drop_reasons_records_are_read(tmp_path):
    """Traces of earlier versions wrote drop_reasons once per new reason (the first
    copy partial): readers take the union."""
    from netsim.traces.recorder import TraceRecorder

    path = tmp_path / "old.mcap"
    with TraceRecorder(path, scenario_metadata={"name": "old"}, matrices={}, family="f",
                       trial=0, trace_format=2) as recorder:
        recorder.drop_reasons.update({"loss": 1, "link down": 2})
        recorder.writer.add_metadata("drop_reasons", {"1": "loss"})  # the partial copy
    with open(path, "rb") as f:
        names = [m.name for m in make_reader(f).iter_metadata()]
    assert names.count("drop_reasons") == 2
    assert read_trace(path).drop_reasons == {1: "loss", 2: "link down"}
    assert layout_source(path).drop_reasons == {1: "loss", 2: "link down"}
