"""Vel2d: the rover's 28-byte velocity setpoint frame (host to STM32 board), and idle-line framing.

Wire layout (spec sheet stm32_board.md §1.2), packed, little-endian, no header,
delimiter or length field::

    offset 0  float64 x    linear.x   m/s
    offset 8  float64 y    linear.y   m/s
    offset 16 float64 z    angular.z  rad/s
    offset 24 uint32  crc  CRC-32/MPEG-2 over bytes 0..23

The board frames purely by time (§1.4): a frame is whatever arrived before
the line went idle for one character time, or 28 bytes when the receive
buffer fills. :class:`IdleLineFramer` reproduces that from byte arrival times
so the emulated board and host tools (a monitor of the host-to-board
direction) frame alike; :func:`decode` then checks a framed chunk the way the
firmware's ``recv_vel`` task does.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from construct import Checksum, Float64l, Int32ul, RawCopy, Struct, this

from hilbench.errors import FormatError
from hilbench.protocols.checksums import crc32_mpeg2
from hilbench.protocols.problem import Problem

FRAME_SIZE = 28
PAYLOAD_SIZE = 24
#: The firmware multiplies x and y by this (m/s to mm/s); z stays in rad/s.
MM_PER_M = 1000.0

#: The firmware's ERROR log messages (ulog), byte for byte.
MSG_INSUFFICIENT = "parsing velocity failed: insufficient bytes received"
MSG_CRC = "crc mismatch!"  #: the firmware's message for a CRC mismatch

_PAYLOAD = struct.Struct("<3d")
_FRAME = struct.Struct("<3dI")

#: The reference layout. ``payload`` is the three doubles; the checksum covers their bytes only.
Frame = Struct(
    "payload" / RawCopy(Struct("x" / Float64l, "y" / Float64l, "z" / Float64l)),
    "crc" / Checksum(Int32ul, crc32_mpeg2, this.payload.data),
)


class Velocity(NamedTuple):
    """A frame that passed its CRC: the host's Twist in SI units (m/s, m/s, rad/s)."""

    x: float
    y: float
    z: float
    crc: int

    def firmware_units(self) -> tuple[float, float, float]:
        """What the firmware puts in ``vel_sp_queue``: (vx mm/s, vy mm/s, omega rad/s)."""
        return self.x * MM_PER_M, self.y * MM_PER_M, self.z


class Vel2dError(FormatError):
    """Raised by :func:`parse` (the strict form); :func:`decode` never raises."""


def crc(payload: bytes) -> int:
    """CRC-32/MPEG-2 of the 24 payload bytes."""
    return crc32_mpeg2(payload)


def build(x: float, y: float, z: float) -> bytes:
    """The 28 wire bytes for a Twist (linear.x, linear.y in m/s; angular.z in rad/s)."""
    payload = _PAYLOAD.pack(x, y, z)
    return payload + crc32_mpeg2(payload).to_bytes(4, "little")


def decode(raw: bytes) -> Velocity | Problem:
    """Check one framed chunk as ``recv_vel`` does; never raises.

    A chunk the board drops is a :class:`~hilbench.protocols.problem.Problem` whose ``detail`` is the
    firmware's log message: ``kind`` ``length`` (not 28 bytes: :data:`MSG_INSUFFICIENT`, nothing counted) or
    ``crc`` (the stored CRC, ``got``, differs from the computed one, ``expected``: :data:`MSG_CRC`, and the
    firmware increments ``crc_err``).
    """
    raw = bytes(raw)
    if len(raw) != FRAME_SIZE:
        return Problem("length", raw, MSG_INSUFFICIENT)
    x, y, z, stored = _FRAME.unpack(raw)
    computed = crc32_mpeg2(raw[:PAYLOAD_SIZE])
    if computed != stored:
        return Problem("crc", raw, MSG_CRC, expected=computed, got=stored)
    return Velocity(x, y, z, stored)


def parse(raw: bytes) -> Velocity:
    """Strict parse with the construct layout; raises :class:`Vel2dError` on a bad frame."""
    result = decode(raw)
    if isinstance(result, Problem):
        if result.kind == "length":
            raise Vel2dError(f"expected {FRAME_SIZE} bytes, got {len(raw)}")
        raise Vel2dError(f"CRC mismatch: stored 0x{result.got:08X}, computed 0x{result.expected:08X}")
    c = Frame.parse(raw)
    return Velocity(c.payload.value.x, c.payload.value.y, c.payload.value.z, c.crc)


def build_with_construct(x: float, y: float, z: float) -> bytes:
    """:func:`build` through the construct layout (tests prove the two agree)."""
    return Frame.build({"payload": {"value": {"x": x, "y": y, "z": z}}})


class IdleLineFramer:
    """Frame a byte stream as the board's UART does: by idle gaps and a 28-byte buffer.

    ``feed(data, t)`` takes bytes that were on the wire back to back, the first
    starting at ``t`` seconds (each byte lasts ``10 / baud``); it returns the
    chunks completed so far as ``(raw, t_end)``, where ``t_end`` is when the
    receive event fires (buffer full: at the last byte's end; idle: one
    character time after it). A chunk that starts later than one character
    time after the previous byte ended first closes the pending chunk.
    :meth:`poll` closes a pending chunk once the line has been idle long
    enough; :meth:`flush` closes it unconditionally.

    Bytes that arrive while earlier ones would still be on the wire are
    queued behind them (a sender cannot overtake itself), so the framer also
    accepts timestamps of whole writes taken on the host side.
    """

    def __init__(self, baud: int = 115_200, size: int = FRAME_SIZE) -> None:
        if baud <= 0 or size <= 0:
            raise ValueError("baud and size must be positive")
        self.baud = baud
        self.size = size
        self.char_time = 10.0 / baud
        self._pending = bytearray()
        self._line_free = float("-inf")  # when the last byte received so far ended

    @property
    def pending(self) -> bytes:
        """Bytes received since the last event."""
        return bytes(self._pending)

    @property
    def line_free_at(self) -> float:
        """When the last byte received so far ended."""
        return self._line_free

    def idle_deadline(self) -> float | None:
        """When the pending chunk will be closed by an idle event (None if nothing is pending)."""
        return self._line_free + self.char_time if self._pending else None

    def feed(self, data: bytes, t: float) -> list[tuple[bytes, float]]:
        out: list[tuple[bytes, float]] = []
        if not data:
            return out
        ct = self.char_time
        start = max(t, self._line_free)
        if self._pending and start > self._line_free + ct:
            out.append((bytes(self._pending), self._line_free + ct))
            self._pending.clear()
        pending = self._pending
        size = self.size
        pos = 0
        n = len(data)
        if pending:  # complete the buffer the last bytes began
            pos = min(size - len(pending), n)
            pending += data[:pos]
            if len(pending) == size:
                out.append((bytes(pending), start + pos * ct))
                pending.clear()
        whole = (n - pos) // size  # then whole buffers straight from the data (a stream of frames)
        if whole:
            stop = pos + whole * size
            out.extend([(data[p : p + size], start + (p + size) * ct) for p in range(pos, stop, size)])
            pos = stop
        if pos < n:
            pending += data[pos:]
        self._line_free = start + n * ct
        return out

    def poll(self, now: float) -> list[tuple[bytes, float]]:
        """Close the pending chunk if the line has been idle for a character time by ``now``."""
        deadline = self.idle_deadline()
        if deadline is not None and now >= deadline:
            return self.flush()
        return []

    def flush(self) -> list[tuple[bytes, float]]:
        """Close the pending chunk now (end of input)."""
        if not self._pending:
            return []
        chunk = (bytes(self._pending), self._line_free + self.char_time)
        self._pending.clear()
        return [chunk]

    def reset(self) -> None:
        """Forget pending bytes (the board was reset)."""
        self._pending.clear()
        self._line_free = float("-inf")


def frame_stream(chunks: list[tuple[bytes, float]], baud: int = 115_200) -> list[Velocity | Problem]:
    """Frame and check a list of ``(bytes, start_time)`` writes; a convenience for tools and tests."""
    framer = IdleLineFramer(baud)
    out: list[Velocity | Problem] = []
    for data, t in chunks:
        out.extend(decode(raw) for raw, _ in framer.feed(data, t))
    out.extend(decode(raw) for raw, _ in framer.flush())
    return out
