"""SLCAN, the LAWICEL ASCII protocol of serial CAN adapters (CAN232, CANUSB, CANable, python-can ``slcan``).

Each host command is a line ended by CR (0x0D); the adapter answers CR for
success and BEL (0x07) for an error, and reports received frames as lines of
their own::

    t1234DEADBEEF\\r      standard frame 0x123, 4 bytes        (T + 8 ID digits: extended)
    r1232\\r              standard remote frame 0x123, DLC 2   (R: extended remote)
    t1234DEADBEEF1A2B\\r  ... with a timestamp (ms, 0000..EA5F) after ``Z1``

Sources: the LAWICEL CAN232/CANUSB manuals, the Linux ``slcan`` driver and
python-can's ``slcan`` interface (which maps 750 kbit/s, not 800 kbit/s, to
``S7``; this module keeps LAWICEL's 800 kbit/s and says so). A line protocol
of fixed-position hex fields: slicing strings says it more plainly than
``construct`` would.
"""

from __future__ import annotations

from typing import NamedTuple

from hilbench.protocols.can_frame import CAN_EFF_MASK, CAN_SFF_MASK, CanFrame

CR = b"\r"
BEL = b"\a"
#: ``Sn`` bitrate presets (LAWICEL). python-can sends S7 for 750000 and S9 for 83300.
BITRATES = {"0": 10_000, "1": 20_000, "2": 50_000, "3": 100_000, "4": 125_000, "5": 250_000, "6": 500_000,
            "7": 800_000, "8": 1_000_000, "9": 83_300}
#: Longest command line kept (an extended frame with 8 bytes and a timestamp is 31 characters).
MAX_LINE = 64
#: Timestamps count milliseconds and wrap after a minute (0xEA60).
TIMESTAMP_WRAP = 60_000

# Status flags of the ``F`` command (LAWICEL CANUSB manual).
FLAG_RX_FULL = 0x01
FLAG_TX_FULL = 0x02
FLAG_ERROR_WARNING = 0x04
FLAG_DATA_OVERRUN = 0x08
FLAG_ERROR_PASSIVE = 0x20
FLAG_ARBITRATION_LOST = 0x40
FLAG_BUS_ERROR = 0x80


class LineSplitter:
    """Bytes in, command lines out (ended by CR; LF is ignored); bounded, never raises.

    A line longer than :data:`MAX_LINE` is dropped whole (counted in
    :attr:`dropped`), as an adapter's command buffer overflows.
    """

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self.max_line = max_line
        self._buf = bytearray()
        self._overflow = False
        self.dropped = 0  #: bytes of lines dropped (too long)

    def feed(self, data: bytes) -> list[str]:
        out: list[str] = []
        buf = self._buf
        start = 0
        data = data.replace(b"\n", b"")
        while True:
            end = data.find(CR, start)
            if end < 0:
                tail = data[start:]
                if self._overflow or len(buf) + len(tail) > self.max_line:
                    self.dropped += len(buf) + len(tail)
                    buf.clear()
                    self._overflow = True
                else:
                    buf += tail
                return out
            piece = data[start:end]
            if self._overflow or len(buf) + len(piece) > self.max_line:
                self.dropped += len(buf) + len(piece) + 1
                self._overflow = False
            else:
                out.append((bytes(buf) + piece).decode("ascii", "replace"))
            buf.clear()
            start = end + 1


class Command(NamedTuple):
    """One parsed host line: ``op`` is its letter (``""`` for an empty line), ``frame`` for t/T/r/R,
    ``value`` the rest of the line; ``valid`` False for a malformed one."""

    op: str
    frame: CanFrame | None = None
    value: str = ""
    valid: bool = True


def _frame(line: str, extended: bool, remote: bool) -> CanFrame | None:
    n = 8 if extended else 3
    if len(line) < 1 + n + 1:
        return None
    try:
        can_id = int(line[1 : 1 + n], 16)
        dlc = int(line[1 + n], 10)
    except ValueError:
        return None
    if not 0 <= dlc <= 8 or can_id > (CAN_EFF_MASK if extended else CAN_SFF_MASK):
        return None
    rest = line[2 + n :]
    if remote:
        return CanFrame(can_id, b"", extended, True, False, dlc) if len(rest) in (0, 4) else None
    hexdata = rest[: 2 * dlc]
    if len(hexdata) != 2 * dlc or len(rest) not in (2 * dlc, 2 * dlc + 4):  # optional 4-digit timestamp
        return None
    try:
        data = bytes.fromhex(hexdata)
    except ValueError:
        return None
    return CanFrame(can_id, data, extended, False, False, dlc)


def parse_command(line: str) -> Command:
    """Read one host line (without its CR); never raises."""
    if not line:
        return Command("")
    op = line[0]
    if op in "tTrR":
        frame = _frame(line, op in "TR", op in "rR")
        return Command(op, frame=frame, valid=frame is not None)
    return Command(op, value=line[1:])


def parse_frame(line: str) -> CanFrame | None:
    """An adapter's frame line (t/T/r/R, optional timestamp) as a frame; None if it is not one."""
    if not line or line[0] not in "tTrR":
        return None
    return _frame(line, line[0] in "TR", line[0] in "rR")


def encode_frame(frame: CanFrame, timestamp_ms: int | None = None) -> bytes:
    """The adapter's line for a received frame (with its CR); ``timestamp_ms`` after ``Z1``."""
    if frame.remote:
        text = f"R{frame.can_id:08X}{frame.length}" if frame.extended else f"r{frame.can_id:03X}{frame.length}"
    else:
        op = "T" if frame.extended else "t"
        width = 8 if frame.extended else 3
        text = f"{op}{frame.can_id:0{width}X}{frame.length}{frame.data.hex().upper()}"
    if timestamp_ms is not None:
        text += f"{timestamp_ms % TIMESTAMP_WRAP:04X}"
    return text.encode() + CR


def encode_command(frame: CanFrame) -> bytes:
    """The host's transmit command for ``frame`` (the same letters as a received frame)."""
    return encode_frame(frame)


def bitrate_command(bitrate: int) -> str:
    """The ``Sn`` command of a LAWICEL preset bitrate; ValueError if there is none."""
    for code, rate in BITRATES.items():
        if rate == bitrate:
            return f"S{code}"
    raise ValueError(f"no SLCAN preset for {bitrate} bit/s (presets: {sorted(BITRATES.values())})")


def acceptance(frame: CanFrame, code: int, mask: int) -> bool:
    """Whether the SJA1000 single acceptance filter (``M`` code, ``m`` mask; mask bit 1 = don't care) passes ``frame``.

    Standard frames compare ID10..0 and RTR (and the first two data bytes); extended
    frames compare ID28..0 and RTR, as in the SJA1000 data sheet's single filter mode.
    """
    if mask == 0xFFFFFFFF:
        return True
    rtr = int(frame.remote)
    if frame.extended:
        value = (frame.can_id << 3) | (rtr << 2)
        care = ~mask & 0xFFFFFFFC
    else:
        d0 = frame.data[0] if len(frame.data) > 0 else 0
        d1 = frame.data[1] if len(frame.data) > 1 else 0
        value = (frame.can_id << 21) | (rtr << 20) | (d0 << 8) | d1
        care = ~mask & 0xFFF0FFFF
    return (value ^ code) & care == 0


__all__ = ["BEL", "BITRATES", "CR", "Command", "LineSplitter", "acceptance", "bitrate_command", "encode_command",
           "encode_frame", "parse_command", "parse_frame"]
