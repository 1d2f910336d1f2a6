"""Value rules: one definition of each range or set, checked the same way in profiles and on the command line.

A :class:`Rule` says what a value must be ("an integer 1..100000000", "a
number >= 0", "one of 9600, 57600, ..."). The profile loader checks a key with
:meth:`Checker.rule <hilbench.bench.checks.Checker.rule>` (``file: key:
expected ..., got ...``); a command-line option uses the same rule as its
argparse ``type`` (``argument --baud: expected ..., got ...``, exit status 2);
a control-channel command checks its arguments with :meth:`Rule.check`. So a
range is written once, next to what it describes (line rates here, a family's
fault knobs in its module), and the three surfaces cannot drift apart.

This module imports nothing from hilbench but :mod:`hilbench.errors`: every layer may use it.
"""

from __future__ import annotations

import argparse
import importlib
import math
from collections.abc import Iterable
from typing import Any

from hilbench.errors import UsageError


class RuleError(UsageError, ValueError):
    """A value a rule refuses; ``str()`` is ``expected <what>, got <value>`` (exit status 2)."""


class Rule:
    """A range (``lo``/``hi``, either open-ended with None) or a set of ``choices`` of ints or floats.

    ``kind`` is ``int`` or ``float`` (a float rule takes ints too; neither takes booleans or NaN
    and infinities). ``above`` makes ``lo`` exclusive (``> 0``). Calling the rule parses command-line
    text (integers also as ``0x`` hex) and checks it, for argparse's ``type=``.
    """

    def __init__(self, kind: type, lo: float | None = None, hi: float | None = None, *, above: bool = False,
                 choices: Iterable[Any] | None = None, what: str | None = None) -> None:
        if kind not in (int, float):
            raise TypeError("a rule is for int or float values")
        self.kind = kind
        self.lo = lo
        self.hi = hi
        self.above = above
        self.choices = tuple(choices) if choices is not None else None
        self._what = what
        self.__name__ = "int" if kind is int else "float"  # argparse names the type in some messages

    @property
    def expected(self) -> str:
        """What the rule wants, as the end of the sentence ``expected ...``."""
        noun = "an integer" if self.kind is int else "a number"
        if self.choices is not None:
            text = f"one of {', '.join(map(str, self.choices))}"
            return f"{self._what} ({text})" if self._what else text
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None and not self.above:
            text = f"{noun} {_num(lo)}..{_num(hi)}"
        elif lo is not None and hi is not None:
            text = f"{noun} > {_num(lo)} and <= {_num(hi)}"
        elif lo is not None:
            text = f"{noun} {'>' if self.above else '>='} {_num(lo)}"
        elif hi is not None:
            text = f"{noun} <= {_num(hi)}"
        else:
            text = noun
        return f"{self._what}: {text}" if self._what else text

    def ok(self, value: Any) -> bool:
        """Whether ``value`` (already a number) satisfies the rule."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            return False
        if self.kind is int and not isinstance(value, int):
            return False
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.choices is not None:
            return value in self.choices
        if self.lo is not None and (value <= self.lo if self.above else value < self.lo):
            return False
        return self.hi is None or value <= self.hi

    def check(self, value: Any) -> Any:
        """``value`` if it satisfies the rule (a float rule returns a float), else :class:`RuleError`."""
        if not self.ok(value):
            raise RuleError(f"expected {self.expected}, got {value!r}")
        return float(value) if self.kind is float else value

    def parse(self, text: str) -> Any:
        """A value from command-line text, checked; :class:`RuleError` if it is none or out of range."""
        try:
            value = int(text, 0) if self.kind is int else float(text)
        except (TypeError, ValueError):
            raise RuleError(f"expected {self.expected}, got {text!r}") from None
        if not self.ok(value):
            raise RuleError(f"expected {self.expected}, got {text}")
        return float(value) if self.kind is float else value

    def __call__(self, text: str) -> Any:
        """argparse ``type=``: a bad value is a one-line usage error naming the option."""
        try:
            return self.parse(text)
        except RuleError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    def any_number(self) -> Rule:
        """The same range taking any number (an integer rule's knob set by a client that sends every value
        as a float); a float rule is itself."""
        if self.kind is float:
            return self
        return Rule(float, self.lo, self.hi, above=self.above, choices=self.choices, what=self._what)

    def __repr__(self) -> str:
        return f"Rule({self.expected!r})"


class Switch:
    """A setting that is on or off: ``true`` or ``false`` (command-line text: true/false, on/off, yes/no, 1/0).

    It answers what a :class:`Rule` answers (``expected``, ``ok``, ``check``, ``parse``, argparse ``type=``),
    so a table of settings mixes both.
    """

    expected = "true or false"
    __name__ = "bool"
    _TEXT = {"true": True, "on": True, "yes": True, "1": True, "false": False, "off": False, "no": False, "0": False}

    def ok(self, value: Any) -> bool:
        return isinstance(value, bool)

    def check(self, value: Any) -> bool:
        if not self.ok(value):
            raise RuleError(f"expected true or false, got {value!r}")
        return value

    def parse(self, text: str) -> bool:
        value = self._TEXT.get(str(text).strip().lower())
        if value is None:
            raise RuleError(f"expected true or false, got {text!r}")
        return value

    __call__ = Rule.__call__  # argparse ``type=``, as a Rule: a one-line usage error naming the option

    def any_number(self) -> Switch:
        return self

    def __repr__(self) -> str:
        return "Switch()"


class RuleRef:
    """A :class:`Rule` defined in a module that is imported only when the rule is used: ``RuleRef(
    "hilbench.families.stm32_rover", "WAIT_TIMEOUT")`` as argparse ``type=`` keeps a verb's registration from
    importing a family (its option still shows and checks that family's range)."""

    def __init__(self, module: str, name: str) -> None:
        self.module = module
        self.name = name
        self.__name__ = name.lower()
        self._rule: Rule | Switch | None = None

    @property
    def rule(self) -> Rule | Switch:
        if self._rule is None:
            self._rule = getattr(importlib.import_module(self.module), self.name)
        return self._rule

    @property
    def expected(self) -> str:
        return self.rule.expected

    def ok(self, value: Any) -> bool:
        return self.rule.ok(value)

    def check(self, value: Any) -> Any:
        return self.rule.check(value)

    def parse(self, text: str) -> Any:
        return self.rule.parse(text)

    def __call__(self, text: str) -> Any:
        return self.rule(text)

    def __repr__(self) -> str:
        return f"RuleRef({self.module!r}, {self.name!r})"


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else repr(x)


#: Any line rate in bit/s (a serial port, a raw dump's byte time, a generic endpoint).
LINE_BAUD = Rule(int, 1, 100_000_000)
#: A duration in seconds (0 often meaning "no limit"; the option's help says).
SECONDS = Rule(float, 0, 1e9)
#: A positive rate in Hz.
RATE_HZ = Rule(float, 0, 1e6, above=True)
#: A probability per byte or per packet.
PROBABILITY = Rule(float, 0.0, 1.0)
#: A count of bytes or packets a fault affects.
FAULT_COUNT = Rule(int, 0, 2**31)
#: A count of at least one (frames to send, reports to wait for, histogram bins).
POSITIVE_COUNT = Rule(int, 1, 2**31)
#: A replay speed: a positive multiple of the recorded speed.
SPEED = Rule(float, 0, 1e6, above=True)
#: A TCP or UDP port to listen on or send to (0, "any free port", is a separate rule where it is allowed).
PORT = Rule(int, 1, 65535, what="a port number")
#: A fault knob or setting that is on or off.
SWITCH = Switch()


__all__ = ["FAULT_COUNT", "LINE_BAUD", "PORT", "POSITIVE_COUNT", "PROBABILITY", "RATE_HZ", "SECONDS", "SPEED", "SWITCH",
           "Rule", "RuleError", "RuleRef", "Switch"]
