"""Fault knobs: named settings of an emulated device that tests and users turn, in a profile or live.

A family gives each knob a range: ``(False, True)`` for a switch, integer
bounds for a count (``(0, 1000)``), float bounds for a rate or a time
(``(0.0, 1.0)``). :func:`check_fault_table` checks a profile's ``faults``
table against those ranges (one-line profile errors), :func:`check_knobs` the
knobs of a control command (a :class:`~hilbench.bench.control.ControlError`);
:func:`requested_knobs` takes the ``knobs`` object of a control request.
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError

#: Knob name -> (lo, hi): (False, True) a switch, int bounds an integer, float bounds a number.
KnobRanges = dict[str, tuple[Any, Any]]


def is_switch(lo: Any) -> bool:
    """Whether a range's ``lo`` makes the knob a switch (true or false)."""
    return lo is False


def is_count(lo: Any) -> bool:
    """Whether a range's ``lo`` makes the knob an integer."""
    return isinstance(lo, int) and not isinstance(lo, bool)


def check_fault_table(c: Checker, key: str, raw: Any, ranges: KnobRanges) -> dict[str, Any]:
    """A profile's fault table at ``key`` checked against ``ranges`` (one-line :class:`Checker` errors); a copy."""
    faults = c.table(raw, key)
    c.unknown(faults, key, tuple(ranges))
    for name, value in faults.items():
        lo, hi = ranges[name]
        if is_switch(lo):
            c.boolean(value, f"{key}.{name}")
        elif is_count(lo):
            c.integer(value, f"{key}.{name}", lo, hi)
        else:
            c.number(value, f"{key}.{name}", lo, hi)
    return dict(faults)


def check_knobs(knobs: dict[str, Any], ranges: KnobRanges, what: str = "fault knob", *,
                whole_counts: bool = True) -> dict[str, Any]:
    """Knobs of a control request checked against ``ranges`` (a copy); ControlError ``"<what> <key>: ..."``, or
    ``"unknown <what> '<key>' (expected one of: ...)"``.

    ``whole_counts=False`` takes any number in a count's range (for a device that rounds, and clients that
    send every value as a float, as ``hilbench board fault`` does).
    """
    out = {}
    for key, value in knobs.items():
        if key not in ranges:
            raise ControlError(f"unknown {what} {key!r} (expected one of: {', '.join(ranges)})")
        lo, hi = ranges[key]
        whole = whole_counts and is_count(lo)
        if is_switch(lo):
            if not isinstance(value, bool):
                raise ControlError(f"{what} {key}: expected true or false, got {value!r}")
        elif (isinstance(value, bool) or not isinstance(value, int | float) or not lo <= value <= hi
              or (whole and not isinstance(value, int))):
            raise ControlError(f"{what} {key}: expected {'an integer' if whole else 'a number'} {lo}..{hi}, "
                               f"got {value!r}")
        out[key] = value
    return out


def requested_knobs(req: dict[str, Any]) -> dict[str, Any]:
    """The ``knobs`` object of a control request (``{}`` when absent); ControlError if it is not an object."""
    knobs = req.get("knobs", {})
    if not isinstance(knobs, dict):
        raise ControlError("knobs: expected an object")
    return knobs


__all__ = ["KnobRanges", "check_fault_table", "check_knobs", "is_count", "is_switch", "requested_knobs"]
