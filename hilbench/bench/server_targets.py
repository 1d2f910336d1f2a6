"""Servers of a running bench as rough-input targets (:mod:`hilbench.fuzzing`, kind ``server``): a client's session.

Both drive a bench started once per process (on free ports, on 127.0.0.1, stopped at exit) with a
device of each family that takes control commands.

- ``server-control``: the control channel. A session is the bytes one client sends over one
  connection, cut into request lines by :func:`~hilbench.bench.control.next_request` and answered by
  :meth:`~hilbench.bench.control.ControlServer.reply` as the channel's loop does, so every family's
  commands meet whatever the mutations made of the requests. The client counts as gone (a command
  that waits, ``wait_report``, returns at once), as one that sends its session and leaves. ``good``
  counts the requests answered ``"ok": true``, ``dropped`` the others.
- ``server-scip``: the UST-10LX on its TCP port, through the bench's own TCP host port, serial medium
  and unit, in the medium's thread: a client connects (once the unit let the last one go), sends the
  session, leaves; the session ends when the port is free again, everything it sent having reached the
  unit. Each connection starts afresh (a line the last one began is not run). ``good`` counts the
  replies the unit sent, ``dropped`` the request bytes it could not read. A traceback the medium logs
  for the unit counts against the session.
"""

from __future__ import annotations

import atexit
import json
import random
import socket
import threading
import time
from typing import Any

from hilbench.fuzzing import FuzzTarget, TracebackWatch

#: A bench with a device of each family that takes commands (every port a free one, on 127.0.0.1).
PROFILE: dict[str, Any] = {
    "schema": 1,
    "description": "every family that takes control commands, for the control channel's fuzz target",
    "scene": {"walls": [[[-2.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-2.0, 2.0], [-2.0, -2.0]]]},
    "endpoints": {
        "rover": {"type": "pty", "protocol": "vel2d", "baud": 115_200},
        "lidar": {"type": "pty", "protocol": "rplidar", "baud": 115_200},
        "ust": {"type": "tcp", "protocol": "scip2", "port": 0},
        "agent": {"type": "udp", "protocol": "xrce-dds", "port": 0},
        "can": {"type": "can", "protocol": "can", "bitrate": 500_000},
    },
    "devices": [
        {"model": "stm32f767-rover", "name": "rover", "endpoint": "rover", "preset": "freertos-50-30", "output": "v3"},
        {"model": "rplidar-a1", "name": "lidar", "endpoint": "lidar", "pose": {"x": 0.1, "y": 0.0}, "motor": "always"},
        {"model": "ust-10lx", "name": "ust", "endpoint": "ust", "pose": {"x": 0.5, "y": 0.3}},
        {"model": "micro-ros-agent", "name": "agent", "endpoint": "agent"},
        {"model": "stm32f767-rover-canopen", "name": "node", "endpoint": "can", "node_id": 2},
    ],
}
#: Request lines a client sends, by command (arguments filled in by :func:`control_session`).
COMMANDS = ("devices", "manifest", "media", "servers", "taps", "control", "status", "button", "reset", "fault",
            "log", "wait_report", "micro_ros", "scanner_status", "scanner_fault", "dtr", "nmt", "emcy", "bus")
#: A bench's command costs about this long to answer: the line the figures are measured against.
LINE = "a client sending 1 000 requests/s of 60 bytes"
LINE_RATE = 1000 * 60

_lock = threading.Lock()
_bench: Any = None


def bench() -> Any:
    """The target's running bench (started on first use, stopped at exit)."""
    global _bench
    with _lock:
        if _bench is None:
            from hilbench.bench import Bench
            from hilbench.bench.profile import parse_profile

            _bench = Bench(parse_profile(PROFILE, "control-fuzz.toml")).start()
            _bench.serve_control()
            atexit.register(_bench.stop)
        return _bench


#: Commands that change a board's state and wait for it to settle (milliseconds each): rare in sessions, so a
#: session costs about what its parsing and dispatch cost.
SLOW = ("button", "reset")


def _request(rng: random.Random) -> dict[str, Any]:
    cmd = rng.choice(COMMANDS)
    while cmd in SLOW and rng.random() < 0.9:
        cmd = rng.choice(COMMANDS)
    req: dict[str, Any] = {"cmd": cmd}
    if cmd in ("status", "reset", "fault") and rng.random() < 0.7:
        req["device"] = rng.choice(("rover", "node", "agent"))
    if cmd in ("scanner_status", "scanner_fault"):
        req["device"] = rng.choice(("lidar", "ust"))
    if cmd == "fault":
        req["knobs"] = rng.choice(({"drop_rate": 0.0}, {"corrupt_next": 1}, {"stall": 0.0}, {"drop_next": 0}))
    if cmd == "scanner_fault":
        req["knobs"] = rng.choice(({"burst": False}, {"bad_sum_next": 0}, {"stall": 0.0}))
    if cmd == "wait_report":
        req.update(timeout=rng.choice((0, 0.001, 5, 3600)), after=rng.randrange(0, 10))
    if cmd == "dtr":
        req.update(device="lidar", value=rng.random() < 0.5)
    if cmd == "nmt":
        req.update(device="node", state=rng.choice(("operational", "stopped", "pre-operational")))
    if cmd == "bus":
        req["device"] = "node"
    return req


def control_session(rng: random.Random, size: int) -> bytes:
    """What a client of the channel sends over one connection: request lines, one JSON object each."""
    out = bytearray()
    while len(out) < size:
        out += json.dumps(_request(rng)).encode() + b"\n"
    return bytes(out)


class _Session:
    """One client's session: lines cut as the channel's loop cuts them, each answered by the running bench."""

    def __init__(self) -> None:
        from hilbench.bench import control

        self.control = control
        self.server = bench().control
        self.buf = bytearray()
        self.gone = threading.Event()
        self.gone.set()  # the client sent its session and left: waits end at once
        self.ok = 0
        self.bad = 0
        self.watch = TracebackWatch.shared()
        self.watch.clear()

    def _answer(self, line: bytes) -> None:
        with self.control.serving(self.gone):
            reply = json.loads(self.server.reply(line))  # what the client reads must be one JSON object
        if reply.get("ok") is True:
            self.ok += 1
        else:
            assert isinstance(reply.get("error"), str) and "\n" not in reply["error"], reply
            self.bad += 1

    def feed(self, data: bytes) -> None:
        self.buf += data
        while True:
            try:
                line = self.control.next_request(self.buf)
            except self.control.RequestTooLong:
                self.bad += 1
                continue
            if line is None:
                break
            self._answer(line)

    def finish(self) -> None:
        if self.buf.strip():  # a last line without its newline is still a request
            self._answer(bytes(self.buf))
        self.watch.check()

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.bad


CONTROL = FuzzTarget("server-control", "control channel: a client's session of request lines on a running bench",
                        _Session, LINE_RATE, LINE, control_session, kind="server", max_input=1024)


# --------------------------------------------------------------------------- SCIP 2.0 over TCP

#: The unit's TCP port at its busiest: 100 Mbit/s Ethernet.
SCIP_LINE = 100e6 / 8
#: Longest a session may take to reach the unit and end (seconds): beyond it the session counts as failed.
SCIP_SETTLE = 5.0


def scip_session(rng: random.Random, size: int) -> bytes:
    """What hokuyolx and urg_library send a UST-10LX: state, version and parameters, time sync, the laser on,
    single scans, a short continuous run, its stop, now and then a string echoed back or CR LF line ends."""
    lines = [b"%ST", b"VV", b"PP", b"II", b"TM0", b"TM1", b"TM1", b"TM2", b"BM", b"GD0000108000", b"GE0000108001",
             b"GS0540054201", b"MD0000108001003", b"ME0300031000002", b"QT", b"RS", b"SS115200", b"XX"]
    out = bytearray()
    while len(out) < size:
        line = rng.choice(lines)
        if rng.random() < 0.1:
            line += b";" + rng.choice((b"abc", b"hokuyolx", b"x" * 16))
        out += line + rng.choice((b"\n", b"\n", b"\r\n", b"\r"))
    return bytes(out)


class _ScipSession:
    def __init__(self) -> None:
        b = bench()
        ep = b.endpoint("ust")
        self.port, self.unit, self.medium = ep.port, b.device("ust"), ep.medium
        self.watch = TracebackWatch.shared()
        self.watch.clear()
        self.replies = 0
        self.dropped0 = self.unit.decoder.dropped
        self._alive()
        self._wait(lambda: self.port.client is None)  # the unit serves one client: the last one has gone
        self.count = self.port.connections
        self.bytes_in0 = self.port.bytes_in
        self.sent = 0
        self.sock: socket.socket | None = socket.create_connection(self.port.address, timeout=5)
        self._wait(lambda: self.port.connections > self.count)  # accepted (not turned away)
        self.tap = lambda t, source, data: self._tapped(source, data)
        self.medium.add_tap(self.tap)

    def _tapped(self, source: str, data: bytes) -> None:
        if source != self.port.name:
            self.replies += data.count(b"\n\n")

    def _alive(self) -> None:
        thread = getattr(self.medium, "_thread", None)
        if thread is not None and not thread.is_alive():
            raise AssertionError(f"the bench's line thread of {self.port.name!r} has died (an earlier session "
                                 "killed it): the unit answers nobody")

    def _wait(self, condition) -> None:
        deadline = time.monotonic() + SCIP_SETTLE
        while not condition():
            self._alive()
            if time.monotonic() > deadline:
                raise AssertionError(f"the SCIP unit's TCP port did not settle within {SCIP_SETTLE} s")
            time.sleep(0.0001)

    def feed(self, data: bytes) -> None:
        if self.sock is None:
            return
        try:
            self.sock.sendall(data)
            self.sent += len(data)
        except OSError:  # the unit closed the connection: the session ends there
            self.sock.close()
            self.sock = None

    def finish(self) -> None:
        try:
            sent = self.sent
            if self.sock is not None:
                self._wait(lambda: self.port.bytes_in - self.bytes_in0 >= sent or self.port.client is None)
                self.sock.close()
                self.sock = None
            self._wait(lambda: self.port.client is None)
            self.watch.check()
        finally:
            self.medium.remove_tap(self.tap)
            if self.sock is not None:
                self.sock.close()

    def good(self) -> int:
        return self.replies

    def dropped(self) -> int:
        return self.unit.decoder.dropped - self.dropped0


SCIP = FuzzTarget("server-scip", "Hokuyo UST-10LX over TCP: a client's SCIP 2.0 session through the bench's port",
                     _ScipSession, SCIP_LINE, "100 Mbit/s Ethernet", scip_session, kind="server",
                     max_input=1024)

__all__ = ["CONTROL", "PROFILE", "SCIP", "bench", "control_session", "scip_session"]
