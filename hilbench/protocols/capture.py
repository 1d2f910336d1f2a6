"""hilbench capture format (``.hbcap``): bus bytes with their time and source.

One definition of the layout, used by the recorder, the capture reader and
the bench's tap server (which streams the same records over TCP). Full
description: ``docs/formats/capture-format.md``. All integers little-endian::

    file   = header record*
    header = magic(8) = 89 'HBC' 0D 0A 1A 0A
             version u16 (1)
             body_size u16, then body_size bytes:
                 flags u16           bit 0: times are measured (live or recorded)
                                     bit 1: times are synthetic (byte time at `baud`)
                 baud u32            line rate in bit/s, 0 if unknown
                 t0_wall f64         Unix time of t = 0
                 t0_monotonic f64    time.monotonic() of t = 0 in the recording process
                 protocol str8       e.g. "dynamixel" ("" if unknown)
                 description str8    what was recorded (a port, a bench endpoint, ...)
             (readers ignore body bytes they do not know: later versions may append fields)
    record = kind u8, source u8, length u16, t_ns i64, payload[length]
             kind 0 DATA    payload = bytes `source` put on the bus, complete at t0 + t_ns
             kind 1 SOURCE  payload = UTF-8 name of source id `source` (before its first DATA)
             kind 2 GAP     payload = u32: bytes of `source` lost before reaching the recorder
             kind 3 ADDRESS payload = family u8 (4 or 6), source address (4|16), source port u16,
                            destination address (4|16), destination port u16: the addresses
                            of the datagram in the next DATA record of `source`
             (readers skip records of unknown kinds)

The magic is built like PNG's (0x89, CR LF, ^Z, LF), so text-mode
transfers and 7-bit channels show up as a bad magic, and no raw Dynamixel
capture (which starts with FF FF FD 00 or fill bytes) is mistaken for one.
A record carries at most 65535 payload bytes; writers split longer chunks.

:func:`pack_record` / :func:`unpack_record_header` are the fast paths the
reader and writer use per record; tests prove they agree with the construct
layouts.
"""

from __future__ import annotations

import struct
from enum import IntEnum, IntFlag
from functools import cache
from typing import Any, NamedTuple

from hilbench.protocols.lazy_layouts import lazy_layouts

MAGIC = b"\x89HBC\r\n\x1a\n"
VERSION = 1
#: Largest payload of one record.
MAX_PAYLOAD = 0xFFFF
#: Suggested file name extension.
EXTENSION = ".hbcap"


class RecordKind(IntEnum):
    DATA = 0
    SOURCE = 1
    GAP = 2
    ADDRESS = 3


class Flags(IntFlag):
    MEASURED = 1  # times were measured (a live source, or a recording of one)
    SYNTHETIC = 2  # times were computed from byte counts at `baud`


#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("HeaderBody", "Header", "RecordHeader", "Record", "GapPayload", "AddressPayload")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts (``_LAYOUT_NAMES``), made with construct's import when first used: the reader and
    writer run on the fast paths per record, and a tap server builds its header when a client connects, so a
    bench or monitor starts without construct."""
    from construct import (
        Bytes,
        Const,
        Float64l,
        Int8ul,
        Int16ul,
        Int32ul,
        Int64sl,
        PascalString,
        Prefixed,
        Struct,
        this,
    )

    HeaderBody = Struct(
        "flags" / Int16ul,
        "baud" / Int32ul,
        "t0_wall" / Float64l,
        "t0_monotonic" / Float64l,
        "protocol" / PascalString(Int8ul, "utf8"),
        "description" / PascalString(Int8ul, "utf8"),
    )

    #: The file header: magic, version, then a length-prefixed body (future fields go at its end).
    Header = Struct(
        "magic" / Const(MAGIC),
        "version" / Int16ul,
        "body" / Prefixed(Int16ul, HeaderBody),
    )

    RecordHeader = Struct(
        "kind" / Int8ul,
        "source" / Int8ul,
        "length" / Int16ul,
        "t_ns" / Int64sl,
    )

    Record = Struct(
        "kind" / Int8ul,
        "source" / Int8ul,
        "length" / Int16ul,
        "t_ns" / Int64sl,
        "payload" / Bytes(this.length),
    )

    #: The payload of a GAP record: how many bytes of the source were lost.
    GapPayload = Struct("lost" / Int32ul)

    #: The payload of an ADDRESS record (a datagram's addresses; ports little-endian like every integer here).
    AddressPayload = Struct(
        "family" / Int8ul,
        "src" / Bytes(lambda ctx: 4 if ctx.family == 4 else 16),
        "src_port" / Int16ul,
        "dst" / Bytes(lambda ctx: 4 if ctx.family == 4 else 16),
        "dst_port" / Int16ul,
    )

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


#: Bytes of a record before its payload.
RECORD_HEADER_SIZE = 12  # (the construct layout's RecordHeader.sizeof(): a test keeps them equal)
#: Bytes of the header up to and including body_size (the body follows).
HEADER_PREFIX_SIZE = len(MAGIC) + 4

_RECORD = struct.Struct("<BBHq")
_HEADER_SIZES = struct.Struct("<HH")  # version, body_size
_HEADER_BODY = struct.Struct("<HIdd")  # flags, baud, t0_wall, t0_monotonic (then protocol and description)


class CaptureInfo(NamedTuple):
    """What a capture's header says."""

    version: int
    flags: int
    baud: int | None
    t0_wall: float
    t0_monotonic: float
    protocol: str
    description: str

    @property
    def measured(self) -> bool:
        return bool(self.flags & Flags.MEASURED)

    @property
    def synthetic(self) -> bool:
        return bool(self.flags & Flags.SYNTHETIC)


def build_header(
    *,
    flags: int = Flags.MEASURED,
    baud: int | None = None,
    t0_wall: float = 0.0,
    t0_monotonic: float = 0.0,
    protocol: str | None = "",
    description: str = "",
) -> bytes:
    """The file header (the ``Header`` layout, packed with ``struct``: a test proves both agree);
    ``protocol`` None or "" means unknown."""
    fields = {
        "flags": int(flags),
        "baud": baud or 0,
        "t0_wall": t0_wall,
        "t0_monotonic": t0_monotonic,
        "protocol": (protocol or "")[:255],
        "description": description.encode()[:255].decode(errors="ignore"),
    }
    name, text = fields["protocol"].encode(), fields["description"].encode()
    if len(name) > 255:  # (no str8 holds it: the layout raises its own error)
        return _layouts()["Header"].build({"version": VERSION, "body": fields})
    body = (_HEADER_BODY.pack(fields["flags"], fields["baud"], t0_wall, t0_monotonic) + bytes((len(name),)) + name
            + bytes((len(text),)) + text)
    return MAGIC + _HEADER_SIZES.pack(VERSION, len(body)) + body


def parse_header(data: bytes) -> CaptureInfo:
    """Parse a whole header (prefix and body); raises ``ValueError`` on a bad magic or version."""
    if data[: len(MAGIC)] != MAGIC:
        raise ValueError("not a hilbench capture (bad magic)")
    version = data[8] | data[9] << 8
    if version > VERSION:
        raise ValueError(f"capture format version {version} is newer than this hilbench reads ({VERSION})")
    c = _layouts()["Header"].parse(data)
    b = c.body
    return CaptureInfo(c.version, b.flags, b.baud or None, b.t0_wall, b.t0_monotonic, b.protocol, b.description)


def header_body_size(prefix: bytes) -> int:
    """The body size from the first :data:`HEADER_PREFIX_SIZE` bytes of a header."""
    return prefix[10] | prefix[11] << 8


def pack_record(kind: int, source: int, t_ns: int, payload: bytes) -> bytes:
    """Fast path: one record (payload at most :data:`MAX_PAYLOAD` bytes)."""
    return _RECORD.pack(kind, source, len(payload), t_ns) + payload


def unpack_record_header(buf: bytes, offset: int = 0) -> tuple[int, int, int, int]:
    """Fast path: (kind, source, length, t_ns) of the record at ``offset``."""
    return _RECORD.unpack_from(buf, offset)


def gap_record(source: int, t_ns: int, lost: int) -> bytes:
    """A GAP record: ``lost`` bytes of ``source`` (capped at 2^32 - 1) never reached the reader."""
    return pack_record(RecordKind.GAP, source, t_ns, _layouts()["GapPayload"].build({"lost": min(lost, 0xFFFFFFFF)}))


def gap_lost(payload: bytes) -> int | None:
    """The byte count of a GAP record's payload, or None if it is too short."""
    return _layouts()["GapPayload"].parse(payload).lost if len(payload) >= 4 else None


def _ip_bytes(host: str) -> tuple[int, bytes]:
    import ipaddress

    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        ip = ipaddress.ip_address("0.0.0.0")  # a host name: unknown address (the port is still kept)
    return (4, ip.packed) if ip.version == 4 else (6, ip.packed)


def build_address(addr: tuple[str, int, str, int]) -> bytes:
    """The ADDRESS payload of ``(source host, source port, destination host, destination port)``."""
    fam_s, src = _ip_bytes(addr[0])
    fam_d, dst = _ip_bytes(addr[2])
    if fam_s != fam_d:  # mixed families cannot share one record: store both as IPv6 (IPv4-mapped)
        import ipaddress

        src = ipaddress.IPv6Address(b"\x00" * 10 + b"\xff\xff" + src).packed if fam_s == 4 else src
        dst = ipaddress.IPv6Address(b"\x00" * 10 + b"\xff\xff" + dst).packed if fam_d == 4 else dst
        fam_s = 6
    return _layouts()["AddressPayload"].build({"family": fam_s, "src": src, "src_port": addr[1], "dst": dst,
                                               "dst_port": addr[3]})


def parse_address(payload: bytes) -> tuple[str, int, str, int] | None:
    """An ADDRESS payload back to its tuple (None if it is cut short or of an unknown family)."""
    import ipaddress

    if not payload or payload[0] not in (4, 6) or len(payload) < (13 if payload[0] == 4 else 37):
        return None
    a = _layouts()["AddressPayload"].parse(payload)
    return str(ipaddress.ip_address(a.src)), a.src_port, str(ipaddress.ip_address(a.dst)), a.dst_port


def address_record(source: int, t_ns: int, addr: tuple[str, int, str, int]) -> bytes:
    """An ADDRESS record for the DATA record of ``source`` that follows it."""
    return pack_record(RecordKind.ADDRESS, source, t_ns, build_address(addr))
