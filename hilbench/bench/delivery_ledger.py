"""The delivery ledger: a shared page where a bench says which bytes its ptys' clients wrote are delivered.

``tcdrain`` on a USB adapter with nothing queued returns at once, and clients
call it when nothing is queued: dynamixel-sdk 3.x's ``clearPort()`` is
``ser.flush()`` before every packet. Under ``hilbench run`` a drain is a round
trip to the port-state server (:mod:`hilbench.bench.port_state_server`), unless the client
can tell that everything it wrote is already delivered. This ledger lets it:

- a client, before each ``write()`` to the pty, counts it in ``writing`` (the C
  shim, atomically; the Python fallback sets ``writing_py`` while its process has
  one under way, having no atomic read-modify-write), then stores the
  ``CLOCK_MONOTONIC`` time (ns) in ``dirty_ns`` (an atomic maximum) or
  ``dirty_py_ns``, and uncounts it once ``write()`` returned;
- the bench, in the medium's thread, each time a host port's last transmission
  has been delivered: reads the clock (``t0``), checks that no write is counted
  (else it looks again a little later), and if a non-blocking read of the pty
  master then finds nothing more, stores ``t0`` in ``idle_ns``: a write stamped
  before ``t0`` was either counted (no store) or had returned, so its bytes were
  taken, and they were delivered. "Everything stamped before ``idle_ns`` is
  delivered" never stops being true: one writer, no lock;
- a drain with ``max(dirty_ns, dirty_py_ns) < idle_ns`` needs no round trip. Each drain
  or output flush stores the clock in ``drain_ns``: the bench looks again when a write was
  under way only if its client drained just before it (dynamixel-sdk 3.x drains before
  every packet; 4.x never does, and its writes should not cost the bench wake-ups).

A file of ``64 + 64 * slots`` bytes beside the port-state socket (``port_state.ledger`` in
the same 0700 directory, so only this user's programs map it), native byte
order, 8-byte aligned words::

    header  magic "HBLEDGR1" | version 1 | slots | slot size 64 | 4 reserved words
    slot    rdev | idle_ns | dirty_ns | dirty_py_ns | writing | writing_py | drain_ns | 1 reserved word

Readers of this layout: ``hilbench/run/shim.c`` and
:mod:`hilbench.run.pyserial_shim` (which may not import hilbench, so it has
its own copy of these numbers; tests compare them).
"""

from __future__ import annotations

import contextlib
import mmap
import os
import threading

MAGIC = b"HBLEDGR1"
VERSION = 1
HEADER_SIZE = 64
SLOT_SIZE = 64
#: Word offsets in a slot.
RDEV, IDLE_NS, DIRTY_NS, DIRTY_PY_NS, WRITING, WRITING_PY, DRAIN_NS = 0, 1, 2, 3, 4, 5, 6
#: A drain at most this long before the latest write makes the bench look again while it is under way.
DRAINING = 10_000_000
#: The ledger's file name beside the port-state server's socket.
FILE_NAME = "port_state.ledger"


class DeliveryLedger:
    """The bench's side of the ledger: one slot per served pty, ``idle_ns`` written here only."""

    def __init__(self, path: str, rdevs: list[int]) -> None:
        self.path = path
        self._slot = {rdev: i for i, rdev in enumerate(rdevs)}
        self._lock = threading.Lock()
        size = HEADER_SIZE + SLOT_SIZE * max(1, len(rdevs))
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
        try:
            os.ftruncate(fd, size)
            self._map: mmap.mmap | None = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        words = memoryview(self._map).cast("Q")
        for rdev, i in self._slot.items():
            words[(HEADER_SIZE + SLOT_SIZE * i) // 8 + RDEV] = rdev
        words[1], words[2], words[3] = VERSION, len(rdevs), SLOT_SIZE
        self._map[0:8] = MAGIC  # last: a reader that sees the magic sees the slots
        self._words: memoryview | None = words

    def _index(self, rdev: int, word: int) -> int:
        return (HEADER_SIZE + SLOT_SIZE * self._slot[rdev]) // 8 + word

    def delivered(self, rdev: int, ns: int) -> None:
        """Every byte written to pty ``rdev`` before ``CLOCK_MONOTONIC`` ``ns`` is delivered."""
        with self._lock:
            if self._words is not None and rdev in self._slot:
                i = self._index(rdev, IDLE_NS)
                if ns > self._words[i]:
                    self._words[i] = ns  # one aligned 8-byte store: readers see the old or the new time

    def writers_idle(self, rdev: int) -> bool:
        """No client is inside a write() to pty ``rdev`` (as far as the ledger counts them)."""
        with self._lock:
            if self._words is None or rdev not in self._slot:
                return False
            return not self._words[self._index(rdev, WRITING)] and not self._words[self._index(rdev, WRITING_PY)]

    def draining(self, rdev: int) -> bool:
        """A client drained pty ``rdev`` shortly before its latest write: it will drain again."""
        with self._lock:
            if self._words is None or rdev not in self._slot:
                return False
            wrote = max(self._words[self._index(rdev, DIRTY_NS)], self._words[self._index(rdev, DIRTY_PY_NS)])
            return 0 <= wrote - self._words[self._index(rdev, DRAIN_NS)] < DRAINING

    def read(self, rdev: int) -> dict[str, int]:
        """The slot's words (for tests and diagnostics)."""
        with self._lock:
            if self._words is None:
                return {}
            return {name: self._words[self._index(rdev, word)]
                    for name, word in (("idle_ns", IDLE_NS), ("dirty_ns", DIRTY_NS), ("dirty_py_ns", DIRTY_PY_NS),
                                       ("writing", WRITING), ("writing_py", WRITING_PY), ("drain_ns", DRAIN_NS))}

    def close(self) -> None:
        """Unmap and remove the file (clients that mapped it keep their copy of the page: harmless)."""
        with self._lock:
            if self._words is not None:
                self._words.release()
                self._words = None
            if self._map is not None:
                self._map.close()
                self._map = None
        with contextlib.suppress(OSError):
            os.unlink(self.path)


__all__ = ["DIRTY_NS", "DIRTY_PY_NS", "DRAINING", "DRAIN_NS", "FILE_NAME", "HEADER_SIZE", "IDLE_NS", "MAGIC", "RDEV", "SLOT_SIZE",
           "VERSION", "WRITING", "WRITING_PY", "DeliveryLedger"]
