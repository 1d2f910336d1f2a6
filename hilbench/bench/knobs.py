"""Fault knobs: named settings of an emulated device that tests and users turn, in a profile or live.

A family gives each knob a rule from :mod:`hilbench.rules`: :data:`~hilbench.rules.SWITCH` for an
on/off knob, a :class:`~hilbench.rules.Rule` for a count (``FAULT_COUNT``), a rate
(``PROBABILITY``) or a time. The same rules check a profile's ``faults`` table
(:func:`check_fault_table`, one-line profile errors), the knobs of a control command
(:func:`check_knobs`, a :class:`~hilbench.bench.control.ControlError`) and a command line
that checks before it sends (``error=RuleError``, a usage error); :func:`requested_knobs`
takes the ``knobs`` object of a control request.
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError, ControlRequestError
from hilbench.errors import HilbenchError
from hilbench.rules import Rule, Switch

#: Knob name -> its rule.
KnobRules = dict[str, Rule | Switch]


def check_fault_table(c: Checker, key: str, raw: Any, rules: KnobRules) -> dict[str, Any]:
    """A profile's fault table at ``key`` checked against ``rules`` (one-line :class:`Checker` errors); a copy."""
    faults = c.table(raw, key)
    c.unknown(faults, key, tuple(rules))
    for name, value in faults.items():
        c.rule(value, f"{key}.{name}", rules[name])
    return dict(faults)


def check_knobs(knobs: dict[str, Any], rules: KnobRules, what: str = "fault knob", *,
                whole_counts: bool = True, error: type[HilbenchError] = ControlError) -> dict[str, Any]:
    """Knobs of a control request checked against ``rules`` (a copy); ``error`` (ControlError)
    ``"<what> <key>: expected ..., got ..."``, or ``"unknown <what> '<key>' (expected one of: ...)"``.

    ``whole_counts=False`` takes any number in a count's range (for a device that rounds, and clients that
    send every value as a float, as ``hilbench board fault`` does).
    """
    out = {}
    for key, value in knobs.items():
        rule = rules.get(key)
        if rule is None:
            raise error(f"unknown {what} {key!r} (expected one of: {', '.join(rules)})")
        if not whole_counts:
            rule = rule.any_number()
        if not rule.ok(value):
            raise error(f"{what} {key}: expected {rule.expected}, got {value!r}")
        out[key] = value
    return out


def requested_knobs(req: dict[str, Any]) -> dict[str, Any]:
    """The ``knobs`` object of a control request (``{}`` when absent); ControlError if it is not an object."""
    knobs = req.get("knobs", {})
    if not isinstance(knobs, dict):
        raise ControlRequestError("knobs: expected an object")
    return knobs


__all__ = ["KnobRules", "check_fault_table", "check_knobs", "requested_knobs"]
