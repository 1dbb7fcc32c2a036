"""Results at home in a notebook (issue 30): repr, HTML, plot, tidy tables and files;
no process-wide change on ``import netsim``, one BLAS thread only while netsim works."""

from __future__ import annotations

import html.parser
import json
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

import netsim
from netsim.outfiles import OutputFileError

ROOT = Path(__file__).resolve().parents[1]
NAMES = ["compensated", "uncompensated", "block", "centralized-kf"]
STEPS, TRIALS = 50, 2


@pytest.fixture(scope="module")
def result():
    return netsim.run("lcsys2022-heterogeneous", steps=STEPS, trials=TRIALS)


@pytest.fixture(scope="module")
def lossy():
    """The heterogeneous scenario with a lossy link model, on both engines."""
    source = tomllib.loads((ROOT / "models" / "scenarios" /
                            "lcsys2022-heterogeneous.toml").read_text())
    source["links"] = {"loss": {"model": "bernoulli", "p": 0.2}}
    scenario = netsim.load_scenario(source)
    return {engine: netsim.run(scenario, steps=30, trials=2, estimators=["compensated"],
                               engine=engine) for engine in ("vectorised", "events")}


# -- display ---------------------------------------------------------------------------

def test_repr_is_a_few_lines_naming_every_estimator(result):
    text = repr(result)
    assert list(result) == NAMES
    assert len(text) < 2000
    assert len(text.splitlines()) <= len(NAMES) + 4
    assert "lcsys2022-heterogeneous" in text
    for name in NAMES:
        assert name in text
        assert result.summary[name].verdict in text
        assert len(repr(result[name])) < 300


def test_other_results_have_short_reprs(tmp_path):
    """What run_one, analyze (a scenario or a trace) and read_trace return."""
    trial = netsim.run_one("lcsys2022-heterogeneous", "compensated", steps=STEPS)
    assert len(repr(trial)) < 400 and "(51, 4, 6)" in repr(trial)
    report = netsim.analyze("lcsys2022-heterogeneous", tau_max=30)
    assert len(repr(report)) < 400 and "tau 0..30" in repr(report)
    parser = _Table()
    parser.feed(report._repr_html_())
    assert "table" in parser.tags and "30" in parser.cells
    netsim.run("lcsys2022-heterogeneous", steps=STEPS, trials=1, estimators=["compensated"],
               trace=tmp_path / "t.mcap")
    trace = netsim.read_trace(tmp_path / "t.mcap")
    assert len(repr(trace)) < 400 and "format 3" in repr(trace)
    analysed = netsim.analyze(tmp_path / "t.mcap", tau_max=4)
    assert len(repr(analysed)) < 400 and "compensated" in repr(analysed)


class _Table(html.parser.HTMLParser):
    """The tags seen and the text of every table cell."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.cells: list[str] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def test_repr_html_is_a_table_of_the_summary(result):
    parser = _Table()
    parser.feed(result._repr_html_())
    parser.close()
    assert "table" in parser.tags
    for name in NAMES:
        assert name in parser.cells
        assert result.summary[name].verdict in parser.cells


def test_repr_html_escapes_every_value(result, monkeypatch):
    row = dict(result.summary_rows()[0], estimator="<script>x</script>", verdict="a&b")
    monkeypatch.setattr(result, "summary_rows", lambda: [row])
    text = result._repr_html_()
    assert "<script>" not in text
    assert "&lt;script&gt;" in text and "a&amp;b" in text
    parser = _Table()
    parser.feed(text)
    assert "<script>x</script>" in parser.cells


def test_plot_draws_one_line_per_estimator(result):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ax = result.plot()
    try:
        lines = ax.get_lines()
        assert [line.get_label() for line in lines] == NAMES
        for line, name in zip(lines, NAMES, strict=True):
            np.testing.assert_array_equal(line.get_ydata(), result.summary[name].mse)
            assert len(line.get_xdata()) == STEPS + 1
        assert ax.get_yscale() in ("log", "linear")
        assert ax.figure is not None
    finally:
        plt.close(ax.figure)
    figure, given = plt.subplots()
    try:
        assert result.plot(ax=given, log=False) is given
        assert given.get_yscale() == "linear" and len(given.get_lines()) == len(NAMES)
    finally:
        plt.close(figure)


# -- tables ----------------------------------------------------------------------------

COLUMNS = {
    "errors": ["family", "trial", "step", "time", "agent", "squared_error"],
    "estimates": ["family", "trial", "step", "time", "agent", "component", "estimate"],
    "states": ["family", "trial", "step", "time", "component", "state"],
    "delays": ["family", "trial", "step", "time", "agent", "sender", "delay"],
    "drops": ["family", "trial", "sent_step", "sender", "receiver", "time", "reason"],
}


def _rows(result, what):
    """Expected row count, from the result's array shapes alone."""
    total = 0
    for name in result:
        fam = result[name]
        if what == "errors":
            total += fam.squared_errors.size
        elif what == "estimates":
            total += fam.estimates.size
        elif what == "states":
            total += fam.states.size
        elif what == "delays":
            total += int(np.count_nonzero(fam.effective_delays != -2))
        else:
            total += sum(len(d) for d in fam.drops)
    return total


@pytest.mark.parametrize("what", sorted(COLUMNS))
def test_to_dataframe_columns_and_rows(result, what):
    frame = result.to_dataframe(what=what)
    assert list(frame.columns) == COLUMNS[what]
    assert len(frame) == _rows(result, what)
    if what != "drops":
        assert set(frame.family) == set(NAMES) - ({"centralized-kf"} if what == "delays"
                                                  else set())
        assert np.array_equal(frame.time, frame.step * result.scenario.sample_period)


def test_default_table_is_the_errors(result):
    import pandas as pd

    pd.testing.assert_frame_equal(result.to_dataframe(), result.to_dataframe("errors"))


def test_table_values_equal_the_arrays(result):
    for name in NAMES:
        fam = result[name]
        M, K1, N, n = fam.estimates.shape
        assert fam.states.shape == (M, K1, n) and fam.squared_errors.shape == (M, K1, N)
        errors = result.to_dataframe("errors").query("family == @name")
        t, k, i = (errors[c].to_numpy() for c in ("trial", "step", "agent"))
        np.testing.assert_array_equal(errors.squared_error.to_numpy(),
                                      fam.squared_errors[t, k, i])
        estimates = result.to_dataframe("estimates").query("family == @name")
        t, k, i, c = (estimates[col].to_numpy()
                      for col in ("trial", "step", "agent", "component"))
        np.testing.assert_array_equal(estimates.estimate.to_numpy(), fam.estimates[t, k, i, c])
        states = result.to_dataframe("states").query("family == @name")
        t, k, c = (states[col].to_numpy() for col in ("trial", "step", "component"))
        np.testing.assert_array_equal(states.state.to_numpy(), fam.states[t, k, c])
        delays = result.to_dataframe("delays").query("family == @name")
        t, k, i, j = (delays[col].to_numpy() for col in ("trial", "step", "agent", "sender"))
        np.testing.assert_array_equal(delays.delay.to_numpy(), fam.effective_delays[t, k, i, j])
        assert (delays.delay >= -1).all()


def test_errors_are_the_squared_distance_of_estimate_and_state(result):
    """squared_error = ||x_k - x-hat^i_k||^2; the summary's MSE is its mean over agents,
    then over the trials (none diverged here)."""
    frame = result.to_dataframe()
    for name in NAMES:
        fam = result[name]
        direct = ((fam.estimates - fam.states[:, :, None, :]) ** 2).sum(axis=-1)
        np.testing.assert_allclose(fam.squared_errors, direct, rtol=1e-12, atol=0)
        assert not any(fam.diverged_at)
        mse = (frame.query("family == @name").groupby(["trial", "step"]).squared_error.mean()
               .groupby("step").mean().to_numpy())
        np.testing.assert_allclose(mse, result.summary[name].mse, rtol=1e-12)


def test_drops_table_lists_every_drop_on_both_engines(lossy):
    tables = {}
    for engine, run in lossy.items():
        frame = run.to_dataframe("drops")
        assert list(frame.columns) == COLUMNS["drops"]
        trials = run.monte_carlo.runs["compensated"]
        assert len(frame) == sum(r.messages_dropped for r in trials) > 0
        for t, trial in enumerate(trials):
            reasons = frame[frame.trial == t].reason.value_counts().to_dict()
            assert reasons == trial.drop_reasons
        links = set(run.scenario.links)
        assert set(zip(frame.sender, frame.receiver, strict=True)) <= links
        assert (frame.time >= frame.sent_step * run.scenario.sample_period).all()
        tables[engine] = frame
    import pandas as pd

    pd.testing.assert_frame_equal(tables["vectorised"], tables["events"])


def test_unknown_table_is_refused(result):
    with pytest.raises(ValueError, match="expected one of errors, estimates"):
        result.to_dataframe(what="messages")


def test_traced_run_has_no_delay_table(tmp_path):
    traced = netsim.run("lcsys2022-heterogeneous", steps=5, trials=1,
                        estimators=["compensated"], trace=tmp_path / "t.mcap")
    assert len(traced.to_dataframe("estimates")) == 6 * 4 * 6
    for what in ("delays", "drops"):
        with pytest.raises(ValueError, match="read them from the trace"):
            traced.to_dataframe(what)


def test_missing_pandas_names_the_extra(result, monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pandas", None)
    message = r"to_dataframe needs pandas: pip install 'netsim\[notebook\]'"
    with pytest.raises(ImportError, match=message):
        result.to_dataframe()
    with pytest.raises(ImportError, match=message):
        result.to_csv(tmp_path / "e.csv")
    assert not (tmp_path / "e.csv").exists()


def test_missing_matplotlib_names_the_extra(result, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    with pytest.raises(ImportError, match=r"RunResult.plot\(\) needs matplotlib.*"
                                          r"pip install 'netsim\[notebook\]'"):
        result.plot()


def test_missing_pyarrow_names_the_extra(result, monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(ImportError, match=r"to_parquet needs pyarrow: .*netsim\[notebook\]"):
        result.to_parquet(tmp_path / "e.parquet")


# -- files -----------------------------------------------------------------------------

@pytest.mark.parametrize("what", sorted(COLUMNS))
def test_csv_and_parquet_round_trip(result, lossy, what, tmp_path):
    import pandas as pd

    source = lossy["events"] if what == "drops" else result
    frame = source.to_dataframe(what)
    assert source.to_csv(tmp_path / "t.csv", what) == tmp_path / "t.csv"
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "t.csv"), frame,
                                  check_dtype=False, rtol=1e-15)
    assert source.to_parquet(tmp_path / "t.parquet", what=what) == tmp_path / "t.parquet"
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "t.parquet"), frame)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv", "t.parquet"]


@pytest.mark.parametrize("method", ["to_csv", "to_parquet"])
def test_files_follow_the_output_rule(result, method, tmp_path):
    write = getattr(result, method)
    target = tmp_path / "kept.txt"
    target.write_text("keep me")
    link = tmp_path / "link.out"
    link.symlink_to(target)
    with pytest.raises(OutputFileError, match="symbolic link"):
        write(link, force=True)
    assert target.read_text() == "keep me" and link.is_symlink()
    with pytest.raises(OutputFileError, match=r"exists; pass force=True"):
        write(target)
    assert target.read_text() == "keep me"
    write(target, force=True)
    assert target.read_text() != "keep me" if method == "to_csv" else target.stat().st_size
    with pytest.raises(OutputFileError, match="does not exist"):
        write(tmp_path / "no" / "such.out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.txt", "link.out"]


# -- threads ---------------------------------------------------------------------------

def _clean_env() -> dict[str, str]:
    """The environment without any BLAS or OpenMP thread setting."""
    return {k: v for k, v in os.environ.items()
            if not k.endswith("_NUM_THREADS") and k != "NETSIM_WORKERS"}


def test_import_changes_no_environment_variable():
    script = textwrap.dedent("""
        import json, os
        before = dict(os.environ)
        import netsim, netsim.api
        from netsim import run, analyze, RunResult
        import netsim.models, netsim.traces, netsim.estimators
        print(json.dumps(dict(os.environ) == before))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=ROOT, env=_clean_env(), timeout=300)
    assert json.loads(out.stdout.strip().splitlines()[-1]) is True


def test_blas_is_single_threaded_only_while_netsim_works():
    """In a process without thread settings: BLAS keeps its threads before and after a
    run, has one inside an estimator's step, and in netsim's worker processes."""
    script = textwrap.dedent("""
        import json
        import numpy as np
        import scipy.linalg  # noqa: F401 - scipy's own BLAS too, loaded before "before"
        from threadpoolctl import threadpool_info, threadpool_limits
        import netsim
        from netsim.parallel import ordered_map

        def blas():
            return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]

        def in_worker(_):
            return blas()

        seen = []

        class Probe:
            def __init__(self, setup):
                self.estimate = np.array(setup.prior_mean, dtype=float)
            def message_arrived(self, sender, sent_step, payload):
                return False
            def step(self, k, y):
                seen.append(blas())
                return self.estimate

        netsim.register_estimator(Probe, "probe", replace_existing=True)
        with threadpool_limits(limits=2, user_api="blas"):
            before = blas()
            netsim.run("lcsys2022-heterogeneous", steps=3, trials=1, estimators=["probe"])
            after = blas()
            workers = ordered_map(in_worker, [0, 1], workers=2)
        # a fresh worker (forkserver: a local sweep's, the claims searches') has loaded
        # no BLAS when its initialiser runs
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        from netsim.threads import limit_worker_threads

        context = multiprocessing.get_context("forkserver")
        with ProcessPoolExecutor(1, mp_context=context,
                                 initializer=limit_worker_threads) as pool:
            fresh = [p["num_threads"] for p in pool.submit(threadpool_info).result()
                     if p["user_api"] == "blas"]
        print(json.dumps({"before": before, "inside": seen, "after": after,
                          "workers": workers, "fresh": fresh}))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=ROOT, env=_clean_env(), timeout=300)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] and got["before"] == got["after"]
    assert got["inside"] and all(n == [1] * len(got["before"]) for n in got["inside"])
    assert got["workers"] == [[1] * len(got["before"])] * 2
    assert got["fresh"] and set(got["fresh"]) == {1}
