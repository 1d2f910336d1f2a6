"""python-can's ``virtual`` interface as a door to an emulated bus, for code in the same process.

``can.Bus(interface="virtual", channel=CHANNEL)`` anywhere in the bench's
process then sees the bus's frames and puts its own on it (through the bus's
arbitration and pacing like every other party). python-can's virtual buses
have no descriptor to wait on, so a small thread receives from the channel
and wakes the bus through a pipe.
"""

from __future__ import annotations

import collections
import contextlib
import threading
from typing import Any

from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.can_door import CanDoor
from hilbench.transports.can_messages import to_frame, to_message
from hilbench.transports.clock import WALL
from hilbench.transports.medium_loop import WakePipe

#: Frames held between the receiving thread and the bus before new ones are dropped.
MAX_INBOX = 100_000


class VirtualChannel(CanDoor):
    """The virtual door of a CAN host port, on python-can virtual channel ``channel``."""

    kind = "virtual"

    def __init__(self, channel: str) -> None:
        import can

        self.channel = channel
        self.source = f"virtual {channel}"
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False,
                           preserve_timestamps=True)  # (the bus clock's Unix time, see write_frame)
        self._inbox: collections.deque[CanFrame] = collections.deque()
        self._waker = WakePipe()
        self._stop = threading.Event()
        self.received = 0
        self.sent = 0
        self.dropped = 0
        self._clock = WALL  # the bus's clock once attached: frames carry its Unix time
        self._thread = threading.Thread(target=self._run, name=f"can-virtual-{channel}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.1)
            except Exception:  # the bus was shut down under us
                return
            if msg is None:
                continue
            frame = to_frame(msg)
            if frame is None:
                continue
            if len(self._inbox) >= MAX_INBOX:
                self.dropped += 1
                continue
            self._inbox.append(frame)
            self._waker.wake()

    def attach(self, medium: Any) -> None:
        self._clock = getattr(medium, "clock", WALL)

    def describe(self) -> str:
        return self.channel

    def filenos(self) -> list[int]:
        return [self._waker.fd]

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        self._waker.drain(65536)
        out = []
        while self._inbox:
            out.append((self.source, self._inbox.popleft()))
        self.received += len(out)
        return out

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        if source == self.source:
            return
        msg = to_message(frame, timestamp=self._clock.wall(t))
        try:
            self.bus.send(msg)
            self.sent += 1
        except Exception:
            self.dropped += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        with contextlib.suppress(Exception):
            self.bus.shutdown()
        self._waker.close()


__all__ = ["VirtualChannel"]
