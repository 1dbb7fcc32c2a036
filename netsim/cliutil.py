"""What every ``netsim`` subcommand shares: the user-facing error and the exit codes.

:mod:`netsim.cli` and the subcommands it registers (:mod:`netsim.bench`) both import
this module, so neither imports the other's internals. :mod:`netsim.cli` re-exports
these names.

Exit codes: 0 success (an estimator that diverged is a result, not an error);
2 bad input (scenario, arguments); 3 gain design failed; 130 interrupted.
"""

from __future__ import annotations

__all__ = ["EXIT_BAD_INPUT", "EXIT_DESIGN_FAILED", "EXIT_INTERRUPTED", "CommandError"]

EXIT_BAD_INPUT = 2
EXIT_DESIGN_FAILED = 3
EXIT_INTERRUPTED = 130


class CommandError(Exception):
    """A user-facing error: one line on stderr and an exit code."""

    def __init__(self, message: str, code: int = EXIT_BAD_INPUT) -> None:
        super().__init__(message)
        self.code = code
