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
                                    (emulate, monitor, record, tap, a live trace
                                    or lidar) stopped by Ctrl-C or SIGTERM
:class:`UsageError`          2      the command as written cannot work, whatever
                                    the machine's state: an unknown option, a
                                    value out of its range, a malformed source,
                                    URL or address, an unknown profile (name or
                                    file) or one that fails its checks (``--set``
                                    included), a file that is not what the verb
                                    reads (not a manifest, capture, profile), a
                                    device or endpoint the bench does not have, an
                                    optional extra that is not installed
                                    (:class:`MissingExtra`)
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
(``--strict``)               3      monitor, trace: the input is damaged;
                                    ``profiles from-capture --verify``: fewer
                                    replies matched than ``--min-ratio``
(Ctrl-C)                     130    interrupted before the verb's work was done
===========================  =====  ==============================================

``hilbench run`` exits with its program's status (126 or 127 when the program
cannot be run, as a shell does).

Every exception class hilbench defines derives from :class:`HilbenchError`
(a test walks the package): a family or a layer subclasses the one that says
what went wrong, adding ``ValueError`` or ``OSError`` as a second base where
callers catch those. Three more carry a meaning every layer shares:

- :class:`FormatError` (a :class:`UsageError` and a ``ValueError``): bytes or
  a file that are not the format they claim (a capture, a strict frame parse);
- :class:`RequestRefused`: a bench-side server refuses a client's request and
  answers it in its own protocol (never a traceback on the bench's stderr);
- :class:`MissingExtra` (a :class:`UsageError`): an optional extra is not
  installed; :func:`require` imports a module of one or raises it, naming
  ``pip install 'hilbench[EXTRA]'``.

This module imports nothing from hilbench: every layer may use it.
"""

from __future__ import annotations

import importlib
from types import ModuleType


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


class FormatError(UsageError, ValueError):
    """Bytes or a file that are not the format they claim (a damaged capture, a frame a strict parser refuses).

    A ``ValueError`` too, so code that parses values catches it as it would any bad value.
    """


class RequestRefused(HilbenchError):
    """A client's request that a bench-side server refuses; the server answers it in its own protocol
    (``err MESSAGE``, a status code) and keeps serving: ``str()`` is what it tells the client."""


class MissingExtra(UsageError):
    """An optional extra of hilbench is not installed; ``str()`` names the ``pip install`` that brings it.

    ``module`` is the module that could not be imported, ``extra`` the extra that provides it.
    """

    def __init__(self, message: str, module: str = "", extra: str = "") -> None:
        super().__init__(message)
        self.module = module
        self.extra = extra


def require(module: str, extra: str, purpose: str = "", *, package: str | None = None) -> ModuleType:
    """Import ``module``, which the optional extra ``extra`` installs, or raise :class:`MissingExtra`.

    ``package``: the distribution to name instead of the extra, for a dependency of hilbench itself that
    was uninstalled (``pip install PACKAGE``).

    ``purpose`` starts the one-line message: ``require("cantools", "can", "decoding with a DBC")`` raises
    "decoding with a DBC needs cantools: pip install 'hilbench[can]'"; without it the message says the
    module is not installed.

    >>> require("json", "none").__name__
    'json'
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        top = module.partition(".")[0]
        missing = (exc.name or "").partition(".")[0]
        # The extra's module is there but something it imports is not: say which, as pip would not.
        why = "" if missing in ("", top) else f" ({exc})"
        head = f"{purpose} needs {top}" if purpose else f"{top} is not installed"
        fix = f"pip install {package}" if package else f"pip install 'hilbench[{extra}]'"
        raise MissingExtra(f"{head}{why}: {fix}", module, extra) from None


__all__ = ["BenchError", "DeviceError", "FormatError", "HilbenchError", "MissingExtra", "OptionError",
           "RequestRefused", "UnavailableError", "UsageError", "require"]
