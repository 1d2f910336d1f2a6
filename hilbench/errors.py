"""hilbench's exceptions: one hierarchy, so every surface reports errors the same way.

Every error a user can cause or meet is a :class:`HilbenchError`; its
``str()`` is one line and its :attr:`~HilbenchError.exit_code` is what the
``hilbench`` command exits with. Layers raise the subclass that says what went
wrong; the command line catches :class:`HilbenchError` alone, so a family's
own errors need no special case there (a family subclasses one of these).

The rule every verb follows (a test walks every registered verb through it):

===========================  =====  ==============================================
class                        exit   meaning
===========================  =====  ==============================================
(none)                       0      done; also a verb that runs until stopped
                                    (emulate, monitor, record, tap, a live profile
                                    or lidar) stopped by Ctrl-C or SIGTERM
:class:`UsageError`          2      the command as written cannot work, whatever
                                    the machine's state: an unknown option, a
                                    value out of its range, a malformed source,
                                    URL or address, an unknown profile (name or
                                    file) or one that fails its checks (``--set``
                                    included), a file that is not what the verb
                                    reads (not a manifest, capture, profile), a
                                    device or endpoint the bench does not have
:class:`UnavailableError`    1      the command is fine but something it needs is
                                    not there, is taken or did not answer in time:
                                    a file, port or manifest that does not exist
                                    (a bench that is not running), a refused
                                    connection, an address already in use, a
                                    timeout
:class:`DeviceError`         1      a device (real or emulated) did not answer or
                                    refused; the request itself was fine
:class:`BenchError`          1      a running bench could not be reached or
                                    refused
(OSError)                    1      anything else the system refused (permissions,
                                    a full disk)
(``--strict``)               3      monitor, profile: the input is damaged
(Ctrl-C)                     130    interrupted before the verb's work was done
===========================  =====  ==============================================

``hilbench run`` exits with its program's status (126 or 127 when the program
cannot be run, as a shell does).

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


class UnavailableError(HilbenchError):
    """Something the command needs is not there, is taken, or did not answer in time (a file, port or manifest
    that does not exist, a refused connection, an address in use, a timeout): exit status 1."""


class OptionError(UsageError):
    """A bad value under ``key`` of a configuration table (profile keys of a host port, a family, ...).

    Raised by code that does not know which file it is checking; the profile
    loader prefixes the file and the full key: ``file: endpoints.x.port: ...``.
    """

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f"{key}: {message}")
        self.key = key
        self.message = message


__all__ = ["BenchError", "DeviceError", "HilbenchError", "OptionError", "UnavailableError", "UsageError"]
