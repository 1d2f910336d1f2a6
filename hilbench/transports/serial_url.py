"""Opening a serial port or pyserial URL so that a refusing server's own words reach the user.

A busy RFC 2217 port (hilbench's, as ser2net's) answers a second client with a
line of text and hangs up. pyserial's client takes that line as port data and
then fails its Telnet negotiation, with "Broken pipe" or "Remote does not seem
to support RFC2217": nothing about the port being busy. :func:`open_url` opens
as ``serial.serial_for_url`` does and, when opening fails, reports the text the
server sent instead (one line, printable characters only, bounded).
"""

from __future__ import annotations

import os
import stat
from typing import Any

from hilbench.errors import UsageError

#: The most of a server's refusal that is quoted (it comes from the network).
MAX_SAID = 300


def server_said(ser: Any) -> str:
    """The first line of text a URL port's server sent before hanging up ("" if none)."""
    queued = getattr(ser, "_read_buffer", None)  # pyserial's rfc2217 client: one item per received byte
    if queued is None:
        return ""
    data = b"".join(item for item in list(queued.queue)[: MAX_SAID * 4] if item)
    line = data.decode("utf-8", "replace").strip().splitlines()[:1]
    text = "".join(ch for ch in (line[0] if line else "") if ch.isprintable())
    return text[:MAX_SAID].strip()


class NotAPort(UsageError):
    """A path given as a serial port that is a regular file or a directory: one line, exit status 2."""


def check_port(path: str) -> None:
    """Raise :class:`NotAPort` if ``path`` (not a URL) is a regular file or a directory: pyserial would fail on
    it with "Inappropriate ioctl for device". Nothing is opened (opening a real port may toggle its DTR)."""
    if "://" in path:
        return
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return  # not there: opening it says so (exit status 1)
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        kind = "a directory" if stat.S_ISDIR(mode) else "a file"
        raise NotAPort(f"{path}: {kind}, not a serial port (a recording of a bus is read by `hilbench monitor`)")


def open_url(url: str, **settings: Any):
    """``serial.serial_for_url(url, **settings)``, opened; a server's refusal raises
    ``serial.SerialException("the server refused: <its line>")``, any other failure a SerialException
    with pyserial's reason."""
    import serial  # pyserial

    check_port(url)
    ser = serial.serial_for_url(url, do_not_open=True, **settings)
    try:
        ser.open()
    except (serial.SerialException, OSError) as exc:
        said = server_said(ser)
        if said:
            raise serial.SerialException(f"the server refused: {said}") from None
        if isinstance(exc, serial.SerialException):
            raise
        raise serial.SerialException(str(exc)) from None
    return ser


__all__ = ["MAX_SAID", "NotAPort", "check_port", "open_url", "server_said"]
