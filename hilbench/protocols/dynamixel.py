"""Dynamixel Protocol 2.0: packet layouts, byte stuffing, CRC and a stream decoder.

One definition serves both directions. The construct structures below are the
reference layouts (they read like the ROBOTIS e-Manual); fakes and senders build
with them and the monitor parses with them. Two hot paths are hand-tuned because
interpreted construct is ~50x too slow for a bus at line rate: building
instruction/status packets (:func:`instruction_packet`, :func:`status_packet`)
and framing a byte stream (:class:`Decoder`: plain Python for small chunks,
numpy judging every header candidate of large ones, :class:`ReplySlots` for a
consumer that wants only the data of expected replies). Tests prove they agree
with the construct definitions on every vector of the spec sheet, with a slow
reference framer on random streams, and with each other.

Wire layout (all multi-byte fields little-endian)::

    FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAMS... | CRC_L CRC_H
    LEN = INST + PARAMS (as transmitted, i.e. stuffed) + 2 CRC bytes
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Iterator, Sequence
from enum import IntEnum
from functools import cache
from struct import Struct as Struct_
from typing import TYPE_CHECKING, Any, NamedTuple

from hilbench.protocols.checksums import crc16_buypass, raw_crc_routine
from hilbench.protocols.lazy_layouts import lazy_layouts
from hilbench.protocols.problem import Problem

if TYPE_CHECKING:
    import numpy as np
    from construct import Container, Struct

HEADER = b"\xff\xff\xfd\x00"
#: The pattern that stuffing escapes, and its escaped form.
STUFF_PATTERN = b"\xff\xff\xfd"
STUFFED = b"\xff\xff\xfd\xfd"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
#: Sanity cap on LENGTH, as the official SDK uses (RXPACKET_MAX_LEN).
MAX_LENGTH = 1024
STATUS = 0x55
ALERT_BIT = 0x80
CLEAR_KEY = b"\x44\x58\x4c\x22"  # 'DXL"'
BACKUP_KEY = b"\x43\x54\x52\x4c"  # 'CTRL'
#: CRC state after the header, so the decoder can check a packet without re-joining it.
_HEADER_CRC = crc16_buypass(HEADER)


def _crc_residues() -> tuple[int, ...]:
    """Register value after running the CRC over a message *and* its correct CRC (low byte first).

    Hand-derived because no library offers it for a little-endian CRC field: when
    the register holds c and the bytes c_lo, c_hi follow, the result depends only on
    c_lo ^ c_hi, so a 256-entry table gives it. Each register update is a bijection
    of the register, so for given stored bytes only the matching CRC reaches that
    value: the check is exact, not probabilistic (a test proves it against crcmod).
    """
    routine, table = raw_crc_routine(crc16_buypass)
    return tuple(routine(bytes((x, 0)), x, table) for x in range(256))


_CRC_RESIDUE = _crc_residues()


@cache
def _tables() -> tuple[np.ndarray, np.ndarray]:
    """:func:`_judge_candidates`' lookups, made (with numpy's import) the first time a large buffer comes:
    a program that reads a few packets starts without numpy.

    - verdicts: (CRC field as u16 LE) | (0x10000 for an instruction) -> verdict: the residue a matching CRC
      leaves (plus 0x10000 for an instruction); the extra last entry (-1) is for candidates that need the
      general path;
    - kind: INSTRUCTION byte -> 0 for a status, 0x10000 for an instruction (the offset of its verdicts).
    """
    import numpy as np

    crc = np.arange(0x10000)
    residue = np.array(_CRC_RESIDUE, dtype=np.int64)[(crc & 0xFF) ^ (crc >> 8)]
    kind = np.full(256, 0x10000, dtype=np.int64)
    kind[STATUS] = 0
    return np.concatenate((residue, residue + 0x10000, [-1])), kind


_GENERAL = 0x20000  # index of the -1 verdict


class Instruction(IntEnum):
    """Protocol 2.0 instruction codes (the SDK's INST_* constants)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    BACKUP = 0x20
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


#: snake_case names used in every hilbench output (spec sheet §2.1).
INSTRUCTION_NAMES: dict[int, str] = {i.value: i.name.lower() for i in Instruction}
INSTRUCTION_NAMES[Instruction.BACKUP] = "backup"


class ErrorNumber(IntEnum):
    """Error numbers in bits 6..0 of a status packet's ERR byte."""

    OK = 0
    RESULT_FAIL = 1
    INSTRUCTION_ERROR = 2
    CRC_ERROR = 3
    DATA_RANGE_ERROR = 4
    DATA_LENGTH_ERROR = 5
    DATA_LIMIT_ERROR = 6
    ACCESS_ERROR = 7


ERROR_MESSAGES: dict[int, str] = {
    1: "result fail",
    2: "instruction error",
    3: "CRC error",
    4: "data range error",
    5: "data length error",
    6: "data limit error",
    7: "access error",
}

#: Hardware Error Status (address 70) and Shutdown (63) bits.
HARDWARE_ERROR_BITS: dict[int, str] = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}


def describe_error(err: int) -> str:
    """Human text for an ERR byte, e.g. ``"alert, data range error"``."""
    parts = []
    if err & ALERT_BIT:
        parts.append("alert")
    num = err & 0x7F
    if num:
        parts.append(ERROR_MESSAGES.get(num, f"error {num}"))
    return ", ".join(parts) or "ok"


def describe_hardware_error(bits: int) -> list[str]:
    """Names of the bits set in a Hardware Error Status value."""
    return [name for mask, name in HARDWARE_ERROR_BITS.items() if bits & mask]


# --------------------------------------------------------------------------- stuffing


def stuff(body: bytes) -> bytes:
    """Insert FD after every FF FF FD in INSTRUCTION..PARAMETERS (transmit side).

    ``bytes.replace`` is exact here: the pattern cannot overlap itself, so
    non-overlapping replacement equals the byte-by-byte rule of the e-Manual.
    """
    return body.replace(STUFF_PATTERN, STUFFED) if STUFF_PATTERN in body else body


def unstuff(body: bytes) -> bytes:
    """Remove the FD inserted after every FF FF FD (receive side)."""
    return body.replace(STUFFED, STUFF_PATTERN) if STUFFED in body else body


def _is_fast_reply(packet_id: int, body: bytes) -> bool:
    # The combined Fast Sync/Bulk Read reply is never stuffed (spec §1.6).
    return packet_id == BROADCAST_ID and body[:1] == b"\x55"


def _wire_body_length(ctx) -> int:
    body = ctx.body
    return len(body if _is_fast_reply(ctx.id, body) else stuff(body))


# --------------------------------------------------------------------------- layouts

#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("Packet", "NoParams", "ReadParams", "WriteParams", "FactoryResetParams", "ClearParams",
                 "BackupParams", "SyncReadParams", "SyncWriteParams", "BulkReadEntry", "BulkReadParams",
                 "BulkWriteEntry", "BulkWriteParams", "StatusParams", "PingReply", "FastReplySlice", "PARAMS")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts, the reference definition of every packet (``_LAYOUT_NAMES``), made with
    construct's import when first used: benches and monitors run on the fast paths below and start without
    construct (tens of ms)."""
    from construct import (
        Adapter,
        Bytes,
        Checksum,
        Const,
        GreedyBytes,
        GreedyRange,
        Int8ul,
        Int16ul,
        OneOf,
        RawCopy,
        Rebuild,
        Struct,
        Terminated,
        this,
    )

    class _Stuffing(Adapter):
        """Adapter between the transmitted (stuffed) body and the logical one."""

        def _decode(self, obj, context, path):
            return obj if _is_fast_reply(context.id, obj) else unstuff(obj)

        def _encode(self, obj, context, path):
            return obj if _is_fast_reply(context.id, obj) else stuff(obj)

    #: A whole Protocol 2.0 packet. ``body`` is INSTRUCTION + PARAMETERS, unstuffed.
    Packet = Struct(
        "frame"
        / RawCopy(
            Struct(
                "header" / Const(HEADER),
                "id" / Int8ul,
                "length" / Rebuild(Int16ul, lambda ctx: _wire_body_length(ctx) + 2),
                "body" / _Stuffing(Bytes(this.length - 2)),
            )
        ),
        "crc" / Checksum(Int16ul, crc16_buypass, this.frame.data),
    )

    #: Parameter layouts per instruction, all unstuffed. ``Terminated`` makes a parse
    #: fail when entries do not tile the parameters exactly (spec §2.5).
    NoParams = Struct(Terminated)
    ReadParams = Struct("address" / Int16ul, "length" / Int16ul, Terminated)
    WriteParams = Struct("address" / Int16ul, "data" / GreedyBytes)
    FactoryResetParams = Struct("mode" / OneOf(Int8ul, [0xFF, 0x01, 0x02]), Terminated)
    ClearParams = Struct("mode" / OneOf(Int8ul, [0x01, 0x02]), "key" / Bytes(4), Terminated)
    BackupParams = Struct("mode" / OneOf(Int8ul, [0x01, 0x02]), "key" / Const(BACKUP_KEY), Terminated)
    SyncReadParams = Struct("address" / Int16ul, "length" / Int16ul, "ids" / GreedyRange(Int8ul), Terminated)
    SyncWriteParams = Struct(
        "address" / Int16ul,
        "length" / Int16ul,
        "entries" / GreedyRange(Struct("id" / Int8ul, "data" / Bytes(this._.length))),
        Terminated,
    )
    BulkReadEntry = Struct("id" / Int8ul, "address" / Int16ul, "length" / Int16ul)
    BulkReadParams = Struct("entries" / GreedyRange(BulkReadEntry), Terminated)
    BulkWriteEntry = Struct("id" / Int8ul, "address" / Int16ul, "length" / Int16ul, "data" / Bytes(this.length))
    BulkWriteParams = Struct("entries" / GreedyRange(BulkWriteEntry), Terminated)
    #: Status: ERR then data. A Ping reply's data is PingReply.
    StatusParams = Struct("error" / Int8ul, "data" / GreedyBytes)
    PingReply = Struct("model_number" / Int16ul, "firmware" / Int8ul, Terminated)
    #: One slice of the combined Fast Sync/Bulk Read reply. Its CRC runs over every
    #: byte from the packet's first FF through this slice's data, which construct
    #: cannot express as a local checksum, so build_fast_reply computes it.
    FastReplySlice = Struct("error" / Int8ul, "id" / Int8ul, "data" / Bytes(this._.length), "crc" / Int16ul)

    PARAMS: dict[int, Struct] = {
        Instruction.PING: NoParams,
        Instruction.READ: ReadParams,
        Instruction.WRITE: WriteParams,
        Instruction.REG_WRITE: WriteParams,
        Instruction.ACTION: NoParams,
        Instruction.FACTORY_RESET: FactoryResetParams,
        Instruction.REBOOT: NoParams,
        Instruction.CLEAR: ClearParams,
        Instruction.BACKUP: BackupParams,
        Instruction.SYNC_READ: SyncReadParams,
        Instruction.SYNC_WRITE: SyncWriteParams,
        Instruction.FAST_SYNC_READ: SyncReadParams,
        Instruction.BULK_READ: BulkReadParams,
        Instruction.BULK_WRITE: BulkWriteParams,
        Instruction.FAST_BULK_READ: BulkReadParams,
        Instruction.STATUS: StatusParams,
    }

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


#: Instructions that are valid only when broadcast (ID FE).
BROADCAST_ONLY = frozenset(
    {
        Instruction.SYNC_READ,
        Instruction.SYNC_WRITE,
        Instruction.FAST_SYNC_READ,
        Instruction.BULK_READ,
        Instruction.BULK_WRITE,
        Instruction.FAST_BULK_READ,
    }
)
#: Instructions answered by one status per listed device.
MULTI_READS = frozenset(
    {Instruction.SYNC_READ, Instruction.BULK_READ, Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ}
)


# --------------------------------------------------------------------------- packets


class InstructionPacket(NamedTuple):
    """A decoded instruction packet (master to device).

    NamedTuple rather than a frozen dataclass: the decoder creates one per
    packet and a frozen dataclass costs about three times as much to build.
    """

    id: int
    instruction: int
    params: bytes
    raw: bytes
    t: float = 0.0

    @property
    def name(self) -> str:
        return INSTRUCTION_NAMES.get(self.instruction, f"0x{self.instruction:02x}")

    def fields(self) -> Container:
        """Parameters decoded with the construct layout of this instruction."""
        return _layouts()["PARAMS"][self.instruction].parse(self.params)


class StatusPacket(NamedTuple):
    """A decoded status packet (device to master).

    For the combined Fast-read reply ``id`` is FE, ``error`` is ERR_1 and
    ``data`` holds the remaining slices; split it with :func:`split_fast_reply`.
    """

    id: int
    error: int
    data: bytes
    raw: bytes
    t: float = 0.0

    instruction = STATUS
    name = "status"

    @property
    def alert(self) -> bool:
        return bool(self.error & ALERT_BIT)

    @property
    def error_number(self) -> int:
        return self.error & 0x7F

    @property
    def is_fast_reply(self) -> bool:
        return self.id == BROADCAST_ID


class FastSlice(NamedTuple):
    """One device's part of a combined Fast Sync/Bulk Read reply."""

    id: int
    error: int
    data: bytes
    crc_ok: bool


# --------------------------------------------------------------------------- building


def build(packet_id: int, instruction: int, **fields) -> bytes:
    """Build a packet with the construct layouts (reference path).

    ``fields`` are the parameter fields of the instruction, e.g.
    ``build(1, Instruction.READ, address=132, length=4)``.
    """
    layouts = _layouts()
    params = layouts["PARAMS"][instruction].build(fields)
    return layouts["Packet"].build({"frame": {"value": {"id": packet_id, "body": bytes([instruction]) + params}}})


def parse(raw: bytes) -> InstructionPacket | StatusPacket:
    """Parse one whole packet with the construct layouts (reference path); raises on bad input."""
    c = _layouts()["Packet"].parse(raw)
    frame = c.frame.value
    body = frame.body
    if body[0] == STATUS:
        return StatusPacket(frame.id, body[1], bytes(body[2:]), bytes(raw))
    return InstructionPacket(frame.id, body[0], bytes(body[1:]), bytes(raw))


_CRC16, _CRC16_TABLE = raw_crc_routine(crc16_buypass)
_PACK_CRC = Struct_("<H").pack


def _frame(packet_id: int, body: bytes) -> bytes:
    n = len(body) + 2
    head = b"\xff\xff\xfd\x00" + bytes((packet_id, n & 0xFF, n >> 8)) + body
    return head + _PACK_CRC(_CRC16(head, 0, _CRC16_TABLE))


def instruction_packet(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """Fast path: a stuffed instruction packet from raw parameter bytes."""
    return _frame(packet_id, stuff(bytes((instruction,)) + params))


def instruction_packet_unstuffed(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction exactly as the official Python SDK emits it: never stuffed (spec §7.3)."""
    return _frame(packet_id, bytes((instruction,)) + params)


def status_packet(packet_id: int, error: int = 0, data: bytes = b"") -> bytes:
    """Fast path: a stuffed status packet."""
    body = bytes((STATUS, error)) + data
    if STUFF_PATTERN in body:
        body = body.replace(STUFF_PATTERN, STUFFED)
    n = len(body) + 2
    head = b"\xff\xff\xfd\x00" + bytes((packet_id, n & 0xFF, n >> 8)) + body
    return head + _PACK_CRC(_CRC16(head, 0, _CRC16_TABLE))


def build_fast_reply(slices: list[tuple[int, int, bytes]]) -> bytes:
    """Combined Fast Sync/Bulk Read reply from ``(id, error, data)`` slices, in list order.

    Each slice's CRC covers every byte from the first FF through its data; the
    last slice's CRC is the packet CRC. Never stuffed.
    """
    length = 1 + sum(len(d) + 4 for _, _, d in slices)
    out = bytearray(HEADER + bytes((BROADCAST_ID, length & 0xFF, length >> 8, STATUS)))
    for dev_id, err, data in slices:
        out += bytes((err, dev_id)) + data
        crc = crc16_buypass(out)
        out += bytes((crc & 0xFF, crc >> 8))
    return bytes(out)


def split_fast_reply(raw: bytes, lengths: list[int]) -> list[FastSlice]:
    """Split a combined Fast-read reply into slices using the request's data lengths.

    Stops early (returning fewer slices) where the reply is shorter than the
    request implies, instead of raising as the SDK does.
    """
    out = []
    pos = 8
    end = len(raw)
    for n in lengths:
        if pos + n + 4 > end:
            break
        err, dev_id = raw[pos], raw[pos + 1]
        data = bytes(raw[pos + 2 : pos + 2 + n])
        crc_at = pos + 2 + n
        ok = crc16_buypass(raw[:crc_at]) == raw[crc_at] | raw[crc_at + 1] << 8
        out.append(FastSlice(dev_id, err, data, ok))
        pos = crc_at + 2
    return out


# --------------------------------------------------------------------------- validation

_FIXED_PARAM_LENGTHS = {
    Instruction.PING: 0,
    Instruction.ACTION: 0,
    Instruction.REBOOT: 0,
    Instruction.READ: 4,
    Instruction.FACTORY_RESET: 1,
    Instruction.CLEAR: 5,
    Instruction.BACKUP: 5,
}


def check_instruction(pkt: InstructionPacket) -> str | None:
    """Validate an instruction against spec §2.5; return a reason or None if valid."""
    inst, p, n = pkt.instruction, pkt.params, len(pkt.params)
    if inst not in INSTRUCTION_NAMES or inst == STATUS:
        return f"unknown instruction 0x{inst:02x}"
    if pkt.id in (0xFD, 0xFF):
        return f"invalid device id {pkt.id}"
    fixed = _FIXED_PARAM_LENGTHS.get(inst)
    if fixed is not None:
        if n != fixed:
            return f"{pkt.name} needs {fixed} parameter bytes, got {n}"
        if inst == Instruction.FACTORY_RESET and p[0] not in (0xFF, 0x01, 0x02):
            return f"factory reset mode 0x{p[0]:02x} unknown"
        if inst == Instruction.BACKUP and (p[0] not in (1, 2) or p[1:] != BACKUP_KEY):
            return "backup needs 01|02 + 'CTRL'"
        if inst == Instruction.CLEAR and p[0] not in (1, 2):
            return f"clear mode 0x{p[0]:02x} unknown"
        return None
    if inst in (Instruction.WRITE, Instruction.REG_WRITE):
        return None if n >= 2 else f"{pkt.name} needs an address"
    if pkt.id != BROADCAST_ID:
        return f"{pkt.name} must be broadcast"
    if inst in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ):
        if n < 4:
            return f"{pkt.name} needs address and length"
        if BROADCAST_ID in p[4:]:
            return f"{pkt.name} lists the broadcast id"
        return None
    if inst == Instruction.SYNC_WRITE:
        if n < 4:
            return "sync_write needs address and length"
        size = p[2] | p[3] << 8
        if (n - 4) % (size + 1):
            return "sync_write entries do not tile the parameters"
        if BROADCAST_ID in p[4 :: size + 1]:
            return "sync_write lists the broadcast id"
        return None
    if inst in (Instruction.BULK_READ, Instruction.FAST_BULK_READ):
        if n % 5:
            return f"{pkt.name} parameters are not 5-byte entries"
        ids = p[0::5]
        if len(set(ids)) != len(ids):
            return f"{pkt.name} lists an id twice"
        return None
    if inst == Instruction.BULK_WRITE:
        pos, seen = 0, set()
        while pos < n:
            if pos + 5 > n:
                return "bulk_write entries do not tile the parameters"
            if p[pos] in seen:
                return "bulk_write lists an id twice"
            seen.add(p[pos])
            pos += 5 + (p[pos + 3] | p[pos + 4] << 8)
        return None if pos == n else "bulk_write entries do not tile the parameters"
    return None


# --------------------------------------------------------------------------- decoder

Item = InstructionPacket | StatusPacket | Problem


class ReplySlots:
    """Status packets a consumer expects next, to be stored in place instead of returned as items.

    After a Sync/Bulk Read or a Read the master knows which IDs answer and how
    many data bytes each sends (§2.4). A consumer that only wants the data of
    those replies (the bus monitor) hands these slots to :meth:`Decoder.scan`
    and points them at its bookkeeping with :meth:`point`: a status that passes
    its CRC, is not stuffed, has ERR 0, comes from an ID in ``index`` whose slot
    is not yet ``filled`` and is exactly ``sizes[slot]`` bytes long on the wire
    (data length + 11) is then not yielded; instead ``filled[slot] = 1``,
    ``store[slot] = data``, ``stamps[slot] = t`` and ``fills.append(slot)``.
    Every other packet is yielded as usual, and the consumer may re-point or
    :meth:`clear` the slots whenever ``scan`` yields. Saving the item is worth
    it: in a servo bus such replies are nine packets in ten.
    """

    __slots__ = ("state", "fills")

    def __init__(self) -> None:
        #: Slots filled by the decoder, in order, until the consumer empties the list.
        self.fills: list[int] = []
        self.clear()

    def point(
        self, index: dict[int, int], sizes: Sequence[int], filled: bytearray, store: list, stamps: list
    ) -> None:
        """Expect replies: device ID -> slot, wire size, filled flag, data and time per slot."""
        # one tuple, so the decoder sees a change with one identity check per yielded item
        self.state = (index.get, sizes, filled, store, stamps)

    def clear(self) -> None:
        """Expect nothing: every packet is yielded."""
        self.state = _NO_SLOTS


_NO_SLOTS = ({}.get, (), bytearray(), [], [])


class Decoder:
    """Incremental Protocol 2.0 stream decoder; never raises on input.

    ``feed(data, t)`` returns the packets and problems completed so far and
    keeps a partial packet for the next call. Framing follows spec §1.7: search
    ``FF FF FD 00``, frame by LENGTH, check the CRC; on a mismatch resume one
    byte after the candidate start, so a corrupted LENGTH cannot swallow good
    packets. Memory is bounded by ``7 + max_length`` bytes of pending input.

    :meth:`scan` yields the same items one by one and can store expected
    replies in place instead (:class:`ReplySlots`).

    ``strict_stuffing`` reports unescaped ``FF FF FD`` inside a packet as a
    ``stuffing`` problem; the default accepts it, because the official SDK never
    stuffs what it sends. ``inter_byte_timeout`` (seconds) drops a partial packet
    when the next byte arrives later than that, as a servo does (1.5 ms).
    """

    def __init__(
        self,
        *,
        max_length: int = MAX_LENGTH,
        strict_stuffing: bool = False,
        inter_byte_timeout: float | None = None,
    ) -> None:
        self.max_length = max_length
        self.strict_stuffing = strict_stuffing
        self.inter_byte_timeout = inter_byte_timeout
        self._buf = b""
        self._last_t: float | None = None
        self._consumed = 0  # where the last _frames() left off
        #: Counters: bytes fed, bytes outside valid packets, packets, and problems by kind.
        self.bytes_in = 0
        self.bytes_skipped = 0
        self.packets = 0
        self.problems: dict[str, int] = {"crc": 0, "truncated": 0, "bad_length": 0, "stuffing": 0}

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a packet."""
        return len(self._buf)

    def feed(self, data: bytes, t: float = 0.0, t_first: float | None = None) -> list[Item]:
        """Decode ``data`` (stamped ``t``) and return what it completed.

        ``t_first`` is when the chunk's first byte arrived (default ``t``); the
        inter-byte timeout measures from the previous chunk's ``t`` to it.
        """
        out: list[Item] = []
        buf = self._take(data, t, t_first, out)
        self._buf = buf[self._scan(buf, out, t, final=False) :]
        return out

    def scan(
        self, data: bytes, t: float = 0.0, t_first: float | None = None, slots: ReplySlots | None = None
    ) -> Iterator[Item]:
        """:meth:`feed`, item by item, optionally storing expected replies in ``slots``.

        Iterate to the end: the decoder's state is settled when the iterator
        finishes. ``slots`` (:class:`ReplySlots`) may be changed by the consumer
        between items; from :data:`VECTOR_MIN` bytes on, replies that fit them
        are stored there instead of being yielded.
        """
        out: list[Item] = []
        buf = self._take(data, t, t_first, out)
        self._buf = b""
        if out:
            yield from out
        if len(buf) >= VECTOR_MIN:
            yield from self._frames(buf, t, False, slots)
            self._buf = buf[self._consumed :]
        else:
            out = []
            self._buf = buf[self._scan_plain(buf, out, t, False) :]
            yield from out

    def flush(self, t: float = 0.0) -> list[Item]:
        """End of stream (or idle line): report a pending partial packet as truncated."""
        out: list[Item] = []
        self._flush_into(out, t)
        return out

    def _take(self, data: bytes, t: float, t_first: float | None, out: list[Item]) -> bytes:
        """Start of a feed: apply the inter-byte timeout, count the bytes, join them to the pending ones."""
        if (
            self.inter_byte_timeout is not None
            and self._last_t is not None
            and (t if t_first is None else t_first) - self._last_t > self.inter_byte_timeout
            and len(self._buf) >= 4
        ):
            self._flush_into(out, t)
        self._last_t = t
        self.bytes_in += len(data)
        return self._buf + data if self._buf else bytes(data)

    def _flush_into(self, out: list[Item], t: float) -> None:
        buf = self._buf
        self._buf = b""
        if buf:
            self._scan(buf, out, t, final=True)

    def _scan(self, buf: bytes, out: list[Item], t: float, final: bool) -> int:
        """Frame packets in ``buf`` into ``out``; return the offset of the first unconsumed byte.

        Two hand-tuned implementations of spec §1.7 with identical output (a
        test runs both on random and real streams): numpy's fixed cost per call
        (about 40 us) pays off from :data:`VECTOR_MIN` bytes on.
        """
        if len(buf) >= VECTOR_MIN:
            out.extend(self._frames(buf, t, final, None))
            return self._consumed
        return self._scan_plain(buf, out, t, final)

    def _frames(self, buf: bytes, t: float, final: bool, slots: ReplySlots | None) -> Iterator[Item]:
        """:meth:`_scan` for large buffers: numpy judges every candidate, Python only builds items.

        :func:`_judge_candidates` finds the headers and decides, for all
        candidates at once, whether each is a plain packet that lies within
        the buffer (then only its CRC is left to check) or needs the general
        path (:meth:`_candidate`: bad LENGTH, incomplete, stuffed). The loop
        below is what remains per packet: skip headers inside the previous good
        packet, one CRC call, one item or one reply slot. A generator, so that
        :meth:`scan`'s consumer can change ``slots`` between items; where to
        resume is left in ``self._consumed``.
        """
        starts, ends, verdicts = _judge_candidates(buf, self.max_length)
        crc16, table = raw_crc_routine(crc16_buypass)
        new = tuple.__new__  # NamedTuple's own __new__ is a Python frame; skip it
        status, instruction = StatusPacket, InstructionPacket
        problems = self.problems
        side: list[Item] = []
        others = skipped = pos = 0  # others: candidates that were not packets; pos: first byte not consumed
        stop = -1
        slotted = slots is not None
        if slotted:
            state = slots.state
            slot_of, sizes, filled, store, stamps = state
            fills = slots.fills
        for s, e, x in zip(starts, ends, verdicts, strict=True):
            if s != pos:
                if s < pos:
                    others += 1
                    continue  # a header inside a packet already framed
                skipped += s - pos
            if x >= 0:
                # CRC over the whole packet, CRC bytes included, against the register value a
                # matching CRC leaves; x also tells status (x < 0x10000) from instruction
                raw = buf[s:e]
                c = crc16(raw, 0, table)
                pos = e
                if c == x:
                    if slotted:
                        k = slot_of(raw[4])
                        if k is not None and not filled[k] and len(raw) == sizes[k] and not raw[8]:
                            filled[k] = 1
                            store[k] = raw[9:-2]
                            stamps[k] = t
                            fills.append(k)
                            continue
                        yield new(status, (raw[4], raw[8], raw[9:-2], raw, t))
                        if slots.state is not state:  # the consumer re-pointed the slots
                            state = slots.state
                            slot_of, sizes, filled, store, stamps = state
                        continue
                    yield new(status, (raw[4], raw[8], raw[9:-2], raw, t))
                    continue
                if c + 0x10000 == x:
                    yield new(instruction, (raw[4], raw[7], raw[8:-2], raw, t))
                else:
                    problems["crc"] += 1
                    others += 1
                    skipped += 1
                    pos = s + 1
                    yield Problem("crc", raw, "mismatched checksum", t)
            else:
                nxt = self._candidate(buf, s, side, t, final)
                if nxt < 0:
                    stop = s
                    break
                if nxt == s + 1:
                    others += 1
                    skipped += 1
                pos = nxt
                yield side[0]
                side.clear()
            if slotted and slots.state is not state:
                state = slots.state
                slot_of, sizes, filled, store, stamps = state
        # every candidate up to the stop was a packet, a rejection or covered
        self.packets += (bisect_left(starts, stop) if stop >= 0 else len(starts)) - others
        self._consumed = self._settle(pos, stop, len(buf), skipped, final)

    def _settle(self, pos: int, stop: int, n: int, skipped: int, final: bool) -> int:
        """End of a scan: where to resume, with the bytes left behind counted as skipped."""
        if stop >= 0:
            pos = stop
        else:
            keep = n if final else max(pos, n - 3)  # a header may straddle the chunks
            if keep > pos:
                skipped += keep - pos
                pos = keep
        self.bytes_skipped += skipped
        return pos

    def _scan_plain(self, buf: bytes, out: list[Item], t: float, final: bool) -> int:
        """:meth:`_scan` for small buffers, in plain Python.

        Hand-tuned: this loop is the decoder's (and the bus monitor's) throughput,
        so it avoids construct and per-candidate searches. ``bytes.split`` finds
        every header in one C call; the header cannot overlap itself, so the
        pieces are exactly the candidates a byte-by-byte search would find. A
        packet normally ends inside its piece (fast path); one that runs past the
        next header (an unstuffed FF FF FD 00 in the SDK's instructions or in a
        Fast-read reply, or a corrupted LENGTH), or that needs unstuffing, goes
        through :meth:`_candidate`, which frames it from ``buf`` directly.
        """
        append = out.append
        crc16, table = raw_crc_routine(crc16_buypass)
        new = tuple.__new__  # NamedTuple's own __new__ is a Python frame; skip it
        n = len(buf)
        max_len = self.max_length
        residue = _CRC_RESIDUE
        pieces = iter(buf.split(HEADER))
        skipped = 0
        packets = 0
        pos = 0  # first byte not yet consumed
        h = len(next(pieces))  # where the next piece's header starts
        stop = -1  # set where an incomplete packet waits for more input
        for piece in pieces:
            here = h
            p_len = len(piece)
            h = here + 4 + p_len
            if here < pos:
                continue  # a header inside a packet already framed
            skipped += here - pos
            if p_len >= 3:
                length = piece[1] | piece[2] << 8
                end = here + 7 + length
                # fast path: a plain packet that lies inside its piece
                if end <= h and 3 <= length <= max_len and (length != 3 or piece[3] != 0x55):
                    # CRC over the packet *including* its CRC bytes, against the register value a
                    # matching CRC leaves (_CRC_RESIDUE): no slice when the packet fills its piece
                    whole = piece if p_len == length + 3 else piece[: length + 3]
                    if crc16(whole, _HEADER_CRC, table) != residue[piece[length + 1] ^ piece[length + 2]]:
                        self.problems["crc"] += 1
                        append(Problem("crc", buf[here:end], "mismatched checksum", t))
                        skipped += 1
                        pos = here + 1
                        continue
                    if piece[3] == 0x55:
                        data = piece[5 : length + 1]
                        # stuffing could start at ERR (FF) or inside the data: the general path unstuffs
                        if b"\xff\xff\xfd" not in data and piece[4] != 0xFF:
                            append(new(StatusPacket, (piece[0], piece[4], data, buf[here:end], t)))
                            packets += 1
                            pos = end
                            continue
                    else:
                        body = piece[4 : length + 1]
                        # stuffing could start at the instruction byte (FF) or inside the parameters
                        if b"\xff\xff\xfd" not in body and piece[3] != 0xFF:
                            append(new(InstructionPacket, (piece[0], piece[3], body, buf[here:end], t)))
                            packets += 1
                            pos = end
                            continue
            # general path: the candidate needs bytes beyond its piece, unstuffing, or is invalid
            nxt = self._candidate(buf, here, out, t, final)
            if nxt < 0:
                stop = here
                break
            if nxt == here + 1:
                skipped += 1
            else:
                packets += 1
            pos = nxt
        self.packets += packets
        return self._settle(pos, stop, n, skipped, final)

    def _candidate(self, buf: bytes, start: int, out: list[Item], t: float, final: bool) -> int:
        """Frame the candidate at ``start`` from ``buf``; return where to resume.

        ``start + 1`` after a rejection, the packet's end after a good packet,
        and -1 if the packet is incomplete and more input may come.
        """
        n = len(buf)
        problems = self.problems
        if start + 7 > n:
            if not final:
                return -1
            kind, raw, detail = "truncated", buf[start:], "stream ended inside a packet"
        else:
            length = buf[start + 5] | buf[start + 6] << 8
            end = start + 7 + length
            if not 3 <= length <= self.max_length:
                kind, raw, detail = "bad_length", buf[start : start + 7], f"LENGTH {length}"
            elif end > n:
                if not final:
                    return -1
                kind, raw, detail = "truncated", buf[start:], f"LENGTH {length} past the end"
            elif length == 3 and buf[start + 7] == 0x55:
                kind, raw, detail = "bad_length", buf[start:end], "status with LENGTH 3"
            else:
                raw = buf[start:end]
                if crc16_buypass(raw[:-2]) != raw[-2] | raw[-1] << 8:
                    kind, detail = "crc", "mismatched checksum"
                else:
                    # stuffing covers INSTRUCTION..PARAMETERS (§1.6), the instruction byte included
                    pid, body = raw[4], raw[7:-2]
                    if b"\xff\xff\xfd" in body and (pid != BROADCAST_ID or body[0] != 0x55):
                        if self.strict_stuffing and _unescaped(body):
                            problems["stuffing"] += 1
                            out.append(Problem("stuffing", raw, "unescaped FF FF FD", t))
                            return start + 1
                        body = body.replace(STUFFED, STUFF_PATTERN)
                    if body[0] == 0x55:
                        out.append(StatusPacket(pid, body[1], body[2:], raw, t))
                    else:
                        out.append(InstructionPacket(pid, body[0], body[1:], raw, t))
                    return end
        problems[kind] += 1
        out.append(Problem(kind, raw, detail, t))
        return start + 1


#: From this many bytes on, :meth:`Decoder._scan` judges candidates with numpy.
VECTOR_MIN = 2048


def _judge_candidates(buf: bytes, max_length: int) -> tuple[list[int], list[int], list[int]]:
    """Every ``FF FF FD 00`` in ``buf`` and a verdict on it, computed with numpy for all at once.

    Returns ``(starts, ends, verdicts)``, one entry per candidate in order. The
    verdict is -1 where the candidate needs :meth:`Decoder._candidate`: fewer
    than 8 bytes, LENGTH out of range or past the end, a status with LENGTH 3,
    or another candidate (or ``FF FF FD``) starting inside it, as stuffing or
    an unstuffed header the SDK sends make. Otherwise the packet lies in
    ``buf`` and the verdict is the CRC register value that running the CRC over
    the whole packet leaves when its CRC matches (:data:`_CRC_RESIDUE`), plus
    0x10000 for an instruction. The byte layout is the one of §1.2: ID at 4,
    LENGTH at 5-6, INSTRUCTION at 7, CRC in the last two bytes.
    """
    n = len(buf)
    if n < 8:
        starts = [i for i in range(n - 3) if buf.startswith(HEADER, i)]
        return starts, starts, [-1] * len(starts)
    import numpy as np

    verdict_of, kind_of = _tables()
    # At 4 KiB per feed numpy's fixed cost per call is what limits this function: the checks are
    # folded into as few calls as possible (lookup tables instead of comparisons, 4-byte views).
    a = np.frombuffer(buf, dtype=np.uint8)
    fd = (a[2 : n - 1] == 0xFD).nonzero()[0]  # p with FD at p + 2 and p + 3 inside buf
    words = np.ndarray((n - 3,), "<u4", buf, 0, (1,))  # unaligned little-endian view: bytes p..p+3
    w = words[fd]
    heads = fd[w == 0x00FDFFFF]
    starts = heads.tolist()
    m = bisect_left(starts, n - 7)  # candidates with ID, LENGTH and INSTRUCTION inside buf
    if not m:
        return starts, starts, [-1] * len(starts)
    h = heads[:m] if m < len(starts) else heads
    w4 = words[h + 4]  # ID | LEN_L << 8 | LEN_H << 16 | INSTRUCTION << 24
    length = (w4 >> 8) & 0xFFFF
    kind = kind_of[w4 >> 24]  # 0 for a status, 0x10000 for an instruction
    end = h + length + 7
    ok = _length_ok(max_length)[length + kind]
    # A packet is plain if nothing that looks like a header starts inside it. Where FF FF FD
    # occurs only in headers that is the next candidate; otherwise search every FF FF FD. Both
    # end with n, so this also rejects packets that run past the end of buf.
    if len(fd) > len(starts) and np.count_nonzero((w & 0xFFFFFF) == 0xFDFFFF) > len(starts):
        patterns = fd[(w & 0xFFFFFF) == 0xFDFFFF]
        first = np.append(patterns, n)[np.searchsorted(patterns, h + 7)]
    else:
        first = heads[1 : m + 1] if m < len(starts) else np.append(heads[1:], n)
    ok &= first >= end
    end = np.minimum(end, n)
    crc = np.ndarray((n - 1,), "<u2", buf, 0, (1,))[end - 2]  # the CRC field (for the general path: any)
    verdicts = verdict_of[np.where(ok, crc + kind, _GENERAL)].tolist()
    ends = end.tolist()
    if m < len(starts):
        ends += starts[m:]
        verdicts += [-1] * (len(starts) - m)
    return starts, ends, verdicts


@cache
def _length_ok(max_length: int) -> np.ndarray:
    """LENGTH + kind offset -> whether LENGTH is valid: 3..max_length, 4..max_length for a status."""
    import numpy as np

    length = np.arange(0x10000)
    return np.concatenate(((length >= 4) & (length <= max_length), (length >= 3) & (length <= max_length)))


def _unescaped(body: bytes) -> bool:
    """True if ``body`` holds FF FF FD not followed by the stuffing FD."""
    i = body.find(STUFF_PATTERN)
    while i >= 0:
        if body[i + 3 : i + 4] != b"\xfd":
            return True
        i = body.find(STUFF_PATTERN, i + 4)
    return False
