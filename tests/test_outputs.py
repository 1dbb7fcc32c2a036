"""What the commands print and keep: true headers, trace paths that are refused, results
kept when a trace cannot be written, chunk-level recovery, no raw numpy warnings."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from netsim.traces.reader import read_trace

from netsim.cli import main

#: Five agents on a directed cycle (the [links] table sets unbounded geometric delays).
GEOMETRIC = """
name = "geo5"
description = "5 agents on a cycle, geometric link delays"
[run]
steps = 60
trials = 2
seed = 0
estimators = ["compensated", "uncompensated"]
[plant]
A = [[0.9, 0.1], [0.0, 0.95]]
C = [ [[1.0, 0.0]], [[0.0, 1.0]], [[1.0, 1.0]], [[1.0, 0.0]], [[0.0, 1.0]] ]
Q = 0.004
R = 0.004
[network]
topology = "cycle"
agents = 5
weights = "uniform"
[delays]
model = "none"
[links]
delay = { distribution = "geometric", p = 0.6 }
"""
#: The cycle's edges, written out by hand: agent i receives from i - 1.
CYCLE5 = [[0, 1], [1, 2], [2, 3], [3, 4], [4, 0]]


@pytest.fixture
def geometric(tmp_path):
    path = tmp_path / "geo5.toml"
    path.write_text(GEOMETRIC)
    return path


def _run(capsys, *args):
    code = main(["run", *map(str, args), "--no-progress"])
    out = capsys.readouterr()
    return code, out.out, out.err


# -- headers that say what is true ---------------------------------------------------


def test_links_table_keeps_the_edge_list_and_the_header_counts_the_links(geometric, capsys):
    code, out, err = _run(capsys, geometric, "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["scenario"]["links"] == CYCLE5
    models = data["scenario"]["link_models"]
    assert models["default"]["delay"]["distribution"] == "geometric"
    code, out, err = _run(capsys, geometric)
    assert code == 0, err
    assert f"N = 5 agents, {len(CYCLE5)} links" in out.splitlines()[0]


def test_header_says_the_bound_is_a_quantile_and_reports_the_realised_maximum(
        geometric, tmp_path, capsys):
    code, out, err = _run(capsys, geometric, "--trace", tmp_path / "g.mcap")
    assert code == 0, err
    realised = 0
    for path in sorted(tmp_path.glob("g.*.mcap")):
        trace = read_trace(path)
        for j, i in trace.links:
            realised = max([realised] + [m.delay_steps for m in
                                         trace.link_events(j, i, "delivered")])
    delays = out.splitlines()[1]
    assert "99.9% quantile" in delays and "delays beyond it occur" in delays
    assert f"realised max step delay {realised} (traces)" in delays
    code, out, _ = _run(capsys, geometric, "--json", "--trace", tmp_path / "h.mcap")
    bound = json.loads(out)["delay_bound"]
    assert bound["kind"] == "quantile" and bound["quantile"] == 0.999
    assert bound["realised_max"] == realised


def test_header_of_a_hard_bound_says_nothing_more(capsys):
    code, out, err = _run(capsys, "lcsys2022-heterogeneous", "--tau", "3", "--trials", "1",
                          "--steps", "10")
    assert code == 0, err
    assert out.splitlines()[1] == "delays: heterogeneous, tau = 3; bound 3"


def test_bench_banner_says_how_the_run_departs_from_the_preset(capsys):
    code = main(["bench", "delay-tolerance", "lcsys2022-fig1", "--trials", "2", "--steps",
                 "10", "--taus", "0", "--delays", "homogeneous", "--workers", "1",
                 "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0
    head = "\n".join(out.splitlines()[:3])
    assert "100 trials" not in head
    assert "trials 2 (preset 100)" in head and "steps 10 (preset 500)" in head
    assert "taus 0 (preset 0,3,8,19)" in head
    assert "run: 2 trials x 10 steps" in out


def test_inspect_text_prints_the_drop_reasons_of_every_link(tmp_path, capsys):
    root = Path(__file__).resolve().parents[1]
    path = tmp_path / "lossy.mcap"
    code, _, err = _run(capsys, root / "examples" / "aoi-random-lossy.toml", "--trials", "1",
                        "--estimators", "aoi", "--trace", path)
    assert code == 0, err
    trace = read_trace(path)
    expected = {}
    for j, i in trace.links:  # counted from the raw dropped events
        for m in trace.link_events(j, i, "dropped"):
            expected.setdefault(f"{j}->{i}", {}).setdefault(m.reason, 0)
            expected[f"{j}->{i}"][m.reason] += 1
    assert expected
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    section = text.split("drop reasons")[1].split("agents")[0].splitlines()[1:]
    rows = {line.split()[0]: line for line in section if line.strip()}
    assert set(rows) == set(expected)
    for link, reasons in expected.items():
        for reason, count in reasons.items():
            assert f"{reason} {count}" in rows[link]
