"""The bench in virtual time: one thread runs every medium's events, host ports and device timers in rounds.

A bench with ``virtual_time`` has a :class:`~hilbench.transports.clock.VirtualClock` and one
:class:`VirtualLoop` instead of a thread per medium. The loop owns the clock: time moves only when the loop
moves it, and then it *jumps* to the next event (a delivery, a frame, a device timer), so a bench where
nothing happens for a minute gets through that minute in no time, and every run of the same inputs does
the same things at the same instants. A round:

- **A, bench phase**: every event due at ``now`` of every medium, in ``(t, seq)`` order (the media share
  one sequence counter, so events at the same instant run in the order they were queued, whatever medium
  they are on); what deliveries write to host ports is buffered, and written once per port at the end of
  the phase (:meth:`~hilbench.transports.serial_medium.SerialMedium.vt_flush`);
- **D, input**: a non-blocking look at the host ports (ptys, sockets) and the media's wake-up pipes
  (``call_at`` from other threads: a control command, a test); what a port has is read in one read,
- **E, commit**: and put on its medium at ``now``, one transmission per port and round (a program's
  writes at one instant are one burst: computation takes no virtual time);
- **F, advance**: if anything is due at ``now`` (a zero-delay reply), another round at the same instant;
  otherwise ``now`` becomes the next event's time, as far as the mode allows.

(B and C, settling the ptys and waking lockstep clients, come with the clock shim's controller.)

Modes. ``hold`` (the default): time advances only through :meth:`VirtualLoop.run_for` /
:meth:`VirtualLoop.run_until` (tests and scripts in the bench's process drive it; lockstep clients under
``hilbench run`` will, once the clock shim and controller exist). ``free``: time runs from event to event
on its own, as fast as the bench computes them. With nothing due in either mode the loop sleeps until a host port or another thread has
something for it.

Programs outside the bench's process are not part of the lockstep yet: what they write is stamped with
the virtual instant the loop reads it at, and their own clocks are the wall clock.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from hilbench.transports.clock import VirtualClock
from hilbench.transports.medium_loop import WakePipe
from hilbench.transports.readiness import Readiness

log = logging.getLogger(__name__)

#: Longest the loop sleeps in real time with nothing to do before looking at its media again (service
#: timers of host ports, such as a socketcand client's stall timer, run on the wall clock).
IDLE_LOOK = 0.1
#: Reads of one medium's host ports in one round, so a flood cannot keep the loop at one instant for ever.
MAX_READ_ROUNDS = 8

MODES = ("hold", "free")


@dataclass
class LoopStats:
    """What the loop did: rounds, the rounds that stayed at the same instant, events run, time jumps."""

    rounds: int = 0
    delta_rounds: int = 0
    events: int = 0
    advances: int = 0
    callback_errors: int = 0


class VirtualLoop:
    """Runs the media of one bench on a :class:`~hilbench.transports.clock.VirtualClock`; see the module
    docstring. Add media with :meth:`add` before :meth:`start`."""

    def __init__(self, clock: VirtualClock, *, mode: str = "hold", name: str = "bench") -> None:
        if mode not in MODES:
            raise ValueError(f"virtual time mode must be one of {', '.join(MODES)}, got {mode!r}")
        self.clock = clock
        clock.loop = self
        self.name = name
        self.mode = mode
        self.stats = LoopStats()
        #: One sequence for every medium's events: equal times run in the order they were queued.
        self.seq = itertools.count()
        self.media: list[Any] = []
        # The loop's own timers (bench-side sleeps, run_until targets): (t, seq, fn)
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._target: float | None = None  # run_until: advance a held clock up to here
        self._settled = float("-inf")  # the latest instant whose events have all run
        self._waker = WakePipe()
        self._stop = threading.Event()
        self._paused = 0
        self._holding = False  # the loop waits in paused()
        self._thread: threading.Thread | None = None
        self._readiness = Readiness([])
        self._news = Readiness([])
        #: The lockstep controller (:class:`~hilbench.bench.lockstep.Lockstep`) when clients under
        #: ``hilbench run`` share the clock (phases B, C, D and F wait for them); None: no clients.
        self.lockstep: Any = None

    # ------------------------------------------------------------------ wiring

    def add(self, medium: Any) -> None:
        """Run ``medium`` (built with this loop's clock) in this loop; before :meth:`start`."""
        if medium.clock is not self.clock:
            raise ValueError(f"medium {medium.name!r} is not on this loop's clock")
        vt_attach = getattr(medium, "vt_attach", None)
        if vt_attach is None:
            raise TypeError(f"{type(medium).__name__} {medium.name!r} cannot run in virtual time (no vt_attach)")
        vt_attach(self)
        self.media.append(medium)

    @property
    def thread(self) -> threading.Thread | None:
        return self._thread

    def in_loop(self) -> bool:
        return self._thread is not None and threading.current_thread() is self._thread

    def wake(self) -> None:
        """Make the loop look at its inputs now (any thread)."""
        self._waker.wake()

    # ------------------------------------------------------------------ timers of the loop itself

    def call_at(self, t: float | None, fn: Callable[[], None]) -> None:
        """Run ``fn`` in the loop's thread at virtual time ``t`` (None: now); thread-safe."""
        with self._lock:
            heapq.heappush(self._events, (self.clock.now() if t is None else t, next(self.seq), fn))
        if not self.in_loop():
            self.wake()

    # ------------------------------------------------------------------ driving the clock (other threads)

    def run_until(self, t: float, timeout: float | None = None) -> float:
        """Advance the clock to ``t``, running every event before it; returns once there (the new now).
        TimeoutError after ``timeout`` real seconds. Not from the loop's own thread."""
        if self.in_loop():
            raise RuntimeError("run_until from the loop's own thread would wait for itself")
        if self._thread is None:
            raise RuntimeError("the virtual loop is not running (start the bench first)")
        with self._cv:
            self._target = t if self._target is None else max(self._target, t)
            self.wake()
            if not self._cv.wait_for(lambda: self._settled >= t or self._stop.is_set(), timeout):
                raise TimeoutError(f"virtual time did not reach {t} within {timeout} s (now {self.clock.now()})")
            return self.clock.now()

    def run_for(self, seconds: float, timeout: float | None = None) -> float:
        """Advance the clock by ``seconds`` (see :meth:`run_until`)."""
        return self.run_until(self.clock.now() + seconds, timeout)

    def hold(self) -> None:
        """Time moves only through :meth:`run_for` / :meth:`run_until`."""
        self.mode = "hold"
        self.wake()

    def free(self) -> None:
        """Time runs from event to event on its own."""
        self.mode = "free"
        self.wake()

    def sleep(self, seconds: float) -> None:
        """Block the calling thread (not the loop's) until ``seconds`` of virtual time have passed."""
        if self.in_loop():
            raise RuntimeError("the loop's own thread cannot sleep in virtual time: schedule a call_at")
        done = threading.Event()
        self.call_at(self.clock.now() + max(0.0, seconds), done.set)
        while not done.wait(IDLE_LOOK):
            if self._stop.is_set():
                return

    def wait_event(self, event: threading.Event, timeout: float | None) -> bool:
        """Wait for ``event``, or until ``timeout`` virtual seconds have passed; returns ``event.is_set()``."""
        if self.in_loop():
            raise RuntimeError("the loop's own thread cannot wait in virtual time: schedule a call_at")
        expired = threading.Event()
        if timeout is not None:
            self.call_at(self.clock.now() + max(0.0, timeout), expired.set)
        while not event.wait(0.001):
            if expired.is_set() or self._stop.is_set():
                break
        return event.is_set()

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Keep the loop between rounds for the block (a test that prepares input for one round): returns
        once the loop waits at the start of a round, so it reads nothing until the block ends."""
        with self._cv:
            self._paused += 1
            self.wake()
            if self._thread is not None and not self.in_loop():
                self._cv.wait_for(lambda: self._holding or self._stop.is_set(), 5.0)
        try:
            yield
        finally:
            with self._cv:
                self._paused -= 1
                self._cv.notify_all()
            self.wake()

    # ------------------------------------------------------------------ thread

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"vt-{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5)
        self._thread = None
        for medium in self.media:
            medium.vt_thread(None)
        with self._cv:
            self._cv.notify_all()

    def close(self) -> None:
        self.stop()
        self._waker.close()

    def _run(self) -> None:
        for medium in self.media:
            medium.vt_thread(threading.current_thread())
        try:
            while not self._stop.is_set():
                self._round()
        except Exception:  # (a bug here must be loud: the bench's time stops)
            log.exception("virtual loop %s failed; the bench's time has stopped", self.name)
            raise
        finally:
            with self._cv:
                self._cv.notify_all()

    # ------------------------------------------------------------------ one round

    def _heads(self) -> list[tuple[float, int, Any]]:
        """The next event of each medium and of the loop: (t, seq, owner)."""
        heads = []
        with self._lock:
            if self._events:
                t, seq, _ = self._events[0]
                heads.append((t, seq, self))
        for medium in self.media:
            head = medium.vt_head()
            if head is not None:
                heads.append((head[0], head[1], medium))
        return heads

    def _next_time(self, now: float) -> float | None:
        """The next instant anything is due: a queued event (possibly ``now`` itself: a zero-delay one), or a
        host port's timed work after ``now`` (its work due at ``now`` ran in this round's bench phase)."""
        times = [h[0] for h in self._heads()]
        times += [t for m in self.media if (t := m.vt_deadline()) is not None and t > now]
        return min(times) if times else None

    def _run_one(self) -> None:
        with self._lock:
            _, _, fn = heapq.heappop(self._events)
        try:
            fn()
        except Exception:
            self.stats.callback_errors += 1
            log.exception("virtual-time timer failed")

    def _bench_phase(self, now: float) -> None:
        """A: run everything due at ``now`` in (t, seq) order; then each medium writes to its hosts once."""
        stats = self.stats
        while True:
            due = [h for h in self._heads() if h[0] <= now]
            if not due:
                break
            owner = min(due, key=lambda h: (h[0], h[1]))[2]
            if owner is self:
                self._run_one()
            else:
                owner.vt_run_one()
            stats.events += 1
        for medium in self.media:
            medium.vt_poll(now)  # timed work of host ports (a socketcand client's cyclic job)
            medium.vt_flush()

    def _commit(self, now: float) -> None:
        """E: put what the host ports had on the media, at ``now``."""
        for medium in self.media:
            medium.vt_commit(now)

    def _held(self) -> bool:
        return any(medium.vt_held() for medium in self.media if hasattr(medium, "vt_held"))

    def _input(self, now: float, timeout: float | None, commit: bool = True) -> bool:
        """D and E: look at the host ports and wake-up pipes (waiting up to ``timeout`` real seconds,
        None: until something comes), read what they have and commit it at ``now`` (``commit``, and no
        lockstep client is there: a serial line deferring its clients' input keeps it for :meth:`_commit`,
        also when a client joined during the wait). True if anything came."""
        fds = [self._waker.fd]
        for medium in self.media:
            fds += medium.vt_fds()
        r = self._readiness
        if fds != r.key:
            r = self._readiness = Readiness(fds)
        ready = r.look() if timeout == 0 else r.idle(timeout)
        if not ready:
            return False
        got = False
        if self._waker.fd in ready:
            self._waker.drain()
            got = True
        for medium in self.media:
            try:
                if medium.vt_read(ready, now):
                    got = True
            except Exception:  # (a host port closed under the loop: count it, keep the bench's time going)
                self.stats.callback_errors += 1
                log.exception("reading the host ports of %s failed", medium.name)
        ls = self.lockstep
        if commit and (ls is None or not ls.active()):  # (lockstep clients': when they all wait, in _lockstep)
            self._commit(now)
        return got

    def _round(self) -> None:
        clock, stats = self.clock, self.stats
        with self._cv:
            if self._paused:
                self._holding = True
                self._cv.notify_all()
                self._cv.wait_for(lambda: not self._paused or self._stop.is_set())
                self._holding = False
        now = clock.now()
        stats.rounds += 1
        ls = self.lockstep
        if ls is not None:
            ls.publish(now)
        self._bench_phase(now)
        if ls is not None:
            ls.wake_due(ls.settle())  # B and C: clients see what the bench did at now before they act at now
        # (with lockstep clients what they write is sent once they all wait, in _lockstep: a client woken
        # in C may be between two writes of one instant now)
        self._input(now, 0)
        nxt = self._next_time(now)
        if nxt is not None and nxt <= now:
            stats.delta_rounds += 1
            return  # zero-delay work: another round at the same instant
        if ls is not None and not ls.active():
            self._commit(now)  # (what the last client wrote before it left)
            ls.end_stall()  # (the last client left while time followed the wall clock)
        elif ls is not None:
            t = self._lockstep(ls, now, nxt)
            with self._cv:
                self._settled = now
                if t is not None and t > now:
                    self._advance(t)
                else:
                    self._cv.notify_all()
            return
        with self._cv:
            self._settled = now
            target = self._target
            limit = float("inf") if self.mode == "free" else target if target is not None else now
            if nxt is not None and nxt <= limit:
                self._advance(nxt)
                return
            if target is not None and target > now:
                self._advance(target)  # nothing before the target: jump to it
                return
            self._target = None
            self._cv.notify_all()
        # Nothing to do at this instant and time may not (or need not) move: wait for input or another thread.
        self._input(now, IDLE_LOOK)

    def _lockstep(self, ls: Any, now: float, nxt: float | None) -> float | None:
        """D with lockstep clients: wait until every client thread waits (or a stall lets time follow the
        wall clock); returns the time to move to (None: another round at ``now``: input came, or a client
        was woken to look again). ``nxt``: the bench's next event."""
        while not self._stop.is_set():
            real = time.monotonic()  # wall-clock: the stall watchdog and /proc looks run in real time
            # (input first: what a client wrote before it began to wait is read before the look that may find
            # every client waiting, and a write after the look keeps its writer running or its bytes in flight)
            if self._input(now, 0, commit=False):
                self._commit(now)
                return None  # what clients wrote is committed at now: its zero-delay work runs first
            v = ls.look(real)
            if v.recheck:
                ls.wake(v.recheck)
                continue
            if v.again:
                continue
            if v.quiet and self._held():
                self._commit(now)  # every client waits: what they wrote at now goes on the line, one burst a port
                return None
            if v.quiet:
                ls.end_stall()
                if not ls.active():
                    return None  # the last client just left: time is the mode's again (hold: it stays)
                if v.next_ns is not None and (nxt is None or v.next_ns / 1e9 <= nxt):
                    return ls.moved_to(max(v.next_ns, ls.vnow_ns))
                if nxt is not None:
                    return nxt
                # everyone waits without a deadline and the bench has nothing scheduled: only input moves it
                self._wait_news(ls, IDLE_LOOK)
                return None
            if self._paused:
                self._commit(now)
                return None
            target = ls.stall_target(v, real)
            if target is not None:  # a stall: time follows the wall clock, events and deadlines as it reaches them
                due = [t for t in (nxt, None if v.next_ns is None else v.next_ns / 1e9) if t is not None]
                t = min([target / 1e9, *due])
                if t > now:
                    self._commit(now)
                    return t
            self._wait_news(ls, ls.wait_hint(v, real))
        return None

    def _wait_news(self, ls: Any, timeout: float) -> None:
        """Block up to ``timeout`` real seconds for a client's notification, a process's end, host input or
        another thread's call."""
        states = ls.arm()
        ready: list[int] = []
        try:
            if ls.unchanged(states):
                fds = [self._waker.fd, *ls.fds()]
                for medium in self.media:
                    fds += medium.vt_fds()
                r = self._news
                if fds != r.key:
                    r = self._news = Readiness(fds)
                ready = r.wait(timeout)
        finally:
            ls.disarm(ready)

    def _advance(self, t: float) -> None:
        """F: the clock moves to ``t`` (called with the condition held)."""
        self.clock._vnow = t
        self.stats.advances += 1
        self._cv.notify_all()


__all__ = ["IDLE_LOOK", "MODES", "LoopStats", "VirtualLoop"]
