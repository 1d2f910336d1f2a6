"""The control channel: commands to a running bench's devices from another process.

``hilbench emulate`` serves it on 127.0.0.1 (a free port, listed in the
manifest as ``"control": "127.0.0.1:PORT"``). The protocol is one JSON object
per line each way::

    -> {"cmd": "button", "device": "rover"}
    <- {"ok": true, "status": {...}}

The bench answers ``devices`` (each device that takes commands, with them, and
each endpoint whose bus does, under ``endpoints``),
``taps`` (each endpoint's traffic tap: its clients, limits and what it dropped),
``media`` (each endpoint's line or bus: kind, paced, what its thread is scheduled
under and its counters, e.g. how late a paced serial line handed transmissions
over against its wire model; ``host``: the host port's own, e.g. a socketcand
server's clients and what it refused or dropped),
``servers`` (each endpoint's network servers, e.g. RFC 2217, with their
client and counters), ``control`` (this channel's limits and counters), ``overflow`` (every bounded queue's
limits and what it refused, evicted, dropped, stalled on or timed out: the channel's and, per endpoint, its
tap's, its doors', its servers' and its devices' (:mod:`hilbench.bench.overflow`); ``endpoint``: only that
one's; every ``status`` reply carries it too, under ``overflow``), ``clock`` (the bench's clock:
virtual or not, its time, and with virtual time the lockstep counters: stalls, ``stalled_s``,
``last_stall``, client threads), ``manifest`` (the bench's
manifest, for programs that reach the bench only through this channel, e.g. over labgrid),
``world`` (the truth: every body's pose and velocity, each device's body and pose, as ``hilbench world
--json`` prints it), ``world_place`` (put a body somewhere: ``body``, ``x``, ``y``, ``theta``) and
``world_slip`` (the share of a driven body's wheel motion lost on the floor from now on: ``body``, ``slip``);
every other command belongs to a device's family
(:attr:`~hilbench.bench.family.DeviceFamily.control_commands`), e.g. the rover
board's ``status``, ``button``, ``reset``, ``fault``, ``log`` and
``wait_report``, or to an endpoint's bus kind
(:attr:`~hilbench.bench.bus.BusKind.control_commands`, e.g. a CAN bus's
``bus``, addressed with ``"endpoint": NAME`` or a device on it). ``device``
(``endpoint``) may be left out when one device (one endpoint) answers the
command. Errors come back as ``{"ok": false, "error": "...", "exit": N}``,
malformed requests included (``exit``: 2 for a request the bench cannot do as
asked, such as an unknown device or a knob out of range, 1 when the bench or
device failed, as :mod:`hilbench.errors`' rule says; the client raises a
:class:`ControlError` with that exit status), and nothing a client sends (or a
client leaving early) puts a traceback on the bench's stderr.

Many clients are served at once by one thread that waits on every socket
(epoll) and starts a thread per command, so no client can hold up another:

- a request line is at most :data:`MAX_LINE` bytes and JSON nested at most
  :data:`MAX_DEPTH` levels;
- a request line must arrive whole within :data:`REQUEST_TIMEOUT` s of its
  first byte, and a reply must be taken within as long, or the connection is
  closed (a client that stalls halfway holds nothing);
- a connection with nothing to do for :data:`IDLE_TIMEOUT` s is closed;
- at most :data:`MAX_CLIENTS` connections are kept: a newcomer beyond that
  closes the connection that has been waiting longest without a command
  running (it is told so in a JSON error line), and is itself refused with
  ``{"ok": false, "error": "too many control clients ..."}`` only when every
  kept connection is running a command;
- a command that waits (``wait_report``) ends when its client closes the
  connection (:func:`client_waits`);
- the kernel's queue of connections not yet accepted holds :data:`BACKLOG`.

:class:`ControlClient` is the Python side; ``hilbench board`` a command line.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import errno
import json
import os
import re
import selectors
import socket
import threading
import time
from collections.abc import Callable
from itertools import accumulate
from pathlib import Path
from typing import Any

from hilbench.errors import BenchError, HilbenchError
from hilbench.transports.listener import listen
from hilbench.transports.medium import medium_timing
from hilbench.transports.medium_loop import WakePipe

#: Longest request line the bench reads (bytes); longer ones are answered with an error and dropped.
MAX_LINE = 65536
#: Longest reply a client reads (a status with the board's log is a few kB).
MAX_REPLY = 16 << 20
#: Deepest nesting of arrays and objects a request may have.
MAX_DEPTH = 32
#: Connections kept at once (each may run one command); see the module docstring for who gives way.
MAX_CLIENTS = 64
#: Seconds a request line may take to arrive whole (from its first byte), and a reply to be taken.
REQUEST_TIMEOUT = 10.0
#: A connection with no request, command or reply under way for this long is closed (seconds).
IDLE_TIMEOUT = 300.0
#: Kernel send buffer of a control connection (bytes): bounds what a client that never reads costs.
SEND_BUFFER = 64 << 10
#: Connections the kernel queues before the server accepts them (``listen()``; capped by somaxconn).
BACKLOG = 1024

#: What every bench answers, whatever its devices.
BENCH_COMMANDS = ("control", "devices", "manifest", "media", "overflow", "servers", "taps", "world", "world_place",
                  "world_slip")

_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')
_NESTING = bytes.maketrans(b"[{]}", b"\x01\x01\x02\x02")


def nesting(raw: bytes) -> int:
    """How deeply the arrays and objects of a JSON text nest (strings do not count); linear time."""
    opened = _JSON_STRING.sub(b"", raw).translate(_NESTING)
    steps = (1 if c == 1 else -1 for c in opened if c in (1, 2))
    return max(accumulate(steps, initial=0))


class ControlError(BenchError):
    """The bench refused or failed a command (one line)."""


class ControlUnreachable(ControlError):
    """No bench answered at the control address (refused, closed, not JSON): exit status 1."""


class ControlRequestError(ControlError):
    """A request the bench cannot do as asked (unknown command or device, a bad argument): exit status 2."""

    exit_code = 2


class ClientGone(ControlError):
    """The client of a running command closed its connection: the command stops (nobody reads its reply)."""


class RequestTooLong(ControlError):
    """:data:`MAX_LINE` bytes arrived without a newline."""


_request = threading.local()  # .gone: the threading.Event of the connection whose command this thread runs


@contextlib.contextmanager
def serving(gone: threading.Event):
    """Run commands (:meth:`ControlServer.handle`) in this thread for a connection whose client is gone once
    ``gone`` is set: :func:`client_waits` then stops waiting."""
    _request.gone = gone
    try:
        yield
    finally:
        _request.gone = None


def next_request(buf: bytearray) -> bytes | None:
    """Take the next request line (up to and with its newline) from a connection's input ``buf``; None while
    it is still arriving. :class:`RequestTooLong` (and ``buf`` emptied) when :data:`MAX_LINE` bytes hold none."""
    end = buf.find(b"\n", 0, MAX_LINE)
    if end < 0:
        if len(buf) >= MAX_LINE:
            buf.clear()
            raise RequestTooLong(f"request too long (at most {MAX_LINE} bytes)")
        return None
    line = bytes(buf[:end + 1])
    del buf[:end + 1]
    return line


def client_waits(done: Callable[[], bool], timeout: float, poll: float = 0.01) -> bool:
    """Wait up to ``timeout`` s, checking ``done()`` every ``poll`` s; True once it is true, False at the timeout.

    A family command that waits (``wait_report``) waits with this, so it ends when the client that asked
    closes its connection: then it raises :class:`ClientGone`. Called outside a control connection (a test
    calling :meth:`ControlServer.handle`) it only waits.
    """
    gone: threading.Event | None = getattr(_request, "gone", None)
    deadline = time.monotonic() + timeout
    while not done():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        if gone is None:
            time.sleep(min(poll, left))
        elif gone.wait(min(poll, left)):
            raise ClientGone("the control client left")
    return True


class _Conn:
    """One control connection as the server's loop keeps it."""

    __slots__ = ("sock", "fd", "inbuf", "out", "busy", "gone", "last", "started", "out_since", "closing", "events")

    def __init__(self, sock: socket.socket, now: float) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.inbuf = bytearray()  # received, not yet taken as a request (bounded: see _read)
        self.out = bytearray()  # one reply (or error line) not yet sent
        self.busy = False  # a command of this connection is running
        self.gone = threading.Event()  # the client closed while its command ran: the command may stop
        self.last = now  # last sign of life (bytes in, a reply taken, the connection made)
        self.started: float | None = None  # first byte of the request line still arriving
        self.out_since: float | None = None  # when self.out started waiting for the client
        self.closing = False  # close once self.out is sent
        self.events = selectors.EVENT_READ


def _refusal(text: str) -> bytes:
    return (json.dumps({"ok": False, "error": text}) + "\n").encode()


class ControlServer:
    """Serves the control channel of a running bench in a background thread.

    :data:`BENCH_COMMANDS` are the bench's own commands; every other command
    goes to the family of the device it names (or of the only device whose
    family answers it): :attr:`DeviceFamily.control_commands`, or to the bus
    kind of the endpoint it names (:attr:`BusKind.control_commands`). The limits
    (clients, timeouts) are the module's constants unless given here.
    """

    def __init__(self, bench, host: str = "127.0.0.1", port: int = 0, *, max_clients: int = MAX_CLIENTS,
                 request_timeout: float = REQUEST_TIMEOUT, idle_timeout: float = IDLE_TIMEOUT) -> None:
        self.bench = bench
        self.max_clients = max_clients
        self.request_timeout = request_timeout
        self.idle_timeout = idle_timeout
        #: What the channel did: connections accepted, requests answered, and every connection it
        #: closed or turned away, by reason (``control`` command: ``{"control": {...}}``).
        self.stats: dict[str, int] = dict.fromkeys((
            "connections", "requests", "refused", "evicted", "request_timeouts", "reply_timeouts", "idle_closed",
            "too_long", "clients_gone", "accept_errors", "errors"), 0)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = listen(host, port, BACKLOG, family)
        self._sel = selectors.DefaultSelector()
        self._wake = WakePipe()
        self._conns: dict[int, _Conn] = {}
        self._done: collections.deque[tuple[_Conn, bytes]] = collections.deque()
        self._stop = False
        self._listening = True
        self._listen_again = 0.0
        self._reserve: int | None = self._open_reserve()
        self._sel.register(self._listener, selectors.EVENT_READ, None)
        self._sel.register(self._wake.fd, selectors.EVENT_READ, "wake")
        self._thread = threading.Thread(target=self._loop, name="hilbench-control", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self._listener.getsockname()[:2]

    @property
    def address_text(self) -> str:
        host, port = self.address
        return f"{host}:{port}"

    @property
    def clients(self) -> int:
        """Connections kept now."""
        return len(self._conns)

    def status(self) -> dict[str, Any]:
        """The channel's limits, its connections now and :attr:`stats` (the ``control`` command)."""
        return {"address": self.address_text, "clients": len(self._conns),
                "running": sum(c.busy for c in list(self._conns.values())), "max_clients": self.max_clients,
                "request_timeout": self.request_timeout, "idle_timeout": self.idle_timeout, **self.stats}

    def limits(self) -> dict[str, Any]:
        """The channel's bounds (see the module docstring), for the manifest (``control_limits``)."""
        return {"max_clients": self.max_clients, "max_line": MAX_LINE, "max_depth": MAX_DEPTH,
                "request_timeout": self.request_timeout, "idle_timeout": self.idle_timeout, "backlog": BACKLOG,
                "send_buffer": SEND_BUFFER}

    def close(self) -> None:
        """Stop serving: running commands are told their clients are gone, every connection is closed."""
        self._stop = True
        self._wake.wake()
        self._thread.join(timeout=5)
        for conn in list(self._conns.values()):
            conn.gone.set()
            with contextlib.suppress(OSError):
                conn.sock.close()
        self._conns.clear()
        with contextlib.suppress(OSError):
            self._listener.close()
        self._sel.close()
        self._wake.close()
        if self._reserve is not None:
            with contextlib.suppress(OSError):
                os.close(self._reserve)
            self._reserve = None

    # ------------------------------------------------------------------ the connections' loop

    def _loop(self) -> None:
        while not self._stop:
            try:
                ready = self._sel.select(self._timeout())
            except OSError:  # (closed under us)
                return
            for key, mask in ready:
                if self._stop:
                    return
                if key.data is None:
                    self._accept()
                elif key.data == "wake":
                    self._wake.drain()
                else:
                    conn = key.data
                    if self._conns.get(conn.fd) is not conn:
                        continue  # closed by an earlier event of this round
                    try:
                        if mask & selectors.EVENT_WRITE:
                            self._write(conn)
                        if mask & selectors.EVENT_READ and self._conns.get(conn.fd) is conn:
                            self._read(conn)
                    except Exception:  # noqa: BLE001 (a bug must cost one connection, never the channel)
                        self.stats["errors"] += 1
                        self._close(conn)
            self._finish_commands()
            self._expire(time.monotonic())

    def _timeout(self) -> float | None:
        """Seconds until the next deadline (None: none)."""
        now = time.monotonic()
        times = [] if self._listening else [self._listen_again]
        for c in self._conns.values():
            if c.busy:
                continue
            if c.out_since is not None:
                times.append(c.out_since + self.request_timeout)
            elif c.started is not None:
                times.append(c.started + self.request_timeout)
            else:
                times.append(c.last + self.idle_timeout)
        return max(0.0, min(times) - now) if times else None

    def _want(self, conn: _Conn, events: int) -> None:
        """Wait for these events on the connection (0: none for now)."""
        if events == conn.events:
            return
        if not conn.events:
            self._sel.register(conn.sock, events, conn)
        elif not events:
            self._sel.unregister(conn.sock)
        else:
            self._sel.modify(conn.sock, events, conn)
        conn.events = events

    # ------------------------------------------------------------------ accepting

    @staticmethod
    def _open_reserve() -> int | None:
        """A descriptor kept spare, so a full descriptor table still lets us answer and close a newcomer."""
        try:
            return os.open(os.devnull, os.O_RDONLY)
        except OSError:
            return None

    def _accept(self) -> None:
        while True:
            try:
                sock, _addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.stats["accept_errors"] += 1
                if exc.errno in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM):
                    self._shed()
                return
            self._admit(sock)

    def _shed(self) -> None:
        """Out of descriptors: answer the waiting newcomer through the spare descriptor, or stop listening a
        moment (the listener stays readable, and waiting on it would spin)."""
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None
            try:
                sock, _addr = self._listener.accept()
            except OSError:
                sock = None
            if sock is not None:
                self.stats["refused"] += 1
                self._turn_away(sock, "too many control clients (the bench is out of file descriptors)")
            self._reserve = self._open_reserve()
        if self._reserve is None and self._listening:
            self._listening = False
            self._listen_again = time.monotonic() + 0.1
            self._sel.unregister(self._listener)

    def _admit(self, sock: socket.socket) -> None:
        self.stats["connections"] += 1
        sock.setblocking(False)
        # What the kernel holds for a client that does not read: replies are small, the default grows to MBs.
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        if len(self._conns) >= self.max_clients:
            idle = [c for c in self._conns.values() if not c.busy]
            if not idle:
                self.stats["refused"] += 1
                self._turn_away(sock, f"too many control clients (at most {self.max_clients}, all running commands)")
                return
            oldest = min(idle, key=lambda c: c.last)
            self.stats["evicted"] += 1
            self._send_and_close(oldest, f"connection closed: the bench keeps at most {self.max_clients} control "
                                         "clients and this one had waited longest")
        now = time.monotonic()
        conn = _Conn(sock, now)
        self._conns[conn.fd] = conn
        self._sel.register(sock, selectors.EVENT_READ, conn)

    @staticmethod
    def _turn_away(sock: socket.socket, text: str) -> None:
        """A one-line JSON error to a connection we do not keep, then close it."""
        with contextlib.suppress(OSError):
            sock.setblocking(False)
            with contextlib.suppress(OSError):
                sock.recv(MAX_LINE)  # what it sent already: closing over unread bytes would reset the connection
            sock.send(_refusal(text))
            sock.shutdown(socket.SHUT_WR)
        with contextlib.suppress(OSError):
            sock.close()

    def _send_and_close(self, conn: _Conn, text: str) -> None:
        self._forget(conn)
        self._turn_away(conn.sock, text)

    # ------------------------------------------------------------------ requests and replies

    def _read(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:  # reset
            data = b""
        now = time.monotonic()
        if not data:
            if conn.busy:  # its command may stop; the reply still goes out if it comes (a half-closed client)
                self.stats["clients_gone"] += 1
                conn.gone.set()
                conn.closing = True
                self._want(conn, 0 if not conn.out else selectors.EVENT_WRITE)
                return
            if conn.inbuf.strip() and not conn.out:  # a last request without its newline
                conn.closing = True
                self._want(conn, 0)
                self._start(conn, bytes(conn.inbuf), now)
                conn.inbuf.clear()
                return
            self._close(conn)
            return
        conn.last = now
        if conn.started is None:
            conn.started = now
        conn.inbuf += data
        self._next(conn, now)

    def _next(self, conn: _Conn, now: float) -> None:
        """Take the next request line of a connection with nothing running and nothing to send."""
        if conn.busy or conn.out:
            # Pipelined requests wait; the connection is not read further than one whole line meanwhile.
            if len(conn.inbuf) > MAX_LINE and conn.events & selectors.EVENT_READ:
                self._want(conn, conn.events & ~selectors.EVENT_READ)
            return
        try:
            line = next_request(conn.inbuf)
        except RequestTooLong as exc:
            self.stats["too_long"] += 1
            conn.closing = True  # the rest of that line is not worth reading
            self._reply(conn, _refusal(str(exc)), now)
            return
        if line is None:
            if not conn.inbuf:
                conn.started = None
            if not conn.events & selectors.EVENT_READ and not conn.closing:
                self._want(conn, selectors.EVENT_READ)
            return
        conn.started = now if conn.inbuf else None
        self._start(conn, line, now)

    def _start(self, conn: _Conn, line: bytes, now: float) -> None:
        conn.busy = True
        conn.last = now
        try:
            threading.Thread(target=self._run, args=(conn, line), name="hilbench-control-command",
                             daemon=True).start()
        except RuntimeError:  # no thread to be had
            conn.busy = False
            self._reply(conn, _refusal("the bench cannot start a thread for this command now"), now)

    def _run(self, conn: _Conn, line: bytes) -> None:
        """One command, in a thread of its own; the reply goes back to the loop."""
        try:
            with serving(conn.gone):
                reply = self.reply(line)
        except BaseException:  # noqa: BLE001 (reply() never raises; this keeps the connection's state sane)
            reply = _refusal("command failed")
        # (sent even to a client that closed its side: one that only half-closed still reads it)
        self._done.append((conn, reply))
        self._wake.wake()

    def _finish_commands(self) -> None:
        now = time.monotonic()
        while self._done:
            conn, reply = self._done.popleft()
            conn.busy = False
            conn.last = now
            if self._conns.get(conn.fd) is not conn:
                continue  # closed meanwhile
            self.stats["requests"] += 1
            self._reply(conn, reply, now)

    def _reply(self, conn: _Conn, data: bytes, now: float) -> None:
        conn.out += data
        conn.out_since = now
        self._write(conn)

    def _write(self, conn: _Conn) -> None:
        if conn.out:
            try:
                sent = conn.sock.send(conn.out)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError:
                self._close(conn)
                return
            del conn.out[:sent]
        now = time.monotonic()
        if conn.out:
            self._want(conn, (conn.events | selectors.EVENT_WRITE) if not conn.closing else selectors.EVENT_WRITE)
            return
        conn.out_since = None
        conn.last = now
        if conn.closing:
            if not conn.busy:
                self._close(conn)
            return
        self._want(conn, selectors.EVENT_READ)
        self._next(conn, now)

    def _expire(self, now: float) -> None:
        if not self._listening and now >= self._listen_again:
            self._listening = True
            self._sel.register(self._listener, selectors.EVENT_READ, None)
            if self._reserve is None:
                self._reserve = self._open_reserve()
        for conn in list(self._conns.values()):
            if conn.busy:
                continue
            if conn.out_since is not None:
                if now - conn.out_since >= self.request_timeout:
                    self.stats["reply_timeouts"] += 1  # it does not read: nothing more to tell it
                    self._close(conn)
            elif conn.started is not None:
                if now - conn.started >= self.request_timeout:
                    self.stats["request_timeouts"] += 1
                    self._send_and_close(conn, f"request timed out (a request line must arrive within "
                                               f"{self.request_timeout:g} s)")
            elif now - conn.last >= self.idle_timeout:
                self.stats["idle_closed"] += 1
                self._close(conn)

    def _forget(self, conn: _Conn) -> None:
        if self._conns.get(conn.fd) is conn:
            del self._conns[conn.fd]
            if conn.events:
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._sel.unregister(conn.sock)
                conn.events = 0
        conn.gone.set()  # (a command still running for it may stop)

    def _close(self, conn: _Conn) -> None:
        self._forget(conn)
        with contextlib.suppress(OSError):
            conn.sock.close()

    # ------------------------------------------------------------------ commands

    def reply(self, raw: bytes) -> bytes:
        """The reply line to one request line, as the channel sends it; never raises."""
        answer = self.handle(raw)
        try:
            return (json.dumps(answer, default=str) + "\n").encode()
        except (ValueError, TypeError, RecursionError) as exc:
            return _refusal(f"command failed: its reply is not JSON ({exc})")

    def handle(self, raw: bytes) -> dict[str, Any]:
        """The reply to one request line; never raises (a malformed request gets an error reply)."""
        try:
            if nesting(raw) > MAX_DEPTH:
                raise ControlRequestError(f"request nested too deeply (at most {MAX_DEPTH} levels)")
            try:
                req = json.loads(raw)
            except (ValueError, RecursionError):  # UnicodeDecodeError is a ValueError
                raise ControlRequestError("request is not JSON (one object per line)") from None
            if not isinstance(req, dict):
                raise ControlRequestError("expected a JSON object")
            return {"ok": True, **self._dispatch(req)}
        except HilbenchError as exc:  # ControlError and the rules' one-line errors (their exit status too)
            return {"ok": False, "error": str(exc), "exit": exc.exit_code}
        except Exception as exc:  # noqa: BLE001 (a command that broke must not break the channel)
            return {"ok": False, "error": f"command failed: {type(exc).__name__}: {exc}"}

    def _commands(self) -> dict[str, list[str]]:
        """Device name -> the control commands its family answers."""
        out = {}
        for ep in self.bench.endpoints.values():
            for name in ep.devices:
                commands = self.bench.family_of(name).control_commands
                if commands:
                    out[name] = list(commands)
        return out

    def _bus_commands(self) -> dict[str, list[str]]:
        """Endpoint name -> the control commands its bus kind answers."""
        return {ep.name: list(ep.bus_kind.control_commands) for ep in self.bench.endpoints.values()
                if ep.bus_kind.control_commands}

    def _endpoint(self, cmd: str, req: dict[str, Any]):
        """The endpoint a bus command is for: named (``endpoint``), the endpoint of the named ``device``, or
        the only one whose bus answers ``cmd``."""
        able = sorted(n for n, cmds in self._bus_commands().items() if cmd in cmds)
        name = req.get("endpoint")
        if name is not None and not isinstance(name, str):
            raise ControlRequestError(f"endpoint: expected an endpoint name, got {name!r:.40}")
        device = req.get("device")
        if name is None and isinstance(device, str):
            name = next((ep.name for ep in self.bench.endpoints.values() if device in ep.devices), None)
            if name is None:
                raise ControlRequestError(f"no device named {device!r} (endpoints answering {cmd!r}: "
                                          f"{', '.join(able) or 'none'})")
        if name is None:
            if len(able) != 1:
                raise ControlRequestError(f"name an endpoint: the bench has {', '.join(able)} answering {cmd!r}")
            name = able[0]
        if name not in able:
            raise ControlRequestError(f"endpoint {name!r} has no command {cmd!r} (endpoints answering it: "
                                      f"{', '.join(able) or 'none'})")
        return self.bench.endpoints[name]

    def _device(self, cmd: str, req: dict[str, Any]):
        commands = self._commands()
        able = sorted(n for n, cmds in commands.items() if cmd in cmds)
        name = req.get("device")
        if name is not None and not isinstance(name, str):
            raise ControlRequestError(f"device: expected a device name, got {name!r:.40}")
        if name is None:
            if len(able) != 1:
                if not able:
                    known = sorted({c for cmds in commands.values() for c in cmds} | set(BENCH_COMMANDS)
                                   | {c for cmds in self._bus_commands().values() for c in cmds})
                    raise ControlRequestError(f"unknown command {cmd!r} (expected {', '.join(known)})")
                raise ControlRequestError(f"name a device: the bench has {', '.join(able)} answering {cmd!r}")
            name = able[0]
        if name not in able:
            family = self.bench.family_of(name) if name in self.bench.devices else None
            if family is not None and family.control_commands:
                raise ControlRequestError(f"{name} ({family.name}) has no command {cmd!r} "
                                          f"(expected {', '.join(family.control_commands)})")
            word = self._word(cmd)
            raise ControlRequestError(f"no {word} named {name!r} ({word}s: {', '.join(able) or 'none'})")
        return name, self.bench.devices[name], self.bench.family_of(name)

    def _word(self, cmd: str) -> str:
        """How the devices answering ``cmd`` are called (a family's device word, e.g. "board")."""
        families = {self.bench.family_of(n) for ep in self.bench.endpoints.values() for n in ep.devices}
        words = {f.device_word for f in families if cmd in f.control_commands}
        return words.pop() if len(words) == 1 else "device"

    def _dispatch(self, req: dict[str, Any]) -> dict[str, Any]:
        cmd = req.get("cmd")
        if not isinstance(cmd, str):
            raise ControlRequestError("expected {\"cmd\": NAME, ...}")
        if cmd == "devices":
            return {"devices": self._commands(), "endpoints": self._bus_commands()}
        if cmd == "servers":
            return {"servers": {ep.name: {name: service.status() if hasattr(service, "status") else service.describe()
                                          for name, service in ep.services.items()}
                                for ep in self.bench.endpoints.values() if ep.services}}
        if cmd == "manifest":
            return {"manifest": self.bench.manifest()}
        if cmd == "media":
            return {"media": {ep.name: {**medium_status(ep.medium),
                                        **({"host": ep.port.status()} if hasattr(ep.port, "status") else {})}
                              for ep in self.bench.endpoints.values() if ep.medium is not None}}
        if cmd == "control":
            return {"control": self.status()}
        if cmd == "overflow":
            return {"overflow": self._overflow(req)}
        if cmd == "clock":
            return {"clock": clock_status(self.bench)}
        if cmd == "taps":
            return {"taps": {ep.name: {"url": ep.tap.url, **ep.tap.status()}
                             for ep in self.bench.endpoints.values() if ep.tap is not None}}
        if cmd in ("world", "world_place", "world_slip"):
            from hilbench.bench import world

            return world.control(self.bench, cmd, req)
        if any(cmd in c for c in self._bus_commands().values()) and (
                "endpoint" in req or not any(cmd in c for c in self._commands().values())):
            ep = self._endpoint(cmd, req)
            return ep.bus_kind.control(self.bench, ep, cmd, req)
        if cmd == "status" and not any("status" in c for c in self._commands().values()):
            return {"overflow": self._overflow({})}  # a bench whose devices have no status: the bench's own
        _name, device, family = self._device(cmd, req)
        answer = family.control(self.bench, device, cmd, req)
        if cmd == "status":  # the device's, and the whole bench's overflow counters (its keys stay as they are)
            answer = {**answer, "overflow": self._overflow({})}
        return answer

    def _overflow(self, req: dict[str, Any]) -> dict[str, Any]:
        """Limits and overflow counters of the channel and each endpoint's servers (``endpoint``: only its)."""
        from hilbench.bench.overflow import overflow

        name = req.get("endpoint")
        if name is not None and (not isinstance(name, str) or name not in self.bench.endpoints):
            raise ControlRequestError(f"no endpoint named {name!r:.40} (endpoints: "
                                      f"{', '.join(self.bench.endpoints) or 'none'})")
        return overflow(self.bench, name)


def clock_status(bench: Any) -> dict[str, Any]:
    """The bench's clock for ``clock``: virtual or not, now, and the lockstep's counters (virtual time)."""
    clock = bench.clock
    out: dict[str, Any] = {"virtual": clock.virtual, "now": clock.now()}
    lockstep = bench.services.get("clock")
    if lockstep is not None:
        out.update(lockstep.describe())
    if bench.loop is not None:
        out["mode"] = bench.loop.mode
        out["loop"] = dataclasses.asdict(bench.loop.stats)
    return out


def medium_status(medium: Any) -> dict[str, Any]:
    """A line's or bus's kind, pacing, scheduling and counters (its ``stats`` dataclass), for ``media``.

    The counters are read while the medium's thread runs: each field is one consistent value, the whole
    is not an atomic snapshot (a dict the thread grows meanwhile is copied again)."""
    stats: dict[str, Any] = {}
    counters = getattr(medium, "stats", None)  # (a plug-in's medium may keep none)
    for f in dataclasses.fields(counters) if dataclasses.is_dataclass(counters) else ():
        value = getattr(counters, f.name)
        for _ in range(5):
            try:
                stats[f.name] = dict(value) if isinstance(value, dict) else value
                break
            except RuntimeError:  # the line thread added a key while we copied
                continue
    return {"kind": getattr(medium, "kind", None), "paced": getattr(medium, "paced", False),
            "scheduling": None, **medium_timing(medium), "stats": stats}


class ControlClient:
    """Talks to a bench's control channel (``host:port``, or the manifest that lists it).

    :meth:`call` sends any command; families add clients with named methods
    (:class:`hilbench.clients.stm32_rover.BoardClient`: ``button()``, ``status()``, ...).
    """

    def __init__(self, address: str | tuple[str, int], timeout: float = 10.0) -> None:
        if isinstance(address, str):
            host, _, port = address.rpartition(":")
            if not host or not port.isdigit():
                raise ControlRequestError(f"expected HOST:PORT, got {address!r}")
            address = (host, int(port))
        self.address = address
        self.timeout = timeout

    @classmethod
    def from_manifest(cls, path: str | Path, timeout: float = 10.0) -> ControlClient:
        """The client of the bench whose manifest is ``path`` (:func:`~hilbench.bench.manifest.read_manifest`:
        a bench that is gone raises :class:`~hilbench.bench.manifest.BenchNotRunning`)."""
        from hilbench.bench.manifest import ManifestError, read_manifest

        try:
            data = read_manifest(path)
        except ManifestError as exc:
            raise ControlRequestError(str(exc)) from None
        if not isinstance(data.get("control"), str):
            raise ControlRequestError(f"{path}: the bench serves no control channel (run it with hilbench emulate)")
        return cls(data["control"], timeout)

    def call(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command; returns the reply or raises :class:`ControlError`."""
        req = {"cmd": cmd, **{k: v for k, v in args.items() if v is not None}}
        timeout = self.timeout + float(args.get("timeout") or 0)
        where = f"{self.address[0]}:{self.address[1]}"
        try:
            with socket.create_connection(self.address, timeout=timeout) as sock:
                sock.sendall((json.dumps(req) + "\n").encode())
                buf = b""
                while not buf.endswith(b"\n"):
                    chunk = sock.recv(65536)
                    if not chunk:
                        raise ControlUnreachable(f"the bench at {where} closed the control connection")
                    buf += chunk
                    if len(buf) > MAX_REPLY:
                        raise ControlUnreachable(f"the bench at {where} sent a reply longer than {MAX_REPLY} bytes")
        except OSError as exc:
            raise ControlUnreachable(f"no bench control channel at {where}: {exc.strerror or exc}") from None
        try:
            reply = json.loads(buf)
        except (ValueError, RecursionError):
            raise ControlUnreachable(f"the bench at {where} sent something that is not JSON") from None
        if not isinstance(reply, dict):
            raise ControlUnreachable(f"the bench at {where} sent a reply that is not a JSON object")
        if not reply.get("ok"):
            error = ControlError(str(reply.get("error", "command failed")))
            if reply.get("exit") in (1, 2):  # the bench's judgement (benches before it sent none: 1)
                error.exit_code = reply["exit"]
            raise error
        return reply

    def devices(self) -> dict[str, list[str]]:
        """Each device that takes commands, with the commands: ``{"rover": ["status", "button", ...]}``."""
        return self.call("devices")["devices"]

    def manifest(self) -> dict[str, Any]:
        """The bench's manifest, as ``hilbench emulate --manifest`` writes it."""
        return self.call("manifest")["manifest"]

    def media(self) -> dict[str, dict[str, Any]]:
        """Each endpoint's line or bus: ``{"dxl": {"kind": "serial", "paced": true, "scheduling": ...,
        "stats": {"transmissions": ..., "late_count": ..., "late_total": ..., ...}}}``."""
        return self.call("media")["media"]

    def servers(self) -> dict[str, dict[str, Any]]:
        """Each served endpoint's servers: ``{"arm": {"rfc2217": {"url": ..., "client": ..., ...}}}``."""
        return self.call("servers")["servers"]

    def control(self) -> dict[str, Any]:
        """The channel's own limits and counters: ``{"clients": 1, "max_clients": 64, "refused": 0, ...}``."""
        return self.call("control")["control"]

    def overflow(self, endpoint: str | None = None) -> dict[str, Any]:
        """Every bounded queue's limits and what it turned away (:mod:`hilbench.bench.overflow`): ``{"control":
        {...}, "endpoints": {"can": {"tap": {"bytes_dropped": 0, ...}, "socketcand": {...}}}}``."""
        return self.call("overflow", endpoint=endpoint)["overflow"]

    def world(self, **args: Any) -> dict[str, Any]:
        """The bench's world now (``geometry=True``, ``scans=True``, ``since=T`` add more): see
        :func:`hilbench.bench.world.control`."""
        return self.call("world", **args)

    def place(self, body: str, x: float, y: float, theta: float = 0.0) -> dict[str, Any]:
        """Put a body of the bench's world at (x, y, theta) (m, m, rad)."""
        return self.call("world_place", body=body, x=x, y=y, theta=theta)

    def slip(self, body: str, slip: float) -> dict[str, Any]:
        """Let a driven body lose ``slip`` (0..0.9) of its wheels' motion from now on (its odometry drifts)."""
        return self.call("world_slip", body=body, slip=slip)

    def taps(self) -> dict[str, dict[str, Any]]:
        """Each endpoint's traffic tap: ``{"rover": {"url": "tcp://...", "clients": 1}}``."""
        return self.call("taps")["taps"]


def control_overflow(control: str, endpoint: str, timeout: float = 2.0) -> dict[str, Any] | None:
    """An endpoint's overflow counters asked of its bench's control channel (``HOST:PORT``; the ``overflow``
    command), or None: no channel, or the bench does not answer (closed, gone, too old to know the command)."""
    try:
        found = ControlClient(control, timeout).overflow(endpoint)["endpoints"].get(endpoint)
    except (ControlError, KeyError, TypeError, AttributeError):
        return None
    return {"endpoint": endpoint, **found} if isinstance(found, dict) else None


__all__ = ["BACKLOG", "BENCH_COMMANDS", "IDLE_TIMEOUT", "MAX_CLIENTS", "MAX_DEPTH", "MAX_LINE", "MAX_REPLY",
           "REQUEST_TIMEOUT", "ClientGone", "ControlClient", "ControlError", "ControlRequestError", "ControlServer",
           "ControlUnreachable", "RequestTooLong", "client_waits", "control_overflow", "next_request", "serving"]
