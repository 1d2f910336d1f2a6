"""Giving memory back to the system once a flood is over.

A client that stops reading makes a server queue up to its bounds (megabytes
of bytearrays); when the client leaves or catches up the queues are freed,
but glibc's malloc keeps freed chunks in the middle of its heaps for reuse
and returns only the top of each: measured on a bench, 40 tap clients that
read nothing left the process 20-30 MB larger after they were gone, and
``malloc_trim(0)`` took it back (about 1 ms for a 50 MB heap).

:class:`Ebb` watches one queue's size (or a server's total): once it has held
more than :data:`HIGH` bytes and falls under :data:`LOW`, it asks for a trim.
Trims run in one background thread, coalesced and at most every
:data:`MIN_INTERVAL` seconds, so a server thread never waits for one. Where
the C library has no ``malloc_trim`` (musl, macOS) nothing happens.
"""

from __future__ import annotations

import contextlib
import ctypes
import threading
import time

#: A queue that held more than this many bytes ...
HIGH = 1 << 20
#: ... and falls under this many, asks for the memory to be given back.
LOW = 64 << 10
#: Seconds between trims at most (a queue that fills and empties over and over costs one trim per interval).
MIN_INTERVAL = 2.0
#: Seconds a trim waits after being asked, for the rest of a flood's queues to be freed with it.
DELAY = 0.2

_lock = threading.Lock()
_asked = threading.Event()
_trim = None
#: None until the first request; then whether this C library can trim (and the thread runs).
_can_trim: bool | None = None
#: Trims done (for tests and status reports).
trims = 0


def _malloc_trim():
    """glibc's ``malloc_trim``, or None where the C library has none."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        fn = ctypes.CDLL(None).malloc_trim
        fn.argtypes = [ctypes.c_size_t]
        fn.restype = ctypes.c_int
        return fn
    return None


def give_back() -> None:
    """Ask for freed memory to go back to the system soon (never blocks; coalesced with other requests)."""
    global _can_trim, _trim
    with _lock:
        if _can_trim is None:
            _trim = _malloc_trim()
            _can_trim = _trim is not None
            if _can_trim:
                threading.Thread(target=_run, name="hilbench-heap", daemon=True).start()
        if not _can_trim:
            return
    _asked.set()


def _run() -> None:
    global trims
    last = float("-inf")
    while True:
        _asked.wait()
        time.sleep(max(DELAY, last + MIN_INTERVAL - time.monotonic()))
        _asked.clear()
        _trim(0)  # type: ignore[misc]
        trims += 1
        last = time.monotonic()


class Ebb:
    """Watches a queue's size; :meth:`note` after it changes (0 when the queue is freed). Once it held more
    than ``high`` bytes (:data:`HIGH`) and falls under :data:`LOW`, :func:`give_back` is asked."""

    __slots__ = ("high", "limit")

    def __init__(self, high: int = HIGH) -> None:
        self.limit = high
        self.high = False

    def note(self, size: int) -> None:
        if size > self.limit:
            self.high = True
        elif self.high and size < LOW:
            self.high = False
            give_back()


__all__ = ["DELAY", "HIGH", "LOW", "MIN_INTERVAL", "Ebb", "give_back"]
