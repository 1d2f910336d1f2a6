"""Waiting for file descriptors or a deadline with sub-millisecond precision."""

from __future__ import annotations

import ctypes
import ctypes.util
import select
import time

#: Below this much time to a deadline, spin instead of sleeping: the kernel's
#: wake-up latency (timer slack plus scheduling) is of this order.
SPIN_WINDOW = 150e-6

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


def wait(fds: list[int], deadline: float | None, *, precise: bool = False, idle: float = 0.5) -> list[int]:
    """Wait until one of ``fds`` is readable or ``time.monotonic()`` reaches ``deadline``.

    Returns the readable descriptors (possibly none). With ``precise`` the last
    :data:`SPIN_WINDOW` before the deadline is spent polling, so the caller
    wakes within microseconds of it; select's own wake-up can be 100 us late.
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
