"""A disk cache of gain designs: the LMI is solved once per scenario, not per command.

A design is deterministic given the consensus matrix P, the plant's A and C_i, the
scenario's ``[gains]`` request and the solver stack, so it is stored under a
fingerprint of exactly those: the bytes of P (dense; or a sparse P's CSR shape,
indptr, indices and values, never densified), A and every C_i (float64), the request
(method, tau1, refine_from, the given K_i), and the versions of netsim, numpy, scipy,
cvxpy and clarabel. An entry is one ``.npz`` file holding the design (layout 2: the K_i
stacked, shape (N, n, n), the L_i side by side, shape (n, sum m_i), so two arrays at any
N; and the scalar fields) and the fingerprint it was made for; an entry that does not load, does
not carry its own fingerprint or has arrays of the wrong shapes is ignored and
rewritten, never trusted. Writes go to a temporary file renamed into place, so a
killed writer leaves no half entry.

Location: ``$NETSIM_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/netsim/gains`` (default
``~/.cache/netsim/gains``); ``NETSIM_CACHE_DIR=off`` (or ``--no-cache``) disables it.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from netsim.estimators.gains import GainDesign

__all__ = ["cache_dir", "fingerprint", "cached_design", "load", "store", "disabled"]

#: Bumped when the stored layout changes (old entries are then foreign and rewritten).
LAYOUT = 2
_SCALARS = ("rho", "certified_rate", "certified", "method", "solver", "status", "message",
            "design_tau", "rho_design", "iterations")


_OFF = [False]


@contextlib.contextmanager
def disabled() -> Iterator[None]:
    """Within this block every design is solved afresh (``--no-cache``); worker
    processes started inside (sweeps) inherit it through ``NETSIM_CACHE_DIR=off``."""
    _OFF.append(True)
    before = os.environ.get("NETSIM_CACHE_DIR")
    os.environ["NETSIM_CACHE_DIR"] = "off"
    try:
        yield
    finally:
        _OFF.pop()
        if before is None:
            os.environ.pop("NETSIM_CACHE_DIR", None)
        else:
            os.environ["NETSIM_CACHE_DIR"] = before


def cache_dir() -> Path | None:
    """The cache folder, or None when caching is off."""
    if _OFF[-1]:
        return None
    value = os.environ.get("NETSIM_CACHE_DIR")
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "none") else Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                            ".cache")
    return Path(base) / "netsim" / "gains"


def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def fingerprint(scenario: Any, request: dict[str, Any]) -> str:
    """SHA-256 of what the design depends on (see the module docstring)."""
    digest = hashlib.sha256()
    digest.update(f"netsim-gains-{LAYOUT}".encode())
    for name in ("netsim", "numpy", "scipy", "cvxpy", "clarabel"):
        digest.update(f"{name}={_version(name)};".encode())
    digest.update(json.dumps({k: request[k] for k in sorted(request)}, sort_keys=True,
                             default=str).encode())

    def add(array: Any) -> None:
        a = np.ascontiguousarray(np.asarray(array, dtype=np.float64))
        digest.update(repr(a.shape).encode())
        digest.update(a.tobytes())

    weights = scenario.weights
    if sp.issparse(weights):
        # CSR with sorted indices: shape, structure and values (never densified)
        W = sp.csr_array(weights)
        W.sort_indices()
        digest.update(b"csr")
        add(np.asarray(W.shape, dtype=np.float64))
        add(W.indptr)
        add(W.indices)
        add(W.data)
    else:
        add(weights)
    add(scenario.plant.A)
    for C in scenario.plant.C:
        add(C)
    for K in (scenario.gains.K or ()):
        add(K)
    return digest.hexdigest()


def load(path: Path, key: str, scenario: Any) -> GainDesign | None:
    """The design stored at ``path`` for fingerprint ``key``, or None if it is missing,
    unreadable, made for another fingerprint or of the wrong shapes."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"][()]))
            if meta.get("fingerprint") != key or meta.get("layout") != LAYOUT:
                return None
            n = scenario.plant.n_states
            sizes = [C.shape[0] for C in scenario.plant.C]
            K_all = np.array(data["K"], dtype=np.float64)
            L_all = np.array(data["L"], dtype=np.float64)
            if K_all.shape != (len(sizes), n, n) or L_all.shape != (n, sum(sizes)):
                return None
            K = tuple(K_all)
            L = tuple(np.split(L_all, np.cumsum(sizes)[:-1], axis=1)) if sizes else ()
    except (OSError, ValueError, KeyError, TypeError, EOFError, json.JSONDecodeError):
        return None
    shapes_ok = all(k.shape == (n, n) for k in K) and all(
        gain.shape == (n, C.shape[0]) for gain, C in zip(L, scenario.plant.C, strict=True))
    if not shapes_ok:
        return None
    try:
        return GainDesign(L=L, K=K, **{name: meta[name] for name in _SCALARS})
    except (KeyError, TypeError):
        return None


def store(path: Path, key: str, design: GainDesign) -> None:
    """Write ``design`` to ``path`` atomically (a failure to write is ignored: the cache
    is an optimisation, never a reason to fail a command)."""
    meta = {"fingerprint": key, "layout": LAYOUT,
            **{name: getattr(design, name) for name in _SCALARS}}
    # layout 2: K stacked (N, n, n), L side by side (n, sum m_i): two arrays at any N
    arrays = {"K": np.stack([np.asarray(K) for K in design.K]),
              "L": np.concatenate([np.asarray(L).reshape(len(K), -1)
                                   for L, K in zip(design.L, design.K, strict=True)],
                                  axis=1)}
    buffer = io.BytesIO()
    np.savez(buffer, meta=np.array(json.dumps(meta, default=float)), **arrays)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
        with os.fdopen(handle, "wb") as out:
            out.write(buffer.getvalue())
        os.replace(tmp, path)
    except OSError:
        try:
            os.unlink(tmp)  # type: ignore[possibly-undefined]
        except (OSError, NameError):
            pass


def cached_design(scenario: Any, request: dict[str, Any],
                  design: Callable[[], GainDesign], *, use_cache: bool = True
                  ) -> GainDesign:
    """Return the cached design for (scenario, request), or run ``design()`` and store it."""
    folder = cache_dir() if use_cache else None
    if folder is None:
        return design()
    key = fingerprint(scenario, request)
    path = folder / f"{key}.npz"
    found = load(path, key, scenario)
    if found is not None:
        return found
    result = design()
    store(path, key, result)
    return result
