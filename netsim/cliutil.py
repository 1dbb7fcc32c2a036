"""What every ``netsim`` subcommand shares: the user-facing error and the exit codes.

:mod:`netsim.cli` and the subcommands it registers (:mod:`netsim.bench`) both import
this module, so neither imports the other's internals. :mod:`netsim.cli` re-exports
these names.

Exit codes: 0 success (an estimator that diverged is a result, not an error);
2 bad input (scenario, arguments); 3 gain design failed; 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import Any, NoReturn

__all__ = ["EXIT_BAD_INPUT", "EXIT_DESIGN_FAILED", "EXIT_INTERRUPTED", "CommandError",
           "REPRODUCE_HELP", "OneLineParser", "TableEpilogFormatter", "analyze_with_progress",
           "gains_if_needed", "tau_star_text", "NOT_COMPUTED",
           "note_kernel_fallbacks", "progress_bar", "scenario_warnings"]

#: ``netsim reproduce``'s one-line help, shared by the full parser and the cheap listing.
REPRODUCE_HELP = "regenerate every figure and table of the four papers, with a report"

EXIT_BAD_INPUT = 2
EXIT_DESIGN_FAILED = 3
EXIT_INTERRUPTED = 130


#: What a table prints for a number that was not computed (never ``None``).
NOT_COMPUTED = "not computed"


def tau_star_text(tau_star: int | None, computed: bool = True) -> str:
    """LCSYS2022 Theorem 1's tau* as table text, never ``None``.

    ``tau_star`` None means the condition fails already at tau = 0 (the delay-free
    design is not stable: :func:`netsim.models.augmented.tau_star`), so no delay is
    tolerated; ``computed=False``: the analysis did not run.

    Examples
    --------
    >>> tau_star_text(10), tau_star_text(None), tau_star_text(None, computed=False)
    ('10', 'none (no delay is tolerated)', 'not computed')
    """
    if not computed:
        return NOT_COMPUTED
    return "none (no delay is tolerated)" if tau_star is None else str(tau_star)


class CommandError(Exception):
    """A user-facing error: one line on stderr and an exit code."""

    def __init__(self, message: str, code: int = EXIT_BAD_INPUT) -> None:
        super().__init__(message)
        self.code = code


def gains_if_needed(scenario: Any, families: Sequence[Any], name: str) -> Any:
    """The scenario's gains when one of ``families`` needs them, else None.

    Raises CommandError (exit 3) naming the scenario when the design fails.
    """
    from netsim.estimators.gains import GainDesignError
    from netsim.runner import scenario_gains

    if not any(f.needs_gains for f in families):
        return None
    try:
        return scenario_gains(scenario)
    except (GainDesignError, ValueError) as exc:
        raise CommandError(f"scenario {name}: gain design failed: {exc}",
                           EXIT_DESIGN_FAILED) from None


def note_kernel_fallbacks(command: str, names: Sequence[str], what: str = "them") -> None:
    """Say on stderr which families ``--engine auto`` runs in the event kernel."""
    if not names:
        return
    one = len(names) == 1
    sys.stderr.write(f"netsim {command}: note: {', '.join(names)} "
                     f"{'has' if one else 'have'} no batched form; --engine auto runs "
                     f"{'it' if one and what == 'them' else what} in the event kernel\n")


class TableEpilogFormatter(argparse.HelpFormatter):
    """Help formatter that wraps paragraphs as usual but prints any text with line breaks
    (a table, such as :data:`netsim.verdicts.VERDICT_TABLE` as an epilog) as it is."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit 2).

    argparse prints its usage before the error; netsim's promise is one line naming
    what is wrong, so the usage is left to ``--help``. Subcommand parsers inherit it.
    """

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} "
                  "--help)\n")


@contextlib.contextmanager
def scenario_warnings(command: str) -> Iterator[None]:
    """Print each distinct :class:`netsim.models.scenario.ScenarioWarning` raised inside
    as one line ``netsim <command>: warning: <key>: <message>`` on stderr (a scenario
    loaded several times, as a sweep's variants are, warns once). numpy's and scipy's
    RuntimeWarnings (overflow, invalid value: arithmetic on a diverging run, which the
    verdict reports as "diverged at step k") are not printed: an error or a result is
    one line, not a line and numpy's noise. Other warnings go to Python's usual display."""
    seen: set[str] = set()
    shown = warnings.showwarning

    def show(message: Any, category: type[Warning], filename: str = "", *args: Any,
             **kwargs: Any) -> None:
        from netsim.models.scenario import ScenarioWarning

        if issubclass(category, RuntimeWarning) and any(
                f"{os.sep}{lib}{os.sep}" in str(filename) for lib in ("numpy", "scipy")):
            return
        if issubclass(category, ScenarioWarning):
            text = str(message)
            if text not in seen:
                seen.add(text)
                sys.stderr.write(f"netsim {command}: warning: {text}\n")
            return
        shown(message, category, filename, *args, **kwargs)

    with warnings.catch_warnings():
        warnings.simplefilter("always", UserWarning)
        warnings.showwarning = show
        yield


class _NoBar:
    """What :func:`progress_bar` returns when no bar shows: ``update`` and ``close``."""

    def update(self, n: float = 1) -> None:
        """Ignore ``n`` ticks."""

    def close(self) -> None:
        """Nothing to close."""


def progress_bar(*, total: int, desc: str, unit: str, disable: bool | None = None,
                 leave: bool = False) -> Any:
    """A tqdm bar on stderr, or a stand-in without output when it would not show.

    ``disable=None`` shows the bar only on a terminal, as tqdm decides; tqdm (and its
    importlib.metadata) is imported only when the bar shows (start-up, issue 34).
    """
    if disable or (disable is None and hasattr(sys.stderr, "isatty")
                   and not sys.stderr.isatty()):  # tqdm's own test
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=disable, file=sys.stderr,
                leave=leave)


def analyze_with_progress(scenario: Any, gains: Any, tau_max: int, analyze: Any,
                          disable: bool | None = None, **options: Any) -> Any:
    """``analyze(scenario, gains, tau_max, **options)`` with a tqdm bar on stderr (one
    tick per delay pattern, in completion order when the patterns run in parallel).

    The bar shows only on a terminal (``disable=None``; True: never); Ctrl-C raises
    KeyboardInterrupt as soon as the running eigenvalue computation returns (the
    command line turns it into exit 130).
    """
    bar = progress_bar(total=tau_max + 1, desc=f"netsim analyze {scenario.name}",
                       unit="tau", disable=disable)
    try:  # no graceful handler: nothing is written, Ctrl-C may stop at once
        return analyze(scenario, gains, tau_max, progress=bar.update, **options)
    finally:
        bar.close()
