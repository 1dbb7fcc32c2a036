"""The one exception every gain design in :mod:`netsim.estimators` raises.

Both the consensus gain design (:mod:`netsim.estimators.gains`: LMI, CCL, refinement)
and the age-of-information source gains (:mod:`netsim.estimators.aoi`: deadbeat, pole
placement) raise :class:`GainDesignError`; each of those modules re-exports it, so
``netsim.estimators.gains.GainDesignError is netsim.estimators.aoi.GainDesignError``.
"""

from __future__ import annotations

__all__ = ["GainDesignError"]


class GainDesignError(ValueError):
    """No (certified) gain could be designed.

    Raised for an unobservable pair or block, an infeasible or uncertified LMI/CCL
    design, a solver failure, misplaced poles or a deadbeat gain that is not nilpotent
    to tolerance. It is a :class:`ValueError`, so callers that catch ``ValueError``
    for bad input must catch it first if they treat a failed design differently.
    """
