"""A tiny device for `hilbench run` tests: it records bytes and line events in arrival order and, when
the host clears both DTR and RTS, drives CTS, DSR and CD (as a modem answering would)."""

from __future__ import annotations

import threading
from typing import Any

from hilbench.transports.port_state import (
    BreakCondition,
    ModemSignals,
    OutputFlushed,
    PortEvent,
    SerialSettings,
)

ANSWER = {"cts": True, "dsr": True, "ri": False, "cd": True}


class PortEventRecorder:
    """Put it on a running bench's endpoint with :meth:`attach`."""

    def __init__(self, name: str = "recorder") -> None:
        self.name = name
        self.port: Any = None
        self._lock = threading.Lock()
        self.log: list[Any] = []

    def attach(self, endpoint: Any) -> PortEventRecorder:
        self.port = endpoint.medium.add_device(self)
        return self

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        with self._lock:
            self.log.append(bytes(data))

    def on_port_event(self, event: PortEvent, t: float) -> None:
        with self._lock:
            self.log.append(event)
        if event == ModemSignals(False, False):
            self.port.set_lines(**ANSWER)

    def sequence(self, *, settings: bool = True) -> list[Any]:
        """The log with consecutive byte chunks joined (and SerialSettings left out unless ``settings``)."""
        out: list[Any] = []
        with self._lock:
            log = list(self.log)
        for item in log:
            if isinstance(item, bytes) and out and isinstance(out[-1], bytes):
                out[-1] += item
            elif settings or not isinstance(item, SerialSettings):
                out.append(item)
        return out

    def received(self) -> bytes:
        with self._lock:
            return b"".join(x for x in self.log if isinstance(x, bytes))

    def events(self) -> list[Any]:
        with self._lock:
            return [x for x in self.log if not isinstance(x, bytes)]


__all__ = ["ANSWER", "BreakCondition", "PortEventRecorder", "SerialSettings", "ModemSignals", "OutputFlushed"]
