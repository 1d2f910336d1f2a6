"""The thread that runs a medium: a heap of timed callbacks, a wake-up pipe, start, stop and close.

Each medium runs everything in one thread (reading host ports, delivering,
its devices' callbacks), so device logic needs no locks. What waits for what
differs by medium (a CAN bus polls its doors' deadlines, a datagram net reads
sockets), so :meth:`LoopMedium._run` is the subclass's; the rest is here:

- :meth:`~LoopMedium.call_at` queues ``fn`` for time ``t`` from any thread
  (the heap is ordered by time, then by arrival, so equal times run in order);
- :meth:`~LoopMedium._run_due` runs what is due, in the medium's thread; a
  failing callback is counted (``stats.callback_errors``) and logged, and the
  medium keeps running;
- :class:`WakePipe` wakes the thread out of its wait when another thread
  queued work (or stops it).
"""

from __future__ import annotations

import heapq
import itertools
import logging
import os
import threading
from collections.abc import Callable
from typing import Any, ClassVar

from hilbench.transports.clock import WALL, WallClock
from hilbench.transports.medium import Medium

log = logging.getLogger(__name__)


class WakePipe:
    """A self-pipe: :meth:`wake` (any thread) makes :attr:`fd` readable until :meth:`drain` (the waiting thread).

    Both ends are non-blocking: a wake while the pipe is full is already pending, and one after
    :meth:`close` has nobody left to wake, so neither :meth:`wake` nor :meth:`drain` raises.
    """

    __slots__ = ("fd", "_w")

    def __init__(self) -> None:
        self.fd, self._w = os.pipe()
        os.set_blocking(self.fd, False)
        os.set_blocking(self._w, False)

    def wake(self) -> None:
        try:
            os.write(self._w, b"x")
        except OSError:  # BlockingIOError: already pending; another OSError: closed, nobody waits
            pass

    def drain(self, size: int = 4096) -> None:
        """Read pending wake-ups (up to ``size`` of them)."""
        try:
            os.read(self.fd, size)
        except OSError:  # BlockingIOError: none pending; another OSError: closed under a reader finishing up
            pass

    def close(self) -> None:
        for fd in (self.fd, self._w):
            try:
                os.close(fd)
            except OSError:
                pass


class LoopMedium(Medium):
    """A medium run by one thread of its own; subclasses implement :meth:`_run` (see the module docstring).

    They wait on ``self._waker.fd`` besides their ports, ``drain()`` it when it is ready, stop when
    ``self._stop`` is set, and call :meth:`_run_due` each round. ``stats.callback_errors`` counts failures.
    """

    #: The thread's name is ``<thread_prefix>-<medium name>``.
    thread_prefix: ClassVar[str] = "medium"
    stats: Any

    def __init__(self, name: str, baud: int | None, *, paced: bool = False, clock: WallClock = WALL) -> None:
        super().__init__(name, baud, paced=paced, clock=clock)
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._waker = WakePipe()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ timers

    def call_at(self, t: float | None, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the medium's thread at time ``t`` (None: at once); thread-safe."""
        with self._lock:
            self._push(self._now() if t is None else t, fn)
        if threading.current_thread() is not self._thread:
            self._wake()

    def _push(self, t: float, fn: Callable[[], None]) -> None:
        """Queue ``fn`` at ``t`` (the caller holds the lock or is the medium's thread)."""
        heapq.heappush(self._events, (t, next(self._seq), fn))

    def _run_due(self) -> None:
        while True:
            with self._lock:
                if not self._events or self._events[0][0] > self._now():
                    return
                _, _, fn = heapq.heappop(self._events)
            try:
                fn()
            except Exception:  # one faulty callback must not stop the medium
                self.stats.callback_errors += 1
                log.exception("timed callback failed on %s medium %s", self.kind, self.name)

    # ------------------------------------------------------------------ thread

    def start(self) -> None:
        """Run the medium in a background thread."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"{self.thread_prefix}-{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread (host ports stay open; close them separately)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def _wake(self) -> None:
        self._waker.wake()

    def _run(self) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ virtual time (a VirtualLoop runs it)

    def vt_attach(self, loop: Any) -> None:
        """Run in ``loop`` instead of a thread of its own; its events join the loop's one sequence."""
        self._seq = loop.seq

    def vt_thread(self, thread: threading.Thread | None) -> None:
        """The loop's thread is the medium's (its callbacks run there), or None once the loop stops."""
        self._thread = thread

    def vt_head(self) -> tuple[float, int] | None:
        with self._lock:
            return self._events[0][:2] if self._events else None

    def vt_deadline(self) -> float | None:
        """Timed work outside the heap (a host port's), in virtual time."""
        return None

    def vt_run_one(self) -> None:
        with self._lock:
            _, _, fn = heapq.heappop(self._events)
        try:
            fn()
        except Exception:  # one faulty callback must not stop the bench
            self.stats.callback_errors += 1
            log.exception("timed callback failed on %s medium %s", self.kind, self.name)

    def vt_poll(self, now: float) -> None:
        """Host ports' timed work due at ``now`` (after the bench phase's events)."""

    def vt_flush(self) -> None:
        """End of the bench phase: host ports send what was queued for them."""

    def vt_fds(self) -> list[int]:
        return [self._waker.fd]

    def vt_read(self, ready: list[int], now: float) -> bool:
        """Read what ready host ports have, at ``now``; True if any of the medium's descriptors was ready."""
        if self._waker.fd in ready:
            self._waker.drain()
            return True
        return False

    def vt_commit(self, now: float) -> None:
        """Put what :meth:`vt_read` took on the medium (at ``now``)."""

    def close(self) -> None:
        """Stop the medium and release its wake-up pipe."""
        self.stop()
        self._waker.close()


__all__ = ["LoopMedium", "WakePipe"]
