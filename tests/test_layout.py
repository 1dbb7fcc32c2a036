"""Foxglove layouts (``netsim layout``, ``netsim run --trace --layout``): every message
path a layout references exists in the trace, checked against the file alone (its
channels, the FileDescriptorSet stored as schema data and the decoded messages, read
with the plain ``mcap`` reader), for a consensus trace and a lossy AoI trace."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from netsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "tests" / "fixtures"
_F = descriptor_pb2.FieldDescriptorProto
_NUMERIC = {_F.TYPE_DOUBLE, _F.TYPE_FLOAT, _F.TYPE_FIXED64, _F.TYPE_SFIXED64, _F.TYPE_FIXED32,
            _F.TYPE_SFIXED32, _F.TYPE_UINT64, _F.TYPE_INT64, _F.TYPE_UINT32, _F.TYPE_INT32,
            _F.TYPE_BOOL}


@pytest.fixture(scope="module")
def traces(tmp_path_factory):
    folder = tmp_path_factory.mktemp("layouts")
    consensus = folder / "consensus.mcap"
    assert main(["run", "lcsys2022-heterogeneous", "--tau", "3", "--trials", "1",
                 "--steps", "25", "--estimators", "compensated", "--trace", str(consensus),
                 "--layout", "--no-progress", "--json"]) == 0
    aoi = folder / "aoi.mcap"
    assert main(["run", str(ROOT / "examples" / "aoi-random-lossy.toml"), "--trials", "1",
                 "--steps", "20", "--estimators", "aoi", "--trace", str(aoi), "--layout",
                 "--no-progress", "--json"]) == 0
    return {"consensus": consensus, "aoi": aoi}


def _file_contents(path: Path):
    """Topics -> (message descriptor, first decoded message), from the file alone."""
    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(
                log_time_order=False):
            if channel.topic in out:
                continue
            schema = summary.schemas[channel.schema_id]
            fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
            package, _, name = schema.name.rpartition(".")
            [message] = [m for fd in fds.file if fd.package == package
                         for m in fd.message_type if m.name == name]
            out[channel.topic] = (message, decoded)
    return out


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
        descriptor, first = contents[topic]
        [fd] = [f for f in descriptor.field if f.name == name] or [None]
        assert fd is not None, f"{value}: {descriptor.name} has no field {name}"
        assert fd.type in _NUMERIC, f"{value}: not a plottable field"
        if index is None:
            assert fd.label != _F.LABEL_REPEATED, f"{value}: an array needs an index"
        else:
            assert fd.label == _F.LABEL_REPEATED, f"{value}: not an array"
            assert int(index) < len(getattr(first, name)), f"{value}: index out of range"
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
