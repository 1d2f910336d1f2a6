"""The RFC 2217 server as a fuzz target (:mod:`hilbench.fuzzing`, kind ``server``): a pyserial client's session.

``server-rfc2217`` drives an :class:`~hilbench.transports.rfc2217.Rfc2217Port` as a serial medium drives it
(``read`` until it has nothing more, its timers run, the devices' bytes written now and then), with a real
:class:`~hilbench.transports.port_state.PortState` whose events a device would hear. A client connects on
127.0.0.1 and sends the session in writes of at least :data:`~hilbench.fuzzing.SESSION_WRITE` bytes. When the
client leaves, the port must hang up. One port per process serves session after session, as on a bench.
``good`` counts the bytes the client received, ``dropped`` what the port counted as a problem.
"""

from __future__ import annotations

import atexit
import random
import threading
from typing import Any

from hilbench.fuzzing import FuzzTarget, TcpSession, drain
from hilbench.protocols import rfc2217 as p
from hilbench.transports.clock import WALL

#: A pyserial client at 1 Mbaud: what an RFC 2217 session carries at most, in bytes per second.
RFC2217_LINE = 1_000_000 / 10

_lock = threading.Lock()
_server: tuple[Any, Any] | None = None


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
    runs what is due), and port events for the devices (counted)."""

    def __init__(self) -> None:
        self.due: list[Any] = []
        self.events = 0
        self.clock = WALL  # (a medium's clock: the wall clock, its default)

    def call_at(self, t: float | None, fn: Any) -> None:
        self.due.append(fn)

    def run(self) -> None:
        due, self.due = self.due, []
        for fn in due:
            fn()


def _rfc2217_port() -> tuple[Any, _Loop]:
    global _server
    from hilbench.transports.port_state import PortState
    from hilbench.transports.rfc2217 import Rfc2217Port

    with _lock:
        if _server is None:
            loop = _Loop()
            lines = PortState()
            lines.set_listener(lambda event: setattr(loop, "events", loop.events + 1))
            _server = (Rfc2217Port("fuzz:rfc2217", lines, loop, baud=115_200), loop)
            atexit.register(close_server)
        return _server


class _Rfc2217Session(TcpSession):
    kept_client = "the RFC 2217 port kept a client that left"

    def __init__(self) -> None:
        self.port, self.loop = _rfc2217_port()
        self.problems0 = self.port.problems
        self.writes = 0
        self._connect(self.port.address)

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
            self.received += len(drain(self.sock))

    def _client_gone(self) -> bool:
        return self.port.client is None  # the port notices the client left and hangs up

    def dropped(self) -> int:
        return self.port.problems - self.problems0


RFC2217 = FuzzTarget("server-rfc2217", "RFC 2217 server: a pyserial client's session (telnet options, COM-PORT "
                        "commands, data)", _Rfc2217Session, RFC2217_LINE, "a 1 Mbaud serial line",
                        rfc2217_session, kind="server", max_input=2048)


def close_server() -> None:
    """Close the target's port (its listening socket); the next session opens another."""
    global _server
    with _lock:
        if _server is not None:
            _server[0].close()
            _server = None


__all__ = ["RFC2217", "RFC2217_LINE", "close_server", "rfc2217_session"]
