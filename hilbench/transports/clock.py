"""Waiting for file descriptors or a deadline with sub-millisecond precision, without hogging a core.

A paced line must hand bytes over at their wire time, tens of microseconds
apart, on machines where other programs want the CPU too. Spinning on the
clock gets the precision but makes the line a CPU hog that the scheduler
then preempts for milliseconds as soon as a neighbour is busy. So the line
sleeps in ``select`` (woken at once by input), with the kernel's timer slack
cut to a microsecond, and spins only the last :data:`SPIN_WINDOW` before a
deadline, which covers select's own wake-up latency. Where the OS allows it
the line's thread also runs under SCHED_FIFO (:func:`try_realtime`), so a
wake-up preempts CPU-bound neighbours instead of waiting for their time slice.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import select
import time

#: Below this much time to a deadline, spin instead of sleeping. select's wake-up is typically
#: 15-25 us late on a 2-core Linux VM (p99 40-70 us), but spinning through a Sync Read's twenty
#: replies (75 us apart at 2 Mbaud) cost the emulator 1.7 ms of CPU per 1.5 ms of replies and, under
#: SCHED_FIFO, took that core from the client: sleeping all the way is the better trade. A delivery
#: is then that much late, never early, and a late one does not delay the next (times are absolute).
SPIN_WINDOW = 0.0
#: SCHED_FIFO priority of a paced line's thread: the lowest band, above every normal process but
#: below the kernel's own real-time threads and audio/IRQ threads that use 50 and more.
REALTIME_PRIORITY = 10

_PR_SET_TIMERSLACK = 29


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


def wait(fds: list[int], deadline: float | None, *, precise: bool = False, idle: float = 0.5) -> list[int]:
    """Wait until one of ``fds`` is readable or ``time.monotonic()`` reaches ``deadline``.

    Returns the readable descriptors (possibly none). The thread sleeps in
    select; with ``precise`` it wakes :data:`SPIN_WINDOW` before the deadline
    and polls the rest of the way, so it returns within microseconds of it
    (select's own wake-up can be 50 us late). Input ends the wait at once
    either way.
    """
    now = time.monotonic()
    if deadline is None:
        timeout = idle
    else:
        timeout = deadline - now
        if precise:
            timeout -= SPIN_WINDOW
        timeout = max(0.0, min(timeout, idle))
    ready = select.select(fds, [], [], timeout)[0]
    if ready or deadline is None or not precise:
        return ready
    while time.monotonic() < deadline:
        ready = select.select(fds, [], [], 0)[0]
        if ready:
            return ready
    return []
