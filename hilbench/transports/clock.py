"""Waiting for file descriptors or a deadline with sub-millisecond precision."""

from __future__ import annotations

import ctypes
import ctypes.util
import select
import time

#: Below this much time to a deadline, spin instead of sleeping: the kernel's
#: wake-up latency (timer slack plus scheduling) is of this order.
SPIN_WINDOW = 150e-6
#: After traffic, keep polling input this long in precise mode (a host's next
#: request usually follows within a millisecond).
SPIN_AFTER_ACTIVITY = 2e-3

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


def wait(
    fds: list[int],
    deadline: float | None,
    *,
    precise: bool = False,
    spin_until: float = 0.0,
    idle: float = 0.5,
) -> list[int]:
    """Wait until one of ``fds`` is readable or ``time.monotonic()`` reaches ``deadline``.

    Returns the readable descriptors (possibly none). With ``precise`` the last
    :data:`SPIN_WINDOW` before the deadline is spent polling, so the caller
    wakes within microseconds of it; select's own wake-up can be 100 us late.
    Until ``spin_until`` input is polled too, so a reply that follows soon
    after activity is stamped when it arrives rather than when the thread
    wakes up.
    """
    now = time.monotonic()
    if precise and now < spin_until:
        limit = spin_until if deadline is None else min(spin_until, deadline - SPIN_WINDOW)
        while now < limit:
            ready = select.select(fds, [], [], 0)[0]
            if ready:
                return ready
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
