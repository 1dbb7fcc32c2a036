"""Clock and trigger studies on the LCSYS2022 plant (issue 32), declared by
:mod:`netsim.papers.lcsys2022` as sweep presets (``netsim bench sweep PRESET``).

All three run the paper's plant (our instance, scenario ``lcsys2022-heterogeneous``:
n = 6, rho(A) = 1.04, N = 4 on the cycle, fixed heterogeneous delays 0..3 steps, LMI
gains) under a ``[time]`` table (``docs/time.rst``); the paper itself has one common
clock and sends every estimate, so nothing in it predicts these curves.

- ``lcsys2022-clock-offset``: fixed clock offsets o x (-1, 1, -1/2, 1/2) T
  (:func:`netsim.bench.variants.fixed_pattern`), o = 0..1, the compensating and the
  uncompensated estimator. Every trial has the same offsets, so the cells run on the
  batched timed engine (:mod:`netsim.timedlockstep`).
- ``lcsys2022-clock-drift``: fixed clock drifts s x (-1, 1, -1/2, 1/2) ppm, s = 0..10^4:
  over the 150 periods of a run each clock is off by up to 150 s 10^-6 T (1.5 T at
  10^4 ppm). Batched timed engine.
- ``lcsys2022-trigger``: send-on-delta thresholds 0..30 (an agent sends when its
  estimate moved by the threshold since its last message), the compensating estimator,
  MSE beside the message rate (estimates sent per agent per T). Threshold 0 sends every
  update and runs batched; a threshold above 0 holds updates back per trial, so those
  cells run on the event kernel alone (each row names its engine).

``--engine events`` runs the same cells on the event kernel, the reference the batched
engine is tested against (``tests/test_time_presets.py``).
"""

from __future__ import annotations

from netsim.bench.presets import SweepPreset

__all__ = ["CLOCK_OFFSETS", "CLOCK_DRIFTS_PPM", "TRIGGER_THRESHOLDS", "TIME_STEPS",
           "TIME_TRIALS", "CLOCK_OFFSET_SWEEP", "CLOCK_DRIFT_SWEEP", "TRIGGER_SWEEP",
           "TIME_SWEEPS"]

_SCENARIO = "lcsys2022-heterogeneous"
#: Swept offsets o (units of T = 1): agent i's offset is o p_i, p = (-1, 1, -1/2, 1/2).
CLOCK_OFFSETS = (0.0, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
#: Swept drifts s (ppm): agent i's drift is s p_i ppm.
CLOCK_DRIFTS_PPM = (0.0, 1.0, 10.0, 100.0, 1000.0, 10000.0)
#: Send-on-delta thresholds (Euclidean norm of the estimate's change).
TRIGGER_THRESHOLDS = (0.0, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
#: Horizon and trials: 150 periods keep the plant's state (1.04^k) moderate, so a clock
#: error shows as a rise of the MSE before it diverges (at 300 steps every offset from
#: 0.01 T diverges).
TIME_STEPS = 150
TIME_TRIALS = 20
_BOTH = ("compensated", "uncompensated")

CLOCK_OFFSET_SWEEP = SweepPreset(
    name="lcsys2022-clock-offset",
    scenario=_SCENARIO,
    axes={"offset": CLOCK_OFFSETS, "offset_pattern": ("fixed",)},
    families=_BOTH,
    trials=TIME_TRIALS,
    steps=TIME_STEPS,
    description="LCSYS2022 plant (our instance), not in the paper: MSE and message rate "
                "against fixed clock offsets o x (-1, 1, -1/2, 1/2) T, o = 0..1, "
                "compensated and uncompensated; batched timed engine",
)

CLOCK_DRIFT_SWEEP = SweepPreset(
    name="lcsys2022-clock-drift",
    scenario=_SCENARIO,
    axes={"drift_ppm": CLOCK_DRIFTS_PPM, "drift_pattern": ("fixed",)},
    families=_BOTH,
    trials=TIME_TRIALS,
    steps=TIME_STEPS,
    description="LCSYS2022 plant (our instance), not in the paper: MSE and message rate "
                "against fixed clock drifts s x (-1, 1, -1/2, 1/2) ppm, s = 0..10^4, "
                "compensated and uncompensated; batched timed engine",
)

TRIGGER_SWEEP = SweepPreset(
    name="lcsys2022-trigger",
    scenario=_SCENARIO,
    axes={"threshold": TRIGGER_THRESHOLDS},
    families=("compensated",),
    trials=TIME_TRIALS,
    steps=TIME_STEPS,
    description="LCSYS2022 plant (our instance), not in the paper: MSE and message rate "
                "against the send-on-delta threshold 0..30, compensated; threshold 0 on "
                "the batched timed engine, the others on the event kernel",
)

#: The three presets, in the order ``netsim bench sweep --help`` lists them.
TIME_SWEEPS = (CLOCK_OFFSET_SWEEP, CLOCK_DRIFT_SWEEP, TRIGGER_SWEEP)
