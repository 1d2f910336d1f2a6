"""A socketcand server on 127.0.0.1: other processes join an emulated CAN bus over TCP.

Unmodified python-can (``interface="socketcand"``), ``can.viewer``,
``can.logger``, ``cantools monitor`` and the ``canopen`` package connect here (SavvyCAN's
Kayak connection speaks the same protocol; not tested) as they would to the linux-can daemon
(:mod:`hilbench.protocols.socketcand` has the message syntax). Each client is
a party of its own on the bus: it receives every frame but its own.

What the daemon does and clients rely on:

- ``< hi >`` on connect, each handshake reply in a TCP write of its own
  (python-can compares whole ``recv`` results with ``< ok >``);
- an unknown bus name gets ``< error could not open bus >`` and the
  connection is closed;
- after ``< rawmode >`` and its ``< ok >``, frames follow only after
  ``rawmode_delay`` seconds (100 ms by default): a frame in the same segment
  as the ``< ok >`` breaks python-can's handshake. Frames of that interval
  are held (up to a bound), not lost;
- RAW mode reports every data frame and error frame with Unix time stamps;
  remote frames are not reported (the daemon leaves them out too);
- BCM mode: ``send``, cyclic ``add``/``update``/``delete`` jobs (removed when
  the client leaves BCM mode), ``subscribe``/``unsubscribe`` and content
  ``filter`` (reported in BCM's spaced format, throttled by the interval);
  ``muxfilter`` is treated as a subscription to its identifier;
- CONTROL mode: ``< statistics ms >`` reports ``< stat ... >`` periodically;
- ``< echo >`` is echoed; anything else gets ``< error unknown command >``;
  ISO-TP mode is entered but its commands are refused that way.

With ``beacon`` the server announces itself every 2 s to 127.0.0.1:42000,
where python-can's ``detect_beacon()`` listens (never broadcast).

Limits (the daemon forks a process per client and lets the kernel bound the
rest; one bad client must not take the bus from the others here):

- at most :data:`MAX_CLIENTS` clients at once. A newcomer beyond takes the
  place of a client of no use (:mod:`~hilbench.transports.client_limit`), which
  reads ``< error too many clients: closed for a newcomer >`` and is closed:
  first one that has not opened a bus :data:`OPEN_GRACE` seconds after
  connecting (python-can sends ``< open >`` at once), the longest connected
  first; then one that has left what it was sent unread for
  :data:`READ_GRACE` seconds, the longest unread first; then one that can
  receive nothing (no raw mode, subscription, job or statistics) and sent
  no command for :data:`IDLE_GRACE` seconds. Only when no kept client is
  one of these is the newcomer refused: it gets ``< error too many clients >``
  instead of ``< hi >`` and is closed (python-can then raises ``CanError``
  with that message);
- a number out of its range (an interval beyond the kernel's 400 days or a
  million microseconds, an identifier beyond 11/29 bits, a statistics interval
  beyond 32 bits) is answered with ``< error interval out of range >`` (or
  ``identifier``, ``statistics interval``) and counted;
- at most :data:`MAX_BCM_ENTRIES` cyclic jobs and as many subscriptions per
  client (``< error too many jobs >``, ``< error too many subscriptions >``);
  a job never sends faster than its frame takes on the bus (an interval of
  1 us makes it fill the bus, as on the wire), a job that falls behind skips
  the periods it missed, and a client's jobs end when it leaves;
- what waits for a client (frames, replies) is at most :data:`MAX_PENDING`
  bytes, and :data:`MAX_PENDING_TOTAL` for all clients: beyond, frames for it
  are dropped and counted, and its commands are left unread (TCP then holds
  the client back, as the daemon's blocking ``send`` does); a client that
  takes nothing for :data:`STALL_TIMEOUT` seconds while full is disconnected.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import time
from dataclasses import dataclass, field
from typing import Any

from hilbench.protocols import can_frame as cf
from hilbench.protocols import socketcand as sc
from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.can_door import CanDoor
from hilbench.transports.channel_book import TCP
from hilbench.transports.client_limit import Eviction, ReadWatch
from hilbench.transports.heap import Ebb
from hilbench.transports.listener import BACKLOG, Listener, refuse

log = logging.getLogger(__name__)

#: Clients served at once; a newcomer beyond takes the place of a client of no use, or is refused with
#: ``< error too many clients >`` (see the module docstring).
MAX_CLIENTS = 64
#: A client that has not opened a bus this long after connecting may be let go for a newcomer (seconds).
OPEN_GRACE = 3.0
#: A client that has left what it was sent unread this long may be let go for a newcomer (seconds).
READ_GRACE = 5.0
#: A client that can receive nothing and sent no command this long may be let go for a newcomer (seconds).
IDLE_GRACE = 60.0
#: Bytes waiting for one client (frames, replies, frames held during the rawmode delay) beyond which its
#: newest frames are dropped and its commands left unread (a client that stopped reading).
MAX_PENDING = 512 << 10
#: The same bound for all clients together.
MAX_PENDING_TOTAL = 16 << 20
#: A client that takes nothing for this long while its queue is full is disconnected (seconds).
STALL_TIMEOUT = 30.0
#: Cyclic jobs, and subscriptions, one client may have.
MAX_BCM_ENTRIES = 256
#: Each client's kernel send buffer (bytes; the kernel holds up to megabytes for a client that reads nothing).
SEND_BUFFER = 64 << 10
#: While a client has bytes waiting, the bus thread retries sending them this often (seconds).
FLUSH_RETRY = 0.005
BEACON_INTERVAL = 2.0
#: Largest write to a client (python-can's socketcand client reads 1024 bytes at a time).
SEND_CHUNK = 1024


ERROR_TOO_MANY_CLIENTS = "< error too many clients >"
#: What a client let go for a newcomer reads before the end of the connection.
ERROR_EVICTED = "< error too many clients: closed for a newcomer >"
ERROR_TOO_MANY_JOBS = "< error too many jobs >"
ERROR_TOO_MANY_SUBSCRIPTIONS = "< error too many subscriptions >"


@dataclass
class _Job:
    frame: CanFrame
    interval: float  # as asked (0: send once)
    next_t: float
    period: float = 0.0  # as run: never shorter than the frame takes on the bus


@dataclass
class _Sub:
    interval: float
    mask: bytes | None
    last_data: bytes | None = None
    last_sent: float = float("-inf")


@dataclass
class _Client:
    sock: socket.socket
    name: str
    connected: float  # (monotonic)
    watch: ReadWatch
    splitter: sc.MessageSplitter = field(default_factory=sc.MessageSplitter)
    mode: str = "nobus"
    out: bytearray = field(default_factory=bytearray)
    raw_at: float | None = None  # when frames may start flowing after rawmode
    held: list[str] = field(default_factory=list)
    held_bytes: int = 0
    full_since: float | None = None  # when its queue last became full (None: not full)
    jobs: dict[tuple[int, bool], _Job] = field(default_factory=dict)
    subs: dict[tuple[int, bool], _Sub] = field(default_factory=dict)
    stat_interval: float = 0.0
    stat_next: float = 0.0
    rx_frames: int = 0
    rx_bytes: int = 0
    tx_frames: int = 0
    tx_bytes: int = 0
    dropped: int = 0
    closing: bool = False
    last_command: float = 0.0
    peer: tuple[str, int] | None = None  # its address (a virtual bench counts its bytes per address)


class SocketcandServer(CanDoor):
    """The socketcand door of a CAN host port; see the module docstring."""

    kind = "socketcand"

    def __init__(self, name: str = "can", *, bind: str = "127.0.0.1", port: int = 0, channel: str = "can0",
                 rawmode_delay: float = 0.1, beacon: bool = False) -> None:
        if not channel or len(channel) > sc.MAX_BUS_NAME:
            raise ValueError(f"a socketcand channel name has 1..{sc.MAX_BUS_NAME} characters, got {channel!r}")
        self.name = name
        self.channel = channel
        self.rawmode_delay = rawmode_delay
        self.listener = Listener(bind, port, BACKLOG, max_clients=MAX_CLIENTS, refusal=self._refusal,
                                 send_buffer=SEND_BUFFER)
        self.eviction: Eviction[_Client] = Eviction(self._judge, lambda c: (c.sock, c.watch,
                                                                            len(c.out) + c.held_bytes))
        self.clients: list[_Client] = []
        self.connections = 0
        self.malformed = 0
        self.out_of_range = 0
        self.too_many = 0
        self.frames_dropped = 0
        self.stalled = 0
        self.queued = 0  # bytes waiting for all clients
        self._ebb = Ebb()  # memory goes back to the system once the queues empty after a flood
        self.bitrate = 500_000
        self.wall_offset = 0.0
        self._due = float("inf")  # the earliest timed work of any client (poll() does nothing before it)
        self._stall_at = float("inf")  # (wall clock) when a client full since then would be disconnected
        self._backlog = False  # some client has bytes waiting: retry sending soon
        self._beacon_sock: socket.socket | None = None
        self._beacon_next = 0.0
        self.book: Any = None  # a virtual bench's ChannelBook
        if beacon:
            self._beacon_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def attach(self, medium: Any) -> None:
        """Learn the bus clock's mapping to Unix time (frames carry Unix time stamps) and its bitrate."""
        self.wall_offset = medium.wall_offset
        self.bitrate = getattr(medium, "bitrate", self.bitrate)
        book = getattr(medium.clock, "channels", None)
        if book is not None:  # virtual time: bytes in and out per client address (the lockstep's channels)
            self.book = book
            book.door(TCP, self.address)

    @property
    def address(self) -> tuple[str, int]:
        return self.listener.getsockname()[:2]

    @property
    def url(self) -> str:
        host, port = self.address
        return f"socketcand://{host}:{port}/{self.channel}"

    def describe(self) -> dict[str, Any]:
        host, port = self.address
        return {"host": host, "port": port, "channel": self.channel, "max_clients": self.listener.max_clients}

    def status(self) -> dict[str, Any]:
        """Clients (and how many are in each mode: ``{"raw": 1}``), limits and what was refused or dropped, for
        status reports (control ``media``)."""
        modes: dict[str, int] = {}
        for client in list(self.clients):  # (a copy: the medium's thread changes the list)
            modes[client.mode] = modes.get(client.mode, 0) + 1
        return {"url": self.url, "clients": len(self.clients), "modes": modes, **self.listener.status(),
                "malformed": self.malformed, "out_of_range": self.out_of_range, "too_many": self.too_many,
                "frames_dropped": self.frames_dropped, "stalled": self.stalled, "queued_bytes": self.queued,
                "max_pending": MAX_PENDING, "max_pending_total": MAX_PENDING_TOTAL}

    @staticmethod
    def _refusal(reason: str) -> bytes:
        return ERROR_TOO_MANY_CLIENTS.encode()

    # ------------------------------------------------------------------ host port duties

    def filenos(self) -> list[int]:
        # A client whose queue is full is not read (see the module docstring): not waited on either.
        return self.listener.filenos() + [c.sock.fileno() for c in self.clients if len(c.out) <= MAX_PENDING]

    def _accept(self) -> None:
        for sock, addr in self.listener.accept(len(self.clients), self._evict):
            self.connections += 1
            now = time.monotonic()  # wall-clock: service timer
            client = _Client(sock, f"socketcand {addr[0]}:{addr[1]}", now, ReadWatch(now), last_command=now,
                             peer=(addr[0], addr[1]))
            self.clients.append(client)
            self._reply(client, sc.HI)

    @staticmethod
    def _judge(c: _Client, now: float) -> tuple[int, float] | None:
        """Whether ``c`` may be let go for a newcomer, and how surely (see the module docstring)."""
        if c.mode == "nobus":
            return (0, c.connected) if now - c.connected >= OPEN_GRACE else None
        if c.watch.unread_for(now) >= READ_GRACE:
            return 1, c.watch.since
        receives = c.mode == "raw" or c.subs or c.jobs or c.stat_interval
        if not receives and now - c.last_command >= IDLE_GRACE:
            return 2, c.last_command
        return None

    def _evict(self) -> bool:
        """Let a client of no use go for a newcomer (the listener asks when the server is full)."""
        victim = self.eviction.victim(self.clients, time.monotonic())  # wall-clock: service timer
        if victim is None:
            return False
        log.info("%s: closed for a newcomer (%d clients at most)", victim.name, MAX_CLIENTS)
        sock = victim.sock
        self._drop(victim, close=False)
        refuse(sock, ERROR_EVICTED.encode())
        return True

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        """Accept clients and read their commands; returns the frames they send."""
        self._accept()
        out: list[tuple[str, CanFrame]] = []
        for client in list(self.clients):
            if len(client.out) > MAX_PENDING:
                continue  # it reads nothing: neither do we (TCP holds it back)
            try:
                data = client.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                self._drop(client)
                continue
            if not data:
                self._drop(client)
                continue
            if self.book is not None and client.peer is not None:
                self.book.took(TCP, client.peer, len(data))
            for message in client.splitter.feed(data):
                self._command(client, message, now, out)
                if client.closing:
                    self._drop(client)
                    break
        return out

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        """A frame on the bus: format it for every client that should see it."""
        if frame.remote:
            return
        wall = t + self.wall_offset
        raw_text = None
        for client in self.clients:
            if client.name == source:
                continue
            client.rx_frames += 1
            client.rx_bytes += frame.length
            if client.mode == "raw":
                if raw_text is None:
                    raw_text = sc.frame_message(frame, wall)
                if client.raw_at is not None:
                    if self._room(client, len(raw_text)):
                        client.held.append(raw_text)
                        client.held_bytes += len(raw_text)
                        self.queued += len(raw_text)
                    continue
                self._queue(client, raw_text)
            elif client.mode == "bcm" and client.subs and not frame.error:
                sub = client.subs.get((frame.can_id, frame.extended))
                if sub is None:
                    continue
                if sub.mask is not None and sub.last_data is not None:
                    masked = bytes(a & b for a, b in zip(frame.data, sub.mask, strict=False))
                    if masked == bytes(a & b for a, b in zip(sub.last_data, sub.mask, strict=False)) and \
                            len(frame.data) == len(sub.last_data):
                        continue
                if t - sub.last_sent < sub.interval:
                    continue  # throttled: the BCM would report it later; here the next change reports
                sub.last_data, sub.last_sent = frame.data, t
                self._queue(client, sc.frame_message(frame, wall, bcm=True))

    def _room(self, client: _Client, n: int) -> bool:
        """Whether ``n`` more bytes may wait for ``client`` (else the frame is dropped and counted)."""
        if len(client.out) + client.held_bytes + n <= MAX_PENDING and self.queued + n <= MAX_PENDING_TOTAL:
            return True
        client.dropped += 1
        self.frames_dropped += 1
        if client.full_since is None:
            client.full_since = time.monotonic()  # wall-clock: service timer
            self._stall_at = min(self._stall_at, client.full_since + STALL_TIMEOUT)
        return False

    def _queue(self, client: _Client, text: str) -> None:
        if self._room(client, len(text)):
            client.out += text.encode()
            self.queued += len(text)

    def flush(self) -> None:
        backlog = False
        for client in list(self.clients):
            if client.out:
                self._send(client)
                backlog = backlog or bool(client.out)
        self._backlog = backlog
        self._ebb.note(self.queued)

    def _send(self, client: _Client) -> None:
        # Whole messages in writes of at most SEND_CHUNK bytes: python-can reads 1024 bytes at a time and logs a
        # warning (to stderr, over a curses screen) for every read that ends inside a message. A client that
        # keeps up then reads our writes whole; one that falls behind splits them, as with the real daemon.
        out = client.out
        while out:
            cut = len(out) if len(out) <= SEND_CHUNK else out.rfind(b">", 0, SEND_CHUNK) + 1
            if cut <= 0:
                cut = min(len(out), SEND_CHUNK)
            try:
                sent = client.sock.send(out[:cut])
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self._drop(client)
                return
            del out[:sent]  # (a bytearray shrinks its buffer once it is less than half full)
            if self.book is not None and client.peer is not None:
                self.book.sent(TCP, client.peer, sent)
            self.queued -= sent
            client.watch.sent += sent
            if client.full_since is not None:
                client.full_since = None  # it reads again
            if sent < cut:
                return

    def _reply(self, client: _Client, text: str) -> None:
        """A handshake or command reply in a write of its own (python-can reads replies whole)."""
        if client.out:
            self._send(client)
        client.out += text.encode()  # (replies are not dropped: a full client's commands are not read)
        self.queued += len(text)
        self._send(client)
        if len(client.out) > MAX_PENDING and client.full_since is None:
            client.full_since = time.monotonic()  # wall-clock: service timer
            self._stall_at = min(self._stall_at, client.full_since + STALL_TIMEOUT)

    def deadline(self) -> float | None:
        """The next timed work on the bus's clock: a handshake delay, a cyclic job, statistics, the beacon."""
        times = [self._due]
        if self._beacon_sock is not None:
            times.append(self._beacon_next)
        t = min(times)
        return t if t != float("inf") else None

    def wall_deadline(self) -> float | None:
        """Service timers on the wall clock: a flush retry, a stalled client's timeout, the EMFILE pause."""
        times = [self._stall_at]
        if self._backlog:
            times.append(time.monotonic() + FLUSH_RETRY)  # wall-clock: service timer
        pause = self.listener.deadline()
        if pause is not None:
            times.append(pause)
        t = min(times)
        return t if t != float("inf") else None

    def _schedule(self, t: float) -> None:
        """Timed work of a client at ``t``: poll() must run then."""
        if t < self._due:
            self._due = t

    def poll(self, now: float) -> list[tuple[str, CanFrame]]:
        """Timed work: end handshake delays, run cyclic BCM jobs, statistics and the beacon; disconnect a
        client stalled with a full queue."""
        out: list[tuple[str, CanFrame]] = []
        if self._stall_at != float("inf") and (wall := time.monotonic()) >= self._stall_at:  # wall-clock: service
            stall_at = float("inf")
            for c in list(self.clients):
                if c.full_since is not None:
                    if wall - c.full_since >= STALL_TIMEOUT:
                        self.stalled += 1
                        log.warning("%s: read nothing for %.0f s with %d bytes waiting; disconnected",
                                    c.name, STALL_TIMEOUT, len(c.out))
                        self._drop(c)
                        continue
                    stall_at = min(stall_at, c.full_since + STALL_TIMEOUT)
            self._stall_at = stall_at
        if now >= self._due:
            due = float("inf")
            for c in list(self.clients):
                if c.raw_at is not None:
                    if now >= c.raw_at:
                        c.raw_at = None
                        self.queued -= c.held_bytes
                        c.held_bytes = 0
                        held, c.held = c.held, []
                        for text in held:
                            self._queue(c, text)
                    else:
                        due = min(due, c.raw_at)
                for job in c.jobs.values():
                    if now >= job.next_t:
                        out.append((c.name, job.frame))
                        c.tx_frames += 1
                        c.tx_bytes += job.frame.length
                        if job.period > 0:
                            nxt = job.next_t + job.period
                            job.next_t = nxt if nxt > now else now + job.period  # behind: skip what it missed
                        else:
                            job.next_t = float("inf")  # an interval of 0: sent once, as the BCM does
                    due = min(due, job.next_t)
                if c.stat_interval:
                    if now >= c.stat_next:
                        self._queue(c, sc.stat_message(c.rx_bytes, c.rx_frames, c.tx_bytes, c.tx_frames))
                        c.stat_next = now + c.stat_interval
                    due = min(due, c.stat_next)
            self._due = due
        if self._beacon_sock is not None and now >= self._beacon_next:
            self._beacon_next = now + BEACON_INTERVAL
            host, port = self.address
            with contextlib.suppress(OSError):
                self._beacon_sock.sendto(sc.beacon("hilbench", host, port, [self.channel], "hilbench emulated bus"),
                                         ("127.0.0.1", sc.BEACON_PORT))
        return out

    # ------------------------------------------------------------------ commands

    def _command(self, client: _Client, message: str, now: float, out: list[tuple[str, CanFrame]]) -> None:
        client.last_command = time.monotonic()  # wall-clock: judged for eviction (service)
        cmd = sc.parse_command(message)
        if cmd.name == "range":
            self.out_of_range += 1
            self._reply(client, sc.error_out_of_range(cmd.value))
            return
        mode = client.mode
        if mode == "nobus":
            if cmd.name == "open":
                if cmd.value != self.channel:
                    self._reply(client, sc.ERROR_OPEN)
                    client.closing = True
                    return
                client.mode = "bcm"
                self._reply(client, sc.OK)
            elif cmd.name == "configure":  # bit timing or control modes: the emulated bus keeps its own
                if cmd.value != self.channel:
                    self._reply(client, sc.ERROR_OPEN)
                    client.closing = True
                    return
                self._reply(client, sc.OK)
            else:
                self._reply(client, sc.ERROR_UNKNOWN)
            return
        if cmd.name in sc.MODE_COMMANDS:
            new = cmd.name[: -len("mode")]  # raw, bcm, control, isotp
            if new == mode:
                self._reply(client, sc.ERROR_UNKNOWN)  # the daemon answers only real changes
                return
            client.jobs.clear()
            client.subs.clear()
            client.stat_interval = 0.0
            client.mode = new
            self._reply(client, sc.OK)
            self.queued -= client.held_bytes
            client.held_bytes = 0
            client.held.clear()
            if new == "raw" and self.rawmode_delay > 0:
                client.raw_at = now + self.rawmode_delay
                self._schedule(client.raw_at)
            else:
                client.raw_at = None
            return
        if cmd.name == "echo":
            self._reply(client, sc.ECHO)
            return
        if cmd.name == "send" and mode in ("raw", "bcm"):
            out.append((client.name, cmd.frame))  # type: ignore[arg-type]
            client.tx_frames += 1
            client.tx_bytes += cmd.frame.length  # type: ignore[union-attr]
            return
        if mode == "bcm":
            key = (cmd.can_id, cmd.extended)
            if cmd.name == "add":
                if key not in client.jobs and len(client.jobs) >= MAX_BCM_ENTRIES:
                    self.too_many += 1
                    self._reply(client, ERROR_TOO_MANY_JOBS)
                    return
                client.jobs[key] = self._job(cmd.frame, cmd.interval, now)  # type: ignore[arg-type]
                self._schedule(now)
                return
            if cmd.name == "update":
                frame = cmd.frame
                job = client.jobs.get((frame.can_id, frame.extended))  # type: ignore[union-attr]
                if job is not None:  # (the timer is not touched; the new frame may take longer on the bus)
                    updated = self._job(frame, job.interval, job.next_t)  # type: ignore[arg-type]
                    job.frame, job.period = updated.frame, updated.period
                return
            if cmd.name == "delete":
                client.jobs.pop(key, None)
                return
            if cmd.name in ("subscribe", "filter"):
                if key not in client.subs and len(client.subs) >= MAX_BCM_ENTRIES:
                    self.too_many += 1
                    self._reply(client, ERROR_TOO_MANY_SUBSCRIPTIONS)
                    return
                client.subs[key] = _Sub(cmd.interval, cmd.mask if cmd.name == "filter" else None)
                return
            if cmd.name == "unsubscribe":
                client.subs.pop(key, None)
                return
        if mode == "control" and cmd.name == "statistics":
            ms = int(cmd.value)  # (bounded by parse_command)
            client.stat_interval = ms / 1000.0
            client.stat_next = now + client.stat_interval
            if ms:
                self._schedule(client.stat_next)
            return
        if cmd.name == "invalid":
            self.malformed += 1  # the daemon drops a malformed command and only logs it
            log.debug("socketcand: malformed command %r from %s", message, client.name)
            return
        self._reply(client, sc.ERROR_UNKNOWN)

    def _job(self, frame: CanFrame, interval: float, now: float) -> _Job:
        """A cyclic job sent first now; it never repeats faster than its frame takes on the bus."""
        period = max(interval, cf.frame_bits(frame) / self.bitrate) if interval > 0 else 0.0
        return _Job(frame, interval, now, period)

    # ------------------------------------------------------------------ closing

    def _drop(self, client: _Client, close: bool = True) -> None:
        """Disconnect a client: its jobs, subscriptions and queue go with it (the socket is closed unless
        ``close`` is False: the caller says goodbye first)."""
        if self.book is not None and client.peer is not None:
            self.book.forget(TCP, client.peer)
        if client in self.clients:
            self.clients.remove(client)
            self.queued -= len(client.out) + client.held_bytes
            self._ebb.note(self.queued)
        client.out = bytearray()
        client.held = []
        client.held_bytes = 0
        client.jobs.clear()
        if close:
            with contextlib.suppress(OSError):
                client.sock.close()

    def close(self) -> None:
        for client in list(self.clients):
            self._drop(client)
        with contextlib.suppress(OSError):
            self.listener.close()
        if self._beacon_sock is not None:
            with contextlib.suppress(OSError):
                self._beacon_sock.close()


__all__ = ["SocketcandServer"]
