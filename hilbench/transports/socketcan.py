"""SocketCAN: join a kernel CAN interface (``vcan0``, a real ``can0``) where the kernel has AF_CAN.

:func:`af_can_status` probes for the address family once; where it is
missing (many containers, this project's CI) every SocketCAN path says why
in one line instead of failing deep inside. :class:`SocketCanDoor` is the
door of a CAN host port: it reads and writes ``struct can_frame`` records
(:func:`hilbench.protocols.can_frame.pack`) on a raw CAN socket. It takes any
connected datagram socket of that shape, so the same code runs on a kernel
socket and, in tests, on a SEQPACKET socket pair standing in for the kernel.
"""

from __future__ import annotations

import contextlib
import functools
import socket

from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.can_door import CanDoor

#: Frames read per call at most (the rest wait for the next round).
READ_BATCH = 256


@functools.lru_cache(maxsize=1)
def af_can_status() -> tuple[bool, str]:
    """``(True, "")`` where raw CAN sockets can be made, else ``(False, why)``."""
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return False, "this Python has no socket.AF_CAN (not Linux?)"
    try:
        sock = socket.socket(family, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return False, f"the kernel refuses AF_CAN sockets ({exc.strerror or exc}): no SocketCAN here"
    sock.close()
    return True, ""


def open_raw_socket(channel: str) -> socket.socket:
    """A raw CAN socket bound to ``channel`` that also receives error frames; OSError with the reason."""
    ok, why = af_can_status()
    if not ok:
        raise OSError(f"SocketCAN {channel}: {why}")
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    try:
        sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_ERR_FILTER, cf.CAN_ERR_MASK)
        sock.bind((channel,))
    except OSError as exc:
        sock.close()
        raise OSError(f"SocketCAN {channel}: {exc.strerror or exc} (does the interface exist and is it up?)") from None
    return sock


class SocketCanDoor(CanDoor):
    """The SocketCAN door of a CAN host port: frames both ways between the emulated bus and ``sock``."""

    kind = "socketcan"

    def __init__(self, sock: socket.socket, channel: str) -> None:
        self.sock = sock
        self.channel = channel
        self.source = f"socketcan {channel}"
        self.sock.setblocking(False)
        self.received = 0
        self.sent = 0
        self.dropped = 0
        self.malformed = 0

    @classmethod
    def open(cls, channel: str) -> SocketCanDoor:
        """Join kernel interface ``channel``; raises OSError saying why it cannot."""
        return cls(open_raw_socket(channel), channel)

    def describe(self) -> str:
        return self.channel

    def filenos(self) -> list[int]:
        return [self.sock.fileno()]

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        out: list[tuple[str, CanFrame]] = []
        for _ in range(READ_BATCH):
            try:
                data = self.sock.recv(cf.FRAME_SIZE + 56)  # a CAN FD frame (72 bytes) is read whole, then refused
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            if len(data) != cf.FRAME_SIZE:
                self.malformed += 1
                continue
            frame = cf.unpack(data)
            if frame.error:
                continue  # the kernel's error reports for that interface, not frames of this bus
            out.append((self.source, frame))
            self.received += 1
        return out

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        if source == self.source or frame.error:
            return
        try:
            self.sock.send(cf.pack(frame))
            self.sent += 1
        except (BlockingIOError, InterruptedError):
            self.dropped += 1  # the interface's queue is full (txqueuelen): the kernel drops as well
        except OSError:
            self.dropped += 1

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


__all__ = ["SocketCanDoor", "af_can_status", "open_raw_socket"]
