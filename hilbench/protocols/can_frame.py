"""Classic CAN frames: the frame itself, its SocketCAN byte layout, and its length on the wire.

One frame type (:class:`CanFrame`) is shared by every CAN part of hilbench:
the emulated bus, the socketcand/SLCAN/SocketCAN/virtual doors, the CANopen
fakes, the monitor and python-can log files.

Byte layout
-----------
Wherever a CAN frame travels as bytes inside hilbench (a medium's taps, the
bench's TCP traffic tap, hilbench captures, the SocketCAN door), it is Linux's
``struct can_frame`` (``linux/can.h``), 16 bytes, little-endian::

    offset 0  u32 can_id    bits 0-28 identifier; bit 31 EFF (extended),
                            bit 30 RTR (remote), bit 29 ERR (error frame:
                            bits 0-28 are then the error class)
    offset 4  u8  len       data length 0..8 (the DLC; a remote frame's
                            requested length)
    offset 5  u8  pad, u8 res0, u8 len8_dlc (0)
    offset 8  u8  data[8]   data bytes, zero padded

So a capture record (or a tap chunk) of a CAN medium holds a whole number of
16-byte frames, normally exactly one.

Wire length
-----------
:func:`frame_bits` gives a frame's duration in bit times the way can-utils'
``canframelen.c`` (used by ``canbusload``) does: ``exact`` stuffs the real
bit stream (SOF to the end of the CRC, with the CRC-15 computed), ``worst``
and ``none`` are the closed forms. Every mode includes the 3-bit interframe
space. One difference: a remote frame carries no data field here, while
can-utils also stuffs the data bytes a remote frame does not send.
"""

from __future__ import annotations

import struct
from functools import lru_cache
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from construct import Struct

    SocketCanFrame: Struct

CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_SFF_MASK = 0x7FF
CAN_EFF_MASK = 0x1FFFFFFF
CAN_ERR_MASK = 0x1FFFFFFF
#: Bytes of one frame in the SocketCAN layout.
FRAME_SIZE = 16
#: Bytes of an error frame's data (``CAN_ERR_DLC``).
CAN_ERR_DLC = 8

# Error classes (linux/can/error.h): the identifier bits of an error frame.
CAN_ERR_TX_TIMEOUT = 0x001
CAN_ERR_LOSTARB = 0x002
CAN_ERR_CRTL = 0x004
CAN_ERR_PROT = 0x008
CAN_ERR_TRX = 0x010
CAN_ERR_ACK = 0x020
CAN_ERR_BUSOFF = 0x040
CAN_ERR_BUSERROR = 0x080
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200
# data[1]: controller state.
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
# data[2]: protocol violation type.
CAN_ERR_PROT_BIT = 0x01
CAN_ERR_PROT_FORM = 0x02
CAN_ERR_PROT_STUFF = 0x04
CAN_ERR_PROT_TX = 0x80
# data[3]: where in the frame.
CAN_ERR_PROT_LOC_CRC_SEQ = 0x08
CAN_ERR_PROT_LOC_DATA = 0x0A
CAN_ERR_PROT_LOC_ACK = 0x19

ERROR_CLASS_NAMES = {
    CAN_ERR_TX_TIMEOUT: "tx-timeout",
    CAN_ERR_LOSTARB: "lost-arbitration",
    CAN_ERR_CRTL: "controller",
    CAN_ERR_PROT: "protocol",
    CAN_ERR_TRX: "transceiver",
    CAN_ERR_ACK: "no-ack",
    CAN_ERR_BUSOFF: "bus-off",
    CAN_ERR_BUSERROR: "bus-error",
    CAN_ERR_RESTARTED: "restarted",
    CAN_ERR_CNT: "counters",
}


class CanFrame(NamedTuple):
    """One classic CAN frame.

    ``can_id`` is the bare identifier (11 or 29 bits; for an error frame its
    error class bits). ``dlc`` is the data length code (``len(data)`` for data
    frames; the requested length of a remote frame, whose ``data`` is empty).
    """

    can_id: int
    data: bytes = b""
    extended: bool = False
    remote: bool = False
    error: bool = False
    dlc: int = -1

    @property
    def length(self) -> int:
        """The DLC (``len(data)`` unless a remote frame asks for another length)."""
        return self.dlc if self.dlc >= 0 else len(self.data)

    @property
    def id_text(self) -> str:
        """The identifier as candump writes it: 3 hex digits, or 8 for an extended one."""
        return f"{self.can_id:08X}" if self.extended else f"{self.can_id:03X}"

    def __str__(self) -> str:
        if self.error:
            return f"error {self.can_id:03X} [{self.data.hex(' ').upper()}]"
        body = f"R{self.length}" if self.remote else self.data.hex().upper()
        return f"{self.id_text}#{body}"


def data_frame(can_id: int, data: bytes | bytearray = b"", *, extended: bool | None = None) -> CanFrame:
    """A data frame; ``extended`` defaults to whether the ID needs 29 bits. Raises ValueError on bad input."""
    data = bytes(data)
    if extended is None:
        extended = can_id > CAN_SFF_MASK
    if not 0 <= can_id <= (CAN_EFF_MASK if extended else CAN_SFF_MASK):
        raise ValueError(f"CAN ID 0x{can_id:X} does not fit an {'extended' if extended else 'standard'} frame")
    if len(data) > 8:
        raise ValueError(f"a classic CAN frame carries at most 8 bytes, got {len(data)}")
    return CanFrame(can_id, data, extended, False, False, len(data))


def remote_frame(can_id: int, dlc: int = 0, *, extended: bool | None = None) -> CanFrame:
    """A remote frame asking for ``dlc`` bytes."""
    if extended is None:
        extended = can_id > CAN_SFF_MASK
    if not 0 <= dlc <= 8:
        raise ValueError(f"DLC must be 0..8, got {dlc}")
    return CanFrame(can_id, b"", extended, True, False, dlc)


def error_frame(error_class: int, data: bytes | bytearray = bytes(8)) -> CanFrame:
    """A SocketCAN error frame: ``error_class`` bits (CAN_ERR_*) and 8 detail bytes."""
    data = bytes(data).ljust(CAN_ERR_DLC, b"\0")[:CAN_ERR_DLC]
    return CanFrame(error_class & CAN_ERR_MASK, data, False, False, True, CAN_ERR_DLC)


def error_class_names(error_class: int) -> list[str]:
    """The names of the classes set in an error frame's identifier."""
    return [name for bit, name in ERROR_CLASS_NAMES.items() if error_class & bit] or [f"0x{error_class:03X}"]


# --------------------------------------------------------------------------- SocketCAN layout


def __getattr__(name: str) -> Any:
    """``SocketCanFrame``: ``struct can_frame``, the reference layout (:func:`pack`/:func:`unpack` are its fast
    paths), made with construct's import when first asked for (nothing but tests needs it)."""
    if name != "SocketCanFrame":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from construct import Bytes, Int8ul, Int32ul, Padding, Struct

    value = globals()[name] = Struct(
        "can_id" / Int32ul,
        "len" / Int8ul,
        Padding(2),
        "len8_dlc" / Int8ul,
        "data" / Bytes(8),
    )
    return value


_FRAME = struct.Struct("<IB2xB8s")


def raw_can_id(frame: CanFrame) -> int:
    """The ``can_id`` word of the SocketCAN layout (identifier plus EFF/RTR/ERR flags)."""
    if frame.error:
        return CAN_ERR_FLAG | (frame.can_id & CAN_ERR_MASK)
    word = frame.can_id & (CAN_EFF_MASK if frame.extended else CAN_SFF_MASK)
    if frame.extended:
        word |= CAN_EFF_FLAG
    if frame.remote:
        word |= CAN_RTR_FLAG
    return word


def pack(frame: CanFrame) -> bytes:
    """The 16 bytes of ``struct can_frame``."""
    return _FRAME.pack(raw_can_id(frame), frame.length, 0, frame.data)


def from_raw(word: int, length: int, data: bytes) -> CanFrame:
    """A frame from the SocketCAN ``can_id`` word, its length and (at least ``length``) data bytes."""
    length = min(length, 8)
    if word & CAN_ERR_FLAG:
        return CanFrame(word & CAN_ERR_MASK, bytes(data[:CAN_ERR_DLC]).ljust(CAN_ERR_DLC, b"\0"), False, False,
                        True, CAN_ERR_DLC)
    extended = bool(word & CAN_EFF_FLAG)
    can_id = word & (CAN_EFF_MASK if extended else CAN_SFF_MASK)
    if word & CAN_RTR_FLAG:
        return CanFrame(can_id, b"", extended, True, False, length)
    return CanFrame(can_id, bytes(data[:length]), extended, False, False, length)


def unpack(buf: bytes, offset: int = 0) -> CanFrame:
    """The frame of 16 SocketCAN bytes at ``offset`` (a length above 8 is read as 8)."""
    word, length, _len8, data = _FRAME.unpack_from(buf, offset)
    return from_raw(word, length, data)


def split(data: bytes) -> tuple[list[CanFrame], int]:
    """Every whole 16-byte frame of ``data`` and how many trailing bytes were not a whole frame.

    Never raises: a capture record of a CAN medium that is not a multiple of
    16 bytes loses only its tail (counted by the caller).
    """
    n = len(data) // FRAME_SIZE
    unpack_from = _FRAME.unpack_from
    out = []
    for i in range(n):
        word, length, _len8, payload = unpack_from(data, i * FRAME_SIZE)
        out.append(from_raw(word, length, payload))
    return out, len(data) - n * FRAME_SIZE


# --------------------------------------------------------------------------- wire length

#: Bits after the CRC sequence: CRC delimiter, ACK slot, ACK delimiter, 7 EOF, 3 interframe space.
TRAILER_BITS = 3 + 7 + 3
#: Bits an error frame takes after the error is detected: 6 flag, 8 delimiter, 3 intermission.
ERROR_FRAME_BITS = 6 + 8 + 3


def _crc15(bits: list[int]) -> int:
    # CAN's CRC-15 runs over a bit stream that is not byte aligned (SOF..data), which
    # crcmod's byte-wise functions cannot express; the bitwise shift register is short.
    crc = 0
    for bit in bits:
        nxt = bit ^ (crc >> 14)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


def _bits(value: int, width: int) -> list[int]:
    return [(value >> i) & 1 for i in range(width - 1, -1, -1)]


def stream_bits(frame: CanFrame) -> list[int]:
    """The unstuffed bits from SOF to the end of the CRC sequence (the part bit stuffing applies to)."""
    length = frame.length
    if frame.extended:
        head = ([0] + _bits(frame.can_id >> 18, 11) + [1, 1] + _bits(frame.can_id & 0x3FFFF, 18)
                + [int(frame.remote), 0, 0] + _bits(length, 4))
    else:
        head = [0] + _bits(frame.can_id, 11) + [int(frame.remote), 0, 0] + _bits(length, 4)
    if not frame.remote:
        for byte in frame.data[:length]:
            head += _bits(byte, 8)
    return head + _bits(_crc15(head), 15)


def stuff_count(bits: list[int]) -> int:
    """How many stuff bits a transmitter inserts into ``bits`` (after five equal bits, one opposite bit)."""
    count = 0
    run = 0
    last = -1
    for bit in bits:
        if bit == last:
            run += 1
        else:
            last, run = bit, 1
        if run == 5:
            count += 1
            last, run = 1 - bit, 1  # the stuff bit starts the next run
    return count


@lru_cache(maxsize=4096)
def _exact_bits(frame: CanFrame) -> int:
    bits = stream_bits(frame)
    return len(bits) + stuff_count(bits) + TRAILER_BITS


def frame_bits(frame: CanFrame, mode: str = "exact") -> int:
    """Bit times of ``frame`` on the bus including the interframe space (``exact``, ``worst`` or ``none``).

    An error frame (a SocketCAN report, not a transmission) takes
    :data:`ERROR_FRAME_BITS`.
    """
    if frame.error:
        return ERROR_FRAME_BITS
    n = 0 if frame.remote else frame.length
    if mode == "exact":
        return _exact_bits(frame)
    if mode == "worst":
        return (80 if frame.extended else 55) + 10 * n
    if mode == "none":
        return (67 if frame.extended else 47) + 8 * n
    raise ValueError(f"mode must be exact, worst or none, got {mode!r}")


def arbitration_key(frame: CanFrame) -> tuple[int, int, int, int, int]:
    """Sorts frames in the order bitwise arbitration lets them onto the bus (lowest first).

    The base identifier decides first; on a tie a standard data frame (RTR and
    IDE dominant) beats a standard remote frame, which beats any extended frame
    (SRR and IDE recessive), whose 18 low identifier bits and RTR decide next.
    """
    if frame.extended:
        return (frame.can_id >> 18, 1, 1, frame.can_id & 0x3FFFF, int(frame.remote))
    return (frame.can_id, int(frame.remote), 0, 0, 0)


__all__ = [
    "CAN_EFF_FLAG", "CAN_EFF_MASK", "CAN_ERR_FLAG", "CAN_ERR_MASK", "CAN_RTR_FLAG", "CAN_SFF_MASK",
    "ERROR_FRAME_BITS", "FRAME_SIZE", "CanFrame", "SocketCanFrame", "arbitration_key", "data_frame",
    "error_class_names", "error_frame", "frame_bits", "from_raw", "pack", "raw_can_id", "remote_frame", "split",
    "stream_bits", "stuff_count", "unpack",
]
