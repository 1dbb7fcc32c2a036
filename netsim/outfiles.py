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

__all__ = ["OutputFileError", "check_output", "check_output_folder", "same_file",
           "atomic_output", "safe_output", "write_text_safely"]


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


def _check_owned_file(p: Path, option: str) -> None:
    """A file a command writes inside a folder it was given: not a link, not special."""
    if p.is_symlink():
        raise OutputFileError(f"{option} {p}: is a symbolic link; netsim does not write "
                              "through links (name the target file itself)")
    if p.exists() and not stat.S_ISREG(p.stat().st_mode):
        raise OutputFileError(f"{option} {p}: is {file_kind(p.stat().st_mode)}, not a regular "
                              "file")


def check_output_folder(folder: str | os.PathLike[str], option: str,
                        names: Iterable[str] = ()) -> Path:
    """Check, before any work, a folder a command writes its files into (``option``).

    The folder must not be a symbolic link or a non-folder; it may be missing (the command
    creates it). Each of ``names`` that exists in it must be a regular file, not a link.
    The command owns those names: existing regular files of those names are replaced.

    Raises
    ------
    OutputFileError
        One line naming the option and the path.
    """
    p = Path(folder)
    if p.is_symlink() or (p.exists() and not p.is_dir()):
        raise OutputFileError(f"{option} {folder}: is a symbolic link or not a folder; "
                              "netsim writes its files into a real folder")
    if p.is_dir():
        if not os.access(p, os.W_OK | os.X_OK):
            raise OutputFileError(f"{option} {folder}: folder is not writable")
        for name in names:
            _check_owned_file(p / name, option)
    return p


@contextlib.contextmanager
def safe_output(path: str | os.PathLike[str], option: str) -> Iterator[Path]:
    """:func:`atomic_output` for a file a command owns inside a folder the user named
    (``option``): refused (:class:`OutputFileError`) if it is a link or a special file."""
    p = Path(path)
    _check_owned_file(p, option)
    with atomic_output(p) as tmp:
        yield tmp


def write_text_safely(path: str | os.PathLike[str], text: str, option: str) -> Path:
    """Write ``text`` to ``path`` inside a folder the user named (``option``): never
    through a symbolic link or onto a special file; atomically. The command owns the
    file names it writes there (e.g. ``claims.md``), so an existing regular file of that
    name is replaced."""
    p = Path(path)
    with safe_output(p, option) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return p
