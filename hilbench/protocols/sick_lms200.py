"""SICK LMS 200 serial telegrams: framing, SICK's CRC, ACK/NAK, mode changes, variants and B0 scans.

Wire layout (spec sheet laser_scanners.md §2), little-endian::

    STX(02) ADR LEN(u16) CMD DATA[..] [STATUS] CRC(u16, SICK CRC-16)
    ADR: request = sensor address (00); reply = 0x80 | address
    LEN: bytes from CMD through STATUS (request: CMD + DATA)
    reply CMD = request CMD + 0x80 (reset 10 -> 91, later 90)

A single ACK byte (06) precedes every reply; a rejected telegram gets NAK (15).
Scans (reply B0): ``COUNT`` (u16: bits 0-9 n, 11-12 partial index, 13 partial,
14-15 units 0 cm / 1 mm) then n u16 values (bits 0-12 distance, 13-15 field
A/B/C bits in the default measuring mode).

:class:`Decoder` frames a byte stream of either direction, checks each
telegram's CRC, reports ACK/NAK bytes, and never raises: garbage and bad
CRCs are counted and resynchronised on the next STX.
"""

from __future__ import annotations

from enum import IntEnum
from functools import cache
from typing import TYPE_CHECKING, Any, NamedTuple

from hilbench.protocols.checksums import sick_crc16
from hilbench.protocols.lazy_layouts import lazy_layouts
from hilbench.protocols.problem import Problem

STX = 0x02
ACK = 0x06
NAK = 0x15
HOST_ADDRESS_BIT = 0x80
#: The link speed after power-up (and a reset).
POWER_UP_BAUD = 9600
#: Mode byte of a link speed change (mode 40/41/42/48) -> the speed it switches to: the one table of an
#: LMS 200's link speeds.
BAUD_MODES = {0x40: 38_400, 0x41: 19_200, 0x42: 9_600, 0x48: 500_000}
#: Every link speed an LMS 200 runs at, slowest first.
LINK_BAUDS = tuple(sorted(BAUD_MODES.values()))
#: A bounded telegram: the longest a LMS 2xx sends is 1452 bytes (721 values).
MAX_LEN = 2048
#: The installation-mode password.
PASSWORD = b"SICK_LMS"
#: The status byte real units report in normal operation.
STATUS_OK = 0x10
#: Scan variants (angle °, resolution in 1/100 °) -> values per scan.
VARIANTS = {(100, 100): 101, (100, 50): 201, (100, 25): 401, (180, 100): 181, (180, 50): 361}
#: Mirror revolution (75 Hz) and revolutions per full scan by resolution.
MIRROR_PERIOD = 1 / 75
REVOLUTIONS = {100: 1, 50: 2, 25: 4}
UNITS = {0: "cm", 1: "mm"}


class Cmd(IntEnum):
    """Request codes (§2.4)."""

    RESET = 0x10
    MODE = 0x20
    SCAN = 0x30
    STATUS = 0x31
    TYPE = 0x3A
    VARIANT = 0x3B
    READ_CONFIG = 0x74
    WRITE_CONFIG = 0x77


class Mode(IntEnum):
    """Operating-mode bytes of command 20 (§2.5) that hilbench emulates."""

    INSTALLATION = 0x00
    DIAGNOSTIC = 0x10
    CONTINUOUS = 0x24
    POLLED = 0x25
    BAUD_38400 = 0x40
    BAUD_19200 = 0x41
    BAUD_9600 = 0x42
    BAUD_500K = 0x48


REPLY_POWER_ON = 0x90
REPLY_RESET = 0x91
REPLY_INVALID = 0x92

if TYPE_CHECKING:  # (made by _layouts() when first used)
    from construct import Struct

    Telegram: Struct
    CountWord: Struct
    VariantReply: Struct
    VariantRequest: Struct


#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("Telegram", "CountWord", "VariantReply", "VariantRequest")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts (``_LAYOUT_NAMES``), made with construct's import when first used: the decoders
    run without them until a frame needs one (the monitor asks every instrument about a capture's first
    bytes, and must not import construct for that)."""
    from construct import (
        BitsInteger,
        BitStruct,
        Byte,
        Bytes,
        Checksum,
        Const,
        Int16ul,
        RawCopy,
        Struct,
        this,
    )

    #: The telegram frame (CRC over STX .. the last byte before it).
    Telegram = Struct(
        "body" / RawCopy(Struct(
            "stx" / Const(bytes([STX])),
            "address" / Byte,
            "length" / Int16ul,
            "cmd" / Byte,
            "data" / Bytes(this.length - 1),
        )),
        "crc" / Checksum(Int16ul, sick_crc16, this.body.data),
    )
    #: The COUNT word of a B0 scan (little-endian u16; BitStruct reads it as its big-endian bits).
    CountWord = BitStruct(
        "units" / BitsInteger(2),
        "partial" / BitsInteger(1),
        "index" / BitsInteger(2),
        "reserved" / BitsInteger(1),
        "count" / BitsInteger(10),
    )
    #: Reply to 3B (set variant): accepted flag, effective angle and resolution.
    VariantReply = Struct("accepted" / Byte, "angle" / Int16ul, "resolution" / Int16ul)
    VariantRequest = Struct("angle" / Int16ul, "resolution" / Int16ul)

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


def layouts() -> None:
    """Make the construct layouts now (an emulator that builds its replies with them calls this when it is
    made, so that no client's first request waits for construct's import)."""
    _layouts()


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


#: The 32-byte configuration block (74/77); hilbench reads the units byte (index 11: 0 cm, 1 mm).
CONFIG_SIZE = 32
CONFIG_UNITS = 11


def count_word(n: int, units_mm: bool, index: int = 0, partial: bool = False) -> int:
    """The COUNT word of a B0 scan."""
    raw = _layouts()["CountWord"].build({"units": 1 if units_mm else 0, "partial": int(partial), "index": index,
                                         "reserved": 0, "count": n})
    return int.from_bytes(raw, "big")


def parse_count_word(word: int) -> dict[str, int]:
    c = _layouts()["CountWord"].parse(word.to_bytes(2, "big"))
    return {"count": c.count, "index": c.index, "partial": c.partial, "units": c.units}


# ----------------------------------------------------------------------------- building


def telegram(cmd: int, data: bytes = b"", *, address: int = 0, status: int | None = None) -> bytes:
    """A telegram: a request (``status`` None) or a reply (the status byte last in DATA)."""
    body = bytes(data) + (bytes([status]) if status is not None else b"")
    return _layouts()["Telegram"].build({"body": {"value": {"address": address, "length": len(body) + 1, "cmd": cmd,
                                                            "data": body}}})


def request(cmd: int, data: bytes = b"", address: int = 0) -> bytes:
    """A host request to the sensor at ``address``."""
    return telegram(cmd, data, address=address)


def reply(cmd: int, data: bytes = b"", status: int = STATUS_OK, address: int = 0) -> bytes:
    """A sensor reply telegram (without the ACK byte) to request ``cmd`` (reply code ``cmd | 0x80``)."""
    return telegram(cmd, data, address=HOST_ADDRESS_BIT | address, status=status)


def mode_request(mode: int, password: bytes = PASSWORD) -> bytes:
    """Command 20 (operating mode); installation mode carries the password."""
    return request(Cmd.MODE, bytes([mode]) + (password if mode == Mode.INSTALLATION else b""))


def variant_request(angle: int, resolution: int) -> bytes:
    return request(Cmd.VARIANT, _layouts()["VariantRequest"].build({"angle": angle, "resolution": resolution}))


def scan_data(values: list[int], units_mm: bool, index: int = 0, partial: bool = False) -> bytes:
    """DATA of a B0 reply: COUNT and the values (each already carrying its field bits)."""
    import struct as _s

    return _s.pack(f"<H{len(values)}H", count_word(len(values), units_mm, index, partial), *values)


# ----------------------------------------------------------------------------- parsing


class Frame(NamedTuple):
    """A telegram with a good CRC. ``is_reply`` when ADR has bit 7; ``status`` is a reply's last data byte."""

    address: int
    cmd: int
    data: bytes
    status: int | None
    raw: bytes

    @property
    def is_reply(self) -> bool:
        return bool(self.address & HOST_ADDRESS_BIT)

    @property
    def name(self) -> str:
        code = self.cmd & 0x7F if self.is_reply and self.cmd not in (REPLY_POWER_ON, REPLY_RESET,
                                                                       REPLY_INVALID) else self.cmd
        try:
            return Cmd(code).name if code not in (REPLY_POWER_ON, REPLY_RESET, REPLY_INVALID) else {
                REPLY_POWER_ON: "POWER_ON", REPLY_RESET: "RESET_ACK", REPLY_INVALID: "INVALID"}[code]
        except ValueError:
            return f"0x{self.cmd:02X}"

    def fields(self) -> dict[str, Any]:
        """Decoded fields of the telegrams hilbench knows (scans, mode replies, variant replies)."""
        d = self.data
        if self.is_reply and self.cmd == 0xB0 and len(d) >= 2:
            return parse_scan(d)
        if self.is_reply and self.cmd == 0xA0 and d:
            return {"accepted": d[0] == 0}
        if self.is_reply and self.cmd == 0xBB and len(d) >= 5:
            v = _layouts()["VariantReply"].parse(d[:5])
            return {"accepted": bool(v.accepted), "angle": v.angle, "resolution": v.resolution}
        if not self.is_reply and self.cmd == Cmd.MODE and d:
            return {"mode": d[0]}
        if not self.is_reply and self.cmd == Cmd.VARIANT and len(d) >= 4:
            v = _layouts()["VariantRequest"].parse(d[:4])
            return {"angle": v.angle, "resolution": v.resolution}
        return {}


def parse_scan(data: bytes) -> dict[str, Any]:
    """A B0 reply's DATA (without status): count word fields, distances and field bits."""
    word = data[0] | data[1] << 8
    info = parse_count_word(word)
    n = min(info["count"], (len(data) - 2) // 2)
    raw = [data[2 + 2 * k] | data[3 + 2 * k] << 8 for k in range(n)]
    info["values"] = [v & 0x1FFF for v in raw]
    info["field_bits"] = [v >> 13 for v in raw]
    info["complete"] = n == info["count"]
    return info


class Handshake(NamedTuple):
    """A single ACK (06) or NAK (15) byte."""

    ack: bool


class Decoder:
    """Incremental telegram decoder for either direction; never raises.

    ``handshakes``: report single ACK/NAK bytes between telegrams (the sensor's
    direction). Bytes that do not start a telegram with a good CRC are dropped
    and counted; after a bad CRC the search resumes one byte after the STX.
    """

    def __init__(self, *, handshakes: bool = True, max_len: int = MAX_LEN) -> None:
        self._buf = bytearray()
        self.handshakes = handshakes
        self.max_len = max_len
        self.dropped = 0
        self.bad_crc = 0

    def _garbage(self, out: list, raw: bytes) -> None:
        self.dropped += len(raw)
        if out and isinstance(out[-1], Problem) and out[-1].kind == "garbage":
            out[-1] = Problem("garbage", out[-1].raw + raw)
        else:
            out.append(Problem("garbage", raw))

    def feed(self, data: bytes) -> list[Frame | Handshake | Problem]:
        buf = self._buf
        buf += data
        out: list = []
        i, n = 0, len(buf)
        while i < n:
            b = buf[i]
            if b != STX:
                if self.handshakes and b in (ACK, NAK):
                    out.append(Handshake(b == ACK))
                else:
                    self._garbage(out, bytes([b]))
                i += 1
                continue
            if i + 4 > n:
                break
            length = buf[i + 2] | buf[i + 3] << 8
            if length < 1 or length > self.max_len:
                self.dropped += 1
                out.append(Problem("length", bytes(buf[i:i + 4]), f"LEN {length}"))
                i += 1
                continue
            end = i + 4 + length + 2
            if end > n:
                break
            raw = bytes(buf[i:end])
            crc = raw[-2] | raw[-1] << 8
            if sick_crc16(raw[:-2]) != crc:
                self.bad_crc += 1
                self.dropped += 1
                out.append(Problem("crc", raw, f"CRC {crc:04X}, expected {sick_crc16(raw[:-2]):04X}"))
                i += 1
                continue
            address, cmd = raw[1], raw[4]
            data_ = raw[5:-2]
            status = None
            if address & HOST_ADDRESS_BIT and data_:
                status = data_[-1]
                data_ = data_[:-1]
            out.append(Frame(address, cmd, data_, status, raw))
            i = end
        del buf[:i]
        return out


__all__ = [
    "ACK", "BAUD_MODES", "CONFIG_SIZE", "CONFIG_UNITS", "LINK_BAUDS", "MAX_LEN", "MIRROR_PERIOD", "NAK", "PASSWORD",
    "POWER_UP_BAUD", "REPLY_INVALID", "REPLY_POWER_ON", "REPLY_RESET", "REVOLUTIONS", "STATUS_OK", "STX", "UNITS",
    "VARIANTS", "Cmd", "CountWord", "Decoder", "Frame", "Handshake", "Mode", "Telegram",
    "VariantReply", "VariantRequest", "count_word", "layouts", "mode_request", "parse_count_word", "parse_scan",
    "reply", "request", "scan_data", "telegram", "variant_request",
]
