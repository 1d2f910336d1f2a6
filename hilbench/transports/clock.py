"""Waiting for file descriptors or a deadline with sub-millisecond precision, without hogging a core.

A paced line must hand bytes over at their wire time, tens of microseconds
apart, on machines where other programs want the CPU too. Spinning on the
clock gets the precision but makes the line a CPU hog that the scheduler
then preempts for milliseconds as soon as a neighbour is busy. So the line
sleeps in ``ppoll`` (woken at once by input; :mod:`~hilbench.transports.readiness`), with the kernel's timer slack
cut to a microsecond, asks for each wake-up as much earlier as this
machine's wake-ups are late (:class:`Waiter`) and polls the last few
microseconds. Where the OS allows it the line's thread also runs under
SCHED_FIFO (:func:`try_realtime`), so a wake-up preempts CPU-bound neighbours
instead of waiting for their time slice, and the process asks that idle CPUs
stay awake (:class:`CpuLatency`), so waking one (the line, the kernel's tty
worker, the client) takes microseconds instead of tens.

It also holds the bench's clock (:class:`WallClock`, :class:`VirtualClock`):
the one time base every medium, port and device reads (DESIGN §12). Media,
ports and devices never read ``time.monotonic()`` themselves; they call their
clock's :attr:`~WallClock.now` (a device through its
:class:`~hilbench.transports.medium.DevicePort`), and stamp Unix time with
:meth:`~WallClock.wall`.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import struct
import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import Any

from hilbench.transports.readiness import Readiness

#: SCHED_FIFO priority of a paced line's thread: the lowest band, above every normal process but
#: below the kernel's own real-time threads and audio/IRQ threads that use 50 and more.
REALTIME_PRIORITY = 10

_PR_SET_TIMERSLACK = 29
#: Linux's PM QoS request for the whole system: while a process holds it open with a value written,
#: no idle CPU enters a state that takes longer than that many microseconds to leave.
CPU_DMA_LATENCY = "/dev/cpu_dma_latency"


class WallClock:
    """The wall clock: ``now`` *is* :func:`time.monotonic` (the builtin itself, so a paced line's hot path
    pays nothing for going through a clock), ``wall(t)`` maps it to Unix time with one offset taken when
    the clock was made (so stamps never jump). Pacing is the media's matter, not the clock's."""

    #: Whether time is virtual (advanced only by a :class:`~hilbench.transports.virtual_loop.VirtualLoop`).
    virtual = False
    #: A virtual clock's :class:`~hilbench.transports.channel_book.ChannelBook` (None: the wall clock counts none).
    channels: Any = None
    now = staticmethod(time.monotonic)
    now_ns = staticmethod(time.monotonic_ns)

    def __init__(self) -> None:
        #: Unix time minus clock time (:meth:`wall`).
        self.wall_offset = time.time() - time.monotonic()

    def wall(self, t: float) -> float:
        """Unix time of clock time ``t``."""
        return t + self.wall_offset

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of clock time pass (bench-side threads only: never a medium's thread)."""
        time.sleep(max(0.0, seconds))

    def wait(self, event: threading.Event, timeout: float | None) -> bool:
        """``event.wait(timeout)`` with ``timeout`` in clock seconds (bench-side threads only)."""
        return event.wait(timeout)

    def __repr__(self) -> str:
        return "WallClock()"


#: The process's wall clock: what media, ports and devices use unless a bench gives them another.
WALL = WallClock()


class VirtualClock(WallClock):
    """Virtual time: ``now()`` is what the bench's :class:`~hilbench.transports.virtual_loop.VirtualLoop`
    last set, and nothing else moves it.

    Virtual monotonic time starts at ``origin`` (default :attr:`ORIGIN`, 1000 s: "booted 1000 s ago", so
    clients that take 0 for "never" still work); virtual Unix time is ``epoch + (now - origin)``, ``epoch`` being the real
    start time unless given (pinned, payload stamps repeat from run to run). The in-process drivers
    (:meth:`run_for`, :meth:`run_until`, :meth:`hold`, :meth:`free`) are the loop's, once it is attached.
    """

    virtual = True
    #: Where virtual monotonic time starts by default (seconds).
    ORIGIN = 1000.0

    def __init__(self, epoch: float | None = None, origin: float = ORIGIN) -> None:
        self.origin = origin
        self.epoch = time.time() if epoch is None else float(epoch)
        self.wall_offset = self.epoch - origin
        self._vnow = origin
        self.loop: Any = None  # the VirtualLoop that advances it (set by the loop)
        from hilbench.transports.channel_book import ChannelBook

        #: What the bench's socket doors sent to and took from each client address (the lockstep's channels).
        self.channels = ChannelBook()

    def now(self) -> float:  # type: ignore[override]
        """Virtual seconds (the loop's current instant)."""
        return self._vnow

    def now_ns(self) -> int:  # type: ignore[override]
        return round(self._vnow * 1e9)

    def wall(self, t: float) -> float:
        return self.epoch + (t - self.origin)

    def _loop(self) -> Any:
        if self.loop is None:
            raise RuntimeError("this virtual clock has no VirtualLoop yet (start the bench first)")
        return self.loop

    def sleep(self, seconds: float) -> None:
        """Wait until ``seconds`` of virtual time have passed (from a thread other than the loop's)."""
        self._loop().sleep(seconds)

    def wait(self, event: threading.Event, timeout: float | None) -> bool:
        """Wait for ``event`` or ``timeout`` virtual seconds (from a thread other than the loop's)."""
        return self._loop().wait_event(event, timeout)

    def run_for(self, seconds: float, timeout: float | None = None) -> float:
        """Advance a held clock by ``seconds``, running every event on the way; returns the new now."""
        return self._loop().run_for(seconds, timeout)

    def run_until(self, t: float, timeout: float | None = None) -> float:
        """Advance a held clock to ``t`` (virtual seconds), running every event on the way."""
        return self._loop().run_until(t, timeout)

    def hold(self) -> None:
        """Time moves only through :meth:`run_for` / :meth:`run_until` (and, later, lockstep clients)."""
        self._loop().hold()

    def free(self) -> None:
        """Time jumps from event to event on its own, as fast as the bench runs them."""
        self._loop().free()

    def __repr__(self) -> str:
        return f"VirtualClock(now={self._vnow!r}, epoch={self.epoch!r})"


#: What a bench's media, ports and devices share (a :class:`WallClock` or a :class:`VirtualClock`).
Clock = WallClock


def reduce_timer_slack(nanoseconds: int = 1000) -> bool:
    """Ask Linux to wake this thread at most ``nanoseconds`` late (default slack is 50 us).

    Returns False where prctl is unavailable; waiting then stays correct, only
    less precise.
    """
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        return libc.prctl(_PR_SET_TIMERSLACK, nanoseconds, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def try_realtime(priority: int = REALTIME_PRIORITY) -> str:
    """Put the calling thread under SCHED_FIFO if the OS allows it; returns what it runs under.

    Needs root or CAP_SYS_NICE (or an RLIMIT_RTPRIO of at least ``priority``); otherwise
    the thread stays under the normal scheduler and the answer says why. The
    thread must never spin for long: a real-time thread that does starves the
    other programs on its core (the kernel's RT throttling caps it at 95 %).
    """
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None:
        return "SCHED_OTHER (no sched_setscheduler on this OS)"
    try:
        setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0: the calling thread on Linux
    except OSError as exc:
        return f"SCHED_OTHER (SCHED_FIFO refused: {exc.strerror or exc})"
    return f"SCHED_FIFO {priority}"


def wait(fds: list[int], deadline: float | None, idle: float | None = 0.5, *, leave_cpu: bool = False) -> list[int]:
    """Wait until one of ``fds`` is readable or ``time.monotonic()`` reaches ``deadline`` (give or take
    the kernel's wake-up lateness; :class:`Waiter` keeps deadlines precisely). Returns the readable
    descriptors (possibly none). Input ends the wait at once; with no deadline it ends after ``idle``
    seconds (None: only input ends it). A deadline already passed still looks at the descriptors.
    (``leave_cpu`` is :class:`Waiter`'s: this wait always sleeps.) Each thread keeps the last list of
    descriptors it waited on ready for the next wait."""
    r = getattr(_local, "readiness", None)
    if r is None or fds != r.key:
        r = _local.readiness = Readiness(fds)
    if deadline is None:
        return r.idle(idle)
    left = deadline - time.monotonic()
    if idle is not None and left >= idle:
        return r.idle(idle)
    return r.wait(left)


_local = threading.local()


class Waiter:
    """:func:`wait` for one thread that must wake on time: it learns how late this machine's timed
    wake-ups are and asks for each one that much earlier.

    Spinning through the last stretch before every deadline (what paced lines
    did first) gets the precision too, but at 20 replies per Sync Read it kept
    the line on a CPU the client and the kernel's tty worker needed.

    A timed wait wakes late by an amount that hardly varies on a given
    machine (measured on a 2-core Firecracker VM: 22 - 27 us, p50 to p90
    within 1 us; 11 - 15 us with idle CPUs polling, see :class:`CpuLatency`),
    so a deadline kept by sleeping alone is always that late. The waiter
    sleeps until its deadline less the smallest lateness among the last
    :attr:`WINDOW` timed wake-ups and polls the few microseconds left, so it
    returns at the deadline for almost no spinning. A wake-up preempted for
    longer counts as at most :attr:`MAX_EARLY`.

    Polling keeps the CPU, and so does a sleep too short to leave it (the
    timer fires while the kernel is still arming it: under ~15 us on that VM).
    A real-time thread that has just handed the kernel work which runs on its
    own CPU once it sleeps (a pty write: the tty worker that moves the bytes to
    the client) passes ``leave_cpu``: a wait whose early sleep would be shorter
    than :attr:`MIN_SLEEP` then sleeps to the deadline itself, a wake-up's
    lateness late, instead of keeping the worker, and the client, waiting.
    """

    WINDOW = 32
    MAX_EARLY = 100e-6
    MIN_SLEEP = 20e-6

    def __init__(self) -> None:
        self.early = 0.0  # seconds to ask early; 0 until the first timed wake-ups are measured
        self.polls = 0  # non-blocking looks in the last microseconds before deadlines, in all
        self._seen: deque[float] = deque(maxlen=self.WINDOW)
        self._readiness = Readiness([])

    def __call__(self, fds: list[int], deadline: float | None, idle: float | None = 0.5, *,
                 leave_cpu: bool = False) -> list[int]:
        """Like :func:`wait`: the readable descriptors, or none once ``deadline`` has come (never before).
        ``leave_cpu``: sleep rather than poll if the deadline is too near for an early sleep to leave the
        CPU (see the class notes); the wait may then end a wake-up's lateness after the deadline."""
        r = self._readiness
        if fds != r.key:  # (a line's list stays the same object; a bus rebuilds an equal one each round)
            r = self._readiness = Readiness(fds)
        if deadline is None:
            return r.idle(idle)
        now = time.monotonic()
        if deadline <= now:
            # Still look: a thread whose deadlines are always behind (timed work it cannot keep up with)
            # must go on hearing its clients.
            return r.look()
        sleep = deadline - now - self.early
        if leave_cpu and sleep < self.MIN_SLEEP:
            return r.wait(deadline - now)  # (not measured: not an early sleep)
        if sleep > 0:
            if idle is not None and sleep >= idle:
                # a far deadline: look again after ``idle`` (never spin the rest of the way)
                return r.idle(idle)
            ready = r.wait(sleep)
            if ready:
                return ready
            seen = self._seen
            seen.append(min(time.monotonic() - now - sleep, self.MAX_EARLY))
            self.early = min(seen)
        while time.monotonic() < deadline:
            self.polls += 1
            ready = r.look()
            if ready:
                return ready
        return []


class CpuLatency:
    """A process-wide request that idle CPUs wake within a few microseconds (0 by default), held
    while any paced medium runs (:meth:`hold` / :meth:`release`, counted).

    Waking an idle CPU is the slow part of every hand-over a paced line makes:
    the line's own timer, the kernel's tty worker moving a pty's bytes, the
    client woken by them. Written to ``/dev/cpu_dma_latency`` (what
    ``cyclictest`` does), 0 keeps idle CPUs polling instead of halting: on a
    2-core VM a timed wake-up then came 11 - 15 us late instead of 22 - 27 us
    and a pty round trip took 20 us instead of 54 us (the benchmark
    notes, docs/benchmarks/index.md, have what it did to the SDK's cycle). The cost: idle CPUs stay busy
    (power and heat on a laptop) while the bench runs, which is why it ends
    with the last paced medium. Needs root or write access to the device;
    elsewhere nothing changes and :meth:`hold` says why.
    ``HILBENCH_CPU_LATENCY_US`` sets the value (``off``: never ask).
    """

    _lock = threading.Lock()
    _fd: int | None = None
    _users = 0
    _state = "not requested"

    @classmethod
    def setting(cls) -> tuple[int | None, str]:
        """From the environment: (microseconds to ask for, ""), or (None, why nothing is asked for): ``off``,
        or a value that is neither a number nor ``off``."""
        raw = os.environ.get("HILBENCH_CPU_LATENCY_US", "0").strip()
        if raw.lower() in ("off", "no", "none", ""):
            return None, "HILBENCH_CPU_LATENCY_US=off"
        try:
            return max(0, int(raw)), ""
        except ValueError:
            return None, f"HILBENCH_CPU_LATENCY_US={raw!r} is neither a number of microseconds nor off"

    @classmethod
    def hold(cls) -> str:
        """Take a share of the request (asking the kernel on the first); returns what is in force."""
        with cls._lock:
            cls._users += 1
            if cls._fd is None and cls._users == 1:
                us, why_not = cls.setting()
                if us is None:
                    cls._state = f"not requested ({why_not})"
                else:
                    try:
                        fd = os.open(CPU_DMA_LATENCY, os.O_WRONLY | os.O_CLOEXEC)
                    except OSError as exc:
                        cls._state = f"not granted ({CPU_DMA_LATENCY}: {exc.strerror or exc})"
                    else:
                        try:
                            os.write(fd, struct.pack("=i", us))
                        except OSError as exc:
                            os.close(fd)
                            cls._state = f"not granted ({CPU_DMA_LATENCY}: {exc.strerror or exc})"
                        else:
                            cls._fd = fd
                            cls._state = f"{us} us"
            return cls._state

    @classmethod
    def release(cls) -> None:
        """Give a share back; the last one closes the request (idle CPUs may sleep again)."""
        with cls._lock:
            cls._users = max(0, cls._users - 1)
            if not cls._users and cls._fd is not None:
                os.close(cls._fd)
                cls._fd = None
                cls._state = "not requested"


@contextlib.contextmanager
def awake_cpus(wanted: bool) -> Iterator[str | None]:
    """Hold a share of :class:`CpuLatency` for the block if ``wanted``; yields what is in force
    (None when not wanted). A paced medium's thread runs inside it."""
    if not wanted:
        yield None
        return
    state = CpuLatency.hold()
    try:
        yield state
    finally:
        CpuLatency.release()
