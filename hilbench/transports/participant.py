"""A bench participant thread: blocking code of the bench's own process run on a virtual clock, with a baton.

Some device logic is written as a thread that blocks (the rover board's XRCE session: ping, wait for the
answer with a timeout, retry ...). In virtual time such a thread cannot wait on the wall clock, and it
cannot run beside the bench's :class:`~hilbench.transports.virtual_loop.VirtualLoop` either: what it does
would land at whatever virtual instant the loop happens to be at. A :class:`Participant` runs it one at a
time with the loop instead (PLAN26 §3.3):

- the thread runs only while it holds the *baton*; it gets it in an event of the loop (a *turn*), at a
  virtual instant, and the loop's thread waits until the thread gives it back, by waiting again
  (:meth:`Participant.wait`) or by ending;
- :meth:`Participant.wait` schedules a turn at its deadline (``now + timeout``) and hands the baton back;
  :meth:`Participant.notify` (the loop's side: a datagram for it arrived) schedules a turn at ``now`` when
  the thread waits for news. Stale turns (of an earlier wait) are dropped.

So the thread's code runs at deterministic virtual instants, in the loop's one ``(time, sequence)`` order,
and takes no virtual time; time never moves while it runs. The same code runs unchanged on the wall clock
with ordinary waits; only its waits go through an object like this one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class Participant:
    """One thread running ``target()`` on a virtual clock; ``schedule(t, fn)`` queues ``fn`` at virtual time
    ``t`` in the bench's loop (a medium's ``call_at``), ``clock`` is the bench's clock."""

    def __init__(self, schedule: Callable[[float, Callable[[], None]], None], clock: Any, name: str) -> None:
        self._schedule = schedule
        self.clock = clock
        self.name = name
        self._cv = threading.Condition()
        self._baton = False  # True: the participant's thread runs; False: the loop's
        self._token = 0  # the current wait (a turn of an older wait is stale)
        self._news = False  # the current wait ends on news (notify), not only at its deadline
        self._queued = -1  # the wait whose news turn is already queued
        self._stopped = False
        #: The participant's thread (None before start and after join).
        self.thread: threading.Thread | None = None
        #: Turns taken (for tests and status).
        self.turns = 0

    def start(self, target: Callable[[], None]) -> None:
        """Start the thread; it runs ``target`` from its first turn, at the clock's ``now``."""
        self._stopped = False
        self._baton = False
        self._token += 1
        token = self._token
        self._news = False
        self.thread = threading.Thread(target=self._main, args=(target,), name=self.name, daemon=True)
        self.thread.start()
        self._schedule(self.clock.now(), lambda: self._turn(token))

    def _main(self, target: Callable[[], None]) -> None:
        with self._cv:
            self._cv.wait_for(lambda: self._baton or self._stopped)
        try:
            if not self._stopped:
                target()
        except Exception:  # noqa: BLE001 (a participant must not die silently)
            log.exception("%s: participant failed", self.name)
        finally:
            with self._cv:
                self._baton = False
                self._token += 1  # (its queued turns are stale)
                self._cv.notify_all()

    # ------------------------------------------------------------------ the loop's side

    def _turn(self, token: int) -> None:
        """An event of the loop: hand the baton to the thread and wait until it gives it back."""
        with self._cv:
            if token != self._token or self._stopped:
                return
            self._token += 1  # this wait is over: its other queued turn is stale
            self._baton = True
            self.turns += 1
            self._cv.notify_all()
            self._cv.wait_for(lambda: not self._baton or self._stopped)

    def notify(self) -> None:
        """News for the thread (the loop's thread, or any while the loop waits): if it waits for news, its
        turn comes at ``now``, after what is already due then."""
        with self._cv:
            if not self._news or self._queued == self._token or self._stopped:
                return
            token = self._queued = self._token
        self._schedule(self.clock.now(), lambda: self._turn(token))

    # ------------------------------------------------------------------ the thread's side

    def wait(self, timeout: float | None, news: bool = True) -> None:
        """Give the baton back until ``timeout`` virtual seconds have passed (None: no deadline) or, with
        ``news``, until :meth:`notify`; returns holding it again (or at once once stopped)."""
        with self._cv:
            if self._stopped:
                return
            self._token += 1
            token = self._token
            self._news = news
        if timeout is not None:
            # (queued while the thread still holds the baton: the loop is stopped at now, so the turn's
            # place in the loop's sequence is the same in every run)
            self._schedule(self.clock.now() + max(0.0, timeout), lambda: self._turn(token))
        with self._cv:
            self._baton = False
            self._cv.notify_all()
            self._cv.wait_for(lambda: self._baton or self._stopped)

    def stop(self) -> None:
        """End the turns: a waiting thread returns from :meth:`wait` at once and runs on its own (to its end)."""
        with self._cv:
            self._stopped = True
            self._cv.notify_all()

    def join(self, timeout: float | None = None) -> None:
        if self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(timeout)
        self.thread = None


__all__ = ["Participant"]
