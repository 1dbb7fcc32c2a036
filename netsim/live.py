"""Live view: serve a run to a Foxglove WebSocket viewer while it runs (``netsim run --live``).

``netsim run SCENARIO --live [ADDR]`` starts a Foxglove WebSocket server (the official
``foxglove-sdk`` package, optional extra ``live``: ``pip install 'netsim[live]'``) on
ADDR (default ``127.0.0.1:8765``) and serves every message the run's trace holds: the
same topics, the same protobuf schemas (the trace's own ``FileDescriptorSet``) and the
same log times, so the layout of the trace (``netsim layout``) fits the live view as
well. In the Foxglove app: *Open connection* > *Foxglove WebSocket* > ``ws://ADDR``.
foxglove-sdk 0.30 accepts only the WebSocket subprotocol ``foxglove.sdk.v1`` (the
Foxglove WebSocket protocol, formerly named ``foxglove.websocket.v1``): a viewer must
offer that name (one that offers only ``foxglove.websocket.v1`` is refused in the
handshake).

How it works
------------
The trace recorder (:class:`netsim.traces.recorder.TraceRecorder`) writes every
record through its MCAP writer; its ``writer_tap`` option puts a :class:`_Tee` in
front of that writer, which passes every call on unchanged and hands a copy of each
schema, channel and message to a :class:`LiveView`. The event kernel and the
vectorised engine are not touched (no per-event hook); a run without ``--live`` has no
tee at all. Without ``--trace`` the run is recorded to a scratch file, removed at the
end (a scratch trace may pick a different engine than an untraced run, exactly as
``--trace`` does; the results are the same to round-off).

Pacing is the only place where wall-clock time matters: a thread publishes each message
when ``(log_time - first log_time) / speed`` wall-clock seconds have passed since the
first one (``--speed``, simulation seconds per wall-clock second, default 1; 0 or
``inf``: as fast as possible). The simulation runs ahead into a bounded queue and waits
when it is full, so results, verdicts and the trace do not depend on the pacing.
Messages that the trace writes in bulk (format 3 writes a block of steps at once) are
published in log_time order within the block.

Viewers: nothing is published until a viewer subscribes to a first channel (the start
of the run would otherwise be lost); a channel new to the viewer gets up to
:data:`SUBSCRIBE_GRACE` seconds to be subscribed before its first message goes out.
Several runs (estimator families, trials) are served one after the other, each shifted
in time to start one sample period after the previous one ended, so time never goes
back.

Ending: after the run is served the server stays up until Ctrl-C (exit status 130), or
for ``--live-linger SECONDS`` (then exit status 0). Ctrl-C during the run stops it at
the next step, as without ``--live`` (exit 130).
"""

from __future__ import annotations

import argparse
import math
import queue
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from netsim import interrupt
from netsim.cliutil import EXIT_INTERRUPTED, CommandError

__all__ = ["DEFAULT_ADDRESS", "SUBSCRIBE_GRACE", "LiveView", "parse_address", "run_live"]

#: Where ``--live`` serves without an address.
DEFAULT_ADDRESS = "127.0.0.1:8765"
#: Seconds a newly advertised channel waits for a subscription before its first message.
SUBSCRIBE_GRACE = 3.0
#: Messages the simulation may run ahead of the pacing.
QUEUE_SIZE = 4096
#: Outgoing messages buffered per viewer (the SDK drops the oldest beyond it).
BACKLOG = 65536

_END = object()
# MCAP Message record: opcode (1), length (8), channel (2), sequence (4), log_time (8),
# publish_time (8), then the data
_HEAD = 1 + 8 + 2 + 4 + 8 + 8


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT``, ``PORT`` or ``HOST`` -> (host, port); the defaults of
    :data:`DEFAULT_ADDRESS` fill what is left out.

    Raises
    ------
    ValueError
        A port that is not an integer in 0 .. 65535 (0: any free port).
    """
    default_host, default_port = DEFAULT_ADDRESS.rsplit(":", 1)
    text = text.strip()
    if text.isdigit():
        host, port = default_host, text
    elif ":" in text and not text.endswith("]"):
        host, port = text.rsplit(":", 1)
    else:
        host, port = text, default_port
    host = host.strip("[]") or default_host
    if not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{text!r}: the port must be an integer in 0 .. 65535")
    return host, int(port)


if TYPE_CHECKING:  # (foxglove-sdk is an optional extra: imported when a view starts)
    from foxglove.websocket import ServerListener as _ListenerBase
    from foxglove.websocket import WebSocketServer
else:
    _ListenerBase = object


class _Listener(_ListenerBase):
    """The server's listener: which channels some viewer subscribed to."""

    def __init__(self, view: LiveView) -> None:
        self.view = view

    def on_subscribe(self, client: Any, channel: Any) -> None:  # noqa: ARG002
        self.view._subscribed(int(channel.id))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:  # noqa: ARG002
        pass


class LiveView:
    """A Foxglove WebSocket server that publishes trace records, paced in simulation time.

    Parameters
    ----------
    host : str
    port : int
        0: any free port (see :attr:`port`).
    speed : float
        Simulation seconds per wall-clock second; 0 or ``inf``: no pacing.
    name : str
        The server's name (shown by the viewer).
    grace : float
        :data:`SUBSCRIBE_GRACE`.
    """

    def __init__(self, host: str, port: int, *, speed: float = 1.0, name: str = "netsim",
                 grace: float = SUBSCRIBE_GRACE) -> None:
        import foxglove
        from foxglove.websocket import Capability

        if not (speed >= 0):  # NaN too
            raise ValueError(f"speed must be >= 0 (0 or inf: as fast as possible), got {speed}")
        self.speed = math.inf if speed == 0 else float(speed)
        self.grace = float(grace)
        self._foxglove = foxglove
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=QUEUE_SIZE)
        self._channels: dict[str, Any] = {}  # topic -> foxglove.Channel
        self._advertised: dict[int, float] = {}  # channel id -> monotonic time advertised
        self._subscribed_ids: set[int] = set()
        self._lock = threading.Lock()
        self._first_viewer = threading.Event()
        self._stop = threading.Event()
        self._done = threading.Event()
        self.error: BaseException | None = None
        #: Messages published, and per topic.
        self.published = 0
        self.counts: dict[str, int] = {}
        self._shift = 0  # ns added to the log times of the current run
        self._last_enqueued = -1  # largest shifted log_time handed to the queue
        self._runs = 0
        server = foxglove.start_server(
            name=name, host=host, port=port, capabilities=[Capability.Time],
            server_listener=_Listener(self), message_backlog_size=BACKLOG)
        self._server: WebSocketServer | None = server  # None: stopped
        self.host = host
        #: The port served (the actual one when 0 was asked for).
        self.port = int(server.port)
        self._thread = threading.Thread(target=self._pace, name="netsim-live", daemon=True)
        self._thread.start()

    # -- the recorder's side -------------------------------------------------------

    def tap(self, writer: Any, recorder: Any) -> _Tee:
        """The recorder's ``writer_tap``: a tee in front of ``writer`` for one run."""
        origin = int(getattr(recorder, "time_origin_ns", 0))
        period = int(round(float(getattr(recorder, "sample_period", 1.0)) * 1e9))
        with self._lock:
            if self._runs and self._last_enqueued >= 0:
                self._shift = max(0, self._last_enqueued + period - origin)
            else:
                self._shift = 0
            self._runs += 1
        return _Tee(writer, self)

    def channel(self, topic: str, encoding: str, schema: tuple[str, str, bytes] | None
                ) -> Any:
        """The Foxglove channel of a topic (advertised now, once per topic)."""
        found = self._channels.get(topic)
        if found is None:
            fox = self._foxglove
            spec = None if schema is None else fox.Schema(
                name=schema[0], encoding=schema[1], data=bytes(schema[2]))
            found = fox.Channel(topic, schema=spec, message_encoding=encoding)
            with self._lock:
                self._advertised[int(found.id())] = time.monotonic()
            self._channels[topic] = found
        return found

    def put(self, items: list[tuple[int, Any, bytes]]) -> None:
        """Queue messages ``(log_time, channel, data)`` (the current run's shift added);
        blocks while the queue is full. A requested stop (Ctrl-C) drops them: the run
        stops at its next step."""
        if self._done.is_set() or self._stop.is_set():
            return
        shift = self._shift
        for log_time, channel, data in items:
            item = (int(log_time) + shift, channel, data)
            while True:
                if interrupt.requested() or self._stop.is_set():
                    return
                try:
                    self._queue.put(item, timeout=0.2)
                    break
                except queue.Full:
                    if not self._thread.is_alive():
                        return
            if item[0] > self._last_enqueued:
                self._last_enqueued = item[0]

    # -- the pacing thread ---------------------------------------------------------

    def _subscribed(self, channel_id: int) -> None:
        with self._lock:
            self._subscribed_ids.add(channel_id)
        self._first_viewer.set()

    def _wait(self, seconds: float) -> bool:
        """Sleep (False: stopped meanwhile)."""
        return not self._stop.wait(max(0.0, seconds))

    def _pace(self) -> None:
        server = self._server
        assert server is not None  # (started before this thread)
        try:
            while not self._first_viewer.wait(0.2):
                if self._stop.is_set():
                    return
            first: tuple[int, float] | None = None
            last_time = -1
            while not self._stop.is_set():
                try:
                    item = self._queue.get(timeout=0.2)
                except queue.Empty:
                    continue
                if item is _END:
                    return
                log_time, channel, data = item
                if math.isfinite(self.speed):
                    if first is None:
                        first = (log_time, time.monotonic())
                    due = first[1] + (log_time - first[0]) / 1e9 / self.speed
                    if not self._wait(due - time.monotonic()):
                        return
                cid = int(channel.id())
                with self._lock:
                    since = self._advertised.get(cid)
                    waiting = cid not in self._subscribed_ids
                if waiting and since is not None:  # new to the viewer: time to subscribe
                    until = since + self.grace
                    while time.monotonic() < until:
                        with self._lock:
                            if cid in self._subscribed_ids:
                                break
                        if not self._wait(0.02):
                            return
                    with self._lock:
                        self._advertised.pop(cid, None)
                channel.log(data, log_time=log_time)
                self.published += 1
                topic = channel.topic()
                self.counts[topic] = self.counts.get(topic, 0) + 1
                if log_time > last_time:
                    last_time = log_time
                    server.broadcast_time(log_time)
        except BaseException as exc:  # noqa: BLE001 - reported by finish()
            self.error = exc
        finally:
            self._done.set()

    # -- ending ----------------------------------------------------------------------

    def finish(self) -> None:
        """Wait until everything queued was published (KeyboardInterrupt on Ctrl-C)."""
        while True:
            try:
                self._queue.put(_END, timeout=0.2)
                break
            except queue.Full:
                if not self._thread.is_alive():
                    break
        while not self._done.wait(0.2):
            pass
        if self.error is not None:
            raise RuntimeError(f"live view: {self.error}") from self.error

    def stop(self) -> None:
        """Stop publishing and close the server. Idempotent."""
        self._stop.set()
        self._thread.join(timeout=5)
        server, self._server = self._server, None
        if server is not None:
            server.stop()


class _Tee:
    """The recorder's writer, with every schema, channel and message also handed to a
    :class:`LiveView` (other calls pass through)."""

    def __init__(self, writer: Any, view: LiveView) -> None:
        self._writer = writer
        self._view = view
        self._schemas: dict[int, tuple[str, str, bytes]] = {}
        self._channels: dict[int, Any] = {}

    def __getattr__(self, name: str) -> Any:
        return getattr(self._writer, name)

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema_id = int(self._writer.add_schema(name, encoding, data))
        self._schemas[schema_id] = (name, encoding, bytes(data))
        return schema_id

    register_schema = add_schema

    def add_channel(self, topic: str, message_encoding: str, schema_id: int,
                    metadata: Any = None) -> int:
        channel_id = int(self._writer.add_channel(topic, message_encoding, schema_id,
                                                  metadata))
        if channel_id not in self._channels:
            self._channels[channel_id] = self._view.channel(
                topic, message_encoding, self._schemas.get(schema_id))
        return channel_id

    register_channel = add_channel

    def add_message(self, channel_id: int, log_time: int, data: bytes,
                    publish_time: int = 0, sequence: int = 0) -> None:
        self._writer.add_message(channel_id, log_time, data, publish_time, sequence)
        self._view.put([(int(log_time), self._channels[int(channel_id)], bytes(data))])

    def add_messages(self, channel_id: Any, log_time: Any, payloads: Any, **options: Any
                     ) -> None:
        # packed like the writer does it, then through add_records (one code path)
        from netsim.traces.bulkmcap import _column, message_records

        log_time = np.asarray(log_time, dtype=np.uint64).reshape(-1)
        n = log_time.shape[0]
        if n == 0:
            return
        channel = _column(channel_id, n, "<u2", "channel_id")
        publish = options.get("publish_time")
        records, starts = message_records(
            channel, options.get("sequence", 0), log_time,
            log_time if publish is None else publish, payloads, options.get("offsets"))
        self.add_records(records, starts, channel, log_time)

    def add_records(self, records: np.ndarray, starts: np.ndarray, channel_id: np.ndarray,
                    log_time: np.ndarray) -> None:
        self._writer.add_records(records, starts, channel_id, log_time)
        n = int(starts.shape[0])
        if n == 0:
            return
        raw = np.asarray(records, dtype=np.uint8)
        ends = np.append(np.asarray(starts[1:], dtype=np.int64), raw.shape[0])
        times = np.asarray(log_time, dtype=np.uint64).astype(np.int64)
        ids = np.asarray(channel_id).astype(np.int64)
        order = np.argsort(times, kind="stable")  # a block of steps: in time order
        channels = self._channels
        self._view.put([
            (int(times[q]), channels[int(ids[q])],
             raw[int(starts[q]) + _HEAD:int(ends[q])].tobytes())
            for q in order.tolist()])


def run_live(args: argparse.Namespace, command: Callable[[argparse.Namespace], int]) -> int:
    """``netsim run ... --live``: serve the run while ``command(args)`` runs it.

    ``args.live`` is the address; ``args.speed`` and ``args.live_linger`` as the
    options say. Without ``--trace`` the run is recorded to a scratch file that is
    removed at the end. Returns the command's exit status, or 130 after Ctrl-C.

    Raises
    ------
    CommandError
        foxglove-sdk missing, a bad address, speed or linger, or a port in use.
    """
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise CommandError("--live needs the foxglove-sdk package: pip install "
                           "'netsim[live]'") from None
    try:
        host, port = parse_address(args.live)
    except ValueError as exc:
        raise CommandError(f"--live {exc}") from None
    speed = float(args.speed)
    if not speed >= 0:
        raise CommandError(f"--speed must be >= 0 (0 or inf: as fast as possible), got "
                           f"{args.speed}")
    linger = args.live_linger
    if linger is not None and not (linger >= 0 and math.isfinite(linger)):
        raise CommandError(f"--live-linger must be a number of seconds >= 0, got {linger}")
    if args.layout and args.trace is None:
        raise CommandError("--layout needs --trace FILE.mcap")
    try:
        view = LiveView(host, port, speed=speed)
    except Exception as exc:  # noqa: BLE001 - e.g. the port is in use
        raise CommandError(f"--live {args.live}: cannot serve on {host}:{port} ({exc})"
                           ) from None
    scratch = None
    try:
        sys.stderr.write(
            f"netsim run: live view on ws://{host}:{view.port} (in Foxglove: Open "
            "connection > Foxglove WebSocket; subprotocol foxglove.sdk.v1); waiting for a "
            "viewer to connect\n")
        sys.stderr.flush()
        if args.trace is None:
            scratch = tempfile.mkdtemp(prefix="netsim-live-")
            args.trace = str(Path(scratch) / "live.mcap")
            args.live_scratch = True
        args.live_tap = view.tap
        args.live = None
        status = command(args)
        try:
            view.finish()
            if linger is None:
                sys.stderr.write("netsim run: the run was served; Ctrl-C ends the live "
                                 "view\n")
                sys.stderr.flush()
                while True:
                    time.sleep(3600)
            else:
                time.sleep(linger)
        except KeyboardInterrupt:
            sys.stderr.write("netsim run: live view ended (Ctrl-C)\n")
            return EXIT_INTERRUPTED
        return status
    finally:
        view.stop()
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
