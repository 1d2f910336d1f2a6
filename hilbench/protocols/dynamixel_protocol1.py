"""Dynamixel Protocol 1.0: framing, checksum, parameter layouts and a stream decoder.

Wire layout::

    FF FF | ID | LEN | INST (ERR in a status) | PARAMS... | CHECKSUM
    LEN = params + 2;  CHECKSUM = ~(ID + LEN + INST/ERR + sum(params)) & 0xFF

There is no reserved byte, no CRC and no stuffing. Instruction and status
packets share one layout (the byte after LEN is the instruction or the error),
so only the direction tells them apart; the decoder reports a neutral
:class:`Packet1` and callers interpret ``code`` by who sent it.

Besides the servos' instructions, the USB2AX adapter (device ID 0xFD)
answers its own SYNC_READ (0x84, spec sheet ``servo_buses.md`` §2): one status
from ID 0xFD carrying every listed servo's bytes in a row, all-0xFF for a
servo that did not answer. Feetech's servos use the same framing
(:mod:`hilbench.protocols.feetech` adds their instruction set).
"""

from __future__ import annotations

from enum import IntEnum
from functools import cache
from typing import TYPE_CHECKING, Any, NamedTuple

from hilbench.protocols.checksums import dynamixel1_checksum
from hilbench.protocols.lazy_layouts import lazy_layouts
from hilbench.protocols.problem import Problem

if TYPE_CHECKING:
    from construct import Container, Struct

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE


class Instruction1(IntEnum):
    """Protocol 1.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06
    REBOOT = 0x08
    SYNC_WRITE = 0x83
    SYNC_READ = 0x84  # the USB2AX adapter's, answered by ID 0xFD
    BULK_READ = 0x92


#: The USB2AX adapter's own ID, model number and SYNC_READ limits (its firmware's constants, §2.1).
USB2AX_ID = 0xFD
USB2AX_MODEL = 16897
USB2AX_MAX_DEVICES = 119
USB2AX_MAX_LENGTH = 122
USB2AX_MAX_DATA = 229
#: What a USB2AX SYNC_READ reply holds for a servo that did not answer.
USB2AX_MISSING = 0xFF

INSTRUCTION_NAMES: dict[int, str] = {i.value: i.name.lower() for i in Instruction1}

#: Protocol 1.0 status ERR bits.
ERROR_BITS: dict[int, str] = {
    0x01: "input voltage",
    0x02: "angle limit",
    0x04: "overheating",
    0x08: "range",
    0x10: "checksum",
    0x20: "overload",
    0x40: "instruction",
}

#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("Packet", "ReadParams", "WriteParams", "SyncWriteParams", "BulkReadParams", "SyncReadParams",
                 "NoParams", "PARAMS")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts (``_LAYOUT_NAMES``), made with construct's import when first used: the decoder and
    :func:`frame` do without them, so a bench or monitor starts without construct."""
    from construct import (
        Bytes,
        Checksum,
        Const,
        GreedyBytes,
        GreedyRange,
        Int8ul,
        RawCopy,
        Rebuild,
        Struct,
        Terminated,
        len_,
        this,
    )

    Packet = Struct(
        "frame"
        / RawCopy(
            Struct(
                "header" / Const(HEADER),
                "id" / Int8ul,
                "length" / Rebuild(Int8ul, len_(this.params) + 2),
                "code" / Int8ul,
                "params" / Bytes(this.length - 2),
            )
        ),
        # The checksum covers ID..last parameter, i.e. the frame without its 2-byte header.
        "checksum" / Checksum(Int8ul, lambda data: dynamixel1_checksum(data[2:]), this.frame.data),
    )

    ReadParams = Struct("address" / Int8ul, "length" / Int8ul, Terminated)
    WriteParams = Struct("address" / Int8ul, "data" / GreedyBytes)
    SyncWriteParams = Struct(
        "address" / Int8ul,
        "length" / Int8ul,
        "entries" / GreedyRange(Struct("id" / Int8ul, "data" / Bytes(this._.length))),
        Terminated,
    )
    BulkReadParams = Struct(
        "zero" / Const(b"\x00"),
        "entries" / GreedyRange(Struct("length" / Int8ul, "id" / Int8ul, "address" / Int8ul)),
        Terminated,
    )
    SyncReadParams = Struct("address" / Int8ul, "length" / Int8ul, "ids" / GreedyRange(Int8ul))
    NoParams = Struct(Terminated)

    PARAMS: dict[int, Struct] = {
        Instruction1.PING: NoParams,
        Instruction1.READ: ReadParams,
        Instruction1.WRITE: WriteParams,
        Instruction1.REG_WRITE: WriteParams,
        Instruction1.ACTION: NoParams,
        Instruction1.RESET: NoParams,
        Instruction1.REBOOT: NoParams,
        Instruction1.SYNC_WRITE: SyncWriteParams,
        Instruction1.SYNC_READ: SyncReadParams,
        Instruction1.BULK_READ: BulkReadParams,
    }

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


class Packet1(NamedTuple):
    """A Protocol 1.0 packet: ``code`` is the instruction (from a master) or ERR (from a device)."""

    id: int
    code: int
    params: bytes
    raw: bytes
    t: float = 0.0

    def fields(self) -> Container:
        """Decode ``params`` as the parameters of instruction ``code``."""
        return _layouts()["PARAMS"][self.code].parse(self.params)


def build(packet_id: int, code: int, params: bytes = b"") -> bytes:
    """Build a packet (instruction or status: ``code`` is the instruction or ERR)."""
    return _layouts()["Packet"].build({"frame": {"value": {"id": packet_id, "code": code, "params": params}}})


def frame(packet_id: int, code: int, params: bytes = b"") -> bytes:
    """Fast path of :func:`build <hilbench.protocols.dynamixel_protocol1.build>` for the emulators' replies (tests prove both agree on every vector)."""
    body = bytes((packet_id, len(params) + 2, code)) + params
    return HEADER + body + bytes((~sum(body) & 0xFF,))


def build_instruction(packet_id: int, instruction: int, **fields) -> bytes:
    """Build an instruction from its named parameter fields."""
    return build(packet_id, instruction, _layouts()["PARAMS"][instruction].build(fields))


def parse(raw: bytes) -> Packet1:
    """Parse one whole packet; raises on a bad checksum or layout."""
    f = _layouts()["Packet"].parse(raw).frame.value
    return Packet1(f.id, f.code, bytes(f.params), bytes(raw))


class Decoder1:
    """Incremental Protocol 1.0 decoder: resynchronises on ``FF FF`` and never raises."""

    def __init__(self) -> None:
        self._buf = b""
        self.bytes_skipped = 0
        self.packets = 0
        self.problems: dict[str, int] = {"checksum": 0, "bad_length": 0, "truncated": 0}

    def feed(self, data: bytes, t: float = 0.0) -> list[Packet1 | Problem]:
        """Decode ``data`` and return the packets and problems it completed."""
        out: list[Packet1 | Problem] = []
        buf = self._buf + bytes(data)
        self._buf = buf[self._scan(buf, out, t, final=False) :]
        return out

    @property
    def pending(self) -> int:
        """Bytes held back as the start of a packet not yet complete."""
        return len(self._buf)

    def reset(self) -> int:
        """Drop a partial packet (the line went quiet mid-packet); returns how many bytes were dropped."""
        n = len(self._buf)
        self.bytes_skipped += n
        self._buf = b""
        return n

    def flush(self, t: float = 0.0) -> list[Packet1 | Problem]:
        """End of stream: report a pending partial packet as truncated and decode the rest."""
        out: list[Packet1 | Problem] = []
        buf, self._buf = self._buf, b""
        self._scan(buf, out, t, final=True)
        return out

    def _scan(self, buf: bytes, out: list, t: float, final: bool) -> int:
        pos = 0
        n = len(buf)
        find = buf.find
        append = out.append
        new = tuple.__new__  # NamedTuple's own __new__ is a Python frame; skip it
        while True:
            start = find(HEADER, pos)
            if start < 0:
                keep = n if final else max(pos, n - 1)
                self.bytes_skipped += keep - pos
                return keep
            # FF FF FF: the header is the last two FFs (an ID is never FF).
            while start + 2 < n and buf[start + 2] == 0xFF:
                start += 1
            self.bytes_skipped += start - pos
            length = buf[start + 3] if start + 4 <= n else None
            if length is not None and length < 2:
                self.problems["bad_length"] += 1
                out.append(Problem("bad_length", buf[start : start + 4], t=t))
                self.bytes_skipped += 1
                pos = start + 1
                continue
            if length is None or start + 4 + length > n:
                if not final:
                    return start
                self.problems["truncated"] += 1
                out.append(Problem("truncated", buf[start:], t=t))
                self.bytes_skipped += 1
                pos = start + 1
                continue
            end = start + 4 + length
            raw = buf[start:end]
            # the checksum of ID..last parameter (dynamixel1_checksum) from the sum of the whole packet:
            # no copy of the body; the header's two FFs and the checksum byte taken back out
            if ~(sum(raw) - 0x1FE - raw[-1]) & 0xFF != raw[-1]:
                self.problems["checksum"] += 1
                append(Problem("checksum", raw, t=t))
                self.bytes_skipped += 1
                pos = start + 1
                continue
            append(new(Packet1, (raw[2], raw[4], raw[5:-1], raw, t)))
            self.packets += 1
            pos = end
