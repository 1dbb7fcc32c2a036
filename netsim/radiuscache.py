"""A disk cache of exact spectral radii: ``netsim analyze`` computes each one once.

The exact spectral radius of an augmented closed loop (LCSYS2022 eq. 9-10, the
delay-tolerant paper's eq. 11; :func:`netsim.models.augmented.augmented_radius_and_method`)
is a deterministic function of the consensus matrix P, the plant's A and C_i, the gains
L_i, the delay pattern, the augmentation depth, the compensated flag and the
computation (its method version and parameters, and the netsim, numpy and scipy that
ran it). An entry is stored under a SHA-256 fingerprint of exactly those
(:func:`radius_key`): P, A, every C_i and L_i as float64 bytes with their shapes (a
sparse P as its sorted CSR arrays), the delays as int64 bytes, the depth, the flag,
:data:`METHOD_VERSION`, :data:`netsim.models.augmented.DENSE_SIZE_THRESHOLD` and the
ARPACK settings, and the three library versions.

An entry is one small JSON file ``<key>.json``: the radius as ``float.hex`` (read back
bit for bit), the method that computed it, its key, :data:`LAYOUT` and a SHA-256 digest
of those. It is verified when read: it parses, has this layout, the key of its file
name, a non-negative (or infinite) radius, a known method and the right digest. An
entry that fails is ignored, reported as one :class:`RadiusCacheWarning` (``netsim
analyze: warning: radius cache: ...`` on stderr), removed, and recomputed and rewritten;
a missing entry is computed and written silently. Writes go to a temporary file
renamed into place (a killed writer leaves no half entry); a failure to write is
ignored. The folder holds at most :data:`MAX_ENTRIES` entries: a write that finds more
removes the oldest (by modification time) down to three quarters of it.

Location: ``$NETSIM_RADIUS_CACHE`` if set (``off`` disables this cache alone, e.g. to
measure a cold analysis with warm gains), else the folder ``radii`` inside the gain
cache's folder (:func:`netsim.gaincache.cache_dir`); ``--no-cache`` and
``NETSIM_CACHE_DIR=off`` disable it with the gain cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from netsim.models.lazy import issparse
from netsim.models.scenario import ScenarioWarning

__all__ = [
    "LAYOUT",
    "MAX_ENTRIES",
    "METHOD_VERSION",
    "RadiusCacheWarning",
    "load",
    "radius_dir",
    "radius_key",
    "store",
]

#: Bumped when the stored layout changes (it enters the key).
LAYOUT = 1
#: Bumped when the computation of the radii changes in a way the parameters in the
#: key do not show (it enters the key, so older entries are never looked up). 2: the
#: structured radius' root scaling and eigenvector check (issue 34).
METHOD_VERSION = 2
#: Most entries kept (about 300 bytes each).
MAX_ENTRIES = 4096


class RadiusCacheWarning(ScenarioWarning):
    """A radius cache entry was ignored (and rewritten); the ``netsim`` command prints
    it as one ``netsim <command>: warning: radius cache: ...`` line on stderr."""

    def __init__(self, message: str) -> None:
        super().__init__("radius cache", message)


def radius_dir() -> Path | None:
    """The cache folder, or None when this cache is off."""
    value = os.environ.get("NETSIM_RADIUS_CACHE")
    if value is not None and value.strip().lower() in ("", "off", "0", "none"):
        return None
    from netsim import gaincache

    gains = gaincache.cache_dir()  # None under --no-cache / NETSIM_CACHE_DIR=off
    if gains is None:
        return None
    return Path(value) if value is not None else gains / "radii"


_VERSIONS: list[str] = []


def _versions() -> str:
    """``netsim=..;numpy=..;scipy=..`` as the gain cache reads them (once per process)."""
    if not _VERSIONS:
        import sys

        from netsim import gaincache

        names = ("netsim", "numpy", "scipy")
        light = (None if "importlib.metadata" in sys.modules
                 else gaincache._installed_versions(names))
        _VERSIONS.append("".join(f"{name}={gaincache._version(name, light)};"
                                 for name in names))
    return _VERSIONS[0]


def _parameters() -> str:
    """The settings of :mod:`netsim.models.augmented` that decide how a radius is computed."""
    from netsim.models import augmented as aug

    names = ("DENSE_SIZE_THRESHOLD", "DENSE_FALLBACK_MAX", "ARPACK_K", "ARPACK_TOL",
             "ARPACK_MAXITER", "ARPACK_NCV", "ARPACK_RETRIES", "ARPACK_BASIS_BYTES",
             "ARPACK_POWER", "AUGMENTED_ARPACK_POWER", "AUGMENTED_ARPACK_NCV",
             "AUGMENTED_DENSE_SIZE_THRESHOLD", "ROOT_SCALE_FREE", "PAIR_CHECK_RTOL")
    return ";".join(f"{name}={getattr(aug, name, None)!r}" for name in names)


def radius_key(P: Any, A: Any, C: Sequence[Any], L: Sequence[Any], delays: Any,
               depth: int, compensated: bool) -> str:
    """SHA-256 fingerprint of one exact radius' inputs (see the module docstring).

    Parameters
    ----------
    P : array_like or scipy.sparse array, shape (N, N)
    A : array_like, shape (n, n)
    C : sequence of array_like
        ``N`` output matrices, ``C[i]`` of shape ``(m_i, n)``.
    L : sequence of array_like
        ``N`` gains, ``L[i]`` of shape ``(n, m_i)``.
    delays : array_like of int, shape (N, N)
    depth : int
        Augmentation depth ``tau``.
    compensated : bool

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256()
    digest.update(f"netsim-radius-{LAYOUT}-{METHOD_VERSION};{_versions()};"
                  f"{_parameters()};depth={int(depth)};compensated={bool(compensated)};"
                  .encode())

    def add(array: Any, dtype: Any = np.float64) -> None:
        a = np.ascontiguousarray(np.asarray(array, dtype=dtype))
        digest.update(repr(a.shape).encode())
        digest.update(a.tobytes())

    if issparse(P):
        import scipy.sparse as sp

        W = sp.csr_array(P)
        W.sort_indices()
        digest.update(b"csr")
        add(np.asarray(W.shape))
        add(W.indptr, np.int64)
        add(W.indices, np.int64)
        add(W.data)
    else:
        add(P)
    add(A)
    digest.update(f"C{len(C)}".encode())
    for Ci in C:
        add(np.atleast_2d(np.asarray(Ci, dtype=np.float64)))
    digest.update(f"L{len(L)}".encode())
    for Li in L:
        add(Li)
    add(delays, np.int64)
    return digest.hexdigest()


def _digest(key: str, rho_hex: str, method: str) -> str:
    return hashlib.sha256(json.dumps([LAYOUT, key, rho_hex, method]).encode()).hexdigest()


class _BadEntry(ValueError):
    """An entry that must not be used; the message says why (one line)."""


def _read(path: Path, key: str) -> tuple[float, str]:
    from netsim.models.augmented import RADIUS_METHODS

    text = path.read_bytes()  # OSError (missing, unreadable folder): the caller's miss
    try:
        data = json.loads(text.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise _BadEntry(f"unreadable ({type(exc).__name__})") from None
    if not isinstance(data, dict) or data.get("format") != "netsim-radius":
        raise _BadEntry("not a netsim radius entry")
    if data.get("layout") != LAYOUT:
        raise _BadEntry(f"layout {data.get('layout')!r}, not {LAYOUT}")
    if data.get("key") != key:
        raise _BadEntry("made for another key than its file name")
    rho_hex, method = data.get("rho"), data.get("method")
    if not isinstance(rho_hex, str) or method not in RADIUS_METHODS:
        raise _BadEntry("no radius or an unknown method")
    try:
        rho = float.fromhex(rho_hex)
    except (ValueError, OverflowError):
        raise _BadEntry(f"radius {rho_hex[:40]!r} is not a float") from None
    if math.isnan(rho) or rho < 0:
        raise _BadEntry(f"radius {rho!r} is not a non-negative number")
    if data.get("digest") != _digest(key, rho_hex, method):
        raise _BadEntry("digest mismatch (the entry was changed)")
    return rho, method


def load(folder: Path, keys: Sequence[str]) -> dict[str, tuple[float, str]]:
    """The valid entries among ``keys``: ``{key: (radius, method)}``.

    A missing entry is left out silently; an invalid one is left out, reported in one
    :class:`RadiusCacheWarning` and removed (the caller recomputes and stores it).
    """
    found: dict[str, tuple[float, str]] = {}
    bad: list[str] = []
    for key in dict.fromkeys(keys):
        path = folder / f"{key}.json"
        try:
            found[key] = _read(path, key)
        except OSError:  # missing (or an unreadable folder): computed and stored anew
            continue
        except _BadEntry as exc:
            bad.append(f"{path.name} ({exc})")
            with contextlib.suppress(OSError):
                path.unlink()
    if bad:
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        warnings.warn(RadiusCacheWarning(
            f"ignored the entry {folder / bad[0]}{more}; the radii are computed afresh "
            "and the entries rewritten"), stacklevel=2)
    return found


def store(folder: Path, entries: dict[str, tuple[float, str]]) -> None:
    """Write ``{key: (radius, method)}`` atomically, one file each; then bound the folder.

    A failure to write is ignored: the cache is an optimisation, never a reason to fail
    a command.
    """
    if not entries:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    for key, (rho, method) in entries.items():
        rho_hex = float(rho).hex()
        text = json.dumps({"format": "netsim-radius", "layout": LAYOUT, "key": key,
                           "rho": rho_hex, "method": method,
                           "digest": _digest(key, rho_hex, method)})
        tmp = None
        try:
            handle, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=".json")
            with os.fdopen(handle, "w", encoding="utf-8") as out:
                out.write(text)
            os.replace(tmp, folder / f"{key}.json")
        except OSError:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
    _prune(folder)


def _prune(folder: Path, limit: int | None = None) -> None:
    """Remove the oldest entries when the folder holds more than ``limit``
    (:data:`MAX_ENTRIES`), down to three quarters of it."""
    limit = MAX_ENTRIES if limit is None else limit
    try:
        with os.scandir(folder) as it:
            found = [(e.stat().st_mtime, e.path) for e in it
                     if e.name.endswith(".json") and not e.name.startswith(".")]
    except OSError:
        return
    if len(found) <= limit:
        return
    found.sort()
    for _, path in found[: len(found) - (3 * limit) // 4]:
        with contextlib.suppress(OSError):
            os.unlink(path)
