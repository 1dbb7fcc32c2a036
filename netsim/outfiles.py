"""One rule for the files netsim writes (issue 29).

Every command that writes a file names it with an option (``--trace``, ``-o``,
``--figure``, ``--csv``, ``--plot``, ...) and checks it with :func:`check_output` before
it computes anything:

- never through a symbolic link (the link's target is a file the user did not name);
- never onto one of the command's inputs (the scenario file, a trace being read) or onto
  another output of the same command;
- never a directory or a special file (device, pipe, socket);
- an existing file only with ``--force`` (where the command overwrites);
- only into a directory that exists and is writable.

Whole files (plots, layouts, JSON) are written with :func:`atomic_output`: to a temporary
file beside the target, then renamed over it, so an interrupted or failed write leaves
the old file (or none), never half a file. Traces stream to their file by design (an
interrupted run leaves a readable prefix, :mod:`netsim.traces.recorder`) and use only the
checks.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from netsim.models.inputfiles import file_kind

__all__ = ["OutputFileError", "check_output", "same_file", "atomic_output",
           "write_text_safely"]


class OutputFileError(ValueError):
    """An output path netsim refuses to write (one line, naming the option and path)."""


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name the same file (after resolving links and ``..``; for two
    existing files, also the same inode)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists() and os.path.samefile(pa, pb):
            return True
    except OSError:
        pass
    return os.path.realpath(pa) == os.path.realpath(pb)


def check_output(path: str | os.PathLike[str], option: str, *, force: bool = False,
                 inputs: Iterable[str | os.PathLike[str]] = (),
                 others: Iterable[str | os.PathLike[str]] = (),
                 overwrites: bool = True) -> Path:
    """Check an output path by the module's rule; return it as a Path.

    Parameters
    ----------
    path : path-like
        The file to write.
    option : str
        The option that named it (``--trace``, ``-o``, ...), for the message.
    force : bool
        The user allowed overwriting an existing file.
    inputs : iterable of path-like
        The command's input files: the output may be none of them.
    others : iterable of path-like
        The command's other outputs: the output may be none of them.
    overwrites : bool
        False where an existing file is appended to or resumed (e.g. a results file),
        so that it needs no ``--force``.

    Raises
    ------
    OutputFileError
        One line: ``<option> <path>: <why>``.
    """
    p = Path(path)
    head = f"{option} {path}"
    if str(path).endswith(os.sep) or p.is_dir():
        raise OutputFileError(f"{head}: is a directory; give a file name")
    if p.is_symlink():
        raise OutputFileError(f"{head}: is a symbolic link; netsim does not write through "
                              "links (name the target file itself)")
    for other in inputs:
        if same_file(p, other):
            raise OutputFileError(f"{head}: is also an input of this command ({other}); "
                                  "choose another output file")
    for other in others:
        if same_file(p, other):
            raise OutputFileError(f"{head}: is also another output of this command "
                                  f"({other}); choose two different files")
    if p.exists():
        mode = p.stat().st_mode
        if not stat.S_ISREG(mode):
            raise OutputFileError(f"{head}: is {file_kind(mode)}, not a regular file")
        if overwrites and not force:
            raise OutputFileError(f"{head}: exists; pass --force to overwrite it")
    folder = p.parent
    if not folder.is_dir():
        raise OutputFileError(f"{head}: directory {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputFileError(f"{head}: directory {folder} is not writable")
    return p


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix); on success rename it over
    ``path``, on any error remove it and leave ``path`` as it was.

    Example
    -------
    >>> with atomic_output("plot.png") as tmp:      # doctest: +SKIP
    ...     figure.savefig(tmp, format="png")
    """
    target = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=target.suffix or ".tmp",
                                dir=target.parent if str(target.parent) else ".")
    os.close(fd)
    tmp = Path(name)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.chmod(tmp, 0o666 & ~umask)  # the permissions an ordinary open() would give
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_text_safely(path: str | os.PathLike[str], text: str, option: str) -> Path:
    """Write ``text`` to ``path`` inside a folder the user named (``option``): never
    through a symbolic link or onto a special file; atomically. The command owns the
    file names it writes there (e.g. ``claims.md``), so an existing regular file of that
    name is replaced."""
    p = Path(path)
    if p.is_symlink():
        raise OutputFileError(f"{option} {p}: is a symbolic link; netsim does not write "
                              "through links (name the target file itself)")
    if p.exists() and not stat.S_ISREG(p.stat().st_mode):
        raise OutputFileError(f"{option} {p}: is {file_kind(p.stat().st_mode)}, not a regular "
                              "file")
    with atomic_output(p) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return p
