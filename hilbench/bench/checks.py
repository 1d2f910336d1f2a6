"""Profile checks: every mistake becomes one line naming the file, the key and what was expected.

Families and the profile loader check their keys with a :class:`Checker`
bound to the profile's path; each check returns the value or raises
:class:`ProfileError` (``file: key: problem``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NoReturn

from hilbench.errors import OptionError, UsageError
from hilbench.rules import Rule, Switch


class ProfileError(UsageError, ValueError):
    """A profile that cannot be used; ``str()`` is one line: ``file: key: problem``."""


class Checker:
    """Checks values of one profile file; every failure is a :class:`ProfileError`."""

    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> NoReturn:
        raise ProfileError(f"{self.path}: {key}: {message}")

    def address(self, value: str, key: str, spelled: str = '"host:port"') -> tuple[str, int]:
        """A ``host:port`` string read as the UDP transport will read it (``spelled``: how the message names
        the form)."""
        from hilbench.transports.udp import parse_address

        try:
            return parse_address(value)
        except ValueError:
            self.fail(key, f"expected {spelled}, got {value!r}")

    def table(self, value: Any, key: str) -> dict[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(key, f"expected a table, got {type(value).__name__}")
        return value

    def unknown(self, table: dict[str, Any], prefix: str, allowed: tuple[str, ...] | list[str]) -> None:
        for key in table:
            if key not in allowed:
                where = f"{prefix}.{key}" if prefix else key
                self.fail(where, f"unknown key (expected one of: {', '.join(allowed)})")

    def integer(self, value: Any, key: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer {lo}..{hi}, got {value!r}")
        if not lo <= value <= hi:
            self.fail(key, f"expected an integer {lo}..{hi}, got {value}")
        return value

    def number(self, value: Any, key: str, lo: float, hi: float) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, f"expected a number {lo}..{hi}, got {value!r}")
        if not lo <= value <= hi:
            self.fail(key, f"expected a number {lo}..{hi}, got {value}")
        return float(value)

    def rule(self, value: Any, key: str, rule: Rule | Switch) -> Any:
        """A value checked against a shared :class:`~hilbench.rules.Rule` (the command line uses the same)."""
        if not rule.ok(value):
            self.fail(key, f"expected {rule.expected}, got {value!r}")
        return rule.check(value)

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {value!r}")
        return value

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value:
            self.fail(key, f"expected a string, got {value!r}")
        return value

    def choice(self, value: Any, key: str, choices: tuple[str, ...] | list[str]) -> str:
        if value not in choices:
            self.fail(key, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
        return value

    def options(self, check: Callable[[dict[str, Any]], dict[str, Any]], raw: dict[str, Any],
                prefix: str) -> dict[str, Any]:
        """Run a check that raises :class:`~hilbench.errors.OptionError` (a host port's); prefix its key."""
        try:
            return check(raw)
        except OptionError as exc:
            self.fail(f"{prefix}.{exc.key}", exc.message)


__all__ = ["Checker", "ProfileError"]
