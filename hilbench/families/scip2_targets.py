"""The Hokuyo SCIP 2.0 units' servers as fuzz targets (:mod:`hilbench.fuzzing`, kind ``server``).

- ``server-scip``: the UST-10LX on its TCP port, through a running bench's own TCP host port, serial medium
  and unit, in the medium's thread: a client connects (once the unit let the last one go), sends the
  session, leaves; the session ends when the port is free again, everything it sent having reached the
  unit. Each connection starts afresh (a line the last one began is not run). ``good`` counts the
  replies the unit sent, ``dropped`` the request bytes it could not read. A traceback the medium logs
  for the unit counts against the session.
- ``server-control-scip2``: the unit's control commands (:mod:`hilbench.bench.control_targets`), and its
  part of ``server-control``.

(The SCIP reply decoder has its own target, :mod:`hilbench.protocols.scip_targets`.)
"""

from __future__ import annotations

import random
import socket
import time
from typing import Any

from hilbench.bench.control_targets import control_target, running_bench
from hilbench.fuzzing import FuzzTarget, TracebackWatch

#: A UST-10LX on its TCP port, in a room.
PROFILE: dict[str, Any] = {
    "scene": {"walls": [[[-2.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-2.0, 2.0], [-2.0, -2.0]]]},
    "endpoints": {"ust": {"type": "tcp", "protocol": "scip2", "port": 0}},
    "devices": [{"model": "ust-10lx", "name": "ust", "endpoint": "ust", "pose": {"x": 0.5, "y": 0.3}}],
}


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
        b = running_bench("server-scip", PROFILE)
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


SERVER = FuzzTarget("server-scip", "Hokuyo UST-10LX over TCP: a client's SCIP 2.0 session through the bench's "
                     "port", _ScipSession, SCIP_LINE, "100 Mbit/s Ethernet", scip_session, kind="server",
                     max_input=1024)


# --------------------------------------------------------------------------- control channel


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the unit: its state, or a fault knob at its harmless value."""
    req: dict[str, Any] = {"cmd": rng.choice(("scanner_status", "scanner_fault"))}
    if rng.random() < 0.9:
        req["device"] = "ust"
    if req["cmd"] == "scanner_fault":
        req["knobs"] = rng.choice(({"burst": False}, {"bad_sum_next": 0}, {"truncate_next": 0}))
    return req


CONTROL = control_target("scip2", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "SERVER", "request", "scip_session"]
