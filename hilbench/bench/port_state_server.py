"""The port-state server: what a serial adapter does besides bytes, for clients of a bench's ptys.

A pseudo-terminal has no modem lines and no BREAK, and ``tcflush(TCOFLUSH)`` on
it throws away bytes the bench has not read yet (on a USB adapter they are
already on the wire). ``hilbench run`` makes unmodified clients ask this server
instead, through an LD_PRELOAD shim or a pyserial patch (:mod:`hilbench.run`).

One server per bench, a :attr:`Bench.services <hilbench.bench.bench.Bench.services>` entry named ``port_state``: a Unix
socket in a private directory (mode 0700, so only this user's programs reach
it), listed in the manifest with the device number (``st_rdev``) of every pty
it serves. A client sends one line per request and reads one line back, on a
connection it may keep for further requests (one request at a time on each)::

    RDEV VERB [ARG]\\n   ->   ok N\\n  |  err MESSAGE\\n

======================  ==================================================  =======================
request                 what the bench does                                 ``ok`` value
======================  ==================================================  =======================
``ping``                nothing (is the bench there?)                       ports served
``mget``                read the modem lines (TIOCMGET)                     TIOCM_* mask
``mset|mbis|mbic M``    set / raise / clear DTR and RTS (TIOCMSET/BIS/BIC)  mask afterwards
``break on|off|SECS``   BREAK on, off, or for SECS (answered after them)    0
``flush``               take what the client wrote, then OutputFlushed      bytes taken
``drain``               take them and answer once they are delivered        bytes taken
``sync [CFLAG]``        re-read baud rate; CFLAG: the client's framing      baud (0: unknown)
``framing``             the framing the client last set (a pty forgets it)  c_cflag bits, -1: none
======================  ==================================================  =======================

Beside the socket, ``port_state.ledger`` (:mod:`hilbench.bench.delivery_ledger`) tells
clients when everything they wrote is delivered, so a drain or an output flush
with nothing pending needs no request at all.

Every change first takes what the client already wrote from the pty, in the
medium's thread, so a line change or flush never overtakes the bytes written
before it: on an unpaced line the devices hear those bytes first. On a paced
line the change is immediate while the bytes are still on the wire, as on a
real adapter whose client did not wait with ``tcdrain``.

Hand-written over the standard library's socket module: socketserver's
shutdown polls (up to half a second per bench stop), too slow for test suites
that start hundreds of benches. At most :data:`MAX_CLIENTS` connections are
served at once: a newcomer beyond takes the place of the connection that has
waited longest for its next request, if that is :data:`EVICT_IDLE` seconds or
more (it is closed as an idle one is: clients connect anew for their next
request); only when every connection is busy or just answered is the
newcomer answered ``err too many clients`` and closed. A connection idle for
:data:`IDLE_TIMEOUT` seconds is closed.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
import struct
import tempfile
import termios
import threading
import time
from collections.abc import Callable
from typing import Any

from hilbench.bench.delivery_ledger import FILE_NAME as LEDGER_FILE
from hilbench.bench.delivery_ledger import DeliveryLedger
from hilbench.bench.serve_ring import SERVED, ServeRings, openers_run_the_shim
from hilbench.errors import RequestRefused
from hilbench.transports.client_limit import Eviction
from hilbench.transports.listener import Listener
from hilbench.transports.pty import PtyPort
from hilbench.transports.readiness import readable

#: How long a request may wait for the medium's thread before the client is told to give up.
MEDIUM_TIMEOUT = 5.0
#: The longest request line; anything longer is refused.
MAX_REQUEST = 256
#: Connections served at once (a thread each); one more is answered ``err too many clients`` and closed.
MAX_CLIENTS = 64
#: A connection that sends no request for this long is closed (seconds); clients then connect anew.
IDLE_TIMEOUT = 60.0
#: A connection waiting this long for its next request may be closed for a newcomer (seconds).
EVICT_IDLE = 1.0

TIOCM = {"dtr": termios.TIOCM_DTR, "rts": termios.TIOCM_RTS, "cts": termios.TIOCM_CTS,
         "dsr": termios.TIOCM_DSR, "ri": termios.TIOCM_RNG, "cd": termios.TIOCM_CAR}


SIOCOUTQ = termios.TIOCOUTQ  # (the same number: bytes a socket's peer has not read yet, on a Unix socket)


def _queued(fd: int, request: int) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, request, b"\0" * 4))[0]


class _Conn:
    """A connection's state, for choosing one to close for a newcomer."""

    __slots__ = ("sock", "last", "busy", "queued")

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.last = time.monotonic()  # when it last connected or was answered (wall-clock: idle service timer)
        self.busy = False  # a request has begun
        self.queued = False  # its work is in the bench's timeline (it waits for the bench's time, not for us)


class _ServedPort:
    """One served host port: the endpoint's port object and the medium behind it."""

    def __init__(self, name: str, port: Any, medium: Any) -> None:
        self.name = name
        self.port = port
        self.medium = medium
        self.port_state = port.port_state


class PortStateServer:
    """Serves port-state requests for every tty-backed host port of a bench (see the module's docstring).

    :meth:`handle` answers one request line; the socket server calls it for
    other processes, and in-process clients (the pytest plugin's pyserial patch)
    may call it directly.
    """

    def __init__(self, bench: Any) -> None:
        self._ports: dict[int, _ServedPort] = {}
        for ep in bench.endpoints.values():
            port = ep.port
            rdev = getattr(port, "rdev", None)  # only terminals have one (a pty)
            if rdev is not None and getattr(port, "port_state", None) is not None:
                self._ports[rdev] = _ServedPort(ep.name, port, ep.medium)
        self._closed = threading.Event()
        self.requests = 0
        self.directory = _private_dir()
        self.path = os.path.join(self.directory, "port_state.sock")
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._sock.bind(self.path)
            self._sock.listen(64)
        except OSError:
            self._sock.close()
            os.rmdir(self.directory)
            raise
        self.ledger = DeliveryLedger(os.path.join(self.directory, LEDGER_FILE), list(self._ports))
        for rdev, p in self._ports.items():
            watch = getattr(p.medium, "watch_quiet", None)
            if watch is not None:
                watch(p.port, lambda ns, _rdev=rdev: self.ledger.delivered(_rdev, ns),
                      lambda _rdev=rdev: self.ledger.writers_idle(_rdev),
                      lambda _rdev=rdev: self.ledger.draining(_rdev))
        self.rings = ServeRings(self.directory, list(self._ports))
        self._conns: dict[socket.socket, _Conn] = {}
        self._tls = threading.local()  # the connection a request thread serves
        self._conns_lock = threading.Lock()
        self._eviction: Eviction[_Conn] = Eviction(
            lambda c, now: None if c.busy or now - c.last < EVICT_IDLE else (0, c.last))
        self._listener = Listener("", 0, 0, max_clients=MAX_CLIENTS, sock=self._sock,
                                  refusal=lambda reason: f"err too many clients ({reason})\n".encode())
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._accept, name="port-state-server", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ what the manifest says

    @property
    def rdevs(self) -> list[int]:
        """Device numbers of the ptys served."""
        return list(self._ports)

    def describe(self) -> dict[str, Any]:
        """The manifest's ``port_state`` entry: the socket and the served ptys by endpoint name."""
        return {"socket": self.path, "ledger": self.ledger.path,
                "ports": {p.name: {"rdev": rdev, "path": p.port.client_path} for rdev, p in self._ports.items()}}

    # ------------------------------------------------------------------ requests

    def handle(self, line: str) -> str:
        """Answer one request line (without or with its newline): ``ok N`` or ``err MESSAGE``."""
        self.requests += 1
        try:
            return f"ok {self._handle(line.split())}"
        except RequestRefused as exc:
            return f"err {exc}"
        except Exception as exc:  # a request must never take the server down; the client fails open
            return f"err {type(exc).__name__}: {exc}"

    def _handle(self, words: list[str]) -> int:
        if len(words) < 2:
            raise RequestRefused("expected: RDEV VERB [ARG]")
        rdev_text, verb, args = words[0], words[1], words[2:]
        if verb == "ping":
            return len(self._ports)
        try:
            port = self._ports[int(rdev_text)]
        except (ValueError, KeyError):
            raise RequestRefused(f"no pty of this bench has device number {rdev_text}") from None
        if verb == "mget":
            return self._mask(port)
        if verb in ("mset", "mbis", "mbic"):
            mask = _int_arg(args)
            return self._after_taking(port, lambda: self._set_modem(port, verb, mask))
        if verb == "break":
            return self._break(port, args)
        if verb == "flush":
            return self._after_taking(port, lambda: self._flushed(port), taken=True)
        if verb == "drain":
            return self._after_taking(port, lambda: self._quiet(port), taken=True, delivered=True)
        if verb in ("serve", "unserve"):  # the serving path: SERVED (1) or not (0, 2)
            return self._serving_path(port, verb == "serve")
        if verb == "framing":
            framing = getattr(port.port, "framing", None)
            return -1 if framing is None else framing
        if verb == "sync":
            framing = _int_arg(args) if args else None
            return self._after_taking(port, lambda: self._sync(port, framing))
        raise RequestRefused(f"unknown request {verb!r}")

    def _serving_path(self, port: _ServedPort, wanted: bool) -> int:
        """A client asks for the serving path (or gives it up, for good): the mode of the port's ring. The
        pty's writes go to the ring only while it is served (no cost on the kernel path otherwise)."""
        rdev, pty = port.port.rdev, port.port
        conn = getattr(self._tls, "conn", None)
        pid = None
        if conn is not None:
            with contextlib.suppress(OSError):
                pid = struct.unpack("3i", conn.sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, 12))[0]
        mode = self.rings.claim(rdev, wanted and openers_run_the_shim(rdev, self.rings.path, os.getpid()), pid)
        if isinstance(pty, PtyPort):
            if mode == SERVED:
                def serve(data: bytes) -> int | None:
                    left = self.rings.orphaned(rdev)
                    if left is None:
                        return self.rings.append(rdev, data)
                    # every client that asked is gone: the pty again (what they left unread first; counted)
                    pty.serve = pty.serve_discard = pty.serve_pending = None
                    with contextlib.suppress(OSError):
                        os.write(pty.master_fd, left)
                    return None

                pty.serve_discard = lambda: self.rings.discard(rdev)
                pty.serve_pending = lambda: self.rings.pending(rdev)
                pty.serve = serve
            else:
                pty.serve = pty.serve_discard = pty.serve_pending = None
        return mode

    @staticmethod
    def _quiet(port: _ServedPort) -> None:
        """Tell the ledger if everything is delivered now: a client whose write() returned just after
        the medium's last check must not have to ask again and again."""
        check = getattr(port.medium, "check_quiet", None)
        if check is not None:
            check(port.port)

    def _flushed(self, port: _ServedPort) -> None:
        port.port_state.host_flushed_output()
        self._quiet(port)

    @staticmethod
    def _mask(port: _ServedPort) -> int:
        snap = port.port_state.snapshot()
        return sum(bit for name, bit in TIOCM.items() if snap.get(name))

    def _set_modem(self, port: _ServedPort, verb: str, mask: int) -> int:
        dtr, rts = bool(mask & TIOCM["dtr"]), bool(mask & TIOCM["rts"])
        if verb == "mset":
            port.port_state.host_sets(dtr=dtr, rts=rts)
        elif verb == "mbis":
            port.port_state.host_sets(dtr=True if dtr else None, rts=True if rts else None)
        else:
            port.port_state.host_sets(dtr=False if dtr else None, rts=False if rts else None)
        return self._mask(port)

    def _break(self, port: _ServedPort, args: list[str]) -> int:
        if len(args) != 1:
            raise RequestRefused("expected: break on|off|SECONDS")
        if args[0] in ("on", "off"):
            return self._after_taking(port, lambda: port.port_state.host_break(args[0] == "on"))
        try:
            duration = float(args[0])
        except ValueError:
            raise RequestRefused(f"expected a break duration in seconds, got {args[0]!r}") from None
        if not 0.0 < duration <= 60.0:
            raise RequestRefused(f"break duration {duration} s is outside 0..60 s")
        self._after_taking(port, lambda: port.port_state.host_break(True, duration))
        # tcsendbreak returns when the break is over, as on an adapter: in the line's time
        clock = port.medium.clock
        if clock.virtual:
            over = threading.Event()
            port.medium.call_at(clock.now() + duration, over.set)
            while not over.wait(0.1) and not self._closed.is_set():
                pass
        else:
            self._closed.wait(duration)
        return 0

    @staticmethod
    def _sync(port: _ServedPort, framing: int | None) -> int:
        report = getattr(port.port, "report_framing", None)
        if framing is not None and report is not None:
            settings = report(framing)
        else:
            port.port.client_baud()  # re-reads termios; a change becomes an event
            settings = port.port_state.settings
        return settings.baud or 0

    def _after_taking(self, port: _ServedPort, apply: Callable[[], Any], *, taken: bool = False,
                      delivered: bool = False) -> int:
        """In the medium's thread: take what the client wrote, then ``apply`` (when it is delivered,
        if ``delivered``). Returns the bytes taken if ``taken``, else what ``apply`` returned."""
        medium = port.medium
        took, done = threading.Event(), threading.Event()
        box: dict[str, Any] = {}
        conn = getattr(self._tls, "conn", None)

        def finish() -> None:
            try:
                box["value"] = apply()
            except BaseException as exc:
                box["error"] = exc
            finally:
                if conn is not None:
                    conn.queued = False  # the answer is on its way out: virtual time waits for it again
                done.set()

        def take() -> None:
            try:
                box["taken"], box["end"] = medium.drain_host(port.port)
            except BaseException as exc:
                box["error"] = exc
                done.set()
                return
            finally:
                took.set()
            # Queued behind the deliveries of the bytes just taken (an unpaced line delivers them
            # "now"), so the devices hear those bytes before the change.
            medium.call_at(box["end"] if delivered else medium.clock.now(), finish)

        if medium.in_medium_thread():
            raise RequestRefused("called from the bench's own line thread")
        medium.call_at(None, take)
        if not took.wait(MEDIUM_TIMEOUT):
            raise RequestRefused(f"the bench's line did not answer within {MEDIUM_TIMEOUT:g} s")
        if conn is not None:
            conn.queued = True  # (virtual time may move now: what remains happens at the line's instants)
            if done.is_set():
                conn.queued = False  # (finish ran before: its answer is on its way out)
        wire = max(0.0, box.get("end", 0.0) - medium.clock.now())  # a paced line's wire time
        if not done.wait(MEDIUM_TIMEOUT + wire):
            raise RequestRefused(f"the bench's line did not answer within {MEDIUM_TIMEOUT:g} s")
        if "error" in box:
            raise box["error"]
        return box.get("taken", 0) if taken else int(box.get("value") or 0)

    def holding(self) -> bool:
        """Whether a client's request is on its way into the bench, or its answer on its way out: a
        virtual-time bench's clock waits (:mod:`hilbench.bench.lockstep`), since the client that asked
        sleeps in a call its clock shim does not see. A request whose work is queued on the line's
        timeline (a drain waiting for the wire) holds nothing."""
        with self._conns_lock:
            conns = list(self._conns.values())
            if readable([self._sock.fileno()], 0):
                return True  # a client connecting (its first request waits in a connection not accepted yet)
        for c in conns:
            if c.busy and not c.queued:
                return True
            try:
                fd = c.sock.fileno()
                if fd >= 0 and (_queued(fd, termios.FIONREAD) or _queued(fd, SIOCOUTQ)):
                    return True  # a request not read yet, or an answer its client has not read yet
            except OSError:
                continue
        return False

    # ------------------------------------------------------------------ socket

    def _accept(self) -> None:
        listener = self._listener
        while not self._closed.is_set():
            pause = listener.deadline()  # (out of descriptors: see Listener)
            try:
                ready = readable([*listener.filenos(), self._wake_r],
                                 None if pause is None else pause - time.monotonic())  # wall-clock: EMFILE pause
            except OSError:
                return
            if self._wake_r in ready and self._closed.is_set():
                return
            with self._conns_lock:
                if self._closed.is_set():
                    return
                for conn, _ in listener.accept(len(self._conns), self._evict):
                    conn.settimeout(IDLE_TIMEOUT)  # (blocking, with a timeout: one thread per connection)
                    state = self._conns[conn] = _Conn(conn)
                    threading.Thread(target=self._serve, args=(state,), name="line-request", daemon=True).start()

    def _evict(self) -> bool:
        """Close the connection idle longest for a newcomer (called with ``_conns_lock`` held)."""
        victim = self._eviction.victim(list(self._conns.values()), time.monotonic())  # wall-clock: service
        if victim is None:
            return False
        del self._conns[victim.sock]
        with contextlib.suppress(OSError):
            victim.sock.shutdown(socket.SHUT_RDWR)  # its thread's recv() ends: it closes the socket
        return True

    def _serve(self, state: _Conn) -> None:
        """Answer requests on one connection, one line each, until the client closes it (or idles)."""
        conn = state.sock
        data = b""
        self._tls.conn = state
        try:
            while not self._closed.is_set():
                while b"\n" not in data and len(data) <= MAX_REQUEST:
                    chunk = conn.recv(MAX_REQUEST)
                    if not chunk:
                        return  # the client is done (or went away)
                    state.busy = True
                    data += chunk
                line, sep, data = data.partition(b"\n")
                if not sep or len(line) > MAX_REQUEST:
                    conn.sendall(b"err request too long\n")
                    return
                conn.sendall(self.handle(line.decode("ascii", "replace")).encode() + b"\n")
                state.busy, state.queued, state.last = bool(data), False, time.monotonic()  # wall-clock: service
        except OSError:
            pass  # the client went away: it fails open on its side
        finally:
            with self._conns_lock:
                self._conns.pop(conn, None)
            conn.close()

    def close(self) -> None:
        """Stop serving and remove the socket and its directory."""
        if self._closed.is_set():
            return
        self._closed.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        self._sock.close()
        with self._conns_lock:
            conns = list(self._conns)
        for conn in conns:  # wakes their threads (recv returns nothing)
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for p in self._ports.values():
            watch = getattr(p.medium, "watch_quiet", None)
            if watch is not None:
                watch(p.port, None)
        self.ledger.close()
        for p in self._ports.values():
            if isinstance(p.port, PtyPort):
                p.port.serve = p.port.serve_discard = p.port.serve_pending = None
        self.rings.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(self.path)
        with contextlib.suppress(OSError):
            os.rmdir(self.directory)


def _int_arg(args: list[str]) -> int:
    if len(args) != 1:
        raise RequestRefused("expected one integer argument")
    try:
        value = int(args[0], 0)
    except ValueError:
        raise RequestRefused(f"expected an integer, got {args[0]!r}") from None
    if not -(1 << 31) <= value < 1 << 32:  # a modem-line mask or a c_cflag: 32 bits
        raise RequestRefused("integer out of range (32 bits)")
    return value


def _private_dir() -> str:
    """A fresh 0700 directory whose socket path fits sockaddr_un (108 bytes) even with a long TMPDIR."""
    path = tempfile.mkdtemp(prefix="hilbench-port-state-")
    if len(path) + len("/port_state.sock") < 100:
        return path
    os.rmdir(path)
    return tempfile.mkdtemp(prefix="hilbench-port-state-", dir="/tmp")


def serve_port_state(bench: Any) -> PortStateServer | None:
    """Start the bench's port-state server (once) as its ``port_state`` service; None if no endpoint is a tty."""
    server = bench.services.get("port_state")
    if server is None:
        if not any(getattr(ep.port, "rdev", None) is not None for ep in bench.endpoints.values()):
            return None
        server = bench.services["port_state"] = PortStateServer(bench)
    return server


__all__ = ["TIOCM", "PortStateServer", "serve_port_state"]
