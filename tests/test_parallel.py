"""netsim.parallel: ordered results, when it parallelises, bad worker counts."""

from __future__ import annotations

import os
import time

import pytest

from netsim.cli import main
from netsim.parallel import (
    PARALLEL_MIN_SECONDS,
    WORKERS_ENV,
    choose_workers,
    env_workers,
    ordered_map,
)


def _slow_square(x: int) -> tuple[int, int]:
    time.sleep(0.05 * (5 - x))  # the first items finish last
    return x * x, os.getpid()


def test_results_keep_the_items_order_whatever_finishes_first():
    ticks = []
    out = ordered_map(_slow_square, range(5), workers=2, progress=ticks.append)
    assert [v for v, _ in out] == [x * x for x in range(5)]
    assert ticks == [1] * 5
    assert {pid for _, pid in out} != {os.getpid()}  # ran in worker processes
    serial = ordered_map(_slow_square, range(5), workers=1)
    assert [v for v, _ in serial] == [v for v, _ in out]
    assert {pid for _, pid in serial} == {os.getpid()}


def test_serial_below_the_work_threshold(monkeypatch):
    monkeypatch.delenv(WORKERS_ENV, raising=False)
    assert choose_workers(10, None) == 1
    assert choose_workers(10, PARALLEL_MIN_SECONDS / 2) == 1
    assert choose_workers(1, 100.0) == 1
    assert choose_workers(10, 100.0) == min(10, len(os.sched_getaffinity(0)))
    assert choose_workers(3, 0.0, workers=8) == 3  # explicit count, capped by the items
    assert choose_workers(10, 100.0, workers=8, max_workers=2) == 2  # e.g. by memory
    monkeypatch.setenv(WORKERS_ENV, "1")
    assert choose_workers(10, 100.0) == 1


def test_a_check_that_raises_cancels_the_pool():
    calls = []

    def check():
        calls.append(1)
        if len(calls) > 1:
            raise KeyboardInterrupt("interrupted by Ctrl-C")

    with pytest.raises(KeyboardInterrupt):
        ordered_map(_slow_square, range(5), workers=2, check=check)


@pytest.mark.parametrize("value", ["0", "-2", "two"])
def test_bad_worker_counts_are_one_line_errors(monkeypatch, capsys, value):
    monkeypatch.setenv(WORKERS_ENV, value)
    with pytest.raises(ValueError, match=WORKERS_ENV):
        env_workers()
    assert main(["analyze", "lcsys2022-homogeneous", "--tau-max", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and WORKERS_ENV in err[0]
    monkeypatch.delenv(WORKERS_ENV)
    try:
        code = main(["analyze", "lcsys2022-homogeneous", "--workers", value])
    except SystemExit as exc:  # argparse: not an integer
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--workers" in err[0]
