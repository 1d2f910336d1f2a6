"""Fault knobs: named settings of an emulated device that tests and users turn, in a profile or live.

A family gives each knob a range: ``(False, True)`` for a switch, integer
bounds for a count (``(0, 1000)``), float bounds for a rate or a time
(``(0.0, 1.0)``). :func:`check_knobs` checks values against those ranges,
for a control command (a :class:`~hilbench.bench.control.ControlError`) or a
profile table (``fail(key, message)`` reports, e.g. a Checker's ``fail``);
:func:`requested_knobs` takes the ``knobs`` object of a control request.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hilbench.bench.control import ControlError

#: Knob name -> (lo, hi): (False, True) a switch, int bounds an integer, float bounds a number.
KnobRanges = dict[str, tuple[Any, Any]]


def is_switch(lo: Any) -> bool:
    """Whether a range's ``lo`` makes the knob a switch (true or false)."""
    return lo is False


def is_count(lo: Any) -> bool:
    """Whether a range's ``lo`` makes the knob an integer."""
    return isinstance(lo, int) and not isinstance(lo, bool)


def check_knobs(knobs: dict[str, Any], ranges: KnobRanges, what: str = "fault knob",
                fail: Callable[[str, str], Any] | None = None, *, whole_counts: bool = True) -> dict[str, Any]:
    """``knobs`` checked against ``ranges`` (a copy); ``fail(key, message)`` reports (default: ControlError
    ``"<what> <key>: <message>"``, or ``"unknown <what> '<key>' (expected one of: ...)"``).

    ``whole_counts=False`` takes any number in a count's range (for a device that rounds, and clients that
    send every value as a float, as ``hilbench board fault`` does).
    """

    def bad(key: str, message: str) -> None:
        if fail is not None:
            fail(key, message)
        raise ControlError(f"{what} {key}: {message}")

    out = {}
    for key, value in knobs.items():
        if key not in ranges:
            known = ", ".join(ranges)
            if fail is not None:
                fail(key, f"unknown (expected one of: {known})")
            raise ControlError(f"unknown {what} {key!r} (expected one of: {known})")
        lo, hi = ranges[key]
        whole = whole_counts and is_count(lo)
        if is_switch(lo):
            if not isinstance(value, bool):
                bad(key, f"expected true or false, got {value!r}")
        elif (isinstance(value, bool) or not isinstance(value, int | float) or not lo <= value <= hi
              or (whole and not isinstance(value, int))):
            bad(key, f"expected {'an integer' if whole else 'a number'} {lo}..{hi}, got {value!r}")
        out[key] = value
    return out


def requested_knobs(req: dict[str, Any]) -> dict[str, Any]:
    """The ``knobs`` object of a control request (``{}`` when absent); ControlError if it is not an object."""
    knobs = req.get("knobs", {})
    if not isinstance(knobs, dict):
        raise ControlError("knobs: expected an object")
    return knobs


__all__ = ["KnobRanges", "check_knobs", "is_count", "is_switch", "requested_knobs"]
