"""A bench's traffic for other processes: a TCP tap server on 127.0.0.1.

Two readers of one pty steal each other's bytes (spec sheet §7.7), so a
monitor in another process cannot watch a bench by opening its pty. Instead
the bench's serial line hands every transmission to :meth:`TapServer.feed`,
and the server streams it to each connected client as a hilbench capture
(:mod:`hilbench.protocols.capture`): a header, then one record per
transmission with its time and sender. A client therefore reads the stream
exactly like a capture file (``hilbench monitor tcp://127.0.0.1:PORT``, or the
``tap`` address in a bench's manifest).

The line thread never waits for a client: what a client cannot take at once
is buffered, and beyond ``max_buffer`` bytes (:data:`MAX_BUFFER`) per client
new data is dropped and reported to that client as a GAP record once it
catches up (a monitor counts it as lost input). A client that takes nothing
for :data:`STALL_TIMEOUT` seconds while its buffer is full is disconnected.
At most :data:`MAX_CLIENTS` clients are served at once. A newcomer beyond
takes the place of a client that has left what it was sent unread for
:data:`READ_GRACE` seconds, the longest unread first (on this machine the
kernel shows a client that never reads at once, even before the capture
header is read: :mod:`~hilbench.transports.client_limit`); that client's
stream just ends. A client that reads keeps its place. Only when every kept
client reads is the newcomer refused: it reads a line of text starting with
:data:`REFUSAL_PREFIX` instead of a capture header, then the end of the
stream (``hilbench monitor`` reports the line). Counters:
:meth:`TapServer.status`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import selectors
import socket
import threading
import time

from hilbench.protocols import capture as cap
from hilbench.protocols.capture import MAX_PAYLOAD, Flags, RecordKind
from hilbench.transports.client_limit import Eviction, ReadWatch
from hilbench.transports.clock import WALL, WallClock
from hilbench.transports.heap import Ebb
from hilbench.transports.listener import BACKLOG, Listener

log = logging.getLogger(__name__)

#: Clients served at once; a newcomer beyond takes the place of one that does not read, or reads
#: :data:`REFUSAL_PREFIX` and is closed.
MAX_CLIENTS = 32
#: A client that has left what it was sent unread this long may be let go for a newcomer (seconds).
READ_GRACE = 5.0
#: Bytes buffered for one client that reads slower than the line sends; beyond, data is dropped (a GAP record).
MAX_BUFFER = 1 << 20
#: Each client's kernel send buffer (bytes; the kernel holds up to megabytes for a client that reads nothing).
SEND_BUFFER = 256 << 10
#: A client that takes nothing for this long while its buffer is full is disconnected (seconds).
STALL_TIMEOUT = 60.0
#: What a refused client reads first instead of a capture header, then why (a reader recognises the prefix).
REFUSAL_PREFIX = b"hilbench tap: refused: "


class _Client:
    __slots__ = ("sock", "pending", "lost", "full_since", "watch", "ebb")

    def __init__(self, sock: socket.socket, now: float, max_buffer: int) -> None:
        self.sock = sock
        self.pending = bytearray()
        self.lost: dict[int, int] = {}
        self.full_since: float | None = None
        self.watch = ReadWatch(now)
        self.ebb = Ebb(max_buffer // 2)  # memory goes back to the system once a large buffer empties

    def close(self) -> None:
        self.sock.close()
        self.ebb.note(0)


class TapServer:
    """Serves a line's transmissions to TCP clients in the capture format (binds 127.0.0.1 by default)."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        baud: int | None = None,
        protocol: str | None = None,
        description: str = "",
        max_buffer: int = MAX_BUFFER,
        max_clients: int = MAX_CLIENTS,
        clock: WallClock = WALL,
    ) -> None:
        # Records are stamped in the medium's time (``clock``): t0 and its Unix time come from that clock.
        self.t0 = clock.now()
        self.max_buffer = max_buffer
        self._header = cap.build_header(
            flags=Flags.MEASURED,
            baud=baud,
            t0_wall=clock.wall(self.t0),
            t0_monotonic=self.t0,
            protocol=protocol,
            description=description,
        )
        self._listener = Listener(host, port, BACKLOG, max_clients=max_clients, refusal=self._refusal,
                                  send_buffer=SEND_BUFFER)
        self.host, self.port = self._listener.getsockname()[:2]
        self._lock = threading.Lock()
        self._clients: list[_Client] = []
        self._eviction: Eviction[_Client] = Eviction(
            lambda c, now: (0, c.watch.since) if c.watch.unread_for(now) >= READ_GRACE else None,
            lambda c: (c.sock, c.watch, len(c.pending)))
        self._sel: selectors.BaseSelector | None = None
        self._ids: dict[str, int] = {}
        self._names = bytearray()  # SOURCE records sent to every new client
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stop = threading.Event()
        self.clients_served = 0
        self.bytes_dropped = 0  # data no client could take (each client learns of its share by a GAP record)
        self.stalled = 0
        self._thread = threading.Thread(target=self._run, name=f"tap-{self.port}", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """Where clients connect: ``tcp://127.0.0.1:PORT``."""
        return f"tcp://{self.host}:{self.port}"

    @property
    def clients(self) -> int:
        return len(self._clients)

    def status(self) -> dict[str, int]:
        """Clients, limits and what was refused or dropped, for status reports (control ``taps``)."""
        with self._lock:
            buffered = sum(len(c.pending) for c in self._clients)
        return {"clients": len(self._clients), "served": self.clients_served, **self._listener.status(),
                "bytes_dropped": self.bytes_dropped, "stalled": self.stalled, "buffered_bytes": buffered,
                "max_buffer": self.max_buffer}

    def limits(self) -> dict[str, int | float]:
        """Its bounds, for the manifest (``tap_limits``): clients, bytes buffered per client, seconds a client
        may leave its stream unread before a newcomer may take its place, and stalled with a full buffer."""
        return {"max_clients": self._listener.max_clients, "max_buffer": self.max_buffer,
                "read_grace_s": READ_GRACE, "stall_timeout_s": STALL_TIMEOUT, "send_buffer": SEND_BUFFER}

    @staticmethod
    def _refusal(reason: str) -> bytes:
        return REFUSAL_PREFIX + reason.encode() + b"\n"

    def feed(self, t: float, source: str, data: bytes, addr: tuple[str, int, str, int] | None = None) -> None:
        """A transmission on the line (a :data:`~hilbench.transports.serial_medium.Tap`); never blocks.

        ``addr`` (a datagram's addresses) goes out as an ADDRESS record before the data.
        """
        if not self._clients:
            return
        with self._lock:
            sid = self._ids.get(source)
            if sid is None:
                sid = self._ids[source] = len(self._ids) & 0xFF
                names = cap.pack_record(RecordKind.SOURCE, sid, 0, source.encode()[:MAX_PAYLOAD])
                self._names += names
                for c in self._clients:
                    c.pending += names
            t_ns = round((t - self.t0) * 1e9)
            records = (cap.address_record(sid, t_ns, addr) if addr is not None else b"") + b"".join(
                cap.pack_record(RecordKind.DATA, sid, t_ns, data[i : i + MAX_PAYLOAD])
                for i in range(0, len(data), MAX_PAYLOAD)
            )
            wake = False
            for c in self._clients:
                if len(c.pending) > self.max_buffer:
                    c.lost[sid] = c.lost.get(sid, 0) + len(data)
                    self.bytes_dropped += len(data)
                    if c.full_since is None:
                        c.full_since = t
                    elif t - c.full_since >= STALL_TIMEOUT:
                        wake = True  # the server thread disconnects it
                    continue
                if c.lost:
                    for lost_sid, n in c.lost.items():
                        c.pending += cap.gap_record(lost_sid, t_ns, n)
                    c.lost.clear()
                if not c.pending:
                    try:
                        sent = c.sock.send(records)
                    except (BlockingIOError, InterruptedError):
                        sent = 0
                    except OSError:
                        continue  # the server thread notices the broken connection
                    c.watch.sent += sent
                    if sent == len(records):
                        continue
                    c.pending += records[sent:]
                else:
                    c.pending += records
                c.ebb.note(len(c.pending))
                wake = True
        if wake:
            with contextlib.suppress(BlockingIOError):
                os.write(self._wake_w, b"x")

    def _run(self) -> None:
        sel = self._sel = selectors.DefaultSelector()  # (epoll: no limit on descriptor numbers)
        sel.register(self._listener.sock, selectors.EVENT_READ, "accept")
        sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        listening = True
        try:
            while not self._stop.is_set():
                with self._lock:
                    for c in list(self._clients):
                        if c.full_since is not None and time.monotonic() - c.full_since >= STALL_TIMEOUT \
                                and len(c.pending) > self.max_buffer:
                            self.stalled += 1
                            log.warning("tap %s: a client took nothing for %.0f s; disconnected", self.port,
                                        STALL_TIMEOUT)
                            self._clients.remove(c)
                            with contextlib.suppress(KeyError, ValueError):
                                sel.unregister(c.sock)
                            c.close()
                            continue
                        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if c.pending else 0)
                        try:
                            sel.modify(c.sock, events, c)
                        except KeyError:
                            sel.register(c.sock, events, c)
                # A listener out of descriptors pauses (see listener.py): no waiting on it meanwhile.
                timeout = None
                pause = self._listener.deadline()
                if pause is not None:
                    if listening:
                        sel.unregister(self._listener.sock)
                        listening = False
                    timeout = max(0.0, pause - time.monotonic())
                elif not listening:
                    sel.register(self._listener.sock, selectors.EVENT_READ, "accept")
                    listening = True
                # otherwise no timeout: a thread that wakes on its own takes the GIL now and then, and a
                # paced line's real-time thread would wait whenever it was preempted holding it (feed()
                # and close() wake it through the pipe)
                for key, mask in sel.select(timeout=timeout):
                    if key.data == "accept":
                        self._accept()
                    elif key.data == "wake":
                        with contextlib.suppress(BlockingIOError):
                            os.read(self._wake_r, 4096)
                    else:
                        self._serve(sel, key.data, mask)
        finally:
            sel.close()

    def _accept(self) -> None:
        for sock, _ in self._listener.accept(len(self._clients), self._evict):
            c = _Client(sock, time.monotonic(), self.max_buffer)
            with self._lock:
                c.pending += self._header + self._names
                self._clients.append(c)
                self.clients_served += 1

    def _evict(self) -> bool:
        """Let a client that does not read go for a newcomer (the listener asks when the server is full)."""
        with self._lock:
            clients = list(self._clients)
        # Outside the lock: the line thread feeding the clients must not wait for the kernel's answers (a
        # count it changes meanwhile only makes the look a moment older).
        victim = self._eviction.victim(clients, time.monotonic())
        if victim is None:
            return False
        with self._lock:
            if victim not in self._clients:
                return False
            self._clients.remove(victim)
        log.info("tap %s: a client left %d bytes unread for %.0f s; closed for a newcomer", self.port,
                 victim.watch.sent - victim.watch.taken + len(victim.pending),
                 victim.watch.unread_for(time.monotonic()))
        if self._sel is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(victim.sock)
        victim.close()
        return True

    def _serve(self, sel: selectors.BaseSelector, c: _Client, mask: int) -> None:
        try:
            if mask & selectors.EVENT_READ and not c.sock.recv(4096):
                raise ConnectionResetError  # the client went away (it never sends anything)
            if mask & selectors.EVENT_WRITE:
                with self._lock:
                    sent = c.sock.send(c.pending)
                    del c.pending[:sent]  # (a bytearray shrinks its buffer once it is less than half full)
                    c.watch.sent += sent
                    c.ebb.note(len(c.pending))
                    if sent:
                        c.full_since = None
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            with self._lock:
                if c in self._clients:
                    self._clients.remove(c)
            with contextlib.suppress(KeyError, ValueError):
                sel.unregister(c.sock)
            c.close()

    def close(self) -> None:
        """Stop serving and disconnect every client."""
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        with self._lock:
            for c in self._clients:
                c.close()
            self._clients.clear()
        self._listener.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
