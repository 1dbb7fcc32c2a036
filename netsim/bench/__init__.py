"""``netsim bench``: how much delay does each estimator tolerate, do the bounds predict it?

``netsim bench delay-tolerance SCENARIO|PRESET`` runs, for every delay setting and
delay bound tau of a grid and for every estimator family (by default the consensus
estimators with and without delay compensation, the block update, and the centralised
Kalman filter as the reference), M Monte Carlo trials in the event kernel, and puts next
to each other:

* measured: the steady-state network MSE (mean over the last ``steady_state_fraction``
  of the steps, trials that blew up left out), the fitted MSE growth per step over the
  second half, and the empirical decay factor of the error norm per step
  (``netsim.traces.analysis.decay_fit``: exp(slope/2) of log MSE over the transient);
  ``stable`` / ``diverging`` / ``diverged`` exactly as ``netsim run`` decides;
* exact: for time-invariant delays the spectral radius of the augmented closed loop
  of the realised delays (the error recursion the family declares: with A^(r+1)
  compensation for ``compensated``, with A for ``uncompensated``, which describes its
  error only for a still state; for ``block`` its own per-step rate
  rho((I-KD)(P kron A^(tau+1)))^(1/(tau+1)),
  exact when every message arrives within its block); for time-varying delays (or
  lossy links) the realised growth factor of the product A-hat[k]...A-hat[1] along
  trial 0's effective delays (``netsim.traces.analysis.growth_rates``; second-half rate);
* the papers' bounds at tau, as the paper modules declare them
  (:func:`netsim.papers.delay_bounds`: each bound, the error recursions it bounds and
  what it predicts, tau* or any bounded delay);
* a verdict per cell: ``bound violated`` (the exact value exceeds the bound -- the one
  meaning of the words, as in ``netsim analyze``), ``prediction contradicted`` (the bound
  predicts stability but the run is diverging or diverged), ``bound conservative`` (the
  bound does not predict stability, but the run is stable), else the measured verdict:
  ``stable``, ``diverging``, ``undecided`` or ``diverged`` (the rule of
  :mod:`netsim.verdicts`: a statistical test of the MSE growth over trials and steps,
  the exact rho where the error recursion is exact, and the float64 precision horizon).

It also reports the largest tolerated delay per estimator and setting, measured on
the grid, next to the predicted one (Theorem 1's tau*), and the exact homogeneous
tolerance (largest tau with every smaller tau's exact rho < 1); it checks the papers'
statements for the presets and prints, with the numbers, where they disagree. The
cells run on the sweep machinery (:mod:`netsim.sweep`): a local process pool by
default, Dask with ``--dask ADDRESS``, resumable with ``--resume FILE``.

Trial t of every cell uses the seed ``child_sequence(seed, "trial", t)``, the same as
``netsim run``: every estimator and delay setting sees the same initial states and
noise, and a cell's numbers equal ``netsim run``'s for the same scenario, tau and seed.

Modules
-------
:mod:`~netsim.bench.presets`
    estimator families, delay settings, the papers' presets (declared by
    :mod:`netsim.papers`);
:mod:`~netsim.bench.variants`
    the scenario of a cell (delay-setting and sweep variants) and its fingerprint;
:mod:`~netsim.bench.cells`
    one delay-tolerance cell: Monte Carlo measurement, exact analytics, verdict;
:mod:`~netsim.bench.delay_tolerance`
    the benchmark: the grid of cells on the sweep machinery, the tolerance table;
:mod:`~netsim.bench.claims`
    the papers' statements checked against the report;
:mod:`~netsim.bench.fmt`, :mod:`~netsim.bench.report`, :mod:`~netsim.bench.plots`
    the report as text and as a PNG;
:mod:`~netsim.bench.scenario_sweep`
    ``netsim bench sweep``: a parameter grid of Monte Carlo runs;
:mod:`~netsim.bench.command`
    the ``netsim bench`` command line (``python -m netsim.bench``).
"""

import sys
from typing import Any

from netsim.bench.cells import BOUND_SLACK as BOUND_SLACK
from netsim.bench.cells import CURVE_POINTS as CURVE_POINTS
from netsim.bench.cells import ROUNDOFF_WARNING as ROUNDOFF_WARNING
from netsim.bench.cells import _verdict as _verdict
from netsim.bench.cells import delay_tolerance_cell
from netsim.bench.command import add_bench_parser, cmd_bench
from netsim.bench.command import main as main
from netsim.bench.delay_tolerance import SCAN_TAU_MIN as SCAN_TAU_MIN
from netsim.bench.delay_tolerance import run_delay_tolerance
from netsim.bench.plots import plot_report
from netsim.bench.presets import DELAY_MODELS, FAMILIES, Preset, delay_settings, presets
from netsim.bench.report import format_report
from netsim.bench.scenario_sweep import run_scenario_sweep, scenario_sweep_cell
from netsim.bench.variants import scenario_data as scenario_data
from netsim.bench.variants import scenario_fingerprint as scenario_fingerprint
from netsim.bench.variants import sweep_variant as sweep_variant

#: The name benchmarks/engine_scaling.py imports (bench.py's private name before the split).
_scenario_data = scenario_data


def __getattr__(name: str) -> Any:
    # PRESETS and DELAY_SETTINGS come from the paper modules: netsim.bench.presets computes
    # them on access, so that importing the bench does not import the papers
    if name in ("PRESETS", "DELAY_SETTINGS"):
        return getattr(sys.modules["netsim.bench.presets"], name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "DELAY_SETTINGS",
    "DELAY_MODELS",
    "PRESETS",
    "presets",
    "delay_settings",
    "FAMILIES",
    "Preset",
    "run_delay_tolerance",
    "delay_tolerance_cell",
    "format_report",
    "plot_report",
    "scenario_sweep_cell",
    "run_scenario_sweep",
    "add_bench_parser",
    "cmd_bench",
]
