"""Serving rings: the bench hands a pty's device->host bytes to ``hilbench run`` clients in shared memory.

Issue 26's serving path (PLAN26 §8): on under a virtual clock unless
``HILBENCH_SERVE=0``, on the wall clock only with ``HILBENCH_SERVE=1`` (the
environment of ``hilbench run``; the preload shim decides). The bench's medium
writes what a served pty's client should read into a ring in a shared file
instead of the pty master, and the preload shim's ``read``, ``readv``,
``select``, ``poll``, ``ppoll`` and ``FIONREAD`` on that pty answer from the
ring. That is one hand-over (bench thread -> polling client) instead of two
(bench -> the tty layer's worker -> client). Bytes the client writes still go
through the kernel.

A port is served only after a client asked for it (``RDEV serve`` on the
port-state socket) and only while every other process that has the pty open
has this file mapped (so it runs the shim): anything else (a ``cat``, a
pyserial client without the shim) makes the port fall back to the kernel path
for good. Once every process that asked has ended (:meth:`ServeRings.orphaned`),
the port goes back to the kernel path, its unread bytes to the pty first.
Until it is served, and after it fell back, every byte goes to the pty. In
served mode the shim reads the pty first while it holds bytes written before
the switch (the kernel queue is older than the ring).

A file ``port_state.serve`` beside the port-state socket (same 0700
directory), native byte order, 8-byte words::

    header  magic "HBSERVE1" | version 1 | ports | port record size | 4 reserved words
    port    rdev | mode | head | tail | waiters | dropped | 2 reserved words | RING data bytes

``head`` (bench) and ``tail`` (clients, compare-and-swap) count bytes since the
start; ``head - tail`` are unread. ``mode``: 0 kernel, 1 served, 2 fallback.
A client that blocks counts itself in ``waiters`` and polls the FIFO
``serve.<i>`` (i: the port's index), to which the bench writes a byte after
each append while someone waits. Readers of this layout: ``hilbench/run/shim.c``.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import mmap
import os
import threading
import time
from collections.abc import Callable

MAGIC = b"HBSERVE1"
VERSION = 1
HEADER_SIZE = 64
RECORD_HEADER = 64
RING = 65536
RECORD_SIZE = RECORD_HEADER + RING
#: Word offsets in a port record.
RDEV, MODE, HEAD, TAIL, WAITERS, DROPPED = 0, 1, 2, 3, 4, 5
KERNEL, SERVED, FALLBACK = 0, 1, 2
FILE_NAME = "port_state.serve"
#: Wall seconds between two looks at whether a served port's clients are still alive.
ORPHAN_LOOK = 0.05


def _fetch_add() -> Callable[[int, int, int], int] | None:
    """gcc's ``__atomic_fetch_add_8`` (libatomic), or None without it."""
    try:
        f = getattr(ctypes.CDLL(ctypes.util.find_library("atomic") or "libatomic.so.1"), "__atomic_fetch_add_8")
    except (OSError, AttributeError):
        return None
    f.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_int]
    f.restype = ctypes.c_uint64
    return f


class ServeRings:
    """The bench's side: one ring per pty, written by the medium's thread (``append``) only."""

    def __init__(self, directory: str, rdevs: list[int]) -> None:
        self.path = os.path.join(directory, FILE_NAME)
        self._index = {rdev: i for i, rdev in enumerate(rdevs)}
        self._lock = threading.Lock()
        size = HEADER_SIZE + RECORD_SIZE * max(1, len(rdevs))
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        try:
            os.ftruncate(fd, size)
            self._map: mmap.mmap | None = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self._words: memoryview | None = memoryview(self._map).cast("Q")
        # The head moves with a locked add, a full barrier: the load of ``waiters`` after it cannot be done
        # before the new head is visible to clients (x86 lets a plain store wait in the store buffer while a
        # later load goes ahead; a client that counted itself a waiter and then saw the old head would then
        # sleep with nobody to wake it). Without libatomic: a plain store.
        self._add = _fetch_add()
        self._buf: ctypes.Array | None = (ctypes.c_char * size).from_buffer(self._map) if self._add else None
        self._base = ctypes.addressof(self._buf) if self._buf is not None else 0
        self._fifos: dict[int, int] = {}
        self._claimers: dict[int, set[int]] = {}  # port index -> pids that asked for its serving
        self._looked: dict[int, float] = {}  # port index -> wall time of the last look at them
        for rdev, i in self._index.items():
            self._words[self._word(i, RDEV)] = rdev
            fifo = os.path.join(directory, f"serve.{i}")
            os.mkfifo(fifo, 0o600)
            self._fifos[i] = os.open(fifo, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)  # never blocks, never EPIPE
        self._words[1], self._words[2], self._words[3] = VERSION, len(rdevs), RECORD_SIZE
        self._map[0:8] = MAGIC  # last: a reader that sees the magic sees the records

    @staticmethod
    def _word(i: int, word: int) -> int:
        return (HEADER_SIZE + RECORD_SIZE * i) // 8 + word

    def mode(self, rdev: int) -> int:
        """KERNEL, SERVED or FALLBACK (KERNEL for a pty this bench does not have)."""
        i = self._index.get(rdev)
        return KERNEL if i is None or self._words is None else self._words[self._word(i, MODE)]

    def claim(self, rdev: int, openers_ok: bool, pid: int | None = None) -> int:
        """A client (process ``pid``) asks to be served: SERVED if every opener runs the shim (``openers_ok``),
        else FALLBACK for good. Returns the mode."""
        with self._lock:
            i = self._index.get(rdev)
            if i is None or self._words is None:
                return KERNEL
            w = self._word(i, MODE)
            if self._words[w] != FALLBACK:
                self._words[w] = SERVED if openers_ok else FALLBACK
            if self._words[w] == SERVED:  # (no pid: a claim in the bench's own process, which outlives the ring)
                self._claimers.setdefault(i, set()).add(pid or os.getpid())
            return self._words[w]

    def orphaned(self, rdev: int) -> bytes | None:
        """While ``rdev`` is served, look (every :data:`ORPHAN_LOOK` s at most, at an append) whether any
        process that asked for its serving is still alive. If none is, the port goes back to the
        kernel path (KERNEL: a later client may ask again) and the ring's unread bytes are returned, to be
        written to the pty: a program without the shim that opens the port afterwards (a plain pyserial
        client, ``cat``) reads them and what follows from the pty. Else None."""
        i = self._index.get(rdev)
        words = self._words
        if i is None or words is None or self._map is None:
            return None
        base = self._word(i, 0)
        if words[base + MODE] != SERVED:
            return None
        now = time.monotonic()  # wall-clock: a service timer, not the bench's time
        if now - self._looked.get(i, 0.0) < ORPHAN_LOOK:
            return None
        self._looked[i] = now
        claimers = self._claimers.get(i, set())
        for pid in list(claimers):
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                claimers.discard(pid)
            except OSError:
                pass  # alive, not ours to signal
        if claimers:
            return None
        with self._lock:
            if words[base + MODE] != SERVED:
                return None
            words[base + MODE] = KERNEL
            head, tail = words[base + HEAD], words[base + TAIL]
            start, n = tail % RING, head - tail
            data = HEADER_SIZE + RECORD_SIZE * i + RECORD_HEADER
            first = min(n, RING - start)
            left = bytes(self._map[data + start:data + start + first]) + bytes(self._map[data:data + n - first])
            words[base + TAIL] = head
            return left

    def append(self, rdev: int, data: bytes) -> int | None:
        """Put ``data`` in the ring of a served pty: the bytes taken (what does not fit is dropped and
        counted), or None when the pty is not served (write it to the master then)."""
        with self._lock:
            i = self._index.get(rdev)
            if i is None or self._words is None or self._map is None:
                return None
            words = self._words
            if words[self._word(i, MODE)] != SERVED:
                return None
            head, tail = words[self._word(i, HEAD)], words[self._word(i, TAIL)]
            n = min(len(data), RING - (head - tail))
            base = HEADER_SIZE + RECORD_SIZE * i + RECORD_HEADER
            start = head % RING
            first = min(n, RING - start)
            self._map[base + start:base + start + first] = data[:first]
            if n > first:
                self._map[base:base + n - first] = data[first:n]
            if self._add is not None:
                self._add(self._base + self._word(i, HEAD) * 8, n, 5)  # (SEQ_CST: after the bytes, before waiters)
            else:
                words[self._word(i, HEAD)] = head + n  # one aligned store, after the bytes (x86-64: ordered)
            if n < len(data):
                words[self._word(i, DROPPED)] += len(data) - n
            if words[self._word(i, WAITERS)]:
                with contextlib.suppress(BlockingIOError):
                    os.write(self._fifos[i], b"x")
            return n

    def pending(self, rdev: int) -> int:
        """The bytes in the ring of ``rdev`` that no client has read yet (the lockstep's settle: they are on the
        client's side as soon as appended)."""
        i = self._index.get(rdev)
        words = self._words
        if i is None or words is None:
            return 0
        base = self._word(i, 0)
        return words[base + HEAD] - words[base + TAIL]

    def discard(self, rdev: int) -> None:
        """Drop the unread bytes (an input flush of the pty)."""
        with self._lock:
            i = self._index.get(rdev)
            if i is not None and self._words is not None:
                self._words[self._word(i, TAIL)] = self._words[self._word(i, HEAD)]

    def read(self, rdev: int) -> dict[str, int]:
        """The record's words (tests, diagnostics)."""
        i = self._index[rdev]
        assert self._words is not None
        return {name: self._words[self._word(i, word)] for name, word in
                (("mode", MODE), ("head", HEAD), ("tail", TAIL), ("waiters", WAITERS), ("dropped", DROPPED))}

    def close(self) -> None:
        """Unmap, close the FIFOs and remove the files."""
        with self._lock:
            if self._words is not None:
                self._words.release()
                self._words = None
            self._buf = None  # (its export of the map ends before the map closes)
            if self._map is not None:
                self._map.close()
                self._map = None
            for i, fd in self._fifos.items():
                with contextlib.suppress(OSError):
                    os.close(fd)
                with contextlib.suppress(OSError):
                    os.unlink(os.path.join(os.path.dirname(self.path), f"serve.{i}"))
            self._fifos.clear()
        with contextlib.suppress(OSError):
            os.unlink(self.path)


def mode_in(path: str, rdev: int) -> int | None:
    """The mode (KERNEL, SERVED or FALLBACK) of pty ``rdev`` in the rings file ``path``, read from another
    process (tools, diagnostics); None when the file has no record of it."""
    with open(path, "rb") as f:
        words = memoryview(f.read()).cast("Q")
    for i in range(words[2]):
        if words[ServeRings._word(i, RDEV)] == rdev:
            return words[ServeRings._word(i, MODE)]
    return None


def openers_run_the_shim(rdev: int, ring_path: str, exclude: int) -> bool:
    """Every process but ``exclude`` (the bench) with a descriptor on the pty ``rdev`` has ``ring_path``
    mapped, i.e. loaded the shim and found this bench's rings (a ``fuser``-style scan of ``/proc``)."""
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit() or int(entry.name) == exclude:
            continue
        fd_dir = os.path.join(entry.path, "fd")
        try:
            fds = os.listdir(fd_dir)
        except OSError:
            continue
        opens = False
        for fd in fds:
            with contextlib.suppress(OSError):
                st = os.stat(os.path.join(fd_dir, fd))
                if st.st_rdev == rdev and (st.st_mode & 0o170000) == 0o020000:
                    opens = True
                    break
        if not opens:
            continue
        try:
            with open(os.path.join(entry.path, "maps")) as maps:
                if ring_path not in maps.read():
                    return False
        except OSError:
            return False  # a process we cannot inspect: not known to run the shim
    return True


__all__ = ["FALLBACK", "FILE_NAME", "HEAD", "KERNEL", "MAGIC", "RECORD_SIZE", "RING", "SERVED", "ServeRings", "TAIL",
           "VERSION", "openers_run_the_shim"]
