"""Benchmark presets: the estimator families, the delay settings, the papers' studies."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["DELAY_SETTINGS", "FAMILIES", "NO_DELAY", "PRESETS", "Preset"]


#: Estimator families benchmarked, in table order (the last one is the reference).
FAMILIES = ("compensated", "uncompensated", "block", "centralized-kf")


#: Delay settings: name -> (``delays.model``, description).
DELAY_SETTINGS: dict[str, tuple[str, str]] = {
    "homogeneous": ("homogeneous", "fixed, tau on every link (LCSYS2022 Fig. 1)"),
    "heterogeneous": ("heterogeneous", "fixed, uniform in 0..tau per link, drawn once "
                      "(delays.seed; LCSYS2022 Fig. 1)"),
    "asynchronous-fixed": ("heterogeneous", "asynchronous time-invariant: fixed, uniform "
                           "in 0..tau per link, drawn once (delay-tolerant Fig. 2 (iii))"),
    "time-varying": ("asynchronous", "asynchronous time-varying: a uniform draw in 0..tau "
                     "per link per message, reordering (delay-tolerant Figs. 1, 2 (i))"),
    "synchronous": ("synchronous", "synchronous time-varying: one uniform draw in 0..tau "
                    "per step, common to all links (delay-tolerant Fig. 2 (ii))"),
}


#: Cells with tau = 0 are the same whatever the setting; they are computed once.
NO_DELAY = "none"


@dataclass(frozen=True)
class Preset:
    """A built-in benchmark: a paper's simulation study."""

    name: str
    scenario: str
    taus: tuple[int, ...]
    delays: tuple[str, ...]
    trials: int
    steps: int
    focus: str
    description: str
    claims: tuple[str, ...]


#: Built-in presets. 500 steps: on this unstable plant (rho(A) = 1.04) the state grows
#: like 1.04^k, and beyond about 750 steps double-precision round-off (eps |x_k|) reaches
#: the estimation error itself (every estimator's MSE jumps near step 1000). The
#: LCSYS2022 preset (100 trials x 500 steps, 22 distinct cells) takes about 3.5 minutes
#: with the default 2 local workers on the 2-core development machine.
PRESETS: dict[str, Preset] = {
    "lcsys2022-fig1": Preset(
        name="lcsys2022-fig1",
        scenario="lcsys2022-heterogeneous",
        taus=(0, 3, 8, 19),
        delays=("homogeneous", "heterogeneous"),
        trials=100,
        steps=500,
        focus="compensated",
        description="LCSYS2022 Fig. 1: Monte Carlo MSE of the compensating "
                    "estimator for tau = 0, 3, 8, 19, homogeneous and heterogeneous fixed "
                    "delays; rho(A-hat) = 0.64, tau* = 10, eq. (26) bounds 0.74, 0.94, 1.45",
        claims=("L-rho", "L-tau-star", "L-eq26", "L-stable-0-3-8", "L-hom-19",
                "L-het-19", "L-decay"),
    ),
    "delay-tolerant-fig1": Preset(
        name="delay-tolerant-fig1",
        scenario="lcsys2022-heterogeneous",
        taus=(0, 10, 25),
        delays=("time-varying",),
        trials=100,
        steps=500,
        focus="uncompensated",
        description="Delay-tolerant paper Fig. 1: MSE of the uncompensated estimator "
                    "(eqs. 6-7) without delay and with arbitrary random delays bounded by "
                    "tau-bar = 10 and 25; rho(A-hat) = 0.64, bounds 0.96 and 0.983",
        claims=("T-rho", "T-bounds", "T-fig1-stable", "T-decay", "T-theorem1"),
    ),
    "delay-tolerant-fig2": Preset(
        name="delay-tolerant-fig2",
        scenario="lcsys2022-heterogeneous",
        taus=(15,),
        delays=("time-varying", "synchronous", "asynchronous-fixed"),
        trials=100,
        steps=500,
        focus="uncompensated",
        description="Delay-tolerant paper Fig. 2: asynchronous time-varying, synchronous "
                    "time-varying and asynchronous fixed delays, tau-bar = 15",
        claims=("T-fig2-stable", "T-theorem1"),
    ),
}
