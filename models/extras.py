"""Optional dependencies: import one, or say in one line which extra installs it.

The core install (``pip install netsim``) runs, designs, analyses and traces; the
extras of ``pyproject.toml`` add the rest:

========  ==============================  =============================================
extra     installs                        for
========  ==============================  =============================================
plot      matplotlib                      ``netsim plot``, ``layout --figure``, ``bench
                                          --plot``, ``netsim reproduce``
dask      dask[distributed]               the Dask executor (``--dask ADDRESS``)
notebook  pandas, pyarrow, matplotlib     data frames, Parquet, ``RunResult.plot()``
live      foxglove-sdk                    ``netsim run --live``
========  ==============================  =============================================

A missing one raises :class:`MissingExtra` (an ``ImportError``) naming the command to
install it; the command line prints it as one line and exits 2.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["MissingExtra", "require", "missing"]

#: The distribution an importable top-level module comes from, where the names differ.
_DISTRIBUTIONS = {"distributed": "dask[distributed]", "foxglove": "foxglove-sdk",
                  "yaml": "pyyaml"}


class MissingExtra(ImportError):
    """An optional dependency is not installed (the message names ``pip install``)."""


def missing(module: str, extra: str, needed_for: str) -> MissingExtra:
    """The error to raise when ``module`` of ``extra`` is missing for ``needed_for``."""
    top = module.split(".")[0]
    name = _DISTRIBUTIONS.get(top, top)
    return MissingExtra(f"{needed_for} needs {name}, which is not installed: "
                        f"pip install 'netsim[{extra}]'", name=top)


def require(module: str, extra: str, needed_for: str) -> ModuleType:
    """Import ``module`` (an optional dependency of ``extra``) or raise :class:`MissingExtra`.

    Parameters
    ----------
    module : str
        What to import (``"matplotlib.figure"``).
    extra : str
        The extra of ``pyproject.toml`` that installs it (``"plot"``).
    needed_for : str
        What needs it, for the message (``"netsim plot"``).

    Examples
    --------
    >>> from netsim.models.extras import require
    >>> require("json", "plot", "an example").__name__
    'json'
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:  # not installed (a broken install raises as it is)
        raise missing(exc.name or module, extra, needed_for) from None
