"""Pseudo-terminal endpoints: a serial port that client programs open like a USB adapter."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
import stat
import struct
import termios
import tty
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hilbench.errors import OptionError, UsageError
from hilbench.transports.host_port import HostPort
from hilbench.transports.port_state import PortState, SerialSettings

#: termios speed constants to bit/s, for reading the baud a client configured.
_SPEEDS: dict[int, int] = {}
for _name in dir(termios):
    if _name.startswith("B") and _name[1:].isdigit():
        _SPEEDS[getattr(termios, _name)] = int(_name[1:])


def speed_to_baud(speed: int) -> int | None:
    """Map a termios speed constant to bit/s; None for BOTHER or unknown codes."""
    return _SPEEDS.get(speed)


# Linux only: a rate that is no B constant (pyserial's 4.5 Mbaud) is set as BOTHER with the number in
# struct termios2, which Python's termios module cannot read; the request number is pyserial's.
_BOTHER = 0o010000
_TCGETS2 = getattr(termios, "TCGETS2", 0x802C542A)
_TERMIOS2 = struct.Struct("4I B 19s 2I")
_CMSPAR = getattr(termios, "CMSPAR", 0o10000000000)
_BYTESIZE = {termios.CS5: 5, termios.CS6: 6, termios.CS7: 7, termios.CS8: 8}
_FRAMING = termios.CSIZE | termios.PARENB | termios.PARODD | _CMSPAR | termios.CSTOPB


def termios_settings(fd: int, framing: int | None = None) -> SerialSettings:
    """Baud rate and framing a tty is set to (raises termios.error if ``fd`` is none).

    A pty keeps the rate and CSTOPB but forces CS8 and clears PARENB, so the data
    bits and parity a client asked for are only known from its own request:
    ``framing`` is that request's ``c_cflag`` (``hilbench run`` reports it).
    """
    _, _, cflag, _, _, ospeed, _ = termios.tcgetattr(fd)
    return _decode_settings(fd, cflag, ospeed, framing)


def _decode_settings(fd: int, cflag: int, ospeed: int, framing: int | None) -> SerialSettings:
    baud = speed_to_baud(ospeed)
    if baud is None and ospeed == _BOTHER:
        with contextlib.suppress(OSError):
            baud = _TERMIOS2.unpack(fcntl.ioctl(fd, _TCGETS2, bytes(_TERMIOS2.size)))[-1] or None
    if framing is not None:
        cflag = (cflag & ~_FRAMING) | (framing & _FRAMING)
    bytesize = _BYTESIZE.get(cflag & termios.CSIZE, 8)
    if not cflag & termios.PARENB:
        parity = "N"
    elif cflag & _CMSPAR:
        parity = "M" if cflag & termios.PARODD else "S"
    else:
        parity = "O" if cflag & termios.PARODD else "E"
    stopbits = (1.5 if bytesize == 5 else 2.0) if cflag & termios.CSTOPB else 1.0
    return SerialSettings(baud, bytesize, parity, stopbits)


class LinkRefused(UsageError):
    """A stable link whose name is taken (by a file, a directory, or a link not left by a gone bench)."""


def left_by_a_gone_pty(link: str | os.PathLike[str]) -> bool:
    """Whether ``link`` is a symlink to a pty that no longer exists (left by a bench that was killed): a pty's
    node goes away with its last descriptor, so such a link leads nowhere and may be replaced."""
    try:
        target = os.readlink(link)
    except OSError:
        return False
    return target.startswith("/dev/pts/") and not os.path.lexists(target)


def _points_to(link: Path, target: str) -> bool:
    try:
        return os.readlink(link) == target
    except OSError:
        return False


def _what_is(path: Path, st: os.stat_result) -> str:
    if stat.S_ISLNK(st.st_mode):
        try:
            return f"a symlink to {os.readlink(path)}"
        except OSError:
            return "a symlink"
    return "a directory" if stat.S_ISDIR(st.st_mode) else "a file"


class PtyPort(HostPort):
    """One pseudo-terminal pair; the client side is :attr:`path` (and :attr:`link` if given).

    The master and the endpoint's own slave descriptor stay open for the
    endpoint's lifetime, so clients may open, close and reopen the port
    without the master seeing EIO. The slave is in raw mode from the start:
    a cooked pty would echo and rewrite bytes. Both descriptors are
    non-blocking; bytes a client does not read in time are dropped and
    counted, as a UART with a full receive buffer drops them.

    A pty has no modem lines of its own: :attr:`port_state` holds the ones a host
    drives through ``hilbench run`` (or an RFC 2217 server) and the device drives.
    Profile key: ``link`` (a stable symlink to the pty). The link is made only
    where nothing is, or in place of a dead link to a pty that is gone (a
    killed bench's); anything else there is refused (:class:`LinkRefused`).
    :meth:`close` removes the link only while it is still the one made.
    """

    kind = "pty"
    profile_keys = {"link": None}
    backpressure = True  # unread, the kernel's buffer fills and the client's write() waits

    def __init__(self, name: str = "pty", link: str | os.PathLike[str] | None = None) -> None:
        self.name = name
        self.port_state = PortState()  #: modem signals, BREAK and serial settings (the host's and the devices')
        self.master_fd, self.slave_fd = os.openpty()
        tty.setraw(self.slave_fd)
        os.set_blocking(self.master_fd, False)
        self.path = os.ttyname(self.slave_fd)  #: the client side's device path
        self.link: Path | None = None  #: the stable symlink to it, if one was made
        self._link_id: tuple[int, int] | None = None  # (st_dev, st_ino) of the link made
        self.bytes_in = 0
        self.bytes_out = 0
        self.dropped = 0
        self.framing: int | None = None  # c_cflag of the client's last tcsetattr, if reported
        self._settings_key: tuple | None = None
        self._settings = self.port_state.settings
        if link is not None:
            self._make_link(Path(link))

    def _make_link(self, link: Path) -> None:
        """Make ``link`` a symlink to the pty; never in place of anything but a link a gone bench left."""
        try:
            st: os.stat_result | None = os.lstat(link)
        except FileNotFoundError:
            st = None
        except OSError as exc:
            self.close()
            raise LinkRefused(f"{link}: cannot make the link: {exc.strerror or exc}") from None
        # A killed bench's link leads to a pty that is gone, or to the very number this pty was given.
        if st is not None and not (left_by_a_gone_pty(link) or _points_to(link, self.path)):
            self.close()
            raise LinkRefused(f"{link}: {_what_is(link, st)} is there; refusing to replace it (remove it, or "
                              "choose another link path or --link-dir)")
        try:
            link.parent.mkdir(parents=True, exist_ok=True)
            if st is None:
                os.symlink(self.path, link)  # FileExistsError if something appeared since
            else:  # a dead link of a bench that was killed: replaced in one step
                tmp = link.with_name(f".{link.name}.{secrets.token_hex(4)}.tmp")
                os.symlink(self.path, tmp)
                try:
                    os.replace(tmp, link)
                except OSError:
                    with contextlib.suppress(OSError):
                        tmp.unlink()
                    raise
            made = os.lstat(link)
        except OSError as exc:
            self.close()
            raise LinkRefused(f"{link}: cannot make the link: {exc.strerror or exc}") from None
        self.link = link
        self._link_id = (made.st_dev, made.st_ino)

    def _owns_link(self) -> bool:
        """Whether :attr:`link` is still the link this endpoint made, pointing where it made it point."""
        if self.link is None or self._link_id is None:
            return False
        try:
            st = os.lstat(self.link)
            return (st.st_dev, st.st_ino) == self._link_id and os.readlink(self.link) == self.path
        except OSError:
            return False

    @classmethod
    def check_options(cls, raw: dict[str, Any]) -> dict[str, Any]:
        link = raw.get("link")
        if link is not None and not isinstance(link, str):
            raise OptionError("link", f"expected a path string on a pty endpoint, got {link!r}")
        return {"link": link}

    @classmethod
    def open(cls, name: str, options: dict[str, Any], *, link_dir: str | os.PathLike[str] | None = None,
             **_: Any) -> PtyPort:
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

    @property
    def rdev(self) -> int:
        """The pty's device number (``st_rdev``): how ``hilbench run`` recognises it in a client."""
        return os.fstat(self.slave_fd).st_rdev

    def client_settings(self) -> SerialSettings:
        """Baud rate and framing the client set with termios; a change becomes a SerialSettings event."""
        try:
            _, _, cflag, _, _, ospeed, _ = termios.tcgetattr(self.slave_fd)
        except termios.error:
            return self.port_state.settings
        key = (cflag, ospeed, self.framing)
        # The medium asks on every read: skip decoding when nothing changed (a custom rate, BOTHER,
        # hides its number from tcgetattr, so that one is always read again).
        if key == self._settings_key and ospeed != _BOTHER:
            return self._settings
        settings = _decode_settings(self.slave_fd, cflag, ospeed, self.framing)
        self._settings_key, self._settings = key, settings
        self.port_state.host_settings(settings)  # emits only if something changed
        return settings

    def report_framing(self, cflag: int) -> SerialSettings:
        """The client's own ``c_cflag`` from its tcsetattr (the pty forgets data bits and parity)."""
        self.framing = cflag & _FRAMING
        return self.client_settings()

    def client_baud(self) -> int | None:
        """The baud the client set with termios (None if unknown); the medium asks on every read."""
        return self.client_settings().baud

    def read(self, size: int = 65536) -> bytes:
        """Bytes the client wrote (at most ``size``), or b'' if none are waiting."""
        try:
            data = os.read(self.master_fd, size)
        except BlockingIOError:
            return b""
        except OSError as exc:  # EIO would mean no slave is open, which we prevent
            if exc.errno == errno.EIO:
                return b""
            raise
        self.bytes_in += len(data)
        return data

    #: ``hilbench run``'s serving path (:mod:`hilbench.bench.serve_ring`): takes the bytes for a served
    #: client (returns how many it took) or returns None (write them to the pty).
    serve: Callable[[bytes], int | None] | None = None
    #: Its input flush (the ring's unread bytes are dropped with the pty's).
    serve_discard: Callable[[], None] | None = None
    #: The ring's bytes no client has read yet (on the client's side as soon as written).
    serve_pending: Callable[[], int] | None = None

    def write(self, data: bytes) -> int:
        """Send bytes to the client; what does not fit is dropped and counted."""
        if self.serve is not None and (taken := self.serve(data)) is not None:
            self.bytes_out += taken
            self.dropped += len(data) - taken
            return taken
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
        if self.serve_discard is not None:
            self.serve_discard()

    def close(self) -> None:
        """Remove the link and close both descriptors."""
        if self.link is not None:
            if self._owns_link():  # not a link the user (or another bench) put there since
                with contextlib.suppress(OSError):
                    self.link.unlink()
            self.link = None
            self._link_id = None
        for fd in (self.master_fd, self.slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        self.master_fd = self.slave_fd = -1

    def __enter__(self) -> PtyPort:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"PtyPort({self.name!r}, path={self.client_path!r})"
