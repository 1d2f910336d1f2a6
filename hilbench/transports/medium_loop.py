"""The thread that runs a medium: a heap of timed callbacks, a wake-up pipe, start, stop and close.

Each medium runs everything in one thread (reading host ports, delivering,
its devices' callbacks), so device logic needs no locks. What waits for what
differs by medium (a serial line reads its host ports and joins deliveries, a
CAN bus polls its doors' deadlines, a datagram net reads sockets), so
:meth:`LoopMedium._run` is the subclass's; the rest is here:

- :meth:`~LoopMedium.call_at` queues ``fn`` for time ``t`` from any thread
  (the heap is ordered by time, then by arrival, so equal times run in order);
- :meth:`~LoopMedium._run_due` runs what is due, in the medium's thread; a
  failing callback is counted (``stats.callback_errors``) and logged, and the
  medium keeps running;
- :class:`WakePipe` wakes the thread out of its wait when another thread
  queued work (or stops it);
- :meth:`~LoopMedium.start` returns once the thread runs, with what it runs
  under known (:attr:`~LoopMedium.scheduling`, a paced medium's
  :attr:`~LoopMedium.cpu_latency`), so a manifest written next can say it.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import os
import threading
from collections.abc import Callable
from typing import Any, ClassVar

from hilbench.transports.clock import WALL, WallClock, awake_cpus, reduce_timer_slack, try_realtime
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
    A paced medium's thread asks for precise wake-ups (timer slack, idle CPUs kept awake:
    :mod:`~hilbench.transports.clock`), and for SCHED_FIFO where :attr:`realtime` is set.
    """

    #: The thread's name is ``<thread_prefix>-<medium name>``.
    thread_prefix: ClassVar[str] = "medium"
    stats: Any

    def __init__(self, name: str, baud: int | None, *, paced: bool = False, clock: WallClock = WALL) -> None:
        super().__init__(name, baud, paced=paced, clock=clock)
        #: Run the thread under SCHED_FIFO if the OS allows it (a subclass sets it: paced serial lines).
        self.realtime = False
        #: What the thread runs under once started ("SCHED_FIFO 10", or SCHED_OTHER and why).
        self.scheduling: str | None = None
        #: A paced medium's request that idle CPUs wake fast (:class:`~hilbench.transports.clock.CpuLatency`)
        #: once started: "0 us", or why not; None when not paced.
        self.cpu_latency: str | None = None
        # (time, sequence, function, joinable): a subclass may let joinable events (a serial line's
        # deliveries) wait for later ones; the sequence keeps equal times in arrival order.
        self._events: list[tuple[float, int, Callable[[], None], bool]] = []
        self._seq = itertools.count()
        self._waker = WakePipe()
        self._thread: threading.Thread | None = None
        self._ident: int | None = None  # the thread's, while it runs (cheaper to compare than the Thread)
        self._started = threading.Event()
        self._stop = threading.Event()

    # ------------------------------------------------------------------ timers

    def call_at(self, t: float | None, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the medium's thread at time ``t`` (None: at once); thread-safe."""
        with self._lock:
            self._push(self._now() if t is None else t, fn)
        if threading.get_ident() != self._ident:
            self._wake()

    def _push(self, t: float, fn: Callable[[], None], joinable: bool = False) -> None:
        """Queue ``fn`` at ``t`` (the caller holds the lock or is the medium's thread)."""
        heapq.heappush(self._events, (t, next(self._seq), fn, joinable))

    def _run_due(self) -> None:
        """Run what is due (the medium's thread)."""
        events, lock, clock = self._events, self._lock, self._now
        while True:
            with lock:
                if not events or events[0][0] > clock():
                    return
                _, _, fn, _ = heapq.heappop(events)
            try:
                fn()
            except Exception:  # one faulty callback must not stop the medium
                self.stats.callback_errors += 1
                log.exception("timed callback failed on %s medium %s", self.kind, self.name)

    # ------------------------------------------------------------------ thread

    def start(self) -> None:
        """Run the medium in a background thread; returns once it runs (:attr:`scheduling` and
        :attr:`cpu_latency` known)."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._started.clear()
        self._thread = threading.Thread(target=self._main, name=f"{self.thread_prefix}-{self.name}", daemon=True)
        self._thread.start()
        self._started.wait(5)

    def _main(self) -> None:
        self._ident = threading.get_ident()
        if self.paced:
            reduce_timer_slack()
        self.scheduling = try_realtime() if self.realtime else "SCHED_OTHER"
        with awake_cpus(self.paced) as self.cpu_latency:
            self._started.set()
            self._run()

    def stop(self) -> None:
        """Stop the thread (host ports stay open; close them separately)."""
        self._stop.set()
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
            self._ident = None

    def in_medium_thread(self) -> bool:
        return threading.get_ident() == self._ident

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
        self._ident = thread.ident if thread is not None else None

    def vt_head(self) -> tuple[float, int] | None:
        with self._lock:
            return self._events[0][:2] if self._events else None

    def vt_deadline(self) -> float | None:
        """Timed work outside the heap (a host port's), in virtual time."""
        return None

    def vt_run_one(self) -> None:
        with self._lock:
            _, _, fn, _ = heapq.heappop(self._events)
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
