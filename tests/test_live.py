"""``netsim run --live``: the run served over the Foxglove WebSocket protocol.

A subprocess serves ``lcsys2022-heterogeneous`` (and records the same run with
``--trace``); a plain ``websockets`` client subscribes to every advertised channel,
decodes each binary messageData frame (opcode 1: uint32 subscription id, uint64
timestamp, payload) with the protobuf schema the channel advertised, and must hold at
least one message of every topic the trace has, each byte for byte a message of that
topic in the trace at the same log time (the trace read independently with the
``mcap`` reader). Only waits have timeouts; nothing asserts how long anything took.

The foxglove-sdk server speaks the subprotocol ``foxglove.sdk.v1`` (identical to
``foxglove.websocket.v1``, which it refuses in the handshake); the client offers both.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

from netsim.cli import main  # noqa: E402

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(port: int, trace: Path, *extra: str) -> subprocess.Popen:
    command = [sys.executable, "-c", "import sys; from netsim.cli import main; "
               "sys.exit(main())", "run", "lcsys2022-heterogeneous", "--steps", "12",
               "--trials", "1", "--estimators", "compensated", "--trace", str(trace),
               "--live", f"127.0.0.1:{port}", "--no-progress", "--json", *extra]
    return subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True)


def _end(proc: subprocess.Popen) -> None:
    """Kill the server's process group if it is still running."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait(timeout=30)
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()


def _decoder(channel: dict):
    """The message class of an advertised protobuf channel (its FileDescriptorSet)."""
    assert channel["encoding"] == "protobuf", channel
    assert channel.get("schemaEncoding", "protobuf") == "protobuf", channel
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


async def _listen(port: int, proc: subprocess.Popen, *, until: dict | None = None,
                  budget: float = 240.0) -> dict:
    """Subscribe to every channel and collect (log time, payload, decoded) per topic
    until the server closes the connection (or ``until``: topic -> count is reached)."""
    deadline = time.monotonic() + budget
    while True:  # the server takes a moment to start
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}",
                                          subprotocols=SUBPROTOCOLS, max_size=None,
                                          open_timeout=10)
            break
        except (TimeoutError, OSError, websockets.InvalidHandshake):
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the live server never came up"
            await asyncio.sleep(0.2)
    got: dict[str, list] = {}
    subscriptions: dict[int, tuple[str, object]] = {}
    info = {"subprotocol": ws.subprotocol, "capabilities": None, "got": got}
    async with ws:
        while time.monotonic() < deadline:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=5)
            except TimeoutError:
                if proc.poll() is not None:
                    break
                continue
            except websockets.ConnectionClosed:
                break
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "serverInfo":
                    info["capabilities"] = message.get("capabilities")
                elif message["op"] == "advertise":
                    new = []
                    for channel in message["channels"]:
                        sid = len(subscriptions) + 1
                        subscriptions[sid] = (channel["topic"], _decoder(channel))
                        new.append({"id": sid, "channelId": channel["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            elif frame[0] == 1:  # messageData
                sid, stamp = struct.unpack_from("<IQ", frame, 1)
                topic, cls = subscriptions[sid]
                payload = bytes(frame[13:])
                got.setdefault(topic, []).append((stamp, payload, cls.FromString(payload)))
                if until is not None and all(len(got.get(t, ())) >= n
                                             for t, n in until.items()):
                    break
    return info


def _trace_messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    return out


def _check(info: dict, trace: Path) -> None:
    expected = _trace_messages(trace)
    assert expected, "the trace has no messages"
    got = info["got"]
    missing = sorted(set(expected) - set(got))
    assert not missing, f"topics never served: {missing} (served {sorted(got)})"
    assert set(got) <= set(expected), sorted(set(got) - set(expected))
    for topic, messages in got.items():
        recorded = set(expected[topic])
        for stamp, payload, decoded in messages:
            assert (stamp, payload) in recorded, f"{topic}: a message not in the trace"
            assert decoded.ListFields(), topic
    assert info["capabilities"] is not None and "time" in info["capabilities"]


def test_live_serves_every_topic_of_the_trace(tmp_path):
    port = _free_port()
    trace = tmp_path / "run.mcap"
    proc = _serve(port, trace, "--speed", "0", "--live-linger", "1")
    try:
        info = asyncio.run(_listen(port, proc))
        assert proc.wait(timeout=120) == 0, proc.stderr.read().decode()
        result = json.loads(proc.stdout.read())
        assert result["traces"] == [str(trace)]
        _check(info, trace)
        assert info["subprotocol"] in SUBPROTOCOLS
    finally:
        _end(proc)


def test_live_format2_paced_then_ctrl_c(tmp_path):
    """Format 2 (a topic per agent and link event), paced at 20 simulation seconds per
    second; after the run the server stays up until Ctrl-C, which exits 130."""
    port = _free_port()
    trace = tmp_path / "run2.mcap"
    proc = _serve(port, trace, "--speed", "20", "--trace-format", "2")
    try:
        deadline = time.monotonic() + 240
        # the server outlives the run: once the trace is finished (its summary
        # written), listen until every topic of it arrived
        while True:
            assert proc.poll() is None, proc.stderr.read().decode()
            try:
                with open(trace, "rb") as f:
                    summary = make_reader(f).get_summary()
                if summary is not None:
                    break
            except Exception:  # noqa: BLE001 - still being written
                pass
            assert time.monotonic() < deadline
            time.sleep(0.1)
        counts = {summary.channels[c].topic: 1 for c, n in
                  summary.statistics.channel_message_counts.items() if n}
        info = asyncio.run(_listen(port, proc, until=counts))
        assert proc.poll() is None  # still serving
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 130, proc.stderr.read().decode()
        _check(info, trace)
    finally:
        _end(proc)


def test_live_errors(monkeypatch, capsys, tmp_path):
    installed = sys.modules["foxglove"]
    monkeypatch.setitem(sys.modules, "foxglove", None)  # not installed
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "3", "--live"]) == 2
    assert "pip install 'netsim[live]'" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "foxglove", installed)
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "3", "--live",
                 "127.0.0.1:99999"]) == 2
    assert "port" in capsys.readouterr().err
    assert main(["run", "lcsys2022-heterogeneous", "--steps", "3", "--live", "--speed",
                 "-1"]) == 2
    assert "--speed" in capsys.readouterr().err
