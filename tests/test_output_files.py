"""One rule for output files (issue 29): no writes through links, onto inputs or onto
another output; --force to overwrite; whole files written atomically.

Every case asserts the exit code, the one-line message and that no file other than the
named output changed (a snapshot of the folder's bytes before and after).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from netsim.cli import main
from netsim.outfiles import OutputFileError, atomic_output, check_output

SCENARIO = Path(__file__).resolve().parents[1] / "models" / "scenarios" / \
    "lcsys2022-heterogeneous.toml"


def snapshot(folder: Path) -> dict[str, bytes | str]:
    """Every entry of ``folder``: a link's target, a file's bytes."""
    out: dict[str, bytes | str] = {}
    for p in sorted(folder.iterdir()):
        out[p.name] = f"-> {os.readlink(p)}" if p.is_symlink() else p.read_bytes()
    return out


def one_error(capsys: pytest.CaptureFixture[str], command: str) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"netsim {command}: error:"), err
    assert "Traceback" not in err[0]
    return err[0]


@pytest.fixture(scope="module")
def trace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("trace")
    path = folder / "run.mcap"
    assert main(["run", "lcsys2022-heterogeneous", "--estimators", "compensated",
                 "--trials", "1", "--steps", "20", "--trace", str(path),
                 "--no-progress", "--json"]) == 0
    return path


def test_a_trace_is_never_written_through_a_symlink(tmp_path, capsys):
    (tmp_path / "victim.txt").write_text("victim")
    (tmp_path / "t.mcap").symlink_to("victim.txt")
    before = snapshot(tmp_path)
    assert main(["run", "lcsys2022-heterogeneous", "--estimators", "compensated",
                 "--trials", "1", "--steps", "5", "--trace", str(tmp_path / "t.mcap"),
                 "--force", "--no-progress"]) == 2
    assert "symbolic link" in one_error(capsys, "run")
    assert snapshot(tmp_path) == before


def test_a_trace_never_overwrites_the_scenario_it_reads(tmp_path, capsys):
    scenario = tmp_path / "s.toml"
    shutil.copy(SCENARIO, scenario)
    before = snapshot(tmp_path)
    assert main(["run", str(scenario), "--estimators", "compensated", "--trials", "1",
                 "--steps", "5", "--trace", str(scenario), "--force", "--no-progress"]) == 2
    assert "is also an input" in one_error(capsys, "run")
    assert snapshot(tmp_path) == before


def test_plot_needs_force_refuses_links_and_writes_whole_files(tmp_path, trace, capsys):
    out = tmp_path / "p.png"
    out.write_bytes(b"old")
    before = snapshot(tmp_path)
    assert main(["plot", str(trace), "-o", str(out)]) == 2
    assert "pass --force" in one_error(capsys, "plot")
    assert snapshot(tmp_path) == before
    assert main(["plot", str(trace), "-o", str(out), "--force"]) == 0
    capsys.readouterr()
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png"]  # no temporary left
    (tmp_path / "victim.txt").write_text("victim")
    (tmp_path / "l.png").symlink_to("victim.txt")
    before = snapshot(tmp_path)
    assert main(["plot", str(trace), "-o", str(tmp_path / "l.png"), "--force"]) == 2
    assert "symbolic link" in one_error(capsys, "plot")
    assert snapshot(tmp_path) == before
    before = snapshot(trace.parent)
    assert main(["plot", str(trace), "-o", str(trace), "--force"]) == 2  # not a .png
    one_error(capsys, "plot")
    assert snapshot(trace.parent) == before


def test_layout_refuses_links_and_its_own_trace(tmp_path, trace, capsys):
    (tmp_path / "victim.txt").write_text("victim")
    (tmp_path / "lay.json").symlink_to("victim.txt")
    before = snapshot(tmp_path)
    assert main(["layout", str(trace), "-o", str(tmp_path / "lay.json"), "--force"]) == 2
    assert "symbolic link" in one_error(capsys, "layout")
    assert snapshot(tmp_path) == before
    fig = tmp_path / "f.png"
    assert main(["layout", str(trace), "-o", str(tmp_path / "ok.json"), "--figure",
                 str(fig), "--json"]) == 0
    capsys.readouterr()
    assert (tmp_path / "ok.json").is_file() and fig.read_bytes()[:4] == b"\x89PNG"
    before = snapshot(tmp_path)
    assert main(["layout", str(trace), "-o", str(tmp_path / "ok.json")]) == 2
    assert "pass --force" in one_error(capsys, "layout")
    assert snapshot(tmp_path) == before


def test_sweep_results_and_csv_must_be_two_files(tmp_path, capsys):
    out = tmp_path / "r.jsonl"
    out.write_text('{"kept": true}\n')
    before = snapshot(tmp_path)
    assert main(["bench", "sweep", "lcsys2022-heterogeneous", "--taus", "1", "--trials", "1",
                 "--steps", "10", "--out", str(out), "--csv", str(out),
                 "--no-progress"]) == 2
    assert "another output" in one_error(capsys, "bench")
    assert snapshot(tmp_path) == before


def test_atomic_output_keeps_the_old_file_when_the_write_fails(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert target.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["a.json"]
    with atomic_output(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and sorted(os.listdir(tmp_path)) == ["a.json"]


def test_check_output_refuses_directories_pipes_and_missing_folders(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputFileError, match="named pipe"):
        check_output(fifo, "-o", force=True)
    with pytest.raises(OutputFileError, match="directory"):
        check_output(tmp_path, "-o", force=True)
    with pytest.raises(OutputFileError, match="does not exist"):
        check_output(tmp_path / "no" / "x.png", "-o")
    assert check_output(tmp_path / "x.png", "-o") == tmp_path / "x.png"


def test_a_full_disk_during_a_sweep_keeps_the_rows_written_and_resumes(tmp_path, capsys,
                                                                        monkeypatch):
    import errno

    import netsim.sweep as sweep

    real = sweep._Sink.write
    calls = {"n": 0}

    def write(self, row):  # the disk fills on the second row
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, row)

    out = tmp_path / "r.jsonl"
    args = ["bench", "sweep", "lcsys2022-heterogeneous", "--taus", "0,1,2", "--trials", "1",
            "--steps", "10", "--workers", "1", "--out", str(out), "--no-progress"]
    monkeypatch.setattr(sweep._Sink, "write", write)
    assert main(args) == 2
    line = one_error(capsys, "bench")
    assert "No space left" in line and "1 row(s) written before are kept" in line
    assert len(sweep.read_results(out)) == 1
    monkeypatch.setattr(sweep._Sink, "write", real)
    assert main(args) == 0  # the same command resumes: two cells computed, one reused
    assert "1 reused" in capsys.readouterr().out
    assert len(sweep.read_results(out)) == 3


def test_claims_never_write_their_report_through_a_link(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.md"
    victim.write_text("victim")
    (out / "claims.md").symlink_to(victim)
    assert main(["claims", "L-rho", "--out", str(out), "--no-progress"]) == 2
    assert "symbolic link" in one_error(capsys, "claims")
    assert victim.read_text() == "victim" and (out / "claims.md").is_symlink()
    assert sorted(p.name for p in out.iterdir()) == ["claims.md"]
    (out / "claims.md").unlink()
    assert main(["claims", "L-rho", "--out", str(out), "--no-progress"]) == 0
    assert (out / "claims.md").read_text().startswith("# Paper claims")
    assert victim.read_text() == "victim"


def test_reproduce_never_writes_through_a_link(tmp_path, capsys):
    """reproduce --out: its report and figures are checked before any work is done."""
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.md"
    victim.write_text("victim")
    (out / "report.md").symlink_to(victim)
    assert main(["reproduce", "aoi", "--out", str(out), "--no-progress"]) == 2
    assert "symbolic link" in one_error(capsys, "reproduce")
    assert victim.read_text() == "victim" and (out / "report.md").is_symlink()
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]


def test_reproduce_refuses_a_linked_folder(tmp_path, capsys):
    real = tmp_path / "real"
    real.mkdir()
    (tmp_path / "out").symlink_to(real)
    assert main(["reproduce", "aoi", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "symbolic link or not a folder" in one_error(capsys, "reproduce")
    assert list(real.iterdir()) == []


def test_files_a_command_owns_are_written_atomically_and_never_through_links(tmp_path):
    from netsim.outfiles import OutputFileError, safe_output

    victim = tmp_path / "victim"
    victim.write_text("victim")
    (tmp_path / "link.csv").symlink_to(victim)
    with pytest.raises(OutputFileError, match="symbolic link"), \
            safe_output(tmp_path / "link.csv", "--out"):
        pass
    target = tmp_path / "a.csv"
    target.write_text("old")
    with pytest.raises(RuntimeError), safe_output(target, "--out") as tmp:
        tmp.write_text("half")
        raise RuntimeError("the writer failed")
    assert target.read_text() == "old"  # the old file stays whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "link.csv", "victim"]
