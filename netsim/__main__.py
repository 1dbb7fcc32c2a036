"""``python -m netsim``: the ``netsim`` command (:func:`netsim.console.main`)."""

from __future__ import annotations

import sys

from netsim.console import main

__all__: list[str] = []

if __name__ == "__main__":  # pragma: no cover - run as a program
    sys.exit(main())
