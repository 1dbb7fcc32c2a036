"""One rule for the files netsim reads (issue 29).

An input file is opened only if it is a regular file (a device such as ``/dev/zero``
would be read until the memory runs out, a named pipe would block forever), only if its
size is within a stated cap (checked on the file's status before a byte is read), and
then read with the cap enforced again (a file that grows while being read). TOML is
also checked for nesting depth before it is parsed (:func:`check_toml_depth`): deep
dotted keys or nested tables make the parser take minutes or exhaust the recursion.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["InputFileError", "read_input_bytes", "check_toml_depth", "file_kind",
           "MAX_SCENARIO_BYTES",
           "MAX_TABLE_BYTES", "MAX_TOML_DEPTH"]

#: Largest scenario file read (bytes); ``NETSIM_MAX_SCENARIO_BYTES`` replaces it.
MAX_SCENARIO_BYTES = 8 * 1024 * 1024
#: Largest data table read (a latency trace, a results file), bytes.
MAX_TABLE_BYTES = 256 * 1024 * 1024
#: Deepest nesting of tables, arrays or dotted keys a TOML input may have.
MAX_TOML_DEPTH = 64


class InputFileError(ValueError):
    """An input file netsim refuses to read (the message names it and why)."""


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``a named pipe``, ...)."""
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISFIFO(mode):
        return "a named pipe"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _mib(n: int) -> str:
    return f"{n / 2 ** 20:.1f} MiB"


def read_input_bytes(path: str | os.PathLike[str], what: str, max_bytes: int) -> bytes:
    """The bytes of a regular input file of at most ``max_bytes``.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for the message (``scenario file``, ``latency file``).
    max_bytes : int
        The cap.

    Raises
    ------
    InputFileError
        Naming the file: missing or unreadable, not a regular file, or over the cap.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise InputFileError(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(f"{what} {p} is {file_kind(st.st_mode)}, not a regular file")
    if st.st_size > max_bytes:
        raise InputFileError(f"{what} {p} has {_mib(st.st_size)}, more than the "
                             f"{_mib(max_bytes)} netsim reads")
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # swapped since the stat
                raise InputFileError(f"{what} {p} is not a regular file")
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputFileError(f"cannot read {what} {p}: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        raise InputFileError(f"{what} {p} grew past the {_mib(max_bytes)} netsim reads")
    return data


def check_toml_depth(text: str, where: str, max_depth: int = MAX_TOML_DEPTH) -> None:
    """Refuse TOML nested deeper than ``max_depth`` before it is parsed.

    Counts, outside strings and comments, the open ``[`` and ``{`` brackets and the dots
    of a key (a bare or quoted dotted key ``a.b.c`` or a header ``[a.b.c]``); each is one
    level. Linear in the text.

    Raises
    ------
    InputFileError
        Naming ``where`` and the line.
    """
    stack: list[str] = []  # open brackets: "H" a table header, "[" an array, "{" a table
    dots = 0  # dots of the key being read (reset at '=', ',' and a new line)
    line = 1
    in_key = True  # where a key may be read: a line's start at top level, inline tables
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c == "\n":
            line += 1
            dots = 0
            in_key = not stack or stack[-1] == "{"
            i += 1
            continue
        if c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        if c in "\"'":
            triple = text.startswith(c * 3, i)
            end_mark = c * 3 if triple else c
            j = i + len(end_mark)
            while j < n:
                if c == '"' and text[j] == "\\":
                    j += 2
                    continue
                if text.startswith(end_mark, j) or (not triple and text[j] == "\n"):
                    break
                j += 1
            line += text.count("\n", i, j)
            i = j + len(end_mark)
            continue
        if c == "[":
            header = in_key and (not stack or stack[-1] == "H")
            stack.append("H" if header else "[")
            in_key = header
        elif c == "{":
            stack.append("{")
            in_key = True
        elif c in "]}":
            if stack:
                stack.pop()
            in_key = False
        elif c == "=":
            in_key = False
            dots = 0
        elif c == ",":
            in_key = bool(stack) and stack[-1] == "{"
            dots = 0
        elif c == "." and in_key:
            dots += 1
        if len(stack) + dots > max_depth:
            raise InputFileError(f"{where}, line {line}: nested deeper than {max_depth} "
                                 "levels (tables, arrays and dotted keys); netsim does not "
                                 "parse it")
        i += 1
