"""RTPS (DDSI-RTPS 2.x) as FreeRTPS speaks it: header, submessages, entity ids, parameter lists, SPDP/SEDP.

Layouts are ``construct`` structures, used both ways: the emulated FreeRTPS
nodes build their messages with the builders here, and :func:`parse_message`
reads any datagram without ever raising (problems become flags such as
``rtps.bad_length``, spec sheet §3.2). Byte orders (§2.4-§2.8):

- the 20-byte header has no byte order (octets); the vendor id is two opaque octets;
- a submessage's ``octetsToNextHeader`` and body follow its own E flag;
- entity ids are 4 octets, never swapped; a sequence number is high i32, low u32;
- a serialized payload starts with a 2-octet big-endian encapsulation id and
  2 option octets; ``PL_CDR_LE`` bodies are parameter lists (pid u16, length
  u16, value, 4-aligned, ending in SENTINEL).

Ports (§2.2) come from :func:`ports`; GUIDs are ``prefix (12) + entity id (4)``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from construct import (
    Bytes,
    Const,
    Construct,
    GreedyBytes,
    Int8ub,
    Int16ub,
    Int16ul,
    Int32sb,
    Int32sl,
    Int32ub,
    Int32ul,
    Struct,
)

from hilbench.protocols import cdr

MAGIC = b"RTPS"
VERSION = (2, 1)
#: FreeRTPS's unregistered vendor id as it appears in the header (0x2C2F written little-endian, §2.3).
VENDOR_FREERTPS = b"\x2f\x2c"
VENDOR_NAMES = {b"\x01\x01": "RTI Connext", b"\x01\x02": "OpenSplice", b"\x01\x0f": "eProsima Fast DDS",
                b"\x01\x10": "Eclipse Cyclone DDS", b"\x2f\x2c": "FreeRTPS", b"\x2c\x2f": "FreeRTPS"}
HEADER_SIZE = 20

# Port mapping (§2.2).
PB, DG, PG, D0, D1, D2, D3 = 7400, 250, 2, 0, 10, 1, 11


def ports(domain: int, participant: int) -> dict[str, int]:
    """The standard UDP ports of ``domain`` and participant index ``participant``."""
    base = PB + DG * domain
    return {"metatraffic_multicast": base + D0, "metatraffic_unicast": base + D1 + PG * participant,
            "user_multicast": base + D2, "user_unicast": base + D3 + PG * participant}


def port_owner(port: int) -> tuple[int, int, str] | None:
    """``(domain, participant, kind)`` of a standard RTPS port, or None."""
    off = port - PB
    if off < 0:
        return None
    domain, rest = divmod(off, DG)
    if rest == D0:
        return domain, -1, "metatraffic_multicast"
    if rest == D2:
        return domain, -1, "user_multicast"
    if rest >= D1 and (rest - D1) % PG == 0:
        return domain, (rest - D1) // PG, "metatraffic_unicast"
    if rest >= D3 and (rest - D3) % PG == 0:
        return domain, (rest - D3) // PG, "user_unicast"
    return None


class SubmessageId(IntEnum):
    """Submessage ids (§2.4); 0x80-0xFF are vendor-specific and skipped."""

    PAD = 0x01
    ACKNACK = 0x06
    HEARTBEAT = 0x07
    GAP = 0x08
    INFO_TS = 0x09
    INFO_SRC = 0x0C
    INFO_REPLY_IP4 = 0x0D
    INFO_DST = 0x0E
    INFO_REPLY = 0x0F
    NACK_FRAG = 0x12
    HEARTBEAT_FRAG = 0x13
    DATA = 0x15
    DATA_FRAG = 0x16


NAMES = {int(s): s.name for s in SubmessageId}
FLAG_E = 0x01
# DATA flags.
FLAG_Q = 0x02
FLAG_D = 0x04
FLAG_K = 0x08
# HEARTBEAT / ACKNACK flags.
FLAG_F = 0x02
FLAG_L = 0x04
# INFO_TS.
FLAG_I = 0x02

# Entity ids (§2.5).
ENTITYID_UNKNOWN = b"\x00\x00\x00\x00"
ENTITYID_PARTICIPANT = b"\x00\x00\x01\xc1"
SPDP_WRITER = b"\x00\x01\x00\xc2"
SPDP_READER = b"\x00\x01\x00\xc7"
SEDP_PUB_WRITER = b"\x00\x00\x03\xc2"
SEDP_PUB_READER = b"\x00\x00\x03\xc7"
SEDP_SUB_WRITER = b"\x00\x00\x04\xc2"
SEDP_SUB_READER = b"\x00\x00\x04\xc7"
PMD_WRITER = b"\x00\x02\x00\xc2"
PMD_READER = b"\x00\x02\x00\xc7"
BUILTIN_NAMES = {
    ENTITYID_PARTICIPANT: "participant", SPDP_WRITER: "SPDP writer", SPDP_READER: "SPDP reader",
    SEDP_PUB_WRITER: "SEDP publications writer", SEDP_PUB_READER: "SEDP publications reader",
    SEDP_SUB_WRITER: "SEDP subscriptions writer", SEDP_SUB_READER: "SEDP subscriptions reader",
    PMD_WRITER: "participant-message writer", PMD_READER: "participant-message reader",
}
KIND_WRITER_KEY, KIND_WRITER_NO_KEY, KIND_READER_NO_KEY, KIND_READER_KEY = 0x02, 0x03, 0x04, 0x07
#: Builtin endpoint set bits: participant/publications/subscriptions announcer and detector.
BUILTIN_ENDPOINT_SET = 0x3F
BUILTIN_PMD = 0x400 | 0x800

# Parameter ids (§2.8, §2.9 and the RTPS spec's table).
PID_PAD = 0x0000
PID_SENTINEL = 0x0001
PID_PARTICIPANT_LEASE_DURATION = 0x0002
PID_TOPIC_NAME = 0x0005
PID_TYPE_NAME = 0x0007
PID_DOMAIN_ID = 0x000F
PID_PROTOCOL_VERSION = 0x0015
PID_VENDOR_ID = 0x0016
PID_RELIABILITY = 0x001A
PID_LIVELINESS = 0x001B
PID_DURABILITY = 0x001D
PID_PARTITION = 0x0029
PID_UNICAST_LOCATOR = 0x002F
PID_MULTICAST_LOCATOR = 0x0030
PID_DEFAULT_UNICAST_LOCATOR = 0x0031
PID_METATRAFFIC_UNICAST_LOCATOR = 0x0032
PID_METATRAFFIC_MULTICAST_LOCATOR = 0x0033
PID_HISTORY = 0x0040
PID_DEFAULT_MULTICAST_LOCATOR = 0x0048
PID_PARTICIPANT_GUID = 0x0050
PID_BUILTIN_ENDPOINT_SET = 0x0058
PID_ENDPOINT_GUID = 0x005A
PID_ENTITY_NAME = 0x0062
PID_KEY_HASH = 0x0070
PID_STATUS_INFO = 0x0071
PID_NAMES = {
    PID_PAD: "PAD", PID_SENTINEL: "SENTINEL", PID_PARTICIPANT_LEASE_DURATION: "PARTICIPANT_LEASE_DURATION",
    PID_TOPIC_NAME: "TOPIC_NAME", PID_TYPE_NAME: "TYPE_NAME", PID_DOMAIN_ID: "DOMAIN_ID",
    PID_PROTOCOL_VERSION: "PROTOCOL_VERSION", PID_VENDOR_ID: "VENDOR_ID", PID_RELIABILITY: "RELIABILITY",
    PID_LIVELINESS: "LIVELINESS", PID_DURABILITY: "DURABILITY", PID_PARTITION: "PARTITION",
    PID_UNICAST_LOCATOR: "UNICAST_LOCATOR", PID_MULTICAST_LOCATOR: "MULTICAST_LOCATOR",
    PID_DEFAULT_UNICAST_LOCATOR: "DEFAULT_UNICAST_LOCATOR",
    PID_METATRAFFIC_UNICAST_LOCATOR: "METATRAFFIC_UNICAST_LOCATOR",
    PID_METATRAFFIC_MULTICAST_LOCATOR: "METATRAFFIC_MULTICAST_LOCATOR", PID_HISTORY: "HISTORY",
    PID_DEFAULT_MULTICAST_LOCATOR: "DEFAULT_MULTICAST_LOCATOR", PID_PARTICIPANT_GUID: "PARTICIPANT_GUID",
    PID_BUILTIN_ENDPOINT_SET: "BUILTIN_ENDPOINT_SET", PID_ENDPOINT_GUID: "ENDPOINT_GUID",
    PID_ENTITY_NAME: "ENTITY_NAME", PID_KEY_HASH: "KEY_HASH", PID_STATUS_INFO: "STATUS_INFO",
}
LOCATOR_KIND_INVALID = -1
LOCATOR_KIND_RESERVED = 0
LOCATOR_KIND_UDPV4 = 1
LOCATOR_KIND_UDPV6 = 2
LOCATOR_KIND_TCPV4 = 4
LOCATOR_KIND_TCPV6 = 8
RELIABILITY_BEST_EFFORT = 1
RELIABILITY_RELIABLE = 2
DURABILITY_VOLATILE = 0
DURABILITY_TRANSIENT_LOCAL = 1
#: ENCAPSULATION ids as the octets that start a serialized payload (the ids are cdr's, big-endian on the wire).
CDR_LE = cdr.CDR_LE.to_bytes(2, "big")
PL_CDR_LE = cdr.PL_CDR_LE.to_bytes(2, "big")
_PARAMETER_LISTS = (cdr.PL_CDR_BE.to_bytes(2, "big"), PL_CDR_LE)
#: The time FreeRTPS counts its fake epoch from (§2.6).
FREERTPS_EPOCH = 1436564555


# --------------------------------------------------------------------------- layouts

Header = Struct(
    "magic" / Const(MAGIC),
    "major" / Int8ub,
    "minor" / Int8ub,
    "vendor_id" / Bytes(2),
    "guid_prefix" / Bytes(12),
)


def _layouts(le: bool) -> dict[str, Construct]:
    u16, u32, i32 = (Int16ul, Int32ul, Int32sl) if le else (Int16ub, Int32ub, Int32sb)
    sn = Struct("high" / i32, "low" / u32)
    return {
        "submessage_header": Struct("id" / Int8ub, "flags" / Int8ub, "octets_to_next_header" / u16),
        "sequence_number": sn,
        "INFO_TS": Struct("seconds" / i32, "fraction" / u32),
        "INFO_DST": Struct("guid_prefix" / Bytes(12)),
        "INFO_SRC": Struct("unused" / u32, "major" / Int8ub, "minor" / Int8ub, "vendor_id" / Bytes(2),
                           "guid_prefix" / Bytes(12)),
        "HEARTBEAT": Struct("reader_id" / Bytes(4), "writer_id" / Bytes(4), "first_sn" / sn, "last_sn" / sn,
                            "count" / i32),
        "ACKNACK": Struct("reader_id" / Bytes(4), "writer_id" / Bytes(4), "bitmap_base" / sn,
                          "num_bits" / u32, "bitmap" / Bytes(lambda ctx: 4 * ((min(ctx.num_bits, 256) + 31) // 32)),
                          "count" / i32),
        "GAP": Struct("reader_id" / Bytes(4), "writer_id" / Bytes(4), "gap_start" / sn, "list_base" / sn,
                      "num_bits" / u32, "bitmap" / Bytes(lambda ctx: 4 * ((min(ctx.num_bits, 256) + 31) // 32))),
        "DATA_fixed": Struct("extra_flags" / u16, "octets_to_inline_qos" / u16, "reader_id" / Bytes(4),
                             "writer_id" / Bytes(4), "writer_sn" / sn),
        "parameter": Struct("pid" / u16, "length" / u16),
        "locator": Struct("kind" / i32, "port" / u32, "address" / Bytes(16)),
        "time": Struct("seconds" / i32, "fraction" / u32),
        "reliability": Struct("kind" / u32, "max_blocking_time" / Struct("seconds" / i32, "fraction" / u32)),
        "string": Struct("length" / u32, "raw" / GreedyBytes),
    }


LAYOUTS: dict[bool, dict[str, Construct]] = {True: _layouts(True), False: _layouts(False)}


def sn_value(high: int, low: int) -> int:
    return (high << 32) | low


def sn_parts(value: int) -> tuple[int, int]:
    return value >> 32, value & 0xFFFFFFFF


def guid_text(guid: bytes) -> str:
    """A GUID (or prefix) as dotted hex groups: ``2c2f2c4d.59012351.00000000.000001c1``."""
    h = guid.hex()
    return ".".join(h[i:i + 8] for i in range(0, len(h), 8))


def entity_text(eid: bytes) -> str:
    """An entity id for people: its builtin name, or ``user writer 000001 (03)``."""
    if eid in BUILTIN_NAMES:
        return BUILTIN_NAMES[eid]
    if eid == ENTITYID_UNKNOWN:
        return "unknown"
    kind = eid[3]
    what = {0x02: "user writer (key)", 0x03: "user writer", 0x04: "user reader", 0x07: "user reader (key)"}.get(
        kind, f"entity kind {kind:#04x}")
    return f"{what} {eid[:3].hex()}"


def is_writer(eid: bytes) -> bool:
    return (eid[3] & 0x0F) in (0x02, 0x03)


def is_reader(eid: bytes) -> bool:
    return (eid[3] & 0x0F) in (0x04, 0x07)


# --------------------------------------------------------------------------- building


def build_header(guid_prefix: bytes, vendor_id: bytes = VENDOR_FREERTPS, version: tuple[int, int] = VERSION) -> bytes:
    """The 20-byte message header."""
    return Header.build({"major": version[0], "minor": version[1], "vendor_id": vendor_id,
                         "guid_prefix": guid_prefix})


def submessage(sub_id: int, flags: int, body: bytes, *, last: bool = False) -> bytes:
    """One submessage (E flag set: little-endian), padded to 4 unless it is the message's last."""
    pad = b"" if last else b"\x00" * (-len(body) % 4)
    body += pad
    return LAYOUTS[True]["submessage_header"].build({"id": sub_id, "flags": flags | FLAG_E,
                                                     "octets_to_next_header": len(body)}) + body


def info_ts(seconds: int, fraction: int) -> bytes:
    """INFO_TS with a time (seconds + 2^-32 fractions)."""
    return submessage(SubmessageId.INFO_TS, 0, LAYOUTS[True]["INFO_TS"].build(
        {"seconds": seconds, "fraction": fraction & 0xFFFFFFFF}))


def time_parts(t: float) -> tuple[int, int]:
    """Seconds and 2^-32 fraction of a Unix time."""
    sec = int(t // 1)
    return sec, int((t - sec) * 2**32) & 0xFFFFFFFF


def info_dst(guid_prefix: bytes) -> bytes:
    return submessage(SubmessageId.INFO_DST, 0, guid_prefix)


def data(reader_id: bytes, writer_id: bytes, sn: int, payload: bytes | None, *,
         inline_qos: bytes | None = None, last: bool = True) -> bytes:
    """A DATA submessage: ``payload`` is the serialized payload including its encapsulation header."""
    flags = (FLAG_Q if inline_qos is not None else 0) | (FLAG_D if payload is not None else 0)
    high, low = sn_parts(sn)
    body = LAYOUTS[True]["DATA_fixed"].build({"extra_flags": 0, "octets_to_inline_qos": 16, "reader_id": reader_id,
                                             "writer_id": writer_id, "writer_sn": {"high": high, "low": low}})
    body += (inline_qos or b"") + (payload or b"")
    return submessage(SubmessageId.DATA, flags, body, last=last)


def heartbeat(reader_id: bytes, writer_id: bytes, first: int, last: int, count: int, *, final: bool = False,
              liveliness: bool = False) -> bytes:
    flags = (FLAG_F if final else 0) | (FLAG_L if liveliness else 0)
    f, lst = sn_parts(first), sn_parts(last)
    return submessage(SubmessageId.HEARTBEAT, flags, LAYOUTS[True]["HEARTBEAT"].build({
        "reader_id": reader_id, "writer_id": writer_id, "first_sn": {"high": f[0], "low": f[1]},
        "last_sn": {"high": lst[0], "low": lst[1]}, "count": count}))


def sn_set(base: int, missing: list[int], num_bits: int | None = None) -> tuple[int, bytes]:
    """``(num_bits, bitmap)`` of a SequenceNumberSet starting at ``base`` with ``missing`` set (<= 256 bits)."""
    if num_bits is None:
        num_bits = (max(missing) - base + 1) if missing else 0
    num_bits = max(0, min(256, num_bits))
    words = [0] * ((num_bits + 31) // 32)
    for sn in missing:
        i = sn - base
        if 0 <= i < num_bits:
            words[i // 32] |= 1 << (31 - i % 32)
    return num_bits, b"".join(struct.pack("<I", w) for w in words)


def bitmap_members(base: int, num_bits: int, bitmap: bytes, le: bool = True) -> list[int]:
    """The sequence numbers a SequenceNumberSet names."""
    out = []
    fmt = "<I" if le else ">I"
    for i in range(min(num_bits, len(bitmap) * 8)):
        word = struct.unpack_from(fmt, bitmap, (i // 32) * 4)[0]
        if word >> (31 - i % 32) & 1:
            out.append(base + i)
    return out


def acknack(reader_id: bytes, writer_id: bytes, base: int, missing: list[int], count: int, *,
            final: bool = False, num_bits: int | None = None) -> bytes:
    """An ACKNACK: everything below ``base`` received, ``missing`` requested again (R5)."""
    nb, bitmap = sn_set(base, missing, num_bits)
    hb = sn_parts(base)
    return submessage(SubmessageId.ACKNACK, FLAG_F if final else 0, LAYOUTS[True]["ACKNACK"].build({
        "reader_id": reader_id, "writer_id": writer_id, "bitmap_base": {"high": hb[0], "low": hb[1]},
        "num_bits": nb, "bitmap": bitmap, "count": count}))


def gap(reader_id: bytes, writer_id: bytes, start: int, list_base: int) -> bytes:
    """A GAP: sequence numbers start .. list_base-1 are irrelevant (empty bitmap)."""
    s, b = sn_parts(start), sn_parts(list_base)
    return submessage(SubmessageId.GAP, 0, LAYOUTS[True]["GAP"].build({
        "reader_id": reader_id, "writer_id": writer_id, "gap_start": {"high": s[0], "low": s[1]},
        "list_base": {"high": b[0], "low": b[1]}, "num_bits": 0, "bitmap": b""}))


def parameter(pid: int, value: bytes) -> bytes:
    """One parameter (little-endian), its value padded to 4."""
    value += b"\x00" * (-len(value) % 4)
    return struct.pack("<HH", pid, len(value)) + value


def parameter_list(params: list[tuple[int, bytes]]) -> bytes:
    """Parameters followed by SENTINEL."""
    return b"".join(parameter(pid, v) for pid, v in params) + struct.pack("<HH", PID_SENTINEL, 0)


def locator(port: int, address: str = "127.0.0.1", kind: int = LOCATOR_KIND_UDPV4) -> bytes:
    """A locator: kind, port, 16 address octets (IPv4: 12 zeros then the address, §2.8)."""
    octets = bytes(int(p) for p in address.split("."))
    return LAYOUTS[True]["locator"].build({"kind": kind, "port": port, "address": b"\x00" * 12 + octets})


def string_value(text: str) -> bytes:
    raw = text.encode() + b"\x00"
    return struct.pack("<I", len(raw)) + raw


def spdp_payload(guid_prefix: bytes, *, meta_port: int, user_port: int, address: str = "127.0.0.1",
                 lease_s: int = 100, vendor_id: bytes = b"\x2c\x2f", domain_id: int | None = None,
                 builtin: int = BUILTIN_ENDPOINT_SET, name: str | None = None) -> bytes:
    """An SPDP DATA(p) serialized payload (PL_CDR_LE): the §2.8 parameters, unicast locators only."""
    params = [
        (PID_PROTOCOL_VERSION, bytes(VERSION)),
        (PID_VENDOR_ID, vendor_id),
        (PID_DEFAULT_UNICAST_LOCATOR, locator(user_port, address)),
        (PID_METATRAFFIC_UNICAST_LOCATOR, locator(meta_port, address)),
        (PID_PARTICIPANT_LEASE_DURATION, struct.pack("<iI", lease_s, 0)),
        (PID_PARTICIPANT_GUID, guid_prefix + ENTITYID_PARTICIPANT),
        (PID_BUILTIN_ENDPOINT_SET, struct.pack("<I", builtin)),
    ]
    if domain_id is not None:
        params.append((PID_DOMAIN_ID, struct.pack("<I", domain_id)))
    if name:
        params.append((PID_ENTITY_NAME, string_value(name)))
    return PL_CDR_LE + b"\x00\x00" + parameter_list(params)


def sedp_payload(guid: bytes, topic: str, type_name: str, *, reliable: bool = False, vendor_id: bytes = b"\x2c\x2f",
                 partition: str | None = None, unicast: tuple[str, int] | None = None,
                 participant_guid: bytes | None = None) -> bytes:
    """An SEDP publication or subscription DATA payload (PL_CDR_LE, §2.9)."""
    params = [
        (PID_PROTOCOL_VERSION, bytes(VERSION)),
        (PID_VENDOR_ID, vendor_id),
        (PID_ENDPOINT_GUID, guid),
        (PID_TOPIC_NAME, string_value(topic)),
        (PID_TYPE_NAME, string_value(type_name)),
        (PID_RELIABILITY, struct.pack("<IiI", RELIABILITY_RELIABLE if reliable else RELIABILITY_BEST_EFFORT,
                                      0, 0x19999999)),
        (PID_DURABILITY, struct.pack("<I", DURABILITY_VOLATILE)),
    ]
    if participant_guid is not None:
        params.append((PID_PARTICIPANT_GUID, participant_guid))
    if partition:
        params.append((PID_PARTITION, struct.pack("<I", 1) + string_value(partition)))
    if unicast is not None:
        params.append((PID_UNICAST_LOCATOR, locator(unicast[1], unicast[0])))
    return PL_CDR_LE + b"\x00\x00" + parameter_list(params)


def key_hash_qos(guid: bytes) -> bytes:
    """Inline QoS carrying PID_KEY_HASH (the SPDP DATA(p) of §2.8)."""
    return parameter_list([(PID_KEY_HASH, guid)])


def message(guid_prefix: bytes, *submessages: bytes, vendor_id: bytes = VENDOR_FREERTPS) -> bytes:
    """A whole message: header plus submessages (the caller marks the last one unpadded)."""
    return build_header(guid_prefix, vendor_id) + b"".join(submessages)


# --------------------------------------------------------------------------- parsing


@dataclass
class Parameter:
    pid: int
    value: bytes

    @property
    def name(self) -> str:
        return PID_NAMES.get(self.pid & 0x3FFF, f"PID_{self.pid:#06x}")


def parse_parameters(data: bytes, le: bool = True) -> tuple[list[Parameter], int, str | None]:
    """``(parameters, bytes used, problem)``: up to and including SENTINEL; never raises."""
    out: list[Parameter] = []
    fmt = "<HH" if le else ">HH"
    off = 0
    n = len(data)
    while n - off >= 4:
        pid, length = struct.unpack_from(fmt, data, off)
        off += 4
        if pid == PID_SENTINEL:
            return out, off, None
        if off + length > n:
            return out, n, "parameter beyond its list"
        out.append(Parameter(pid, data[off:off + length]))
        off += length
    return out, off, "parameter list without SENTINEL"


def parse_locator(value: bytes, le: bool = True) -> tuple[int, str, int] | None:
    """``(kind, address, port)`` of a locator parameter value."""
    if len(value) < 24:
        return None
    kind, port = struct.unpack_from("<iI" if le else ">iI", value, 0)
    addr = value[8:24]
    text = ".".join(str(b) for b in addr[12:]) if kind == LOCATOR_KIND_UDPV4 else addr.hex()
    return kind, text, port


def locator_problem(value: bytes, le: bool = True) -> str | None:
    """Why a locator parameter is invalid, or None: Cyclone DDS's rules (``do_locator``), under which one
    invalid locator makes the whole parameter list, and so the SPDP or SEDP announcement, invalid.

    IPv4 and IPv6 kinds need a port in 1..65535, IPv4 ones zeros in the first 12 address octets; an
    explicit LOCATOR_INVALID must be all zeros. Other kinds are not judged (a receiver skips them).
    """
    if len(value) < 24:
        return "locator shorter than 24 octets"
    kind, port = struct.unpack_from("<iI" if le else ">iI", value, 0)
    if kind in (LOCATOR_KIND_UDPV4, LOCATOR_KIND_TCPV4, LOCATOR_KIND_UDPV6, LOCATOR_KIND_TCPV6):
        if not 0 < port <= 65535:
            return f"locator port {port} outside 1..65535"
        if kind in (LOCATOR_KIND_UDPV4, LOCATOR_KIND_TCPV4) and any(value[8:20]):
            return "IPv4 locator with junk in its address prefix"
    elif kind == LOCATOR_KIND_INVALID and (port or any(value[8:24])):
        return "LOCATOR_INVALID that is not all zeros"
    return None


def _string(value: bytes, le: bool = True) -> str:
    if len(value) < 4:
        return ""
    n = struct.unpack_from("<I" if le else ">I", value)[0]
    return value[4:4 + n].rstrip(b"\x00").decode("utf-8", errors="replace")


def discovery_fields(params: list[Parameter], le: bool = True) -> dict[str, Any]:
    """The fields of SPDP/SEDP parameters a monitor and a node need, by name.

    Invalid locators (:func:`locator_problem`) are left out and listed under ``locator_problems``."""
    out: dict[str, Any] = {}
    for p in params:
        pid, v = p.pid & 0x3FFF, p.value
        if pid in (PID_TOPIC_NAME, PID_TYPE_NAME, PID_ENTITY_NAME):
            out[{PID_TOPIC_NAME: "topic", PID_TYPE_NAME: "type", PID_ENTITY_NAME: "name"}[pid]] = _string(v, le)
        elif pid in (PID_PARTICIPANT_GUID, PID_ENDPOINT_GUID, PID_KEY_HASH) and len(v) >= 16:
            out[{PID_PARTICIPANT_GUID: "participant_guid", PID_ENDPOINT_GUID: "endpoint_guid",
                 PID_KEY_HASH: "key_hash"}[pid]] = v[:16]
        elif pid in (PID_DEFAULT_UNICAST_LOCATOR, PID_METATRAFFIC_UNICAST_LOCATOR, PID_UNICAST_LOCATOR,
                     PID_DEFAULT_MULTICAST_LOCATOR, PID_METATRAFFIC_MULTICAST_LOCATOR, PID_MULTICAST_LOCATOR):
            problem = locator_problem(v, le)
            if problem is not None:
                out.setdefault("locator_problems", []).append(problem)
                continue
            loc = parse_locator(v, le)
            if loc is not None:
                out.setdefault(PID_NAMES[pid].lower(), []).append(loc)
        elif pid == PID_RELIABILITY and len(v) >= 4:
            kind = struct.unpack_from("<I" if le else ">I", v)[0]
            out["reliable"] = kind == RELIABILITY_RELIABLE
        elif pid == PID_DURABILITY and len(v) >= 4:
            out["durability"] = struct.unpack_from("<I" if le else ">I", v)[0]
        elif pid == PID_PARTICIPANT_LEASE_DURATION and len(v) >= 8:
            s, f = struct.unpack_from("<iI" if le else ">iI", v)
            out["lease_s"] = s + f / 2**32
        elif pid == PID_BUILTIN_ENDPOINT_SET and len(v) >= 4:
            out["builtin_endpoints"] = struct.unpack_from("<I" if le else ">I", v)[0]
        elif pid == PID_VENDOR_ID and len(v) >= 2:
            out["vendor_id"] = v[:2]
        elif pid == PID_PROTOCOL_VERSION and len(v) >= 2:
            out["protocol_version"] = (v[0], v[1])
        elif pid == PID_DOMAIN_ID and len(v) >= 4:
            out["domain_id"] = struct.unpack_from("<I" if le else ">I", v)[0]
        elif pid == PID_PARTITION and len(v) >= 8:
            out["partition"] = _string(v[4:], le)
    return out


@dataclass
class Submessage:
    """One submessage: id, flags, body and the fields decoded from it (``fields`` None if undecoded)."""

    id: int
    flags: int
    offset: int
    length: int
    body: bytes
    fields: dict[str, Any] | None = None
    problem: str | None = None

    @property
    def name(self) -> str:
        return NAMES.get(self.id, f"VENDOR_{self.id:#04x}" if self.id >= 0x80 else f"UNKNOWN_{self.id:#04x}")

    @property
    def little_endian(self) -> bool:
        return bool(self.flags & FLAG_E)


@dataclass
class Message:
    """A parsed RTPS message; ``flags`` lists the integrity problems found (``rtps.*``)."""

    version: tuple[int, int]
    vendor_id: bytes
    guid_prefix: bytes
    submessages: list[Submessage] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    size: int = 0


def _flag(msg: Message, name: str) -> None:
    if name not in msg.flags:
        msg.flags.append(name)


def parse_message(datagram: bytes) -> Message:
    """Parse one datagram as an RTPS message; never raises (problems are ``rtps.*`` flags)."""
    datagram = bytes(datagram)
    n = len(datagram)
    if n < HEADER_SIZE or datagram[:4] != MAGIC:
        msg = Message((0, 0), b"", b"", size=n)
        _flag(msg, "rtps.bad_magic" if datagram[:4] != MAGIC else "rtps.too_short")
        return msg
    msg = Message((datagram[4], datagram[5]), datagram[6:8], datagram[8:20], size=n)
    if datagram[4] != 2:
        _flag(msg, "rtps.bad_version")
    off = HEADER_SIZE
    while n - off >= 4:
        sub_id, flags = datagram[off], datagram[off + 1]
        le = bool(flags & FLAG_E)
        length = struct.unpack_from("<H" if le else ">H", datagram, off + 2)[0]
        start = off + 4
        if length == 0 and sub_id not in (SubmessageId.PAD, SubmessageId.INFO_TS):
            length = n - start  # extends to the end of the message
        end = start + length
        sub = Submessage(sub_id, flags, off, length, datagram[start:min(end, n)])
        msg.submessages.append(sub)
        if end > n:
            sub.problem = "octetsToNextHeader past the end"
            _flag(msg, "rtps.bad_length")
            break
        _decode(msg, sub, le)
        off = end
    return msg


def _decode(msg: Message, sub: Submessage, le: bool) -> None:
    lay = LAYOUTS[le]
    body = sub.body
    sid = sub.id
    try:
        if sid == SubmessageId.INFO_TS:
            if sub.flags & FLAG_I:
                sub.fields = {"invalidate": True}
            else:
                f = lay["INFO_TS"].parse(body)
                sub.fields = {"seconds": f.seconds, "fraction": f.fraction}
        elif sid == SubmessageId.INFO_DST:
            sub.fields = {"guid_prefix": body[:12]}
        elif sid == SubmessageId.INFO_SRC:
            sub.fields = {"guid_prefix": body[8:20], "vendor_id": body[6:8]}
        elif sid == SubmessageId.HEARTBEAT:
            f = lay["HEARTBEAT"].parse(body)
            sub.fields = {"reader_id": f.reader_id, "writer_id": f.writer_id,
                          "first_sn": sn_value(f.first_sn.high, f.first_sn.low),
                          "last_sn": sn_value(f.last_sn.high, f.last_sn.low), "count": f.count,
                          "final": bool(sub.flags & FLAG_F)}
        elif sid == SubmessageId.ACKNACK:
            f = lay["ACKNACK"].parse(body)
            base = sn_value(f.bitmap_base.high, f.bitmap_base.low)
            sub.fields = {"reader_id": f.reader_id, "writer_id": f.writer_id, "base": base, "num_bits": f.num_bits,
                          "missing": bitmap_members(base, f.num_bits, f.bitmap, le), "count": f.count,
                          "final": bool(sub.flags & FLAG_F)}
        elif sid == SubmessageId.GAP:
            f = lay["GAP"].parse(body)
            base = sn_value(f.list_base.high, f.list_base.low)
            sub.fields = {"reader_id": f.reader_id, "writer_id": f.writer_id,
                          "start": sn_value(f.gap_start.high, f.gap_start.low), "list_base": base,
                          "listed": bitmap_members(base, f.num_bits, f.bitmap, le)}
        elif sid == SubmessageId.DATA:
            sub.fields = _decode_data(msg, sub, le)
    except Exception:  # noqa: BLE001 (construct errors: a short body)
        sub.problem = "body too short"
        _flag(msg, "rtps.bad_length")


def _decode_data(msg: Message, sub: Submessage, le: bool) -> dict[str, Any]:
    body = sub.body
    f = LAYOUTS[le]["DATA_fixed"].parse(body)
    out: dict[str, Any] = {"reader_id": f.reader_id, "writer_id": f.writer_id,
                           "sn": sn_value(f.writer_sn.high, f.writer_sn.low)}
    pos = 4 + f.octets_to_inline_qos
    if sub.flags & FLAG_D and sub.flags & FLAG_K:
        _flag(msg, "rtps.data_and_key")
    if sub.flags & FLAG_Q:
        params, used, problem = parse_parameters(body[pos:], le)
        if problem:
            _flag(msg, "rtps.no_sentinel")
        out["inline_qos"] = discovery_fields(params, le)
        pos += used
    if sub.flags & (FLAG_D | FLAG_K):
        payload = body[pos:]
        out["payload"] = payload
        if len(payload) >= 4:
            out["encapsulation"] = payload[:2]
            if payload[:2] in _PARAMETER_LISTS:  # SPDP/SEDP and other parameter lists
                params, _, problem = parse_parameters(payload[4:], payload[1] == 3)
                if problem:
                    _flag(msg, "rtps.no_sentinel")
                out["parameters"] = discovery_fields(params, payload[1] == 3)
                if "locator_problems" in out["parameters"]:
                    _flag(msg, "rtps.bad_locator")
                for loc in out["parameters"].get("default_unicast_locator", []) + \
                        out["parameters"].get("metatraffic_unicast_locator", []):
                    if loc[0] not in (LOCATOR_KIND_UDPV4, LOCATOR_KIND_UDPV6):
                        _flag(msg, "rtps.bad_locator_kind")
    return out


def looks_like_rtps(datagram: bytes) -> bool:
    return datagram[:4] == MAGIC


# --------------------------------------------------------------------------- fast path


def scan(datagram: bytes) -> list[tuple[int, int, int, int]]:
    """The monitor's fast path: ``[(id, flags, body offset, length)...]`` after the header; never raises.

    A length past the end is listed as declared (the caller checks ``offset + length``).
    """
    n = len(datagram)
    out = []
    off = HEADER_SIZE
    unpack_le, unpack_be = _H_LE.unpack_from, _H_BE.unpack_from
    while n - off >= 4:
        sub_id, flags = datagram[off], datagram[off + 1]
        length = (unpack_le if flags & 1 else unpack_be)(datagram, off + 2)[0]
        start = off + 4
        if length == 0 and sub_id != 0x01 and sub_id != 0x09:
            length = n - start
        out.append((sub_id, flags, start, length))
        off = start + length
        if off > n:
            break
    return out


_H_LE = struct.Struct("<H")
_H_BE = struct.Struct(">H")

__all__ = [
    "BUILTIN_ENDPOINT_SET", "CDR_LE", "ENTITYID_PARTICIPANT", "ENTITYID_UNKNOWN", "FLAG_D", "FLAG_E", "FLAG_F",
    "FLAG_K", "FLAG_Q", "HEADER_SIZE", "Header", "LAYOUTS", "MAGIC", "Message", "PL_CDR_LE", "Parameter",
    "SEDP_PUB_READER", "SEDP_PUB_WRITER", "SEDP_SUB_READER", "SEDP_SUB_WRITER", "SPDP_READER", "SPDP_WRITER",
    "Submessage", "SubmessageId", "VENDOR_FREERTPS", "acknack", "bitmap_members", "build_header", "data",
    "discovery_fields", "entity_text", "gap", "guid_text", "heartbeat", "info_dst", "info_ts", "is_reader",
    "is_writer", "key_hash_qos", "locator", "locator_problem", "looks_like_rtps", "message", "parameter", "parameter_list",
    "parse_locator", "parse_message", "parse_parameters", "port_owner", "ports", "scan", "sedp_payload", "sn_parts",
    "sn_set", "sn_value", "spdp_payload", "string_value", "submessage", "time_parts",
]
