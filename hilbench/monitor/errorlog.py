"""The monitor's error log: what went wrong on the bus, when, in words.

Entries carry the bus time of the event; they are formatted relative to the
start of the observation as ``[+MM:SS.mmm] error: <message>``, like the
thesis bus monitor's log (spec sheet §8.4). The log is bounded: it keeps the
newest :attr:`ErrorLog.capacity` entries and counts every entry by kind, so a
bus that fails a thousand times a second cannot exhaust memory. An entry that
repeats the previous one exactly is folded into it with a repeat count.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

#: Kinds of entries, in the order a summary lists them.
KINDS = (
    "crc",
    "truncated",
    "bad_length",
    "missed_reply",
    "disconnected",
    "reconnected",
    "error_status",
    "alert",
    "hardware_error",
    "unexpected_status",
    "bad_reply",
    "invalid_instruction",
    "dropped_input",
)


class LogEntry(NamedTuple):
    """One logged event: bus time ``t``, ``kind`` (see :data:`KINDS`), device ID or None, and its text.

    The text is built only when someone reads it (:attr:`text`): ``message``
    is the text itself, a ``str.format`` template for ``args``, or a function
    of ``args``. Frequent events thus cost no formatting on a busy bus.
    """

    t: float
    kind: str
    device: int | None
    message: str | Callable[..., str]
    repeats: int = 1
    args: tuple[Any, ...] = ()

    @property
    def text(self) -> str:
        if callable(self.message):
            return self.message(*self.args)
        return self.message.format(*self.args) if self.args else self.message


_new = tuple.__new__


def format_offset(seconds: float) -> str:
    """``+MM:SS.mmm`` (minutes grow past 99 rather than wrapping)."""
    if seconds < 0:
        seconds = 0.0
    ms = int(round(seconds * 1000))
    minutes, ms = divmod(ms, 60_000)
    return f"+{minutes:02d}:{ms // 1000:02d}.{ms % 1000:03d}"


class ErrorLog:
    """Bounded log of bus errors with counts by kind."""

    def __init__(self, capacity: int = 1000) -> None:
        self.capacity = capacity  #: entries kept (the newest)
        self.entries: deque[LogEntry] = deque(maxlen=capacity)
        self.counts: dict[str, int] = dict.fromkeys(KINDS, 0)
        self.total = 0
        #: Bus time the offsets are measured from (the first data seen).
        self.t0: float | None = None
        #: False when the bus times mean nothing (a raw dump): entries then show no time.
        self.timed = True

    def add(self, t: float, kind: str, message: str | Callable[..., str], device: int | None = None,
            *args: Any) -> None:
        """Record an event at bus time ``t`` (``message`` with ``args``: see :class:`LogEntry`)."""
        counts = self.counts
        counts[kind] = counts.get(kind, 0) + 1
        self.total += 1
        entries = self.entries
        # on a bus that fails often this runs per packet: fields by index, and tuple.__new__
        # instead of the NamedTuple's own __new__ (a Python frame)
        if entries:
            last = entries[-1]
            if last[1] == kind and last[3] == message and last[5] == args and last[2] == device:
                entries[-1] = _new(LogEntry, (t, kind, device, message, last[4] + 1, args))
                return
        entries.append(_new(LogEntry, (t, kind, device, message, 1, args)))

    def newest(self, n: int = 50) -> list[LogEntry]:
        """The ``n`` newest entries, newest first by bus time.

        A miss is found when its timeout expires, after later events were logged; sorting the
        newest entries by their time shows them where they happened.
        """
        out = []
        for entry in reversed(self.entries):
            if len(out) >= n:
                break
            out.append(entry)
        out.sort(key=lambda e: e.t, reverse=True)
        return out

    def format(self, entry: LogEntry) -> str:
        """``[+MM:SS.mmm] error: message`` (with ``(xN)`` for folded repeats)."""
        offset = format_offset(entry.t - (self.t0 or 0.0)) if self.timed else "--:--.---"
        repeats = f" (x{entry.repeats})" if entry.repeats > 1 else ""
        return f"[{offset}] error: {entry.text}{repeats}"

    def lines(self, n: int = 50) -> list[str]:
        """The ``n`` newest entries formatted, newest first."""
        return [self.format(e) for e in self.newest(n)]
