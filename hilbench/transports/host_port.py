"""Host ports: what a host program opens to reach a bench endpoint (a pty, a UDP or TCP socket, ...).

Every endpoint ``type`` of a profile is a :class:`HostPort` subclass,
registered under that name in the ``hilbench.host_ports`` entry-point group.
A medium treats them all alike: it waits on :meth:`~HostPort.fileno`, takes
what the host sent with :meth:`~HostPort.read` and hands the devices' bytes
to :meth:`~HostPort.write`. A port owns its profile keys
(:attr:`~HostPort.profile_keys`, checked by :meth:`~HostPort.check_options`)
and says where it is for the manifest (:meth:`~HostPort.describe`).

Serial-like ports also carry a :class:`~hilbench.transports.port_state.PortState`
(modem lines, BREAK, settings), which the medium passes on to devices.
"""

from __future__ import annotations

import ipaddress
import re
from typing import Any, ClassVar

from hilbench.errors import OptionError
from hilbench.transports.port_state import PortState


class HostPort:
    """Base class of host ports. Subclasses set :attr:`kind` and implement the I/O methods."""

    #: The endpoint ``type`` this class implements (``"pty"``).
    kind: ClassVar[str] = ""
    #: Profile keys of ``[endpoints.NAME]`` this port type owns, with their defaults.
    profile_keys: ClassVar[dict[str, Any]] = {}
    #: One word for what the port carries: ``"bytes"`` (a stream) or ``"datagrams"``.
    carries: ClassVar[str] = "bytes"
    #: Whether the host's writes wait while the port is not read (a pty's kernel buffer, a TCP window fill),
    #: so a line may leave it unread to hold a fast writer back as a USB adapter does; :meth:`read` then
    #: takes ``size``. Not a datagram port: nothing holds its sender, what is not read is lost.
    backpressure: ClassVar[bool] = False

    name: str
    lines: PortState | None = None

    # ------------------------------------------------------------------ profile

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        """Check this port type's keys of an endpoint table (raise :class:`~hilbench.errors.OptionError`); returns them filled."""
        return {k: raw.get(k, default) for k, default in cls.profile_keys.items()}

    @classmethod
    def open(cls, name: str, options: dict[str, Any], **context: Any) -> HostPort:
        """Open a port for endpoint ``name`` from checked ``options``; ``context`` has e.g. ``link_dir``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ I/O

    def fileno(self) -> int:
        raise NotImplementedError

    def filenos(self) -> list[int]:
        """Every descriptor to wait on (a TCP port waits on its listener and its client)."""
        return [self.fileno()]

    def read(self, size: int = 65536) -> bytes:
        """What the host sent since the last call (b'' if nothing): at most ``size`` bytes on a port with
        :attr:`backpressure` (the rest waits for the next call)."""
        raise NotImplementedError

    def write(self, data: bytes) -> int:
        """Send bytes to the host; returns how many were taken."""
        raise NotImplementedError

    def client_baud(self) -> int | None:
        """The baud rate the host configured, if the port knows it."""
        return None

    @property
    def client_path(self) -> str:
        """What a host program opens (a path or a URL)."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Manifest fields of this port (at least ``path``)."""
        return {"path": self.client_path}

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> HostPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def port_number(value: Any, key: str = "port", *, allow_zero: bool = True) -> int:
    """A TCP/UDP port from a profile (0 means any free port when allowed); raises OptionError."""
    lo = 0 if allow_zero else 1
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= 65535:
        raise OptionError(key, f"expected an integer {lo}..65535, got {value!r}")
    return value


def bind_address(value: Any, key: str = "bind") -> str:
    """An address to bind (an IP address or a host name); raises OptionError."""
    if not isinstance(value, str) or not value or not _HOST.fullmatch(value):
        raise OptionError(key, f"expected an IP address string, got {value!r}")
    return value


_HOST = re.compile(r"[0-9A-Za-z.:_-]+")

#: Where network ports and servers listen unless the user widens it.
DEFAULT_BIND = "127.0.0.1"


def url_host(bind: str) -> str:
    """The host to put in a URL for a socket bound to ``bind`` (a wildcard bind is reached on loopback here)."""
    try:
        addr = ipaddress.ip_address(bind)
    except ValueError:
        return bind
    if addr.is_unspecified:
        return "127.0.0.1" if addr.version == 4 else "[::1]"
    return f"[{bind}]" if addr.version == 6 else bind


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (or ``localhost``)."""
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


__all__ = ["DEFAULT_BIND", "HostPort", "bind_address", "is_loopback", "port_number", "url_host"]
