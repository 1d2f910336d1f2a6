"""The bench's TCP servers as rough-input targets (:mod:`hilbench.fuzzing`, kind ``server``): a client's session.

- ``server-socketcand``: the socketcand daemon (:class:`~hilbench.transports.socketcand_server.SocketcandServer`)
  through its door interface, as the CAN bus thread drives it: a client connects to its listener on
  127.0.0.1, sends the session in pieces, the door reads and answers (``read_frames``), the bus echoes
  each frame it sends back to it as another party's and runs the door's timed work (``poll``: BCM jobs,
  statistics, the rawmode delay, on a clock that advances 10 ms per piece), and the client reads what
  comes. When the client leaves, the door must let it go.
- ``server-rfc2217``: an :class:`~hilbench.transports.rfc2217.Rfc2217Port` as a serial medium drives it
  (``read`` until it has nothing more, its timers run, the devices' bytes written now and then), with a
  real :class:`~hilbench.transports.line.LineState` whose events a device would hear. When the client
  leaves, the port must hang up.

One server per target and process, serving session after session, as on a bench. Pieces are coalesced
into writes of at least :data:`WRITE` bytes (the server still meets every split the fuzzer makes at a
write's end, and a session costs a few system calls, not hundreds). ``good`` counts the replies and
frames the client received, ``dropped`` what the server counted as malformed or a problem.
"""

from __future__ import annotations

import contextlib
import random
import socket
import threading
from typing import Any

from hilbench.fuzzing import FuzzTarget, TracebackWatch
from hilbench.protocols import rfc2217 as p
from hilbench.protocols import socketcand as scd
from hilbench.protocols.can_frame import CanFrame
from hilbench.protocols.can_targets import SOCKETCAND_LINE

#: Pieces of a session are sent in writes of at least this many bytes.
WRITE = 512
#: A pyserial client at 1 Mbaud: what an RFC 2217 session carries at most, in bytes per second.
RFC2217_LINE = 1_000_000 / 10

_lock = threading.Lock()
_servers: dict[str, Any] = {}


def _drain(sock: socket.socket) -> bytes:
    out = bytearray()
    while True:
        try:
            chunk = sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            break
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    return bytes(out)


def _client(address: tuple[str, int]) -> socket.socket:
    sock = socket.create_connection(address, timeout=5)
    sock.setblocking(False)
    return sock


def _send(sock: socket.socket, data: bytes) -> bool:
    """Send a write of the session; False once the server closed the connection (the session ends)."""
    view = memoryview(data)
    while view:
        try:
            sent = sock.send(view)
        except (BlockingIOError, InterruptedError):
            return True  # the server stopped reading: the rest is lost, as a client's would be
        except OSError:
            return False
        view = view[sent:]
    return True


# --------------------------------------------------------------------------- socketcand


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
    from hilbench.transports.socketcand_server import SocketcandServer

    with _lock:
        if "socketcand" not in _servers:
            server = SocketcandServer("fuzz", channel="can0", rawmode_delay=0.05)
            server.wall_offset = 1_700_000_000.0
            _servers["socketcand"] = server
        return _servers["socketcand"]


class _SocketcandSession:
    def __init__(self) -> None:
        self.server = _socketcand_server()
        self.watch = TracebackWatch.shared()
        self.watch.clear()
        self.malformed0 = self.server.malformed
        self.now = 0.0
        self.received = 0
        self.pending = bytearray()
        self.sock: socket.socket | None = _client(self.server.address)

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
            self.received += _drain(self.sock).count(b">")

    def _write(self) -> None:
        if self.sock is not None and not _send(self.sock, bytes(self.pending)):
            self.sock.close()
            self.sock = None
        self.pending.clear()
        self._round()

    def feed(self, data: bytes) -> None:
        self.pending += data
        if len(self.pending) >= WRITE:
            self._write()

    def finish(self) -> None:
        try:
            self._write()
            if self.sock is not None:
                self.sock.close()
                self.sock = None
            for _ in range(20):  # the door notices the client left within a few rounds
                self._round()
                if not self.server.clients:
                    break
            assert not self.server.clients, "the socketcand door kept a client that left"
            self.watch.check()
        finally:
            if self.sock is not None:
                self.sock.close()

    def good(self) -> int:
        return self.received

    def dropped(self) -> int:
        return self.server.malformed - self.malformed0


SOCKETCAND = FuzzTarget("server-socketcand", "socketcand daemon: a client's session (BCM, RAW, CONTROL modes)",
                           _SocketcandSession, SOCKETCAND_LINE, "a saturated 1 Mbit/s bus in socketcand text",
                           socketcand_session, kind="server", max_input=2048)


# --------------------------------------------------------------------------- RFC 2217


def rfc2217_session(rng: random.Random, size: int) -> bytes:
    """What pyserial's ``rfc2217://`` client sends: option negotiation, the line's settings and modem lines,
    then data (0xFF escaped) among flow control, purges, modem-state polls, a BREAK and an AYT now and then."""
    C, K = p.Command, p.Control
    out = bytearray()
    for verb, option in ((p.WILL, p.BINARY), (p.DO, p.BINARY), (p.WILL, p.SGA), (p.DO, p.SGA),
                         (p.WILL, p.COM_PORT_OPTION), (p.DO, p.COM_PORT_OPTION)):
        out += p.negotiation(verb, option)
    out += p.subnegotiation(C.SET_BAUDRATE, p.build_value(C.SET_BAUDRATE, rng.choice((9600, 115_200, 1_000_000))))
    out += p.subnegotiation(C.SET_DATASIZE, b"\x08") + p.subnegotiation(C.SET_PARITY, b"\x01")
    out += p.subnegotiation(C.SET_STOPSIZE, b"\x01") + p.subnegotiation(C.SET_CONTROL, bytes((K.FLOW_NONE,)))
    out += p.subnegotiation(C.SET_CONTROL, bytes((K.DTR_ON,))) + p.subnegotiation(C.SET_CONTROL, bytes((K.RTS_ON,)))
    out += p.subnegotiation(C.PURGE_DATA, bytes((p.Purge.BOTH,)))
    while len(out) < size:
        k = rng.random()
        if k < 0.7:
            out += p.escape(rng.randbytes(rng.randrange(1, 64)))
        elif k < 0.8:
            out += p.subnegotiation(C.SET_CONTROL, bytes((rng.choice(list(K)),)))
        elif k < 0.85:
            out += p.subnegotiation(C.NOTIFY_MODEMSTATE)
        elif k < 0.9:
            out += p.subnegotiation(rng.choice((C.FLOWCONTROL_SUSPEND, C.FLOWCONTROL_RESUME)))
        elif k < 0.93:
            out += p.subnegotiation(C.SIGNATURE)
        elif k < 0.96:
            out += p.subnegotiation(C.SET_BAUDRATE, p.build_value(C.SET_BAUDRATE, rng.choice((57600, 115_200))))
        else:
            out += bytes((p.IAC, rng.choice((p.AYT, p.BRK, p.NOP))))
    return bytes(out)


class _Loop:
    """What the port needs of its medium: timers (run by the session after each round, as the line's thread
    runs what is due), and line events for the devices (counted)."""

    def __init__(self) -> None:
        self.due: list[Any] = []
        self.events = 0

    def call_at(self, t: float | None, fn: Any) -> None:
        self.due.append(fn)

    def run(self) -> None:
        due, self.due = self.due, []
        for fn in due:
            fn()


def _rfc2217_port() -> Any:
    from hilbench.transports.line import LineState
    from hilbench.transports.rfc2217 import Rfc2217Port

    with _lock:
        if "rfc2217" not in _servers:
            loop = _Loop()
            lines = LineState()
            lines.set_listener(lambda event: setattr(loop, "events", loop.events + 1))
            _servers["rfc2217"] = (Rfc2217Port("fuzz:rfc2217", lines, loop, baud=115_200), loop)
        return _servers["rfc2217"]


class _Rfc2217Session:
    def __init__(self) -> None:
        self.port, self.loop = _rfc2217_port()
        self.watch = TracebackWatch.shared()
        self.watch.clear()
        self.problems0 = self.port.problems
        self.received = 0
        self.pending = bytearray()
        self.writes = 0
        self.sock: socket.socket | None = _client(self.port.address)

    def _round(self) -> None:
        port = self.port
        for _ in range(64):  # read() hands over one run of data at a time (b"": nothing more for now)
            data = port.read()
            self.loop.run()
            if not data:
                break
        self.writes += 1
        if self.writes % 3 == 0:
            port.write(b"device \xff bytes\r\n")  # what the devices answer, 0xFF and all
        self.loop.run()
        if self.sock is not None:
            self.received += len(_drain(self.sock))

    def _write(self) -> None:
        if self.sock is not None and not _send(self.sock, bytes(self.pending)):
            self.sock.close()
            self.sock = None
        self.pending.clear()
        self._round()

    def feed(self, data: bytes) -> None:
        self.pending += data
        if len(self.pending) >= WRITE:
            self._write()

    def finish(self) -> None:
        try:
            self._write()
            if self.sock is not None:
                self.sock.close()
                self.sock = None
            for _ in range(20):  # the port notices the client left and hangs up
                self._round()
                if self.port.client is None:
                    break
            assert self.port.client is None, "the RFC 2217 port kept a client that left"
            self.watch.check()
        finally:
            if self.sock is not None:
                self.sock.close()

    def good(self) -> int:
        return self.received

    def dropped(self) -> int:
        return self.port.problems - self.problems0


RFC2217 = FuzzTarget("server-rfc2217", "RFC 2217 server: a pyserial client's session (telnet options, COM-PORT "
                        "commands, data)", _Rfc2217Session, RFC2217_LINE, "a 1 Mbaud serial line",
                        rfc2217_session, kind="server", max_input=2048)


def close_servers() -> None:
    """Close the targets' servers (their listening sockets)."""
    with _lock:
        for server in _servers.values():
            with contextlib.suppress(Exception):
                (server[0] if isinstance(server, tuple) else server).close()
        _servers.clear()


__all__ = ["RFC2217", "SOCKETCAND", "close_servers", "rfc2217_session", "socketcand_session"]
