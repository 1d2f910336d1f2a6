"""Serial ports opened receive-only: a sniffer on a real bus (or a bench's pty)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from urllib.parse import parse_qs, urlparse

from hilbench.transports.chunk import Chunk
from hilbench.transports.sources.base import Source, SourceError, SourceOpener, SourceUnavailable


class SerialSource(Source):
    """A serial port opened receive-only with pyserial: a sniffer on a bus (never writes)."""

    def __init__(self, port: str, baud: int | None = None, *, read_timeout: float = 0.02) -> None:
        import serial  # pyserial; imported here so captures can be read without it

        from hilbench.transports.serial_url import open_url

        self.name = port
        self.baud = baud or 57_600
        try:
            self._ser = open_url(port, baudrate=self.baud, timeout=read_timeout)
        except serial.SerialException as exc:  # not there, busy, refused (an OSError in pyserial)
            raise SourceUnavailable(f"cannot open {port}: {exc}") from None
        except ValueError as exc:  # a malformed URL or setting
            raise SourceError(f"cannot open {port}: {exc}") from None
        self._stop = threading.Event()

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        ser = self._ser
        last = time.monotonic()
        while not self._stop.is_set():
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (OSError, TypeError, AttributeError):
                if self._stop.is_set():
                    return  # closed under us
                raise
            now = time.monotonic()
            if data:
                last = now
                yield Chunk(now, "bus", data)
            elif idle is not None and now - last >= idle:
                last = now
                yield None

    def close(self) -> None:
        self._stop.set()
        try:
            self._ser.close()
        except Exception:  # noqa: BLE001 (closing is best effort)
            pass


def open_serial(spec: str, target: str, fragment: str, *, baud: int | None = None, default_baud: int = 57_600,
                **_: object) -> Source:
    """A character device path, or ``serial:///dev/ttyUSB0?baud=N``."""
    if spec.startswith("serial:"):
        url = urlparse(spec)
        query = parse_qs(url.query)
        if "baud" in query:
            try:
                baud = int(query["baud"][0])
            except ValueError:
                raise SourceError(f"{spec}: baud must be an integer") from None
        target = url.path or url.netloc
    return SerialSource(target, baud or default_baud)


SERIAL = SourceOpener("serial", open_serial, schemes=("serial",), kinds=("char",),
                      usage="/dev/ttyUSB0, a pty, serial:///dev/ttyUSB0?baud=N",
                      what="a serial port opened receive-only with pyserial at --baud (or the URL's rate)")

__all__ = ["SERIAL", "SerialSource", "open_serial"]
