"""The papers' printed numbers (one place; the claim registry, :mod:`netsim.claims`, and
the bench's claim rows, :mod:`netsim.bench.claims`, read them here)."""

from __future__ import annotations

__all__ = ["LCSYS", "TOLERANT", "AOI", "DKFE", "LCSYS_RHO", "LCSYS_TAU_STAR",
           "LCSYS_EQ26", "LCSYS_FIG1_TAUS", "LCSYS_HOM19_RHO", "TOLERANT_RHO",
           "TOLERANT_BOUNDS", "TOLERANT_FIG1_TAUS", "TOLERANT_FIG2_TAU", "PAPER_FILES"]

LCSYS = "LCSYS2022"
TOLERANT = "delay-tolerant"
AOI = "aoi"
DKFE = "dkfe"

#: The text files in ``shared/papers/``.
PAPER_FILES = {
    LCSYS: "known-delays-consensus-estimation-LCSYS2022.txt",
    TOLERANT: "delay-tolerant-consensus-estimation.txt",
    AOI: "aoi-finite-time-distributed-observer.txt",
    DKFE: "dkfe-dimensionality-reduction-delays.txt",
}

#: LCSYS2022 Section IV: rho(A-hat) of its LMI gains and tau*.
LCSYS_RHO = 0.64
LCSYS_TAU_STAR = 10
#: LCSYS2022 Section IV: the eq. (26) bounds printed for tau = 3, 8, 19.
LCSYS_EQ26 = {3: 0.74, 8: 0.94, 19: 1.45}
#: LCSYS2022 Fig. 1: stable taus, and rho(A-bar) = 1 at homogeneous tau = 19.
LCSYS_FIG1_TAUS = (0, 3, 8)
LCSYS_HOM19_RHO = 1.0
#: Delay-tolerant paper Section V: rho(A-hat) and the bounds at tau = 10, 25.
TOLERANT_RHO = 0.64
TOLERANT_BOUNDS = {10: 0.96, 25: 0.983}
TOLERANT_FIG1_TAUS = (0, 10, 25)
TOLERANT_FIG2_TAU = 15
