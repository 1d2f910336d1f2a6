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
"""

from __future__ import annotations

import contextlib
import logging
import socket
from dataclasses import dataclass, field
from typing import Any

from hilbench.protocols import socketcand as sc
from hilbench.protocols.can_frame import CanFrame

log = logging.getLogger(__name__)

#: Bytes waiting for one client before its newest frames are dropped (a client that stopped reading).
MAX_PENDING = 4 << 20
#: Frames held for a client between rawmode and the end of the handshake delay.
MAX_HELD = 100_000
BEACON_INTERVAL = 2.0
#: Largest write to a client (python-can's socketcand client reads 1024 bytes at a time).
SEND_CHUNK = 1024


@dataclass
class _Job:
    frame: CanFrame
    interval: float
    next_t: float


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
    splitter: sc.MessageSplitter = field(default_factory=sc.MessageSplitter)
    mode: str = "nobus"
    out: bytearray = field(default_factory=bytearray)
    raw_at: float | None = None  # when frames may start flowing after rawmode
    held: list[str] = field(default_factory=list)
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


class SocketcandServer:
    """The socketcand door of a CAN host port; see the module docstring."""

    kind = "socketcand"

    def __init__(self, name: str = "can", *, bind: str = "127.0.0.1", port: int = 0, channel: str = "can0",
                 rawmode_delay: float = 0.1, beacon: bool = False) -> None:
        if not channel or len(channel) > sc.MAX_BUS_NAME:
            raise ValueError(f"a socketcand channel name has 1..{sc.MAX_BUS_NAME} characters, got {channel!r}")
        self.name = name
        self.channel = channel
        self.rawmode_delay = rawmode_delay
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((bind, port))
        except OSError:
            self.listener.close()
            raise
        self.listener.listen(16)
        self.listener.setblocking(False)
        self.clients: list[_Client] = []
        self.connections = 0
        self.malformed = 0
        self.wall_offset = 0.0
        self._beacon_sock: socket.socket | None = None
        self._beacon_next = 0.0
        if beacon:
            self._beacon_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def attach(self, medium: Any) -> None:
        """Learn the bus clock's mapping to Unix time (frames carry Unix time stamps)."""
        self.wall_offset = medium.wall_offset

    @property
    def address(self) -> tuple[str, int]:
        return self.listener.getsockname()[:2]

    @property
    def url(self) -> str:
        host, port = self.address
        return f"socketcand://{host}:{port}/{self.channel}"

    def describe(self) -> dict[str, Any]:
        host, port = self.address
        return {"host": host, "port": port, "channel": self.channel}

    # ------------------------------------------------------------------ host port duties

    def filenos(self) -> list[int]:
        return [self.listener.fileno()] + [c.sock.fileno() for c in self.clients]

    def _accept(self) -> None:
        while True:
            try:
                sock, addr = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            sock.setblocking(False)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.connections += 1
            client = _Client(sock, f"socketcand {addr[0]}:{addr[1]}")
            self.clients.append(client)
            self._reply(client, sc.HI)

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        """Accept clients and read their commands; returns the frames they send."""
        self._accept()
        out: list[tuple[str, CanFrame]] = []
        for client in list(self.clients):
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
                    if len(client.held) < MAX_HELD:
                        client.held.append(raw_text)
                    else:
                        client.dropped += 1
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

    def _queue(self, client: _Client, text: str) -> None:
        if len(client.out) > MAX_PENDING:
            client.dropped += 1
            return
        client.out += text.encode()

    def flush(self) -> None:
        for client in list(self.clients):
            if client.out:
                self._send(client)

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
            del out[:sent]
            if sent < cut:
                return

    def _reply(self, client: _Client, text: str) -> None:
        """A handshake or command reply in a write of its own (python-can reads replies whole)."""
        if client.out:
            self._send(client)
        client.out += text.encode()
        self._send(client)

    def deadline(self) -> float | None:
        times = []
        for c in self.clients:
            if c.raw_at is not None:
                times.append(c.raw_at)
            times.extend(j.next_t for j in c.jobs.values())
            if c.stat_interval:
                times.append(c.stat_next)
        if self._beacon_sock is not None:
            times.append(self._beacon_next)
        return min(times) if times else None

    def poll(self, now: float) -> list[tuple[str, CanFrame]]:
        """Timed work: end handshake delays, run cyclic BCM jobs, statistics and the beacon."""
        out: list[tuple[str, CanFrame]] = []
        for c in self.clients:
            if c.raw_at is not None and now >= c.raw_at:
                c.raw_at = None
                for text in c.held:
                    self._queue(c, text)
                c.held.clear()
            for job in c.jobs.values():
                if now >= job.next_t:
                    out.append((c.name, job.frame))
                    c.tx_frames += 1
                    c.tx_bytes += job.frame.length
                    job.next_t = max(job.next_t + job.interval, now) if job.interval > 0 else float("inf")
            if c.stat_interval and now >= c.stat_next:
                self._queue(c, sc.stat_message(c.rx_bytes, c.rx_frames, c.tx_bytes, c.tx_frames))
                c.stat_next = now + c.stat_interval
        if self._beacon_sock is not None and now >= self._beacon_next:
            self._beacon_next = now + BEACON_INTERVAL
            host, port = self.address
            with contextlib.suppress(OSError):
                self._beacon_sock.sendto(sc.beacon("hilbench", host, port, [self.channel], "hilbench emulated bus"),
                                         ("127.0.0.1", sc.BEACON_PORT))
        return out

    # ------------------------------------------------------------------ commands

    def _command(self, client: _Client, message: str, now: float, out: list[tuple[str, CanFrame]]) -> None:
        cmd = sc.parse_command(message)
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
            if new == "raw":
                client.raw_at = now + self.rawmode_delay if self.rawmode_delay > 0 else None
            else:
                client.raw_at = None
                client.held.clear()
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
                client.jobs[key] = _Job(cmd.frame, cmd.interval, now)  # type: ignore[arg-type]
                return
            if cmd.name == "update":
                frame = cmd.frame
                job = client.jobs.get((frame.can_id, frame.extended))  # type: ignore[union-attr]
                if job is not None:
                    job.frame = frame  # type: ignore[assignment]
                return
            if cmd.name == "delete":
                client.jobs.pop(key, None)
                return
            if cmd.name == "subscribe":
                client.subs[key] = _Sub(cmd.interval, None)
                return
            if cmd.name == "filter":
                client.subs[key] = _Sub(cmd.interval, cmd.mask)
                return
            if cmd.name == "unsubscribe":
                client.subs.pop(key, None)
                return
        if mode == "control" and cmd.name == "statistics":
            ms = int(cmd.value)
            client.stat_interval = ms / 1000.0
            client.stat_next = now + client.stat_interval
            return
        if cmd.name == "invalid":
            self.malformed += 1  # the daemon drops a malformed command and only logs it
            log.debug("socketcand: malformed command %r from %s", message, client.name)
            return
        self._reply(client, sc.ERROR_UNKNOWN)

    # ------------------------------------------------------------------ closing

    def _drop(self, client: _Client) -> None:
        if client in self.clients:
            self.clients.remove(client)
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
