"""Pseudo-terminal endpoints: a serial port that client programs open like a USB adapter."""

from __future__ import annotations

import contextlib
import errno
import os
import termios
import tty
from pathlib import Path
from typing import Any

from hilbench.errors import OptionError
from hilbench.transports.host_port import HostPort
from hilbench.transports.line import LineState

#: termios speed constants to bit/s, for reading the baud a client configured.
_SPEEDS: dict[int, int] = {}
for _name in dir(termios):
    if _name.startswith("B") and _name[1:].isdigit():
        _SPEEDS[getattr(termios, _name)] = int(_name[1:])


def speed_to_baud(speed: int) -> int | None:
    """Map a termios speed constant to bit/s; None for BOTHER or unknown codes."""
    return _SPEEDS.get(speed)


class PtyEndpoint(HostPort):
    """One pseudo-terminal pair; the client side is :attr:`path` (and :attr:`link` if given).

    The master and the endpoint's own slave descriptor stay open for the
    endpoint's lifetime, so clients may open, close and reopen the port
    without the master seeing EIO. The slave is in raw mode from the start:
    a cooked pty would echo and rewrite bytes. Both descriptors are
    non-blocking; bytes a client does not read in time are dropped and
    counted, as a UART with a full receive buffer drops them.

    A pty has no modem lines of its own: :attr:`lines` holds the ones a host
    drives through ``hilbench run`` (or an RFC 2217 server) and the device drives.
    Profile key: ``link`` (a stable symlink to the pty).
    """

    kind = "pty"
    profile_keys = {"link": None}

    def __init__(self, name: str = "pty", link: str | os.PathLike[str] | None = None) -> None:
        self.name = name
        self.lines = LineState()
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        os.set_blocking(self.master_fd, False)
        self.path = os.ttyname(self.slave_fd)
        self.link: Path | None = None
        self.bytes_in = 0
        self.bytes_out = 0
        self.dropped = 0
        if link is not None:
            self._make_link(Path(link))

    def _make_link(self, link: Path) -> None:
        if link.is_symlink():
            link.unlink()  # a stale link from an earlier bench
        elif link.exists():
            self.close()
            raise FileExistsError(f"{link} exists and is not a symlink; refusing to replace it")
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(self.path)
        self.link = link

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        link = raw.get("link")
        if link is not None and not isinstance(link, str):
            raise OptionError("link", f"expected a path string on a pty endpoint, got {link!r}")
        return {"link": link}

    @classmethod
    def open(cls, name: str, options: dict[str, Any], *, link_dir: str | os.PathLike[str] | None = None,
             **_: Any) -> PtyEndpoint:
        link = options.get("link")
        if link_dir is not None:
            link = str(Path(link_dir) / name)
        return cls(name, link=os.path.expanduser(link) if link else None)

    def describe(self) -> dict[str, Any]:
        return {"path": self.client_path, "pty": self.path, "link": str(self.link) if self.link else None}

    @property
    def client_path(self) -> str:
        """The path to hand to clients: the stable link if there is one."""
        return str(self.link) if self.link else self.path

    def fileno(self) -> int:
        return self.master_fd

    def client_baud(self) -> int | None:
        """The baud the client set with termios (None if non-standard)."""
        try:
            return speed_to_baud(termios.tcgetattr(self.slave_fd)[5])
        except termios.error:
            return None

    def read(self) -> bytes:
        """Bytes the client wrote, or b'' if none are waiting."""
        try:
            data = os.read(self.master_fd, 65536)
        except BlockingIOError:
            return b""
        except OSError as exc:  # EIO would mean no slave is open, which we prevent
            if exc.errno == errno.EIO:
                return b""
            raise
        self.bytes_in += len(data)
        return data

    def write(self, data: bytes) -> int:
        """Send bytes to the client; what does not fit is dropped and counted."""
        view = memoryview(data)
        sent = 0
        while sent < len(view):
            try:
                sent += os.write(self.master_fd, view[sent:])
            except BlockingIOError:
                break
        self.bytes_out += sent
        self.dropped += len(view) - sent
        return sent

    def discard_client_input(self) -> None:
        """Throw away bytes written to the client that it has not read."""
        termios.tcflush(self.slave_fd, termios.TCIFLUSH)

    def close(self) -> None:
        """Remove the link and close both descriptors."""
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink():
                    self.link.unlink()
            self.link = None
        for fd in (self.master_fd, self.slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.master_fd = self.slave_fd = -1

    def __enter__(self) -> PtyEndpoint:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"PtyEndpoint({self.name!r}, path={self.client_path!r})"
