"""hilbench's exceptions: one hierarchy, so every surface reports errors the same way.

Every error a user can cause or meet is a :class:`HilbenchError`; its
``str()`` is one line and its :attr:`~HilbenchError.exit_code` is what the
``hilbench`` command exits with. Layers raise the subclass that says what went
wrong; the command line catches :class:`HilbenchError` alone, so a family's
own errors need no special case there (a family subclasses one of these).

=======================  =====  ==============================================
class                    exit   meaning
=======================  =====  ==============================================
:class:`UsageError`      2      the user asked for something impossible: a bad
                                option, profile, source string or argument
:class:`DeviceError`     1      a device (real or emulated) did not answer or
                                refused; the request itself was fine
:class:`BenchError`      1      a running bench could not be reached or refused
=======================  =====  ==============================================

This module imports nothing from hilbench: every layer may use it.
"""

from __future__ import annotations


class HilbenchError(Exception):
    """Base of hilbench's errors: ``str()`` is one line; :attr:`exit_code` is the command's exit status."""

    exit_code = 1


class UsageError(HilbenchError):
    """A mistake in what the user asked for (options, profiles, source strings): exit status 2."""

    exit_code = 2


class DeviceError(HilbenchError):
    """A device did not answer or refused a request: exit status 1."""


class BenchError(HilbenchError):
    """A running bench could not be reached, or refused a command: exit status 1."""


class OptionError(UsageError):
    """A bad value under ``key`` of a configuration table (profile keys of a host port, a family, ...).

    Raised by code that does not know which file it is checking; the profile
    loader prefixes the file and the full key: ``file: endpoints.x.port: ...``.
    """

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


__all__ = ["BenchError", "DeviceError", "HilbenchError", "OptionError", "UsageError"]
