"""Fuzz targets: every reader of outside bytes and every server a client talks to, for the fuzz script and the
rough-input benchmarks.

A :class:`FuzzTarget` says how to drive one reader of outside bytes
(a protocol decoder, the capture parser, a monitor's tracker, the profiler)
with nothing but bytes, how fast its fastest line is, and how to make clean
traffic of its kind to mutate. Targets register in the ``hilbench.fuzz_targets``
entry-point group (:data:`hilbench.registry.fuzz_targets`), so a new family's
decoder joins ``tools/fuzz.py`` and the rough-input benchmarks with one line
in its package's ``pyproject.toml``. Each family keeps its targets in its own
modules (hilbench's: ``protocols/<format>_targets.py``, ``families/<family>_targets.py``,
a package's ``targets.py``); shared modules hold only generic ones (the capture
parser, the CAN bridges, the control channel's kit)::

    [project.entry-points."hilbench.fuzz_targets"]
    acme-frames = "acme_hilbench.targets:FRAMES"

The rule the targets are held to (the project's): a decoder never raises on
garbage, resynchronises in linear time and counts what it dropped; on pure
noise and on mutated captures it keeps up with at least ten times its fastest
line (``tools/bench_*.py`` measure it, ``tools/fuzz.py`` hunts for exceptions).

Servers join the same registry with ``kind = "server"``: their input is a
client's session (the bytes it sends over one connection, or its datagrams
framed by :func:`frame_datagram`), driven through the code the bench runs
(the socketcand daemon, the RFC 2217 server, a SCIP unit over TCP, the XRCE
agent, an RTPS participant, the control channel with each family's commands:
:mod:`hilbench.bench.control_targets`). For them a traceback the
server only logs (``log.exception``) counts as much as one it raises:
:class:`TracebackWatch` turns the first into :class:`LoggedTraceback`.
Datagram servers run without sockets: :class:`DatagramFrames` cuts a session
into datagrams, :class:`NetPort` takes what the server sends. A TCP server's
session goes through a real connection (:func:`session_socket`, :func:`send_some`,
:func:`drain`).

This module imports nothing from hilbench but :mod:`hilbench.errors` (and
:mod:`hilbench.registry` in :func:`targets`).
"""

from __future__ import annotations

import logging
import random
import socket
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from hilbench.errors import HilbenchError


class Reader(Protocol):
    """What a target makes: bytes in, counters out (one instance per input)."""

    def feed(self, data: bytes) -> None:
        """The next bytes of the input (any split)."""

    def finish(self) -> None:
        """The input ended."""

    def good(self) -> int:
        """Items decoded whole so far (packets, frames, stamps, records)."""

    def dropped(self) -> int:
        """Bytes (or items) discarded while resynchronising so far."""


@dataclass(frozen=True)
class FuzzTarget:
    """One reader of outside bytes (or a server, fed a client's session), as the fuzz script and the benchmarks
    drive it.

    ``make()`` returns a fresh :class:`Reader`; ``line_rate`` is the bytes per
    second of the fastest line it reads (``line`` says which: the target is ten
    times that on noise and mutated input); ``sample(rng, size)`` makes about
    ``size`` bytes of clean traffic (the seed of mutated inputs); ``kind`` is
    ``decoder``, ``instrument`` or ``server`` (a client's session; see the
    module docstring); ``frame(noise)`` puts noise where the reader
    would meet it (a capture's after a sound header; default: as it is);
    ``refuses`` are the exception types it raises by design, in one line, for
    input it must not read (a capture of a newer format version): counted as
    refusals, not as failures.
    """

    name: str
    title: str
    make: Callable[[], Reader]
    line_rate: float
    line: str
    sample: Callable[[random.Random, int], bytes]
    kind: str = "decoder"
    frame: Callable[[bytes], bytes] | None = None
    refuses: tuple[type[Exception], ...] = ()
    #: Longest input worth feeding it (0: as long as the fuzzer's own bound): a server's session of a kB
    #: already walks its states, and some cost a fraction of a millisecond per datagram.
    max_input: int = 0

    def noise(self, rng: random.Random, size: int) -> bytes:
        """``size`` random bytes, framed as the reader meets them."""
        data = rng.randbytes(size)
        return self.frame(data) if self.frame is not None else data


def targets() -> list[FuzzTarget]:
    """Every registered target, in registration order (built-ins first)."""
    from hilbench import registry

    return list(registry.fuzz_targets.values())


def noise(rng: random.Random, size: int) -> bytes:
    """``size`` random bytes."""
    return rng.randbytes(size)


def mutate(rng: random.Random, data: bytes, *, rate: float = 0.01) -> bytes:
    """``data`` with about ``rate`` of its bytes damaged: flipped bits, random bytes, bytes lost or added."""
    out = bytearray(data)
    n = max(1, int(len(out) * rate))
    for _ in range(n):
        if not out:
            break
        i = rng.randrange(len(out))
        op = rng.random()
        if op < 0.5:
            out[i] ^= 1 << rng.randrange(8)
        elif op < 0.75:
            out[i] = rng.randrange(256)
        elif op < 0.9:
            del out[i : i + rng.randrange(1, 8)]
        else:
            out[i:i] = rng.randbytes(rng.randrange(1, 8))
    return bytes(out)


def run(reader: Reader, data: bytes, chunk: int | Callable[[], int] = 65536) -> Reader:
    """Feed ``data`` in pieces of ``chunk`` bytes (or of the sizes it returns), then finish."""
    pos = 0
    n = len(data)
    while pos < n:
        size = chunk() if callable(chunk) else chunk
        reader.feed(data[pos : pos + max(1, size)])
        pos += max(1, size)
    reader.finish()
    return reader


class Counting:
    """A :class:`Reader` from callables: ``feed(data)`` and ``finish()`` return item lists, ``is_good(item)``
    tells packets from problems (or counts the good units in an item: the stamps of a batch), ``dropped()``
    reads the decoder's own counter."""

    def __init__(self, feed: Callable[[bytes], Any], finish: Callable[[], Any], is_good: Callable[[Any], int],
                 dropped: Callable[[], int]) -> None:
        self._feed = feed
        self._finish = finish
        self._is_good = is_good
        self._dropped = dropped
        self.items = 0
        self.good_items = 0

    def _count(self, items: Any) -> None:
        if items:
            for item in items:
                self.items += 1
                self.good_items += int(self._is_good(item))

    def feed(self, data: bytes) -> None:
        self._count(self._feed(data))

    def finish(self) -> None:
        self._count(self._finish())

    def good(self) -> int:
        return self.good_items

    def dropped(self) -> int:
        return self._dropped()


# --------------------------------------------------------------------------- servers


class LoggedTraceback(HilbenchError):
    """A server logged a traceback (``log.exception``) while it served an input: as bad as raising one."""


class TracebackWatch(logging.Handler):
    """Collects the tracebacks a server would print on the bench's stderr while it keeps serving: records
    with a traceback that hilbench's loggers emit, and exceptions that end a thread (a bench's line thread),
    while installed (:meth:`start`). :meth:`check` raises :class:`LoggedTraceback` with the first one, and
    forgets them."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[str] = []
        self._hook: Callable[[Any], None] | None = None

    def _keep(self, text: str) -> None:
        if len(self.records) < 16:
            self.records.append(text)

    def emit(self, record: logging.LogRecord) -> None:
        if record.exc_info:
            text = "".join(traceback.format_exception(*record.exc_info))  # type: ignore[misc]
            self._keep(f"{record.name}: {record.getMessage()}\n{text}")

    def _thread_died(self, args: Any) -> None:
        name = args.thread.name if args.thread is not None else "?"
        self._keep(f"thread {name} ended: " + "".join(traceback.format_exception(
            args.exc_type, args.exc_value, args.exc_traceback)))
        if self._hook is not None:
            self._hook(args)

    @classmethod
    def shared(cls) -> TracebackWatch:
        """The process's watch, started on first use and never stopped (a reader that raised never finishes,
        so its own watch would never be taken down); each session :meth:`clear` s it when it begins."""
        global _shared_watch
        with _watch_lock:
            if _shared_watch is None:
                _shared_watch = cls().start()
            return _shared_watch

    def clear(self) -> None:
        self.records.clear()

    def start(self) -> TracebackWatch:
        logging.getLogger("hilbench").addHandler(self)
        self._hook, threading.excepthook = threading.excepthook, self._thread_died
        return self

    def stop(self) -> None:
        logging.getLogger("hilbench").removeHandler(self)
        if threading.excepthook == self._thread_died and self._hook is not None:
            threading.excepthook = self._hook
        self._hook = None

    def check(self) -> None:
        if self.records:
            first = self.records[0]
            self.records.clear()
            raise LoggedTraceback(first)


_watch_lock = threading.Lock()
_shared_watch: TracebackWatch | None = None

#: Starts every datagram of a framed session (:func:`frame_datagram`).
DATAGRAM_MAGIC = b"\xa5\x5a"
#: The longest datagram a framed session carries (a jumbo frame's payload).
MAX_DATAGRAM = 9000


def frame_datagram(datagram: bytes, source: int = 0) -> bytes:
    """One datagram of a session in a byte stream: :data:`DATAGRAM_MAGIC`, the sender's number (which of the
    target's clients sent it), a 16-bit big-endian length, the datagram."""
    return DATAGRAM_MAGIC + bytes((source & 0xFF,)) + len(datagram).to_bytes(2, "big") + datagram


class DatagramFrames:
    """Cuts a byte stream of :func:`frame_datagram` frames into ``(source, datagram)``; split anywhere, a damaged
    length or header loses one datagram (the reader resynchronises at the next magic), never raises."""

    HEADER = len(DATAGRAM_MAGIC) + 3

    def __init__(self) -> None:
        self._buf = bytearray()
        self.skipped = 0

    def feed(self, data: bytes, final: bool = False) -> list[tuple[int, bytes]]:
        buf = self._buf
        buf += data
        out: list[tuple[int, bytes]] = []
        pos = 0
        magic, header = DATAGRAM_MAGIC, self.HEADER
        while True:
            start = buf.find(magic, pos)
            if start < 0:
                keep = len(buf) if final else max(pos, len(buf) - len(magic) + 1)  # (a magic split across feeds)
                self.skipped += keep - pos
                pos = keep
                break
            self.skipped += start - pos
            pos = start
            if len(buf) - pos < header:
                if final:
                    self.skipped += len(buf) - pos
                    pos = len(buf)
                break
            n = int.from_bytes(buf[pos + 3:pos + 5], "big")
            end = pos + header + n
            if n > MAX_DATAGRAM:
                pos += 1
                self.skipped += 1
                continue
            if end + len(magic) > len(buf) and not (final and end <= len(buf)):
                if final:  # cut short at the end of the session: what is there is skipped
                    pos += 1
                    self.skipped += 1
                    continue
                break  # the frame, or the next one's magic, is still to come
            if end < len(buf) and buf[end:end + len(magic)] != magic:
                pos += 1
                self.skipped += 1
                continue
            out.append((buf[pos + 2], bytes(buf[pos + header:end])))
            pos = end
        del buf[:pos]
        return out


#: A TCP session's pieces are sent in writes of at least this many bytes: the server still meets every split
#: the fuzzer makes at a write's end, and a session costs a few system calls, not hundreds.
SESSION_WRITE = 512


def session_socket(address: tuple[str, int]) -> socket.socket:
    """A client's connection to a server under test, non-blocking once made."""
    sock = socket.create_connection(address, timeout=5)
    sock.setblocking(False)
    return sock


def send_some(sock: socket.socket, data: bytes) -> bool:
    """Send one write of a session; False once the server closed the connection (the session ends there).
    What the server does not read at once is lost, as a client's would be."""
    view = memoryview(data)
    while view:
        try:
            sent = sock.send(view)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError:
            return False
        view = view[sent:]
    return True


class TcpSession:
    """A fuzz session against a TCP server run in this process: the input goes out in writes of
    :data:`SESSION_WRITE` bytes, the server runs one round after each (``_round``), and at the end the
    client leaves and the server must let it go within 20 rounds (``_client_gone``, else
    ``kept_client`` is the failure). A subclass sets up its server, then calls ``_connect``."""

    kept_client = "the server kept a client that left"

    def _connect(self, address: tuple[str, int]) -> None:
        self.watch = TracebackWatch.shared()
        self.watch.clear()
        self.received = 0
        self.pending = bytearray()
        self.sock: socket.socket | None = session_socket(address)

    def _round(self) -> None:
        raise NotImplementedError

    def _client_gone(self) -> bool:
        raise NotImplementedError

    def _write(self) -> None:
        if self.sock is not None and not send_some(self.sock, bytes(self.pending)):
            self.sock.close()
            self.sock = None
        self.pending.clear()
        self._round()

    def feed(self, data: bytes) -> None:
        self.pending += data
        if len(self.pending) >= SESSION_WRITE:
            self._write()

    def finish(self) -> None:
        try:
            self._write()
            if self.sock is not None:
                self.sock.close()
                self.sock = None
            for _ in range(20):  # the server notices the client left within a few rounds
                self._round()
                if self._client_gone():
                    break
            assert self._client_gone(), self.kept_client
            self.watch.check()
        finally:
            if self.sock is not None:
                self.sock.close()

    def good(self) -> int:
        return self.received


def drain(sock: socket.socket) -> bytes:
    """Whatever the server sent that a non-blocking read gets now."""
    out = bytearray()
    while True:
        try:
            chunk = sock.recv(65536)
        except OSError:  # (BlockingIOError: nothing more for now)
            break
        if not chunk:
            break
        out += chunk
    return bytes(out)


#: A saturated 100 Mbit/s Ethernet link of 100-byte datagrams (166 byte times each on the wire), in framed bytes
#: per second: the line of the datagram servers' targets.
LINK_100M = 100e6 / (8 * 166) * (100 + DatagramFrames.HEADER)


def check_address(dst: Any) -> None:
    """What ``socket.sendto`` refuses in an address: raises as it would (a bad port is an OverflowError)."""
    host, port = dst
    if not isinstance(host, str):
        raise TypeError(f"str, bytes or bytearray expected, not {type(host).__name__}")
    if not isinstance(port, int):
        raise TypeError(f"'{type(port).__name__}' object cannot be interpreted as an integer")
    if not 0 <= port <= 65535:
        raise OverflowError("getsockaddrarg: port must be 0-65535.")


class _WallClock:
    """The wall clock as a medium's clock answers (this module sits below transports: none of their imports)."""

    virtual = False
    now = staticmethod(time.monotonic)

    @staticmethod
    def wall(t: float) -> float:
        return t + (time.time() - time.monotonic())


class NetPort:
    """What a device on a datagram net holds (``send``, ``call_at``), for a target run without sockets:
    datagrams are checked as ``sendto`` checks them and counted, timers kept to be run by the session."""

    def __init__(self) -> None:
        self.sent = 0
        self.timers: list[Any] = []
        self.clock = _WallClock()  # (a DevicePort's clock: the wall clock, a medium's default)

    def now(self) -> float:
        return self.clock.now()

    def send(self, data: bytes, dst: Any, *, via: Any = None, t: float | None = None) -> None:
        check_address(dst)
        bytes(data)
        self.sent += 1

    def call_at(self, t: float | None, fn: Any) -> None:
        if len(self.timers) < 1024:
            self.timers.append(fn)

    def run_timers(self) -> None:
        timers, self.timers = self.timers, []
        for fn in timers:
            fn()


__all__ = ["DATAGRAM_MAGIC", "LINK_100M", "MAX_DATAGRAM", "Counting", "DatagramFrames", "FuzzTarget",
           "LoggedTraceback", "NetPort", "Reader", "SESSION_WRITE", "TcpSession", "TracebackWatch", "check_address", "drain",
           "frame_datagram", "mutate", "noise", "run", "send_some", "session_socket", "targets"]
