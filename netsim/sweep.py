"""Parameter sweeps on a local process pool or a Dask cluster, streamed and resumable.

A sweep is a list of *cells*, each a dict of JSON-able parameters (:func:`grid` makes
the Cartesian product of some axes), and a module-level function
``fn(params, seed, context) -> dict`` that computes one cell. :func:`run_sweep` runs
the cells

* in this process (``executor="serial"``),
* on a local :class:`concurrent.futures.ProcessPoolExecutor` (``"local"``, the
  default, 2 workers, ``forkserver`` start method), or
* on a Dask distributed cluster (``"dask"``: ``dask.distributed.Client(address)``;
  the shared ``context`` is scattered to the workers once),

and streams every finished cell, as it finishes, into a JSON-lines results file
(one row per cell, appended and flushed immediately) and optionally a CSV file, with
a tqdm progress bar on stderr. When the sweep ends, the CSV is rewritten as one table
in grid order.

Keys and resumption. A cell's key is the first 16 hex digits of the SHA-256 of the
canonical JSON of ``{"sweep": name, "root_seed": seed, "params": params}`` (sorted
keys): a stable hash of its parameters. Running a sweep again with the same results
file reads the rows already there and computes only the cells whose key is missing,
so an interrupted sweep (Ctrl-C, a killed worker, a lost cluster) keeps every cell
that finished and resumes where it stopped. A partial last line (the writer was
killed mid-line) is cut off.

Real clusters (issue 34). A Dask worker is a process started before the sweep, often on
another machine, in another folder, with another environment. So

* every worker's netsim version is checked before anything is submitted
  (:func:`check_worker_versions`; a mismatch is :class:`WorkerVersionMismatch`, one line
  naming the worker and both versions), and again by every task (a worker that joined
  later);
* the options a cell reads from the environment (``--no-cache``, ``NETSIM_CACHE_DIR``,
  the memory and time limits) travel in every task (:mod:`netsim.taskoptions`), and
  every task runs with one BLAS thread;
* code that exists only beside the client (a ``module:attribute`` estimator in a file)
  travels by value inside the context (:class:`ByValue`, cloudpickle);
* ``prepare`` builds the context on the client from the cells still to compute, so
  work shared by many cells (the gain designs of ``netsim bench sweep``) is done once,
  there, and sent with the cells.

Determinism. A cell's randomness comes only from its parameters and the root seed:
``seed`` is :func:`cell_seed` (``netsim.models.seeding.child_sequence(root_seed, "sweep",
<key digits>)``), and ``fn`` may also derive streams from the root seed and the
parameters (the benchmark derives Monte Carlo trial seeds from the root seed so that
every estimator sees the same trials). Nothing depends on the executor, the number
of workers or the order cells finish in, so the results are identical bit for bit
(JSON floats round-trip exactly).
"""

from __future__ import annotations

import csv
import hashlib
import importlib
import io
import itertools
import json
import multiprocessing
import os
import socket
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from netsim.models.jsonsafe import json_default, json_tree
from netsim.models.seeding import child_sequence
from netsim.taskoptions import applied, snapshot
from netsim.threads import single_threaded_blas

__all__ = [
    "ByValue",
    "WorkerVersionMismatch",
    "check_worker_versions",
    "csv_columns",
    "DEFAULT_WORKERS",
    "EXECUTORS",
    "SweepInterrupted",
    "SweepResult",
    "grid",
    "cell_key",
    "cell_seed",
    "read_results",
    "run_sweep",
    "flatten",
    "write_csv",
    "demo_cell",
    "environment_cell",
    "version_mismatches",
]

#: Workers of the local process pool by default (this project's machines have 2 cores).
DEFAULT_WORKERS = 2
#: Accepted ``executor`` values.
EXECUTORS = ("serial", "local", "dask")


class SweepInterrupted(Exception):
    """The sweep stopped before every cell finished; the finished ones are saved.

    Attributes
    ----------
    done, total, computed : int
        Cells finished (saved) of ``total``; ``computed`` of them in this run.
    path : str or None
        The results file to resume from.
    """

    def __init__(self, done: int, total: int, computed: int, path: str | None,
                 cause: str = "interrupted") -> None:
        where = f"; resume with the same results file {path}" if path else ""
        super().__init__(f"{cause}: {done} of {total} cells finished "
                         f"({computed} computed in this run){where}")
        self.done, self.total, self.computed, self.path = done, total, computed, path


@dataclass
class SweepResult:
    """What :func:`run_sweep` returns.

    Attributes
    ----------
    rows : list of dict
        One row per cell, in the order of the cells given: ``key``, ``params``,
        ``result`` (what ``fn`` returned), ``elapsed_s``, ``worker``.
    computed : int
        Cells computed in this run.
    reused : int
        Cells read back from the results file (not recomputed).
    path, csv_path : str or None
    """

    rows: list[dict[str, Any]]
    computed: int
    reused: int
    path: str | None = None
    csv_path: str | None = None
    executor: str = "serial"
    workers: int = 1
    elapsed_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)

    def results(self) -> list[dict[str, Any]]:
        """The ``result`` of every row, in cell order."""
        return [row["result"] for row in self.rows]


# -- cells --------------------------------------------------------------------------


def grid(**axes: Any) -> list[dict[str, Any]]:
    """Cartesian product of the axes, in the order given (the last varies fastest).

    ``grid(tau=[0, 3], delays=["homogeneous"])`` -> ``[{"tau": 0, "delays":
    "homogeneous"}, {"tau": 3, "delays": "homogeneous"}]``; a scalar is a one-value axis.
    """
    names = list(axes)
    values = [v if isinstance(v, list | tuple) else [v] for v in axes.values()]
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*values)]


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False,
                      default=json_default)


def cell_key(params: Mapping[str, Any], root_seed: int = 0, sweep: str = "") -> str:
    """Stable key of a cell: 16 hex digits of SHA-256 of its canonical JSON."""
    payload = _canonical({"sweep": sweep, "root_seed": int(root_seed), "params": params})
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()[:16]


def cell_seed(root_seed: int, key: str) -> np.random.SeedSequence:
    """The cell's own seed sequence: ``child_sequence(root_seed, "sweep", k1, k2)`` with
    k1, k2 the two 32-bit halves of the key."""
    return child_sequence(int(root_seed), "sweep", int(key[:8], 16), int(key[8:16], 16))


# -- results file ---------------------------------------------------------------------


def read_results(path: str | os.PathLike[str], *, repair: bool = False
                 ) -> dict[str, dict[str, Any]]:
    """Rows of a JSON-lines results file by key (later rows win).

    A last line without its newline (the writer was killed) is ignored, and cut off
    the file when ``repair`` is true. Any other line that is not a JSON object with a
    ``key`` raises ValueError naming the file and line.
    """
    path = Path(path)
    if not path.exists():
        return {}
    data = path.read_bytes()
    complete = data.rfind(b"\n") + 1
    if complete < len(data) and repair:
        with open(path, "r+b") as f:
            f.truncate(complete)
    rows: dict[str, dict[str, Any]] = {}
    try:
        text = data[:complete].decode("utf-8")
    except UnicodeDecodeError as exc:
        line_no = data[:exc.start].count(b"\n") + 1
        raise ValueError(f"results file {path}, line {line_no}: not UTF-8 text (byte "
                         f"{exc.start}: {exc.reason}); not a JSON-lines results file"
                         ) from None
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ValueError(f"results file {path}, line {number}: not JSON ({exc.msg})"
                             ) from None
        if not isinstance(row, dict) or "key" not in row or "result" not in row:
            raise ValueError(f"results file {path}, line {number}: not a sweep row "
                             "(needs 'key' and 'result')")
        rows[str(row["key"])] = row
    return rows


def flatten(value: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts to dotted keys; scalars kept, lists JSON-encoded."""
    out: dict[str, Any] = {}
    for k, v in value.items():
        name = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, f"{name}."))
        elif isinstance(v, list | tuple):
            out[name] = json.dumps(v, default=json_default)
        else:
            out[name] = v
    return out


def _csv_row(row: Mapping[str, Any]) -> dict[str, Any]:
    return {"key": row["key"], **flatten(row["params"]), **flatten(row["result"])}


def csv_columns(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The CSV columns of ``rows``: ``key``, then every parameter, then every result
    column, each group sorted, so that the table's layout depends on the rows' contents
    only (not on which cells were computed now and which were read back from a resumed
    results file, nor on their order)."""
    params: set[str] = set()
    results: set[str] = set()
    for r in rows:
        params.update(flatten(r["params"]))
        results.update(flatten(r["result"]))
    return ["key", *sorted(params), *sorted(results - params - {"key"})]


def write_csv(rows: Sequence[Mapping[str, Any]], path: str | os.PathLike[str]) -> None:
    """Write rows (``key``, ``params``, ``result``) as one CSV table, flattened, with the
    columns of :func:`csv_columns`."""
    flat = [_csv_row(r) for r in rows]
    columns = csv_columns(rows)
    tmp = Path(str(path) + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="")
        writer.writeheader()
        writer.writerows(flat)
    os.replace(tmp, path)


class _Sink:
    """Appends finished rows to the JSON-lines file (and a streaming CSV)."""

    def __init__(self, path: Path | None, csv_path: Path | None) -> None:
        self.path = path
        self.csv_path = csv_path
        self._f = open(path, "a", encoding="utf-8") if path else None  # noqa: SIM115
        self._csv = None
        self._writer: csv.DictWriter | None = None
        self._columns: list[str] | None = None
        if csv_path is not None:
            fresh = not csv_path.exists() or csv_path.stat().st_size == 0
            self._csv = open(csv_path, "a", newline="", encoding="utf-8")  # noqa: SIM115
            self._fresh = fresh

    def write(self, row: dict[str, Any]) -> None:
        if self._f is not None:
            self._f.write(_canonical(row) + "\n")
            self._f.flush()
            os.fsync(self._f.fileno())
        if self._csv is not None:
            flat = _csv_row(row)
            if self._writer is None:
                self._columns = list(flat)
                self._writer = csv.DictWriter(self._csv, fieldnames=self._columns,
                                              restval="", extrasaction="ignore")
                if self._fresh:
                    self._writer.writeheader()
            self._writer.writerow(flat)
            self._csv.flush()

    def close(self) -> None:
        for f in (self._f, self._csv):
            if f is not None:
                f.close()


# -- running ----------------------------------------------------------------------------


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _run_cell(fn: Callable[..., dict[str, Any]], params: dict[str, Any],
              seed: np.random.SeedSequence, context: Any,
              options: Mapping[str, str] | None = None
              ) -> tuple[dict[str, Any], float, str]:
    start = time.perf_counter()
    # in every executor's worker, serial or not: one BLAS thread, the client's options
    with single_threaded_blas(), applied(options):
        result = fn(params, seed, context)
    # normalise to plain JSON types here, so every executor returns the same thing
    result = json.loads(_canonical(json_tree(result, str_keys=True)))
    return result, time.perf_counter() - start, _worker_name()


def _dask_cell(fn: Callable[..., dict[str, Any]], params: dict[str, Any],
               seed: np.random.SeedSequence, context: Any, options: Mapping[str, str],
               version: str) -> tuple[dict[str, Any], float, str]:
    """A cell on a Dask worker: refused if the worker's netsim is not the client's."""
    import netsim

    if netsim.__version__ != version:
        raise WorkerVersionMismatch(f"worker {_worker_name()} runs netsim "
                                    f"{netsim.__version__}, this client netsim {version}; "
                                    "install the same netsim on every worker")
    return _run_cell(fn, params, seed, context, options)


def _serial(todo: list[tuple[str, dict[str, Any]]], fn: Callable, seeds: dict[str, Any],
            context: Any, options: Mapping[str, str] | None = None
            ) -> Iterator[tuple[str, tuple[dict[str, Any], float, str]]]:
    for key, params in todo:
        yield key, _run_cell(fn, params, seeds[key], context, options)


class _Local:
    def __init__(self, workers: int) -> None:
        from concurrent.futures import ProcessPoolExecutor

        self.pool = ProcessPoolExecutor(
            max_workers=workers, mp_context=multiprocessing.get_context("forkserver"))

    def run(self, todo, fn, seeds, context, options=None):
        from concurrent.futures import as_completed

        futures = {self.pool.submit(_run_cell, fn, params, seeds[key], context, options): key
                   for key, params in todo}
        for future in as_completed(futures):
            yield futures[future], future.result()

    def close(self, cancel: bool) -> None:
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


#: How long the Dask executor waits for its scheduler before giving up.
DASK_CONNECT_TIMEOUT_S = 5


class SchedulerUnreachable(ValueError):
    """The Dask scheduler at the given address did not answer (bad input: exit 2)."""


class WorkerVersionMismatch(ValueError):
    """A Dask worker runs another netsim than the client (bad input: exit 2)."""


def version_mismatches(found: Mapping[str, Any], expected: str,
                       names: Mapping[str, Any] | None = None) -> str | None:
    """The one-line complaint about workers whose netsim is not ``expected``, or None.

    Parameters
    ----------
    found : mapping of worker address to str or exception
        What each worker answered (``Client.run(..., on_error="return")``): its netsim
        version, or the exception it raised (netsim not importable).
    expected : str
        The client's ``netsim.__version__``.
    names : mapping of worker address to name, optional
        The workers' names (``dask worker --name``), shown beside their addresses.

    Returns
    -------
    str or None
        ``worker NAME (ADDRESS) runs netsim X, this client netsim Y; ...`` for the first
        mismatch (by address), with ``(and k more)``; None if every worker matches.
    """
    names = names or {}
    bad = []
    for address in sorted(found):
        answer = found[address]
        name = names.get(address)
        who = f"worker {name} ({address})" if name not in (None, "", address) else \
            f"worker {address}"
        if isinstance(answer, BaseException):
            reason = str(answer).split("\n")[0] or type(answer).__name__
            bad.append(f"{who} cannot import netsim ({type(answer).__name__}: {reason}), "
                       f"this client runs netsim {expected}")
        elif str(answer) != expected:
            bad.append(f"{who} runs netsim {answer}, this client netsim {expected}")
    if not bad:
        return None
    more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
    return f"{bad[0]}{more}; install the same netsim on every worker"


def check_worker_versions(client: Any, what: str = "--dask") -> None:
    """Raise :class:`WorkerVersionMismatch` unless every worker runs this netsim.

    Parameters
    ----------
    client : distributed.Client
        Connected; its workers are asked now (a worker joining later is refused by its
        first task).
    what : str
        Prefix of the message (the option that named the cluster).

    Raises
    ------
    WorkerVersionMismatch
        One line naming the first worker that differs and both versions.
    """
    import netsim

    # a lambda travels by value (cloudpickle): it runs on a worker whose netsim differs
    found = client.run(lambda: importlib.import_module("netsim").__version__,
                       on_error="return")
    info = client.scheduler_info().get("workers", {})
    names = {address: w.get("name") for address, w in info.items()}
    message = version_mismatches(found, netsim.__version__, names)
    if message is not None:
        raise WorkerVersionMismatch(f"{what}: {message}")


_LOADED: dict[str, Any] = {}


def _load_by_value(blob: bytes | None, fallback: Any) -> ByValue:
    """Unpickle a :class:`ByValue` (once per process and contents)."""
    if blob is None:
        return ByValue(fallback)
    digest = hashlib.sha256(blob).hexdigest()
    value = _LOADED.get(digest)
    if value is None:
        import pickle

        value = _LOADED[digest] = pickle.loads(blob)  # noqa: S301 - our own client's bytes
    return ByValue(value)


class ByValue:
    """An object that travels to other processes with the code of some modules.

    A ``module:attribute`` estimator lives in a file beside the scenario or in the
    client's folder; a worker on another machine has no such file. Pickled, a ByValue
    holds its object cloudpickled with ``modules`` registered by value
    (:func:`cloudpickle.register_pickle_by_value`): the classes and functions of those
    modules travel as code, everything else by reference. Without cloudpickle (it comes
    with the ``dask`` extra) it travels as ``fallback``, which the receiver must resolve
    itself (by name, as before).

    Parameters
    ----------
    value : object
        What to ship.
    modules : sequence of module
        Modules whose code goes with it.
    fallback : object, optional
        What arrives when cloudpickle is missing.
    """

    def __init__(self, value: Any, modules: Sequence[Any] = (), fallback: Any = None) -> None:
        self.value = value
        self.modules = tuple(modules)
        self.fallback = fallback
        self._blob: bytes | None = None

    def blob(self) -> bytes | None:
        """The cloudpickled value (None without cloudpickle); computed once."""
        if self._blob is None:
            try:
                import cloudpickle
            except ImportError:
                return None
            added = []
            try:
                for module in self.modules:
                    if module.__name__ not in cloudpickle.list_registry_pickle_by_value():
                        cloudpickle.register_pickle_by_value(module)
                        added.append(module)
                buffer = io.BytesIO()
                cloudpickle.dump(self.value, buffer)
                self._blob = buffer.getvalue()
            finally:
                for module in added:
                    cloudpickle.unregister_pickle_by_value(module)
        return self._blob

    def __reduce__(self) -> tuple[Any, ...]:
        return (_load_by_value, (self.blob(), self.fallback))


class _Dask:
    def __init__(self, address: Any) -> None:
        from netsim.models.extras import require

        Client = require("distributed", "dask", "the Dask executor (--dask)").Client
        if isinstance(address, Client):
            self.client, self.own = address, False
        else:
            try:
                client = Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s")
            except (OSError, ValueError, TypeError) as exc:  # TimeoutError is an OSError
                reason = (f"no answer within {DASK_CONNECT_TIMEOUT_S} s"
                          if isinstance(exc, TimeoutError) else
                          str(exc).split("\n")[0] or type(exc).__name__)
                raise SchedulerUnreachable(f"--dask {address}: could not connect to the Dask "
                                           f"scheduler at {address} ({reason})") from None
            self.client, self.own = client, True
        self.futures: list[Any] = []
        try:
            check_worker_versions(self.client, f"--dask {address}"
                                  if not isinstance(address, Client) else "--dask")
        except BaseException:
            self.close(cancel=True)
            raise

    def run(self, todo, fn, seeds, context, options=None):
        from distributed import as_completed

        import netsim

        shared = self.client.scatter(context, broadcast=True) if context is not None else None
        version = netsim.__version__
        futures = {}
        for key, params in todo:
            future = self.client.submit(_dask_cell, fn, params, seeds[key], shared,
                                        options, version,
                                        key=f"netsim-cell-{key}-{time.time_ns()}", pure=False)
            futures[future] = key
        self.futures = list(futures)
        for future in as_completed(futures):
            yield futures[future], future.result()

    def close(self, cancel: bool) -> None:
        if cancel and self.futures:
            try:
                self.client.cancel(self.futures)
            except Exception:  # noqa: BLE001 - best effort while stopping
                pass
        if self.own:
            self.client.close()


def run_sweep(
    fn: Callable[[dict[str, Any], np.random.SeedSequence, Any], dict[str, Any]],
    cells: Iterable[Mapping[str, Any]],
    *,
    root_seed: int = 0,
    sweep: str = "",
    results: str | os.PathLike[str] | None = None,
    csv_path: str | os.PathLike[str] | None = None,
    executor: str = "local",
    workers: int = DEFAULT_WORKERS,
    dask_address: Any = None,
    context: Any = None,
    progress: bool = True,
    description: str = "sweep",
    on_row: Callable[[dict[str, Any]], None] | None = None,
    stop_after: int | None = None,
    prepare: Callable[[list[dict[str, Any]]], Any] | None = None,
) -> SweepResult:
    """Run every cell not already in ``results``; return all rows in cell order.

    Parameters
    ----------
    fn : callable(params, seed, context) -> dict
        Computes one cell; must be importable by name (module level) for the process
        pool and Dask. ``seed`` is :func:`cell_seed`; its result must be JSON-able
        (numpy scalars and arrays, NaN and inf are converted).
    cells : iterable of dict
        Parameters of each cell (JSON-able); duplicates are computed once.
    root_seed : int
    sweep : str
        Name of the sweep, part of every key (two sweeps can share a results file).
    results : path, optional
        JSON-lines file: rows already in it are reused, new rows are appended as they
        finish (flushed and fsynced). None: nothing is saved, nothing resumed.
    csv_path : path, optional
        Also stream rows to this CSV; rewritten as one table in cell order at the end.
    executor : ``"local"`` (default), ``"dask"`` or ``"serial"``
    workers : int
        Processes of the local pool.
    dask_address : str or distributed.Client
        Scheduler address (e.g. ``tcp://127.0.0.1:8786``) or a connected client;
        giving one selects the Dask executor.
    context : object, optional
        Passed to every call of ``fn`` (pickled once per task for the pool, scattered
        once for Dask): large shared inputs such as a scenario and its gains.
    progress : bool
        tqdm bar on stderr.
    on_row : callable(row), optional
        Called in this process after each new row is saved.
    stop_after : int, optional
        Test hook: stop (as if interrupted) after this many new rows were saved.
    prepare : callable(list of params) -> context, optional
        Called once, in this process, with the parameters of the cells still to compute
        (after the results file is read; not called when none is left); what it returns
        is the ``context`` (``context`` is then ignored). Work that many cells share
        (e.g. gain designs) is done here once and sent with the cells.

    Every cell runs with one BLAS thread and with this process's options
    (:func:`netsim.taskoptions.snapshot`: ``--no-cache``, ``NETSIM_CACHE_DIR``, the
    memory and time limits), whatever the worker's environment. With Dask, every
    worker's netsim version must be this process's (:func:`check_worker_versions`).

    Raises
    ------
    SweepInterrupted
        On KeyboardInterrupt or ``stop_after``: the finished rows are saved.
    SchedulerUnreachable, WorkerVersionMismatch
        The Dask scheduler does not answer, or a worker runs another netsim.
    """
    if dask_address is not None:
        executor = "dask"
    if executor not in EXECUTORS:
        raise ValueError(f"unknown executor {executor!r}; expected one of {', '.join(EXECUTORS)}")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if executor == "dask" and dask_address is None:
        raise ValueError("the dask executor needs a scheduler address")
    started = time.perf_counter()
    ordered: list[tuple[str, dict[str, Any]]] = []
    seen: set[str] = set()
    for params in cells:
        params = json.loads(json.dumps(dict(params), allow_nan=False, default=json_default))
        key = cell_key(params, root_seed, sweep)
        if key not in seen:
            seen.add(key)
            ordered.append((key, params))
    path = Path(results) if results is not None else None
    done: dict[str, dict[str, Any]] = read_results(path, repair=True) if path else {}
    todo = [(k, p) for k, p in ordered if k not in done]
    reused = len(ordered) - len(todo)
    seeds = {k: cell_seed(root_seed, k) for k, _ in todo}
    computed = 0
    runner: Any = None
    if todo and executor == "dask":  # connect first: an unreachable scheduler is one line
        runner = _Dask(dask_address)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(ordered), initial=reused, desc=description, unit="cell",
                   file=sys.stderr, leave=False, dynamic_ncols=True)
    try:
        sink = _Sink(path, Path(csv_path) if csv_path is not None else None)
    except BaseException:
        if runner is not None:
            runner.close(cancel=True)
        if bar is not None:
            bar.close()
        raise
    cancelled = False
    try:
        if todo:
            if prepare is not None:
                context = prepare([p for _, p in todo])
            options = snapshot()
            if executor == "serial":
                stream_ = _serial(todo, fn, seeds, context, options)
            elif executor == "local":
                runner = _Local(min(int(workers), len(todo)))
                stream_ = runner.run(todo, fn, seeds, context, options)
            else:
                stream_ = runner.run(todo, fn, seeds, context, options)
            params_of = dict(todo)
            for key, (result, elapsed, worker) in stream_:
                row = {"key": key, "params": params_of[key], "result": result,
                       "elapsed_s": round(elapsed, 6), "worker": worker}
                sink.write(row)
                done[key] = row
                computed += 1
                if bar is not None:
                    bar.update(1)
                if on_row is not None:
                    on_row(row)
                if stop_after is not None and computed >= stop_after and \
                        computed < len(todo):
                    cancelled = True
                    raise SweepInterrupted(reused + computed, len(ordered), computed,
                                           str(path) if path else None, "stopped (test hook)")
    except KeyboardInterrupt:
        cancelled = True
        raise SweepInterrupted(reused + computed, len(ordered), computed,
                               str(path) if path else None) from None
    except BaseException:
        cancelled = True
        raise
    finally:
        if runner is not None:
            runner.close(cancel=cancelled)
        sink.close()
        if bar is not None:
            bar.close()
    rows = [done[k] for k, _ in ordered]
    if csv_path is not None:
        write_csv(rows, csv_path)
    return SweepResult(rows, computed, reused, str(path) if path else None,
                       str(csv_path) if csv_path else None, executor,
                       1 if executor == "serial" else int(workers),
                       time.perf_counter() - started)


def environment_cell(params: dict[str, Any], seed: np.random.SeedSequence, context: Any
                     ) -> dict[str, Any]:
    """What a cell sees where it runs (a probe of a cluster, used by the tests): the gain
    cache folder (None: off), the memory and time limits and their sources, the worker
    count of :mod:`netsim.parallel`, the BLAS threads and the netsim version."""
    import netsim
    from netsim import budget, gaincache, parallel

    try:
        from threadpoolctl import threadpool_info

        blas = sorted({p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"})
    except ImportError:  # pragma: no cover - a dependency
        blas = []
    cache = gaincache.cache_dir()
    limit, source = budget.memory_limit()
    return {"cache_dir": None if cache is None else str(cache), "memory_limit": limit,
            "memory_limit_source": source, "time_limit": budget.time_limit(),
            "workers": parallel.env_workers(), "blas_threads": blas,
            "netsim": netsim.__version__}


def demo_cell(params: dict[str, Any], seed: np.random.SeedSequence, context: Any
              ) -> dict[str, Any]:
    """A cheap example cell (used by the tests): statistics of ``params["n"]`` normal draws
    from the cell's own seed, scaled by ``params["scale"]`` (default 1) and ``context``
    (a number, default 1). ``params["sleep"]`` seconds of wall time, to simulate work."""
    if params.get("sleep"):
        time.sleep(float(params["sleep"]))
    rng = np.random.Generator(np.random.PCG64(seed))
    x = rng.standard_normal(int(params.get("n", 100))) * float(params.get("scale", 1.0))
    x *= 1.0 if context is None else float(context)
    return {"mean": float(x.mean()), "std": float(x.std()), "max": float(x.max()),
            "first": x[:3]}
