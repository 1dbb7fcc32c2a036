"""A disk cache of gain designs: the LMI is solved once per scenario, not per command.

A design is deterministic given the consensus matrix P, the plant's A and C_i, the
scenario's ``[gains]`` request and the solver stack, so it is stored under a
fingerprint of exactly those: the bytes of P (dense; or a sparse P's CSR shape,
indptr, indices and values, never densified), A and every C_i (float64), the request
(method, tau1, refine_from, the given K_i), and the versions of netsim, numpy, scipy,
cvxpy and clarabel. An entry is one ``.npz`` file holding the design (layout 3: the K_i
stacked, shape (N, n, n), the L_i side by side, shape (n, sum m_i), so two arrays at any
N; the scalar fields), the fingerprint it was made for and a SHA-256 digest of its
contents (:func:`entry_digest`). Writes go to a temporary file renamed into place, so
a killed writer leaves no half entry.

Every entry is verified when it is read (:func:`read_entry`, :func:`verify_design`),
in this order:

1. it can be read, carries this layout and the fingerprint of its file name;
2. ``K`` and ``L`` are float64 arrays of the scenario's shapes, all finite;
3. the stored digest equals the SHA-256 of the stored arrays' bytes (with their
   shapes), the scalar fields and the fingerprint;
4. its ``design_tau`` is the request's ``tau1`` and its ``method`` one the request's
   method produces; ``K_i C_i^T = L_i`` (relative tolerance :data:`KL_RTOL`; one
   small product per agent, vectorised);
5. the certificate is recomputed when ``N n <=`` :data:`VERIFY_RHO_MAX_STATES`: the
   delay-free spectral radius ``rho((I - K D_C-bar)(P kron A))`` of LCSYS2022 eq. (12)
   with the stored gains, by the design's own computation (dense eigenvalues of
   :func:`netsim.models.augmented.delay_free_closed_loop` for the LMI, CCL, refined
   and given designs; :func:`netsim.models.augmented.delay_free_spectral_radius`,
   dense or structured as its ``status`` says, for the local design), must equal the
   stored ``rho`` to the relative tolerance :data:`RHO_RTOL`; likewise ``rho_design``
   (``A^(design_tau+1)`` in place of ``A``) when ``design_tau > 0``; and a design that
   claims to be certified must have ``rho < 1``, ``rho_design < 1`` and
   ``rho_design`` below its certified rate. For ``N n`` above
   :data:`netsim.models.augmented.DENSE_SIZE_THRESHOLD`, a design whose own
   computation is dense is screened by the structured (ARPACK) radius at
   :data:`SCREEN_RTOL` and recomputed densely only if the screen disagrees.

A local design certified by the weighted-norm upper bound (``status``
``"weighted-norm-bound-<basis>"``, :func:`netsim.models.augmented.delay_free_rho_bound`)
stores its certificate, the positive weights ``w`` (array ``W``, shape (1 or 2, N, n),
in the digest): at any ``N n`` the bound ``||T^-1 A-hat T||_inf`` is recomputed from
them in one step linear in the links (:func:`netsim.models.augmented.weighted_norm_bound`,
about 1 s at N = 100,000) and must equal the stored ``rho`` (and ``rho_design``) to
:data:`RHO_RTOL` and be below 1 if certified; the basis must be a known one.

The certificate checks (``rho < 1``, the rate) use the stored values once they match
the recomputed ones, so a design certified at ``rho = 1 - 1e-15`` is not rejected
for rounding. Above :data:`VERIFY_RHO_MAX_STATES` (the local design's range, and every
sparse network) no spectral radius is recomputed -- that is an ARPACK eigenproblem of
``N n`` rows (measured 0.2 s at 6,000, 3 s at 60,000, minutes at 600,000) -- and an
entry is verified by steps 1-4 only (about 0.1 s at N = 100,000, n = 6): the
digest catches any change to a stored file, the ``K``/``L`` check gains replaced
without their partner, but an entry *written* with wrong gains, a consistent
``K``/``L`` pair and a matching digest would pass.

An entry that fails is ignored (the gains are designed afresh), reported as one
:class:`GainCacheWarning` (``netsim <command>: warning: gain cache: ...`` on stderr),
removed and rewritten with the fresh design. A missing entry is designed and written
silently.

Location: ``$NETSIM_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/netsim/gains`` (default
``~/.cache/netsim/gains``); ``NETSIM_CACHE_DIR=off`` (or ``--no-cache``) disables it.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import re
import sys
import tempfile
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from netsim.estimators.gains import BOUND_STATUS, GainDesign
from netsim.models.lazy import issparse, lazy_module
from netsim.models.scenario import ScenarioWarning

if TYPE_CHECKING:
    import scipy.sparse as sp
else:  # imported on first use (start-up latency): only sparse (large-N) weights need it
    sp = lazy_module("scipy.sparse")

__all__ = [
    "KL_RTOL",
    "LAYOUT",
    "RHO_RTOL",
    "SCREEN_RTOL",
    "VERIFY_RHO_MAX_STATES",
    "EntryError",
    "GainCacheWarning",
    "cache_dir",
    "cached_design",
    "disabled",
    "entry_digest",
    "fingerprint",
    "load",
    "read_entry",
    "store",
    "verify_design",
]

#: Bumped when the stored layout changes (it enters the fingerprint, so entries of
#: another layout are never looked up and are left alone). 3: with a digest.
LAYOUT = 3
_SCALARS = ("rho", "certified_rate", "certified", "method", "solver", "status", "message",
            "design_tau", "rho_design", "iterations")

#: Largest ``N n`` at which a cached entry's spectral radius is recomputed on load
#: (about 40 ms for a dense 300-row eigenproblem, 30 ms for the structured radius at
#: 1,500 rows on a 2-core machine); above it entries are verified by digest only.
VERIFY_RHO_MAX_STATES: int = 1500
#: Relative tolerance between the stored and the recomputed ``rho`` (the same
#: computation on the same gains: equal up to rounding).
RHO_RTOL: float = 1e-9
#: Relative tolerance of the structured screen of a dense-computed ``rho``.
SCREEN_RTOL: float = 1e-6
#: Relative tolerance of ``K_i C_i^T = L_i`` (against ``|K_i| |C_i| + |L_i|``).
KL_RTOL: float = 1e-8

#: The ``method`` of :func:`netsim.estimators.gains.design_local`.
_LOCAL = "local-scaled-projection"
#: The stored ``method`` a request's method can produce (prefixes of
#: :attr:`netsim.estimators.gains.GainDesign.method`); a request method not listed
#: (``auto``, or one added later) is not checked.
_PRODUCES = {"lmi": ("block-diagonal-lmi",), "ccl": ("ccl-",), "local": (_LOCAL,),
             "given": ("given",), "refined": ("refined",)}


class GainCacheWarning(ScenarioWarning):
    """A cache entry was ignored (and rewritten); the ``netsim`` command prints it as
    one ``netsim <command>: warning: gain cache: ...`` line on stderr."""

    def __init__(self, message: str) -> None:
        super().__init__("gain cache", message)


class EntryError(ValueError):
    """A cache entry that must not be used; the message says why (one line)."""


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
    from netsim.taskoptions import getenv

    value = getenv("NETSIM_CACHE_DIR")  # a sweep's task carries the client's setting
    if value is not None:
        return None if value.strip().lower() in ("", "off", "0", "none") else Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"),
                                                            ".cache")
    return Path(base) / "netsim" / "gains"


def _normalized(name: str) -> str:
    """A distribution name as importlib.metadata compares them (PEP 503, ``_`` for ``-``)."""
    return re.sub(r"[-_.]+", "_", name).lower()


def _installed_versions(names: Sequence[str]) -> dict[str, str | None]:
    """The ``Version:`` of each distribution's metadata, found as importlib.metadata
    finds it (the first ``<name>-*.dist-info`` or ``.egg-info`` on ``sys.path``), or
    None where this light reader cannot tell (then importlib.metadata decides).

    importlib.metadata costs 20-50 ms of CPU to import (issue 34's start-up); this lists
    each folder of ``sys.path`` once and reads one small file per distribution.
    """
    wanted = {_normalized(name): name for name in names}
    found: dict[str, str | None] = {}
    for entry in sys.path:
        if len(found) == len(wanted):
            break
        folder = entry or "."
        try:
            children = os.listdir(folder)
        except OSError:
            continue
        for child in children:
            low = child.lower()
            if low.endswith(".egg"):  # a legacy egg: importlib.metadata reads it
                key = _normalized(low.partition("-")[0])
                if key in wanted and wanted[key] not in found:
                    found[wanted[key]] = None
                continue
            if not low.endswith((".dist-info", ".egg-info")):
                continue
            key = _normalized(low.rpartition(".")[0].partition("-")[0])
            if key not in wanted or wanted[key] in found:
                continue  # only the first match counts, as for importlib.metadata
            found[wanted[key]] = _metadata_version(os.path.join(folder, child), low)
    return {name: found.get(name) for name in names}


def _metadata_version(path: str, low: str) -> str | None:
    """The ``Version:`` header of a ``.dist-info`` (METADATA) or ``.egg-info``
    (PKG-INFO) folder, or None."""
    meta = os.path.join(path, "METADATA" if low.endswith(".dist-info") else "PKG-INFO")
    try:
        with open(meta, encoding="utf-8") as handle:
            for line in handle:
                if line.startswith("Version:"):
                    return line.partition(":")[2].strip()
                if not line.strip():  # end of the headers
                    break
    except OSError:
        pass
    return None


def _installed_version(name: str) -> str | None:
    """:func:`_installed_versions` of one distribution."""
    return _installed_versions([name])[name]


def _version(name: str, light: dict[str, str | None] | None = None) -> str:
    """The installed version of distribution ``name`` ("absent" when not installed).

    By importlib.metadata when something has imported it already (it costs nothing
    more then), else read from the distribution's metadata file (``light``: what
    :func:`_installed_versions` found, or it is asked now; the same string, found the
    same way); importlib.metadata also when that light reader finds nothing, so
    "absent" means the same as before.
    """
    if "importlib.metadata" not in sys.modules:
        found = (light if light is not None else _installed_versions([name])).get(name)
        if found is not None:
            return found
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def fingerprint(scenario: Any, request: dict[str, Any]) -> str:
    """SHA-256 of what the design depends on (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        Its ``weights`` (P), ``plant.A``, ``plant.C`` and ``gains.K`` enter.
    request : dict
        The resolved ``[gains]`` request (:func:`netsim.estimators.gains.design_request`).

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256()
    digest.update(f"netsim-gains-{LAYOUT}".encode())
    names = ("netsim", "numpy", "scipy", "cvxpy", "clarabel")
    light = None if "importlib.metadata" in sys.modules else _installed_versions(names)
    for name in names:
        digest.update(f"{name}={_version(name, light)};".encode())
    digest.update(json.dumps({k: request[k] for k in sorted(request)}, sort_keys=True,
                             default=str).encode())

    def add(array: Any) -> None:
        a = np.ascontiguousarray(np.asarray(array, dtype=np.float64))
        digest.update(repr(a.shape).encode())
        digest.update(a.tobytes())

    weights: np.ndarray | sp.csr_array = scenario.weights  # CSR at large N
    if issparse(weights):
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


def _canonical(scalars: dict[str, Any]) -> str:
    return json.dumps(scalars, sort_keys=True, default=float)


def entry_digest(key: str, K_all: np.ndarray, L_all: np.ndarray,
                 scalars: dict[str, Any], W_all: np.ndarray | None = None) -> str:
    """SHA-256 of an entry's contents: its fingerprint, the stored arrays' shapes and
    bytes, and its scalar fields (canonical JSON).

    Parameters
    ----------
    key : str
        The fingerprint the entry is made for.
    K_all : numpy.ndarray, shape (N, n, n), float64
        The K_i stacked, as stored.
    L_all : numpy.ndarray, shape (n, sum m_i), float64
        The L_i side by side, as stored.
    scalars : dict
        The GainDesign's scalar fields (``rho``, ``certified``, ...), as stored.
    W_all : numpy.ndarray, optional
        The certificate weights (``GainDesign.certificate_weights`` stacked, shape
        (1 or 2, N, n)), when the design has them; entries without them digest as before.

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256(f"netsim-gain-entry-{LAYOUT};{key};".encode())
    arrays = [("K", K_all), ("L", L_all)] + ([] if W_all is None else [("W", W_all)])
    for name, array in arrays:
        a = np.ascontiguousarray(array)
        digest.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        digest.update(a.tobytes())
    digest.update(_canonical(scalars).encode())
    return digest.hexdigest()


def _one_line(text: Any, limit: int = 160) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[:limit - 3] + "..."


def _read(path: Path) -> tuple[dict[str, Any], np.ndarray, np.ndarray, np.ndarray | None]:
    """The meta dictionary and the raw K and L arrays of the file at ``path`` (a regular
    file only: a named pipe would block, a device would be read without end)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise EntryError(f"cannot be read ({_one_line(exc)})") from None
    if not stat.S_ISREG(mode):
        raise EntryError("is not a regular file")
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"][()]))
            K_all = np.array(data["K"])
            L_all = np.array(data["L"])
            W_all = np.array(data["W"]) if "W" in data.files else None
    except FileNotFoundError:
        raise
    except Exception as exc:  # any failure to read is a damaged entry
        raise EntryError(f"cannot be read ({type(exc).__name__}: {_one_line(exc)})") from None
    if not isinstance(meta, dict):
        raise EntryError("cannot be read (its metadata is not a table)")
    return meta, K_all, L_all, W_all


def _closed_loop_rho(kind: str, P: Any, A: np.ndarray, C: Sequence[np.ndarray],
                     L: Sequence[np.ndarray]) -> float:
    """``rho((I - K D_C-bar)(P kron A))`` computed as ``kind`` says: ``"closed-loop"``
    (dense eigenvalues of the assembled matrix, as the LMI, CCL, refined and given
    designs do), ``"dense"`` or ``"structured"`` (as the local design does)."""
    from netsim.models.augmented import (
        delay_free_closed_loop,
        delay_free_spectral_radius,
        spectral_radius,
    )

    with np.errstate(over="ignore", invalid="ignore"):
        if kind == "closed-loop":
            return float(spectral_radius(delay_free_closed_loop(P, A, C, L)))
        return float(delay_free_spectral_radius(P, A, C, L, method=kind))


def _close(a: float, b: float, rtol: float) -> bool:
    if not (math.isfinite(a) and math.isfinite(b)):
        return a == b
    return abs(a - b) <= rtol * max(abs(a), abs(b), 1e-300)


def _check_rho(what: str, stored: Any, P: Any, A: np.ndarray, C: Sequence[np.ndarray],
               L: Sequence[np.ndarray], own: str, Nn: int) -> float:
    """Recompute one spectral radius (by the design's ``own`` computation, screened by
    the structured one where ``own`` is a dense eigenproblem above
    :data:`netsim.models.augmented.DENSE_SIZE_THRESHOLD` rows) and compare it with the
    stored value; return the stored value once it matches."""
    from netsim.models.augmented import DENSE_SIZE_THRESHOLD

    if not isinstance(stored, (int, float)) or isinstance(stored, bool):
        raise EntryError(f"stored {what} is not a number ({stored!r})")
    stored = float(stored)

    def mismatch(value: float) -> EntryError:
        return EntryError(f"stored {what} = {stored:.6g} but the stored gains give "
                          f"{what} = {value:.6g}")

    if Nn > DENSE_SIZE_THRESHOLD and own != "structured":
        screen = _closed_loop_rho("structured", P, A, C, L)
        if _close(screen, stored, SCREEN_RTOL):
            return stored
        if issparse(P):  # no dense computation to confirm with
            raise mismatch(screen)
    value = _closed_loop_rho(own, P, A, C, L)
    if not _close(value, stored, RHO_RTOL):
        raise mismatch(value)
    return stored


def verify_design(design: GainDesign, scenario: Any,
                  arrays: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Check a stored design against the scenario it claims to be for.

    ``K_i C_i^T = L_i``; and, when ``N n <=`` :data:`VERIFY_RHO_MAX_STATES`, the
    recomputed certificate (steps 4 and 5 of the module docstring). The shapes and the
    finiteness of the arrays are :func:`read_entry`'s checks.

    Parameters
    ----------
    design : GainDesign
        The design read from the cache.
    scenario : Scenario
        The scenario it is looked up for (P, A, C_i).
    arrays : tuple of numpy.ndarray, optional
        ``design.K`` stacked, shape (N, n, n), and ``design.L`` side by side, shape
        (n, sum m_i), as stored (built from ``design`` if not given).

    Raises
    ------
    EntryError
        If the design does not hold; the message says which check failed.
    """
    P, A, C = scenario.weights, np.asarray(scenario.plant.A, dtype=float), scenario.plant.C
    n = A.shape[0]
    N = len(C)
    K_all, L_all = _arrays(design) if arrays is None else arrays
    _check_kl(K_all, L_all, C)
    if design.method == _LOCAL and str(design.status).startswith(BOUND_STATUS):
        _check_bound(design, scenario)
        return
    if N * n > VERIFY_RHO_MAX_STATES:
        return
    if design.method == _LOCAL:
        own = "dense" if design.status == "dense-eigvals" else "structured"
    else:
        own = "structured" if issparse(P) else "closed-loop"
    rho = _check_rho("rho", design.rho, P, A, C, design.L, own, N * n)
    tau = design.design_tau
    if not isinstance(tau, int) or isinstance(tau, bool) or tau < 0:
        raise EntryError(f"stored design_tau is not a non-negative integer ({tau!r})")
    if tau == 0:
        rho_design = rho
        if not _close(float(design.rho_design), rho, RHO_RTOL):  # type: ignore[arg-type]
            raise EntryError(f"stored rho_design = {design.rho_design!r} differs from "
                             f"rho = {rho:.6g} for design_tau = 0")
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            A_design = np.linalg.matrix_power(A, tau + 1)
        rho_design = _check_rho("rho_design", design.rho_design, P, A_design, C, design.L,
                                own, N * n)
    if design.certified is not True and design.certified is not False:
        raise EntryError(f"stored 'certified' is not a boolean ({design.certified!r})")
    if design.certified:
        if not (rho < 1.0 and rho_design < 1.0):
            raise EntryError(f"claims to be certified but rho = {rho:.6g}, rho_design = "
                             f"{rho_design:.6g} (not both below 1)")
        rate = design.certified_rate
        if rate is not None and not (isinstance(rate, (int, float))
                                     and rho_design < float(rate)):
            raise EntryError(f"claims the certified rate {rate!r} but rho_design = "
                             f"{rho_design:.6g} is not below it")


def _check_bound(design: GainDesign, scenario: Any) -> None:
    """A design certified by the weighted-norm upper bound: recompute the bound from the
    stored weights, at any ``N n`` (one step, linear in the links,
    :func:`netsim.models.augmented.weighted_norm_bound`); it must equal the stored
    ``rho`` (and ``rho_design`` with ``A^(design_tau+1)``) to :data:`RHO_RTOL`, and both
    must be below 1 if the design claims to be certified."""
    from netsim.models.augmented import BOUND_BASES, weighted_norm_bound

    basis = str(design.status)[len(BOUND_STATUS) + 1:]
    if basis not in BOUND_BASES:
        raise EntryError(f"stored status {design.status!r} names no known basis")
    tau = design.design_tau
    if not isinstance(tau, int) or isinstance(tau, bool) or tau < 0:
        raise EntryError(f"stored design_tau is not a non-negative integer ({tau!r})")
    weights = design.certificate_weights
    if len(weights) != (2 if tau else 1):
        raise EntryError(f"{len(weights)} certificate weight array(s) stored, not "
                         f"{2 if tau else 1} for design_tau = {tau}")
    P, C = scenario.weights, scenario.plant.C
    A = np.asarray(scenario.plant.A, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        A_design = np.linalg.matrix_power(A, tau + 1)
    # (the stored numbers as read back: checked below)
    checks: list[tuple[str, object, np.ndarray, np.ndarray]] = [
        ("rho", design.rho, A, weights[0])]
    if tau:
        checks.append(("rho_design", design.rho_design, A_design, weights[1]))
    elif not _close(float(design.rho_design), float(design.rho), RHO_RTOL):  # type: ignore[arg-type]
        raise EntryError(f"stored rho_design = {design.rho_design!r} differs from "
                         f"rho = {design.rho!r} for design_tau = 0")
    for what, stored, A_k, W in checks:
        if not isinstance(stored, (int, float)) or isinstance(stored, bool):
            raise EntryError(f"stored {what} is not a number ({stored!r})")
        value = weighted_norm_bound(P, A_k, C, design.L, W, basis)
        if not _close(value, float(stored), RHO_RTOL):
            raise EntryError(f"stored {what} <= {float(stored):.6g} but the stored gains "
                             f"and certificate weights give the bound {value:.6g}")
        if design.certified is True and not float(stored) < 1.0:
            raise EntryError(f"claims to be certified but the bound {what} <= "
                             f"{float(stored):.6g} is not below 1")
    if design.certified is not True and design.certified is not False:
        raise EntryError(f"stored 'certified' is not a boolean ({design.certified!r})")


def _check_kl(K_all: np.ndarray, L_all: np.ndarray, C: Sequence[np.ndarray]) -> None:
    """``K_i C_i^T = L_i`` for every agent: vectorised over the agents with the same
    number of outputs (the distinct C_i objects are converted once; agents often share
    one)."""
    N = len(C)
    if N == 0:
        return
    codes = np.empty(N, dtype=np.int64)
    index: dict[int, int] = {}
    mats: list[np.ndarray] = []
    for i, Ci in enumerate(C):
        j = index.get(id(Ci))
        if j is None:
            j = index[id(Ci)] = len(mats)
            mats.append(np.asarray(Ci, dtype=np.float64))
        codes[i] = j
    rows = np.array([M.shape[0] for M in mats], dtype=np.int64)
    sizes = rows[codes]
    offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    bad_count, first = 0, None
    # sorted(set()), not np.unique: numpy's unique without indices imports numpy.ma
    # (about 40 ms of a warm run's start-up, issue 34); the same sizes, ascending
    for m in sorted(set(sizes.tolist())):
        agents = np.flatnonzero(sizes == m)
        used, inverse = np.unique(codes[agents], return_inverse=True)
        Cs = np.stack([mats[j] for j in used.tolist()])[inverse]           # (g, m, n)
        K = K_all[agents]                                                   # (g, n, n)
        L = L_all[:, offsets[agents][:, None] + np.arange(m)].transpose(1, 0, 2)
        with np.errstate(over="ignore", invalid="ignore"):
            residual = np.linalg.norm(K @ Cs.transpose(0, 2, 1) - L, axis=(1, 2))
            scale = (np.linalg.norm(K, axis=(1, 2)) * np.linalg.norm(Cs, axis=(1, 2))
                     + np.linalg.norm(L, axis=(1, 2)))
        bad = np.flatnonzero(~(residual <= KL_RTOL * scale))
        if bad.size:
            bad_count += int(bad.size)
            i = int(agents[bad[0]])
            if first is None or i < first[0]:
                first = (i, float(residual[bad[0]]))
    if first is not None:
        raise EntryError(f"K_i C_i^T != L_i for {bad_count} agent(s) (agent {first[0]}: "
                         f"residual {first[1]:.3g})")


def read_entry(path: Path, key: str, scenario: Any,
               request: dict[str, Any] | None = None) -> GainDesign:
    """The design stored at ``path`` for fingerprint ``key``, verified.

    Parameters
    ----------
    path : pathlib.Path
        The entry's file.
    key : str
        The fingerprint it must be made for (:func:`fingerprint`).
    scenario : Scenario
        The scenario it is looked up for (shapes, P, A, C_i).
    request : dict, optional
        The ``[gains]`` request: if given, the stored ``design_tau`` must be its
        ``tau1`` and the stored ``method`` one its ``method`` produces.

    Returns
    -------
    GainDesign
        The stored design, which passed every check of the module docstring.

    Raises
    ------
    FileNotFoundError
        If there is no entry.
    EntryError
        If the entry cannot be read, was made for another key or layout, or fails a
        check; the message (one line) says which.
    """
    meta, K_all, L_all, W_all = _read(path)
    if meta.get("layout") != LAYOUT:
        raise EntryError(f"layout {meta.get('layout')!r}, not {LAYOUT}")
    if meta.get("fingerprint") != key:
        raise EntryError(f"made for another key ({str(meta.get('fingerprint'))[:12]}...)")
    n = scenario.plant.n_states
    sizes = [C.shape[0] for C in scenario.plant.C]
    if K_all.dtype != np.float64 or L_all.dtype != np.float64:
        raise EntryError(f"arrays of dtype {K_all.dtype}, {L_all.dtype}, not float64")
    if K_all.shape != (len(sizes), n, n) or L_all.shape != (n, sum(sizes)):
        raise EntryError(f"arrays of shapes {K_all.shape}, {L_all.shape}, not "
                         f"{(len(sizes), n, n)}, {(n, sum(sizes))}")
    if not (np.all(np.isfinite(K_all)) and np.all(np.isfinite(L_all))):
        raise EntryError("non-finite gains")
    if W_all is not None and (W_all.dtype != np.float64 or W_all.ndim != 3
                              or W_all.shape[1:] != (len(sizes), n)
                              or W_all.shape[0] not in (1, 2)):
        raise EntryError(f"certificate weights of dtype {W_all.dtype}, shape {W_all.shape}, "
                         f"not float64 (1 or 2, {len(sizes)}, {n})")
    try:
        scalars = {name: meta[name] for name in _SCALARS}
    except KeyError as exc:
        raise EntryError(f"no field {exc}") from None
    if meta.get("digest") != entry_digest(key, K_all, L_all, scalars, W_all):
        raise EntryError("digest mismatch (the stored contents changed after writing)")
    K = tuple(K_all)
    if sizes and min(sizes) == max(sizes):  # the same m for all: views, no split loop
        L = tuple(L_all.reshape(n, len(sizes), sizes[0]).transpose(1, 0, 2))
    else:
        L = tuple(np.split(L_all, np.cumsum(sizes)[:-1], axis=1)) if sizes else ()
    try:
        design = GainDesign(L=L, K=K, **scalars,
                            certificate_weights=() if W_all is None else tuple(W_all))
    except (TypeError, ValueError) as exc:
        raise EntryError(f"not a design ({_one_line(exc)})") from None
    if request is not None:
        _check_request(design, request)
    try:
        verify_design(design, scenario, (K_all, L_all))
    except EntryError:
        raise
    except (TypeError, ValueError, ArithmeticError, RuntimeError) as exc:
        raise EntryError(f"cannot be verified ({type(exc).__name__}: "
                         f"{_one_line(exc)})") from None
    return design


def _check_request(design: GainDesign, request: dict[str, Any]) -> None:
    """The stored design is of the kind the request asks for (method and tau1)."""
    tau1 = request.get("tau1", 0)
    if design.design_tau != tau1:
        raise EntryError(f"stored design_tau = {design.design_tau!r}, the request's "
                         f"tau1 = {tau1!r}")
    produces = _PRODUCES.get(str(request.get("method")))
    if produces is not None and not str(design.method).startswith(produces):
        raise EntryError(f"stored method {design.method!r} is not what the request's "
                         f"method {request.get('method')!r} produces")


def load(path: Path, key: str, scenario: Any,
         request: dict[str, Any] | None = None) -> GainDesign | None:
    """The verified design stored at ``path`` for fingerprint ``key``, or None if it is
    missing or fails :func:`read_entry` (silently; :func:`cached_design` warns).

    Parameters
    ----------
    path : pathlib.Path
        The entry's file.
    key : str
        Its fingerprint.
    scenario : Scenario
        The scenario it is looked up for.
    request : dict, optional
        Its ``[gains]`` request (see :func:`read_entry`).

    Returns
    -------
    GainDesign or None
    """
    try:
        return read_entry(path, key, scenario, request)
    except (FileNotFoundError, EntryError):
        return None


def _arrays(design: GainDesign) -> tuple[np.ndarray, np.ndarray]:
    # layout 2+: K stacked (N, n, n), L side by side (n, sum m_i): two arrays at any N
    K_all = np.ascontiguousarray(np.stack([np.asarray(K, dtype=np.float64)
                                           for K in design.K]))
    L_all = np.ascontiguousarray(np.concatenate(
        [np.asarray(L, dtype=np.float64).reshape(len(K), -1)
         for L, K in zip(design.L, design.K, strict=True)], axis=1))
    return K_all, L_all


def _weights(design: GainDesign) -> np.ndarray | None:
    """The certificate weights stacked, shape (1 or 2, N, n), or None."""
    weights = getattr(design, "certificate_weights", ())
    if not weights:
        return None
    return np.ascontiguousarray(np.stack([np.asarray(w, dtype=np.float64) for w in weights]))


def store(path: Path, key: str, design: GainDesign) -> None:
    """Write ``design`` to ``path`` atomically, with its fingerprint and digest.

    A failure to write is ignored: the cache is an optimisation, never a reason to
    fail a command.

    Parameters
    ----------
    path : pathlib.Path
        The entry's file.
    key : str
        The fingerprint it is made for.
    design : GainDesign
        The design to store.
    """
    # the scalars as they read back (JSON round trip), so the digest is the reader's
    scalars = json.loads(_canonical({name: getattr(design, name) for name in _SCALARS}))
    K_all, L_all = _arrays(design)
    W_all = _weights(design)
    meta = {"fingerprint": key, "layout": LAYOUT, **scalars,
            "digest": entry_digest(key, K_all, L_all, scalars, W_all)}
    buffer = io.BytesIO()
    extra: dict[str, Any] = {} if W_all is None else {"W": W_all}
    np.savez(buffer, meta=np.array(json.dumps(meta, default=float)), K=K_all, L=L_all,
             **extra)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
        with os.fdopen(handle, "wb") as out:
            out.write(buffer.getvalue())
        os.replace(tmp, path)
    except OSError:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def cached_design(scenario: Any, request: dict[str, Any],
                  design: Callable[[], GainDesign], *, use_cache: bool = True
                  ) -> GainDesign:
    """Return the cached design for (scenario, request), or run ``design()`` and store it.

    An entry that fails verification (:func:`read_entry`) is reported in one
    :class:`GainCacheWarning`, removed, and replaced by the fresh design.

    Parameters
    ----------
    scenario : Scenario
        The scenario (see :func:`fingerprint`).
    request : dict
        Its resolved ``[gains]`` request.
    design : callable
        Runs the design (called only on a miss or a rejected entry).
    use_cache : bool, default True
        False: always ``design()``, nothing read or written.

    Returns
    -------
    GainDesign
    """
    folder = cache_dir() if use_cache else None
    if folder is None:
        return design()
    key = fingerprint(scenario, request)
    path = folder / f"{key}.npz"
    try:
        return read_entry(path, key, scenario, request)
    except FileNotFoundError:
        pass
    except EntryError as exc:
        warnings.warn(GainCacheWarning(
            f"ignored the entry {path} ({_one_line(exc)}); the gains are designed afresh "
            "and the entry rewritten"), stacklevel=2)
        with contextlib.suppress(OSError):
            path.unlink()
    result = design()
    store(path, key, result)
    return result
