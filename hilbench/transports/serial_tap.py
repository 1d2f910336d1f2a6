"""A tap between an application and a serial device: ``hilbench tap REAL_PORT``.

:class:`SerialTap` creates a pseudo-terminal for the application and opens
the real port (any path pyserial opens: a USB adapter, or an emulated bench's
pty). One thread forwards both ways: whatever one side writes is written to
the other as soon as a single read returns it, so the tap adds no delay
beyond that read. Every forwarded chunk also goes to a :class:`PushSource`
(``tap.source``) with its time and direction (``app`` or ``device``), from
which a monitor or a recorder reads it.

The real port follows the baud rate the application sets on its pty (as a
USB adapter would), unless a fixed ``baud`` is given.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time

from hilbench.transports.pty import PtyPort
from hilbench.transports.readiness import Readiness
from hilbench.transports.sources import PushSource, SourceError, SourceUnavailable

APP = "app"
DEVICE = "device"


class SerialTap:
    """Forwards bytes between an application's pty and ``real_port``, publishing both directions."""

    def __init__(self, real_port: str, *, baud: int | None = None, link: str | None = None,
                 max_buffer: int = 16 << 20) -> None:
        import serial  # pyserial

        from hilbench.transports.serial_url import open_url

        self.real_port = real_port
        self.fixed_baud = baud
        try:
            self._ser = open_url(real_port, baudrate=baud or 57_600, timeout=0, write_timeout=2)
        except serial.SerialException as exc:  # not there, busy, refused (an OSError in pyserial)
            raise SourceUnavailable(f"cannot open {real_port}: {exc}") from None
        except ValueError as exc:  # a malformed URL or setting
            raise SourceError(f"cannot open {real_port}: {exc}") from None
        try:
            self.pty = PtyPort(APP, link=link)
        except BaseException:
            self._ser.close()
            raise
        self.baud = baud or self._ser.baudrate
        self.source = PushSource(f"tap {real_port}", baud=self.baud, max_bytes=max_buffer)
        self.bytes_to_device = 0
        self.bytes_to_app = 0
        self.baud_changes = 0
        self.error: OSError | None = None
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name=f"tap-{real_port}", daemon=True)

    @property
    def app_path(self) -> str:
        """What the application opens instead of the real port (the link if one was asked for)."""
        return self.pty.client_path

    def start(self) -> SerialTap:
        self._thread.start()
        return self

    def _follow_baud(self) -> None:
        if self.fixed_baud is not None:
            return
        baud = self.pty.client_baud()
        if baud and baud != self.baud:
            with contextlib.suppress(ValueError, OSError):
                self._ser.baudrate = baud
                self.baud = baud
                self.source.baud = baud
                self.baud_changes += 1

    def _run(self) -> None:
        try:
            self._forward()
        finally:
            self.source.end()

    def _forward(self) -> None:
        app_fd = self.pty.fileno()
        dev_fd = self._ser.fileno()
        ser = self._ser
        push = self.source.push
        self._follow_baud()
        readiness = Readiness([app_fd, dev_fd, self._wake_r])
        while not self._stop.is_set():
            try:
                ready = readiness.idle(0.5)
            except (OSError, ValueError):
                break
            if app_fd in ready:
                data = self.pty.read()
                if data:
                    self._follow_baud()
                    try:
                        ser.write(data)
                    except Exception:  # noqa: BLE001 (the device went away: keep the app side alive)
                        if self._stop.is_set():
                            break
                        continue
                    self.bytes_to_device += len(data)
                    push(time.monotonic(), APP, data)
            if dev_fd in ready:
                try:
                    data = os.read(dev_fd, 65536)
                except BlockingIOError:
                    data = b""
                except OSError as exc:  # the device went away (adapter unplugged)
                    if not self._stop.is_set():
                        self.error = exc
                    break
                if data:
                    self.pty.write(data)
                    self.bytes_to_app += len(data)
                    push(time.monotonic(), DEVICE, data)

    def close(self) -> None:
        """Stop forwarding, end the source, close both ports."""
        self._stop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self.source.end()
        with contextlib.suppress(Exception):
            self._ser.close()
        self.pty.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> SerialTap:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
