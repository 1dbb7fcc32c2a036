"""What the commands print and keep: true headers, trace paths that are refused, results
kept when a trace cannot be written, chunk-level recovery, no raw numpy warnings."""

from __future__ import annotations

import json
import math
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


# -- trace paths that are refused, results kept when a trace cannot be written ---------


@pytest.mark.parametrize("trials", ["1", "2"])
def test_trace_to_a_special_file_is_refused_and_nothing_is_created(geometric, tmp_path,
                                                                   capsys, trials):
    before = set(Path("/dev").iterdir())
    code, out, err = _run(capsys, geometric, "--trials", trials, "--trace", "/dev/full")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "/dev/full" in err and "character device" in err
    assert set(Path("/dev").iterdir()) == before


def test_trace_to_a_directory_or_a_missing_folder_is_refused(geometric, tmp_path, capsys):
    code, _, err = _run(capsys, geometric, "--trace", tmp_path)
    assert code == 2 and f"{tmp_path}: is a directory" in err
    code, _, err = _run(capsys, geometric, "--trace", tmp_path / "no" / "x.mcap")
    assert code == 2 and f"directory {tmp_path / 'no'} does not exist" in err
    assert list(tmp_path.iterdir()) == [geometric]


def test_existing_trace_is_refused_unless_force(geometric, tmp_path, capsys):
    path = tmp_path / "one.mcap"
    args = (geometric, "--trials", "1", "--estimators", "compensated", "--steps", "20",
            "--trace", path)
    assert _run(capsys, *args)[0] == 0
    first = path.read_bytes()
    code, out, err = _run(capsys, *args, "--seed", "5")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert f"{path}: exists; pass --force" in err
    assert path.read_bytes() == first  # untouched
    sibling = tmp_path / "many.compensated.trial1.mcap"
    sibling.write_bytes(b"keep")
    code, _, err = _run(capsys, geometric, "--trace", tmp_path / "many.mcap")
    assert code == 2 and str(sibling) in err and sibling.read_bytes() == b"keep"
    code, _, err = _run(capsys, *args, "--seed", "5", "--force")
    assert code == 0, err
    assert read_trace(path).seed != first and path.read_bytes() != first


class _FillingDisk:
    """``open`` for the recorder whose files share ``budget`` bytes, then ENOSPC."""

    def __init__(self, budget):
        self.left = budget

    def __call__(self, path, mode="r", *args, **kwargs):
        import builtins

        real = builtins.open(path, mode, *args, **kwargs)
        disk = self

        class Stream:
            def write(self, data):
                import errno
                import os

                if len(data) > disk.left:
                    disk.left = 0
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                disk.left -= len(data)
                return real.write(data)

            def __getattr__(self, name):
                return getattr(real, name)

        return Stream()


def _sizes(tmp_path, geometric, capsys, engine):
    """The file sizes of a full traced run (to place the disk-full point)."""
    folder = tmp_path / f"full-{engine}"
    folder.mkdir()
    code, out, err = _run(capsys, geometric, "--trials", "3", "--engine", engine, "--json",
                          "--trace", folder / "t.mcap")
    assert code == 0, err
    return json.loads(out), [Path(p).stat().st_size for p in json.loads(out)["traces"]]


@pytest.mark.parametrize("engine", ["vectorised", "events"])
def test_disk_full_prints_the_finished_runs_then_one_error_line(geometric, tmp_path, capsys,
                                                               monkeypatch, engine):
    import netsim.traces.recorder as recorder

    full, sizes = _sizes(tmp_path, geometric, capsys, engine)
    # the disk fills in the middle of the second family's first trial (file 4 of 6)
    budget = sum(sizes[:3]) + sizes[3] // 2
    monkeypatch.setattr(recorder, "open", _FillingDisk(budget), raising=False)
    base = tmp_path / "t.mcap"
    code, out, err = _run(capsys, geometric, "--trials", "3", "--engine", engine,
                          "--trace", base)
    assert code == 2
    failed = tmp_path / "t.uncompensated.trial0.mcap"
    assert err.count("\n") == 1 and "Traceback" not in err
    assert f"cannot write trace {failed}: No space left on device" in err
    assert "compensated" in out and "INCOMPLETE" in out
    row = next(line for line in out.splitlines() if line.startswith("compensated "))
    # the finished family's numbers, as in the full run: its steady MSE if stable, else
    # its last trusted MSE (the last MSE@ column)
    comp = full["estimators"]["compensated"]
    shown = comp.get("steady_state_mse", comp["last_trusted_mse"])
    assert f"{shown:.4f}" in row
    # --json: what finished plus an error field
    for p in tmp_path.glob("t.*.mcap"):
        p.unlink()
    monkeypatch.setattr(recorder, "open", _FillingDisk(budget), raising=False)
    code, out, err = _run(capsys, geometric, "--trials", "3", "--engine", engine, "--json",
                          "--trace", base)
    assert code == 2 and err.count("\n") == 1
    data = json.loads(out)
    assert data["error"].startswith(f"cannot write trace {failed}")
    assert data["estimators"]["compensated"] == full["estimators"]["compensated"]
    assert "uncompensated" not in data["estimators"]
    assert data["traces"] == [str(tmp_path / f"t.compensated.trial{t}.mcap") for t in range(3)]
    for path in data["traces"]:
        assert read_trace(path).status["status"] in ("complete", "diverged")


def test_disk_full_within_a_family_keeps_its_finished_trials(geometric, tmp_path, capsys,
                                                            monkeypatch):
    import netsim.traces.recorder as recorder

    _, sizes = _sizes(tmp_path, geometric, capsys, "vectorised")
    monkeypatch.setattr(recorder, "open", _FillingDisk(sizes[0] + sizes[1] // 2),
                        raising=False)
    code, out, err = _run(capsys, geometric, "--trials", "3", "--json",
                          "--trace", tmp_path / "t.mcap")
    assert code == 2
    data = json.loads(out)
    assert data["estimators"]["compensated"]["trials_finished"] == 1
    monkeypatch.undo()
    one = tmp_path / "single"
    one.mkdir()
    code, single, _ = _run(capsys, geometric, "--trials", "1", "--estimators", "compensated",
                           "--json", "--trace", one / "s.mcap")
    assert code == 0
    # the one finished trial's numbers are those of a run of that trial alone (to
    # round-off: a batch of 3 trials and one of 1 multiply matrices of other shapes)
    mine, alone = (data["estimators"]["compensated"]["mse_at"],
                   json.loads(single)["estimators"]["compensated"]["mse_at"])
    assert mine.keys() == alone.keys()
    for k in mine:
        assert math.isclose(mine[k], alone[k], rel_tol=1e-12), (k, mine[k], alone[k])


# -- a damaged trace: every intact chunk, and which were lost --------------------------


def test_inspect_reports_the_lost_chunk_of_a_damaged_trace(geometric, tmp_path, capsys):
    from mcap.reader import make_reader

    path = tmp_path / "one.mcap"
    # the event kernel closes a chunk every 25 steps (flush_every), so the trace has a
    # middle chunk to damage (the vectorised engine's would be one 1 MiB chunk)
    code, _, err = _run(capsys, geometric, "--trials", "1", "--estimators", "compensated",
                        "--steps", "120", "--engine", "events", "--trace", path)
    assert code == 0, err
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        total = summary.statistics.message_count
    middle = chunks[len(chunks) // 2]
    data = bytearray(path.read_bytes())
    data[middle.chunk_start_offset + middle.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert main(["inspect", str(bad), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    [lost] = info["lost_chunks"]
    assert lost["chunk"] == len(chunks) // 2 and lost["offset"] == middle.chunk_start_offset
    assert info["damaged"] and info["recovered_messages"] + lost["messages"] == total
    with open(path, "rb") as f:  # log_time = time origin + simulation time (format 2)
        run = {m.name: m.metadata for m in make_reader(f).iter_metadata()}["run"]
    origin = int(run["time_origin_ns"])
    first, last = ((middle.message_start_time - origin) // 10**9,
                   (middle.message_end_time - origin) // 10**9)
    assert lost["steps"] == [first, last]
    assert info["steps"]["first"] == 0 and info["steps"]["last"] == 120  # chunks after it
    assert main(["inspect", str(bad)]) == 0
    text = capsys.readouterr().out
    assert f"lost chunk {lost['chunk']} at byte {lost['offset']}" in text
    assert f"steps {first}..{last}" in text
