"""``python -m netsim.bench ...``: the ``bench`` subcommand on its own."""

import sys

from netsim.bench.command import main

__all__: list[str] = []

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
