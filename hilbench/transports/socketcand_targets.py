"""The socketcand daemon as a fuzz target (:mod:`hilbench.fuzzing`, kind ``server``): a client's session.

``server-socketcand`` drives the daemon (:class:`~hilbench.transports.socketcand_server.SocketcandServer`)
through its door interface, as the CAN bus thread drives it: a client connects to its listener on
127.0.0.1, sends the session in writes of at least :data:`~hilbench.fuzzing.SESSION_WRITE` bytes, the door
reads and answers (``read_frames``), the bus echoes each frame it sends back to it as another party's and
runs the door's timed work (``poll``: BCM jobs, statistics, the rawmode delay, on a clock that advances 10 ms
per write), and the client reads what comes. When the client leaves, the door must let it go. One daemon per
process serves session after session, as on a bench. ``good`` counts the frames and replies the client
received, ``dropped`` what the daemon counted as malformed.
"""

from __future__ import annotations

import atexit
import random
import threading
from typing import Any

from hilbench.fuzzing import FuzzTarget, TcpSession, drain
from hilbench.protocols import socketcand as scd
from hilbench.protocols.can_frame import CanFrame
from hilbench.protocols.can_targets import SOCKETCAND_LINE

_lock = threading.Lock()
_server: Any = None


def _frame(rng: random.Random) -> CanFrame:
    extended = rng.random() < 0.3
    dlc = rng.randrange(9)
    return CanFrame(rng.randrange(0x2000_0000 if extended else 0x800), rng.randbytes(dlc), extended, False, False,
                    dlc)


def _ident(frame: CanFrame) -> str:
    return f"{frame.can_id:08X}" if frame.extended else f"{frame.can_id:03X}"


def socketcand_session(rng: random.Random, size: int) -> bytes:
    """A client of the daemon: open the bus (BCM mode: cyclic jobs, subscriptions, content filters), then RAW
    mode and frames, CONTROL mode statistics, an echo now and then, and now and then numbers of hundreds of
    digits (a hostile client's)."""
    out = bytearray(b"< open can0 >")
    mode = "bcm"
    while len(out) < size:
        frame = _frame(rng)
        data = " ".join(f"{b:02X}" for b in frame.data)
        k = rng.random()
        if k < 0.05:
            mode = rng.choice(("raw", "bcm", "control"))
            out += f"< {mode}mode >".encode()
        elif k < 0.08:
            out += b"< echo >"
        elif k < 0.09:  # now and then the numbers a hostile client sends: hundreds of digits
            big = "9" * rng.choice((20, 400))
            out += rng.choice((f"< statistics {big} >", f"< add {big} 0 123 0 >", f"< subscribe 0 {big} 123 >",
                               f"< filter {big} 0 123 1 FF >", f"< add 0 0 {big} 0 >")).encode()
        elif mode == "control":
            out += f"< statistics {rng.choice((0, 100, 1000))} >".encode()
        elif mode == "raw" or k < 0.4:
            out += scd.send_message(frame).encode()
        else:
            sec, usec = rng.randrange(2), rng.randrange(0, 1_000_000, 1000)
            out += rng.choice((
                f"< add {sec} {usec} {_ident(frame)} {frame.length} {data} >",
                f"< update {_ident(frame)} {frame.length} {data} >",
                f"< delete {_ident(frame)} >",
                f"< subscribe {sec} {usec} {_ident(frame)} >",
                f"< unsubscribe {_ident(frame)} >",
                f"< filter {sec} {usec} {_ident(frame)} {frame.length} {data} >",
            )).encode()
    return bytes(out)


def _socketcand_server() -> Any:
    global _server
    from hilbench.transports.socketcand_server import SocketcandServer

    with _lock:
        if _server is None:
            _server = SocketcandServer("fuzz", channel="can0", rawmode_delay=0.05)
            _server.wall_offset = 1_700_000_000.0
            atexit.register(close_server)
        return _server


class _SocketcandSession(TcpSession):
    kept_client = "the socketcand door kept a client that left"

    def __init__(self) -> None:
        self.server = _socketcand_server()
        self.malformed0 = self.server.malformed
        self.now = 0.0
        self._connect(self.server.address)

    def _round(self) -> None:
        server = self.server
        self.now += 0.01
        frames = server.read_frames(self.now)
        frames += server.poll(self.now)
        for source, frame in frames:  # every frame a client sent reaches the others (and this one, from the bus)
            server.write_frame(self.now, source, frame)
            server.write_frame(self.now, "bus", frame)
        server.flush()
        if self.sock is not None:
            self.received += drain(self.sock).count(b">")

    def _client_gone(self) -> bool:
        return not self.server.clients

    def dropped(self) -> int:
        return self.server.malformed - self.malformed0


SOCKETCAND = FuzzTarget("server-socketcand", "socketcand daemon: a client's session (BCM, RAW, CONTROL modes)",
                           _SocketcandSession, SOCKETCAND_LINE, "a saturated 1 Mbit/s bus in socketcand text",
                           socketcand_session, kind="server", max_input=2048)


def close_server() -> None:
    """Close the target's daemon (its listening socket); the next session opens another."""
    global _server
    with _lock:
        if _server is not None:
            _server.close()
            _server = None


__all__ = ["SOCKETCAND", "close_server", "socketcand_session"]
