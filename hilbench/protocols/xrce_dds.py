"""DDS-XRCE (Micro XRCE-DDS) over UDP: message and submessage layouts, payloads, builders and a decoder.

One XRCE message per datagram (spec sheet §1.1). The layouts are ``construct``
structures used both ways: :func:`build_message` and the payload builders make
what the emulated agent and the micro-ROS board send; :func:`parse_message`
reads any datagram and never raises. Byte orders (§1.2-§1.5):

- the message header's ``sequence_nr`` and every submessage's length are
  little-endian always; ``RequestId`` and ``ObjectId`` are two raw octets;
- payloads are XCDR1 in the submessage's E-flag order, aligned from the start
  of the message (the same as from the payload: headers are 4 or 8 bytes);
- WRITE_DATA/DATA user data is raw XCDR1 with its own alignment origin.

:func:`scan` is the monitor's fast path over the same layout (``struct``, no
construct objects); tests prove it agrees with :func:`parse_message` on every
spec vector. Problems are reported as flag strings (``xrce.bad_length``,
``xrce.zero_fill``, ... as the sheet's §1.9.4 names them), never raised.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from construct import (
    Bytes,
    Construct,
    Flag,
    GreedyBytes,
    If,
    Int8ub,
    Int16ul,
    Struct,
    Switch,
    this,
)

from hilbench.protocols.cdr import primitives, sequence

COOKIE = b"XRCE"
VERSION = b"\x01\x00"
VENDOR_EPROSIMA = b"\x01\x0f"
#: The default agent port of micro-ROS documentation and Xu's log.
DEFAULT_AGENT_PORT = 8888
#: Client transport MTU minus the 4-byte reliable-slot word (§1.1): what CREATE_CLIENT carries.
DEFAULT_MTU = 508

# Session ids (§1.2).
SESSION_NONE_WITH_KEY = 0x00
SESSION_NONE_WITHOUT_KEY = 0x80
# Streams.
STREAM_NONE = 0x00
STREAM_BEST_EFFORT = 0x01
STREAM_RELIABLE = 0x80


class SubmessageId(IntEnum):
    """Submessage ids 0-15 (§1.4); ids 16-255 are unknown and skipped by their length."""

    CREATE_CLIENT = 0
    CREATE = 1
    GET_INFO = 2
    DELETE = 3
    STATUS_AGENT = 4
    STATUS = 5
    INFO = 6
    WRITE_DATA = 7
    READ_DATA = 8
    DATA = 9
    ACKNACK = 10
    HEARTBEAT = 11
    RESET = 12
    FRAGMENT = 13
    TIMESTAMP = 14
    TIMESTAMP_REPLY = 15


NAMES = {int(s): s.name for s in SubmessageId}
#: Minimum payload length per submessage id (§1.4).
MIN_LENGTH = {0: 16, 1: 6, 2: 8, 3: 4, 4: 11, 5: 6, 6: 8, 7: 4, 8: 8, 9: 4, 10: 5, 11: 5, 12: 0, 13: 1, 14: 8,
              15: 24}

# Flags (§1.3).
FLAG_E = 0x01
FLAG_REUSE = 0x02
FLAG_REPLACE = 0x04
FLAG_LAST_FRAGMENT = 0x02
FORMAT_MASK = 0x0E
FORMAT_DATA = 0x00


class ObjectKind(IntEnum):
    """Low nibble of an ObjectId (§1.5)."""

    PARTICIPANT = 0x1
    TOPIC = 0x2
    PUBLISHER = 0x3
    SUBSCRIBER = 0x4
    DATAWRITER = 0x5
    DATAREADER = 0x6
    REQUESTER = 0x7
    REPLIER = 0x8
    TYPE = 0xA
    QOSPROFILE = 0xB
    APPLICATION = 0xC
    AGENT = 0xD
    CLIENT = 0xE
    OTHER = 0xF


OBJECT_AGENT = b"\xff\xfd"
OBJECT_CLIENT = b"\xff\xfe"
OBJECT_SESSION = b"\xff\xff"


class Status(IntEnum):
    """Result status codes (§1.5)."""

    OK = 0x00
    OK_MATCHED = 0x01
    ERR_DDS_ERROR = 0x80
    ERR_MISMATCH = 0x81
    ERR_ALREADY_EXISTS = 0x82
    ERR_DENIED = 0x83
    ERR_UNKNOWN_REFERENCE = 0x84
    ERR_INVALID_DATA = 0x85
    ERR_INCOMPATIBLE = 0x86
    ERR_RESOURCES = 0x87


# Representation formats (§1.8).
REPRESENTATION_BY_REFERENCE = 0x01
REPRESENTATION_AS_XML = 0x02
REPRESENTATION_IN_BINARY = 0x03
# GET_INFO masks.
INFO_CONFIGURATION = 0x01
INFO_ACTIVITY = 0x02
# Binary endpoint QoS flags (the client's is_reliable, is_history_keep_last, durability bits).
QOS_RELIABLE = 0x01 << 0
QOS_HISTORY_KEEP_LAST = 0x01 << 1
QOS_OWNERSHIP_EXCLUSIVE = 0x01 << 2
QOS_DURABILITY_TRANSIENT_LOCAL = 0x01 << 3
QOS_DURABILITY_TRANSIENT = 0x01 << 4
QOS_DURABILITY_PERSISTENT = 0x01 << 5


def object_id(number: int, kind: int) -> bytes:
    """The two ObjectId octets: ``[id >> 4, ((id & 0x0F) << 4) | kind]`` (§1.5)."""
    return bytes(((number >> 4) & 0xFF, ((number & 0x0F) << 4) | (kind & 0x0F)))


def split_object_id(raw: bytes) -> tuple[int, int]:
    """``(id, kind)`` of two ObjectId octets."""
    return (raw[0] << 4) | (raw[1] >> 4), raw[1] & 0x0F


def object_text(raw: bytes) -> str:
    """An ObjectId for people: ``datawriter 1 (0015)``."""
    if raw == OBJECT_AGENT:
        return "agent (FFFD)"
    if raw == OBJECT_CLIENT:
        return "client (FFFE)"
    number, kind = split_object_id(raw)
    try:
        name = ObjectKind(kind).name.lower()
    except ValueError:
        name = f"kind {kind:#x}"
    return f"{name} {number} ({raw.hex().upper()})"


def seq_newer(b: int, a: int) -> bool:
    """Serial arithmetic (§1.2): ``b`` is newer than ``a``."""
    return 0 < (b - a) % 65536 < 32768


def align4(n: int) -> int:
    return (n + 3) & ~3


# --------------------------------------------------------------------------- layouts

MessageHeader = Struct(
    "session_id" / Int8ub,
    "stream_id" / Int8ub,
    "sequence_nr" / Int16ul,
    "client_key" / If(this.session_id < 0x80, Bytes(4)),
)

SubmessageHeader = Struct(
    "submessage_id" / Int8ub,
    "flags" / Int8ub,
    "length" / Int16ul,
)


def _service_binary(string: Construct) -> Construct:
    return Struct("service_name" / string, "request_type" / string, "reply_type" / string,
                  "optional_request_topic_name" / Flag,
                  "request_topic_name" / If(this.optional_request_topic_name, string),
                  "optional_reply_topic_name" / Flag,
                  "reply_topic_name" / If(this.optional_reply_topic_name, string))


def _xml_attributes(text: str, tag: str) -> dict[str, str] | None:
    """The attributes of the first ``<tag ...>`` in ``text``, read the way tinyxml2 (Fast DDS's XML parser,
    so the agent's) reads them: eProsima's RequestAdder/ReplyAdder examples send attributes with no space
    between them (``profile_name="a"service_name="b"``), which the agent accepts and expat rejects."""
    m = re.search(rf"<\s*{tag}\b([^>]*)>", text)
    if m is None:
        return None
    return dict(re.findall(r'([A-Za-z_][\w.-]*)\s*=\s*"([^"]*)"', m.group(1)))


def service_topics(service: str, request_topic: str | None = None, reply_topic: str | None = None
                   ) -> tuple[str, str]:
    """The request and reply topic names of a requester/replier: the given ones, or the agent's defaults
    (``<service>_Request`` and ``<service>_Reply``, as Fast DDS's RequesterAttributes names them)."""
    return request_topic or f"{service}_Request", reply_topic or f"{service}_Reply"


def _layouts(le: bool) -> dict[str, Construct]:
    """Every payload of one byte order (E flag), as construct structures."""
    p = primitives(le)
    u16, u32, i16, i32, string = p["uint16"], p["uint32"], p["int16"], p["int32"], p["string"]
    property_ = Struct("name" / string, "value" / string)
    properties = sequence(property_, le)
    client_rep = Struct(
        "xrce_cookie" / Bytes(4), "xrce_version" / Bytes(2), "xrce_vendor_id" / Bytes(2),
        "client_key" / Bytes(4), "session_id" / Int8ub, "optional_properties" / Flag,
        "properties" / If(this.optional_properties, properties), "mtu" / u16,
    )
    agent_rep = Struct(
        "xrce_cookie" / Bytes(4), "xrce_version" / Bytes(2), "xrce_vendor_id" / Bytes(2),
        "optional_properties" / Flag, "properties" / If(this.optional_properties, properties),
    )
    rep3 = Struct("format" / Int8ub, "value" / Switch(this.format, {
        REPRESENTATION_BY_REFERENCE: string, REPRESENTATION_AS_XML: string,
        REPRESENTATION_IN_BINARY: _bounded_binary(u32)}))
    ref_xml = Struct("format" / Int8ub, "value" / Switch(this.format, {
        REPRESENTATION_BY_REFERENCE: string, REPRESENTATION_AS_XML: string}))
    bin_xml = Struct("format" / Int8ub, "value" / Switch(this.format, {
        REPRESENTATION_IN_BINARY: _bounded_binary(u32), REPRESENTATION_AS_XML: string}))
    variant = Struct("kind" / Int8ub, "rep" / Switch(this.kind, {
        ObjectKind.AGENT: agent_rep,
        ObjectKind.CLIENT: client_rep,
        ObjectKind.APPLICATION: Struct("representation" / ref_xml),
        ObjectKind.PARTICIPANT: Struct("representation" / rep3, "domain_id" / i16),
        ObjectKind.QOSPROFILE: Struct("representation" / ref_xml),
        ObjectKind.TYPE: Struct("representation" / ref_xml),
        ObjectKind.TOPIC: Struct("representation" / rep3, "participant_id" / Bytes(2)),
        ObjectKind.PUBLISHER: Struct("representation" / bin_xml, "participant_id" / Bytes(2)),
        ObjectKind.SUBSCRIBER: Struct("representation" / bin_xml, "participant_id" / Bytes(2)),
        ObjectKind.DATAWRITER: Struct("representation" / rep3, "publisher_id" / Bytes(2)),
        ObjectKind.DATAREADER: Struct("representation" / rep3, "subscriber_id" / Bytes(2)),
        ObjectKind.REQUESTER: Struct("representation" / rep3, "participant_id" / Bytes(2)),
        ObjectKind.REPLIER: Struct("representation" / rep3, "participant_id" / Bytes(2)),
    }))
    locator = Struct("format" / Int8ub, "value" / Switch(this.format, {
        0: Struct("address" / Bytes(2), "port" / Int8ub),
        1: Struct("address" / Bytes(4), "port" / u16),
        2: Struct("address" / Bytes(16), "port" / u32),
        3: Struct("value" / string),
    }))
    activity = Struct("kind" / Int8ub, "info" / Switch(this.kind, {
        ObjectKind.AGENT: Struct("availability" / i16, "address_seq" / sequence(locator, le)),
        ObjectKind.DATAWRITER: Struct("stream_seq_num" / i16, "sample_seq_num" / p["uint64"]),
        ObjectKind.DATAREADER: Struct("highest_acked_num" / i16),
    }))
    base = ("request_id" / Bytes(2), "object_id" / Bytes(2))
    result = ("status" / Int8ub, "implementation_status" / Int8ub)
    time = Struct("seconds" / i32, "nanoseconds" / u32)
    delivery = Struct("max_samples" / u16, "max_elapsed_time" / u16, "max_bytes_per_second" / u16,
                      "min_pace_period" / u16)
    return {
        "CREATE_CLIENT": client_rep,
        "CREATE": Struct(*base, "object_representation" / variant),
        "GET_INFO": Struct(*base, "info_mask" / u32),
        "DELETE": Struct(*base),
        "STATUS_AGENT": Struct(*result, "agent_info" / agent_rep),
        "STATUS": Struct(*base, *result),
        "INFO": Struct(*base, *result, "optional_config" / Flag, "config" / If(this.optional_config, variant),
                       "optional_activity" / Flag, "activity" / If(this.optional_activity, activity)),
        "WRITE_DATA": Struct(*base, "data" / GreedyBytes),
        "READ_DATA": Struct(*base, "preferred_stream_id" / Int8ub, "data_format" / Int8ub,
                            "optional_content_filter" / Flag,
                            "content_filter" / If(this.optional_content_filter, string),
                            "optional_delivery_control" / Flag,
                            "delivery_control" / If(this.optional_delivery_control, delivery)),
        "DATA": Struct(*base, "data" / GreedyBytes),
        "ACKNACK": Struct("first_unacked" / u16, "nack_bitmap" / Bytes(2), "stream_id" / Int8ub),
        "HEARTBEAT": Struct("first_unacked" / u16, "last_unacked" / u16, "stream_id" / Int8ub),
        "RESET": Struct(),
        "FRAGMENT": Struct("data" / GreedyBytes),
        "TIMESTAMP": Struct("transmit" / time),
        "TIMESTAMP_REPLY": Struct("transmit" / time, "receive" / time, "originate" / time),
        # Binary entity representations (the CREATE's binary blob, own alignment origin).
        "participant_binary": Struct("optional_domain_reference" / Flag,
                                     "domain_reference" / If(this.optional_domain_reference, string),
                                     "optional_qos_profile_reference" / Flag,
                                     "qos_profile_reference" / If(this.optional_qos_profile_reference, string)),
        "topic_binary": Struct("topic_name" / string, "optional_type_reference" / Flag,
                               "type_reference" / If(this.optional_type_reference, string),
                               "optional_type_name" / Flag, "type_name" / If(this.optional_type_name, string)),
        # OBJK_Requester_Binary and OBJK_Replier_Binary: one layout (what rmw_microxrcedds sends for services).
        "requester_binary": _service_binary(string),
        "replier_binary": _service_binary(string),
        "publisher_binary": _group_binary(p, le),
        "subscriber_binary": _group_binary(p, le),
        "datawriter_binary": Struct("topic_id" / Bytes(2), "optional_qos" / Flag,
                                    "qos" / If(this.optional_qos, Struct(
                                        "base" / _endpoint_qos(p), "optional_ownership_strength" / Flag,
                                        "ownership_strength" / If(this.optional_ownership_strength,
                                                                  p["uint64"])))),
        "datareader_binary": Struct("topic_id" / Bytes(2), "optional_qos" / Flag,
                                    "qos" / If(this.optional_qos, Struct(
                                        "base" / _endpoint_qos(p), "optional_timebasedfilter_msec" / Flag,
                                        "timebasedfilter_msec" / If(this.optional_timebasedfilter_msec,
                                                                    p["uint64"]),
                                        "optional_contentbased_filter" / Flag,
                                        "contentbased_filter" / If(this.optional_contentbased_filter,
                                                                   string)))),
    }


def _bounded_binary(u32: Construct) -> Construct:
    """sequence<octet>: aligned u32 length, then the bytes (length checked against what is there)."""
    from construct import Prefixed

    return Prefixed(u32, GreedyBytes)


def _endpoint_qos(p: dict[str, Construct]) -> Construct:
    return Struct(
        "qos_flags" / p["uint16"],
        "optional_history_depth" / Flag, "history_depth" / If(this.optional_history_depth, p["uint16"]),
        "optional_deadline_msec" / Flag, "deadline_msec" / If(this.optional_deadline_msec, p["uint32"]),
        "optional_lifespan_msec" / Flag, "lifespan_msec" / If(this.optional_lifespan_msec, p["uint32"]),
        "optional_user_data" / Flag, "user_data" / If(this.optional_user_data, _bounded_binary(p["uint32"])),
    )


def _group_binary(p: dict[str, Construct], le: bool) -> Construct:
    string = p["string"]
    return Struct("optional_name" / Flag, "name" / If(this.optional_name, string),
                  "optional_qos" / Flag, "qos" / If(this.optional_qos, Struct(
                      "optional_partitions" / Flag,
                      "partitions" / If(this.optional_partitions, sequence(string, le)),
                      "optional_group_data" / Flag,
                      "group_data" / If(this.optional_group_data, _bounded_binary(p["uint32"])))))


LAYOUTS: dict[bool, dict[str, Construct]] = {True: _layouts(True), False: _layouts(False)}


def payload_layout(name: str, le: bool = True) -> Construct:
    """The construct layout of payload ``name`` (a submessage name or ``topic_binary`` etc.)."""
    return LAYOUTS[le][name]


# --------------------------------------------------------------------------- building


def build_header(session_id: int, stream_id: int = 0, seq: int = 0, client_key: bytes | None = None) -> bytes:
    """A message header; the client key is required (and only written) for sessions < 0x80."""
    return MessageHeader.build({"session_id": session_id, "stream_id": stream_id, "sequence_nr": seq & 0xFFFF,
                                "client_key": client_key if session_id < 0x80 else None})


def build_submessage(sub_id: int, payload: bytes, flags: int = FLAG_E) -> bytes:
    """A submessage header plus its payload (no padding)."""
    return SubmessageHeader.build({"submessage_id": sub_id, "flags": flags, "length": len(payload)}) + payload


def build_message(session_id: int, stream_id: int, seq: int, submessages: list[tuple[int, int, bytes]],
                  client_key: bytes | None = None) -> bytes:
    """A whole message: header, then ``(id, flags, payload)`` submessages, each next one 4-aligned (§1.3)."""
    out = bytearray(build_header(session_id, stream_id, seq, client_key))
    for i, (sub_id, flags, payload) in enumerate(submessages):
        if i:
            out += b"\x00" * (-len(out) % 4)
        out += build_submessage(sub_id, payload, flags)
    return bytes(out)


def build_payload(name: str, value: dict[str, Any], le: bool = True) -> bytes:
    """A payload from its construct layout (``build_payload("ACKNACK", {...})``)."""
    return payload_layout(name, le).build(value)


def client_representation(client_key: bytes, session_id: int, mtu: int = DEFAULT_MTU,
                          properties: list[tuple[str, str]] | None = None, le: bool = True) -> bytes:
    """A CREATE_CLIENT payload (X3)."""
    return build_payload("CREATE_CLIENT", {
        "xrce_cookie": COOKIE, "xrce_version": VERSION, "xrce_vendor_id": VENDOR_EPROSIMA, "client_key": client_key,
        "session_id": session_id, "optional_properties": bool(properties),
        "properties": [{"name": n, "value": v} for n, v in properties] if properties else None, "mtu": mtu}, le)


def agent_representation() -> dict[str, Any]:
    return {"xrce_cookie": COOKIE, "xrce_version": VERSION, "xrce_vendor_id": VENDOR_EPROSIMA,
            "optional_properties": False, "properties": None}


def status_agent(status: int = Status.OK) -> bytes:
    """A STATUS_AGENT payload (X4)."""
    return build_payload("STATUS_AGENT", {"status": status, "implementation_status": 0,
                                          "agent_info": agent_representation()})


def info_agent(request_id: bytes, obj: bytes, implementation_status: int, availability: int = 1) -> bytes:
    """The INFO reply to a GET_INFO ping (X2): agent config and activity."""
    return build_payload("INFO", {
        "request_id": request_id, "object_id": obj, "status": 0, "implementation_status": implementation_status,
        "optional_config": True, "config": {"kind": ObjectKind.AGENT, "rep": agent_representation()},
        "optional_activity": True, "activity": {"kind": ObjectKind.AGENT,
                                                "info": {"availability": availability, "address_seq": []}}})


def status(request_id: bytes, obj: bytes, code: int = Status.OK, implementation_status: int = 0) -> bytes:
    """A STATUS payload (X12, X20)."""
    return build_payload("STATUS", {"request_id": request_id, "object_id": obj, "status": code,
                                    "implementation_status": implementation_status})


def acknack(first_unacked: int, nack_bitmap: int, stream_id: int) -> bytes:
    """An ACKNACK payload (X11): bit i of the bitmap = first_unacked + i missing."""
    return build_payload("ACKNACK", {"first_unacked": first_unacked & 0xFFFF,
                                     "nack_bitmap": (nack_bitmap & 0xFFFF).to_bytes(2, "big"),
                                     "stream_id": stream_id})


def heartbeat(first_unacked: int, last_unacked: int, stream_id: int) -> bytes:
    """A HEARTBEAT payload (X10)."""
    return build_payload("HEARTBEAT", {"first_unacked": first_unacked & 0xFFFF,
                                       "last_unacked": last_unacked & 0xFFFF, "stream_id": stream_id})


def get_info(request_id: bytes = b"\x00\x0a", obj: bytes = OBJECT_AGENT, mask: int = INFO_ACTIVITY) -> bytes:
    """A GET_INFO payload (X1, the ping)."""
    return build_payload("GET_INFO", {"request_id": request_id, "object_id": obj, "info_mask": mask})


def delete(request_id: bytes, obj: bytes) -> bytes:
    """A DELETE payload (X19 deletes the client: ``00 02``, ``FF FE``)."""
    return build_payload("DELETE", {"request_id": request_id, "object_id": obj})


def data(request_id: bytes, obj: bytes, cdr: bytes) -> bytes:
    """A WRITE_DATA or DATA payload: request id, object id, raw XCDR1 (no encapsulation, X7/X15)."""
    return request_id + obj + cdr


def read_data(request_id: bytes, reader: bytes, stream_id: int, max_samples: int | None = 0xFFFF) -> bytes:
    """A READ_DATA payload (X14); ``max_samples`` None leaves out the delivery control."""
    return build_payload("READ_DATA", {
        "request_id": request_id, "object_id": reader, "preferred_stream_id": stream_id, "data_format": 0,
        "optional_content_filter": False, "content_filter": None,
        "optional_delivery_control": max_samples is not None,
        "delivery_control": {"max_samples": max_samples, "max_elapsed_time": 0, "max_bytes_per_second": 0,
                             "min_pace_period": 0} if max_samples is not None else None})


def timestamp(seconds: int, nanoseconds: int) -> bytes:
    """A TIMESTAMP payload (X17)."""
    return build_payload("TIMESTAMP", {"transmit": {"seconds": seconds, "nanoseconds": nanoseconds}})


def timestamp_reply(transmit: tuple[int, int], receive: tuple[int, int], originate: tuple[int, int]) -> bytes:
    """A TIMESTAMP_REPLY payload (X18)."""
    t = [{"seconds": s, "nanoseconds": n} for s, n in (transmit, receive, originate)]
    return build_payload("TIMESTAMP_REPLY", {"transmit": t[0], "receive": t[1], "originate": t[2]})


def create(request_id: bytes, obj: bytes, kind: int, rep: dict[str, Any], le: bool = True) -> bytes:
    """A CREATE payload: ``rep`` is the kind's representation (``{"representation": {...}, ...}``)."""
    return build_payload("CREATE", {"request_id": request_id, "object_id": obj,
                                    "object_representation": {"kind": kind, "rep": rep}}, le)


def binary_blob(name: str, value: dict[str, Any], le: bool = True) -> bytes:
    """A binary entity representation (``topic_binary``, ``datawriter_binary`` ...), its own origin."""
    return payload_layout(name, le).build(value)


# --------------------------------------------------------------------------- entity representations


def _xml_text(root: Any, *path: str) -> str | None:
    node = root
    for tag in path:
        if node is None:
            return None
        node = next((c for c in node.iter() if c.tag.split("}")[-1] == tag), None)
    return node.text.strip() if node is not None and node.text else None


def _service_info(service: str | None, request_type: str | None, reply_type: str | None,
                  request_topic: str | None, reply_topic: str | None) -> dict[str, Any]:
    req, rep = service_topics(service or "", request_topic, reply_topic)
    return {"service": service, "request_type": request_type, "reply_type": reply_type,
            "request_topic": req, "reply_topic": rep}


def representation_info(kind: int, rep: Any, le: bool = True) -> dict[str, Any]:
    """What a CREATE's representation says (``rep`` = the kind's parsed body): ``format`` and, as far as
    the representation tells, ``topic``, ``type``, ``reliable``, ``depth``, ``name``, ``topic_id``,
    ``parent``, ``domain_id``; ``error`` for XML or binary that cannot be read. Never raises."""
    import xml.etree.ElementTree as ET

    out: dict[str, Any] = {}
    if rep is None or "representation" not in rep:
        return out
    for key in ("participant_id", "publisher_id", "subscriber_id"):
        if key in rep:
            out["parent"] = bytes(rep[key])
    if kind == ObjectKind.PARTICIPANT:
        out["domain_id"] = rep.domain_id
    fmt, value = rep.representation.format, rep.representation.value
    out["format"] = {REPRESENTATION_BY_REFERENCE: "ref", REPRESENTATION_AS_XML: "xml",
                     REPRESENTATION_IN_BINARY: "binary"}.get(fmt, str(fmt))
    try:
        if fmt == REPRESENTATION_BY_REFERENCE:
            out["name"] = str(value)
        elif fmt == REPRESENTATION_AS_XML:
            if kind in (ObjectKind.REQUESTER, ObjectKind.REPLIER):
                tag = "requester" if kind == ObjectKind.REQUESTER else "replier"
                attrs = _xml_attributes(str(value), tag)
                if attrs is None or not attrs.get("service_name"):
                    raise ValueError(f"no <{tag}> with a service_name")
                out.update(_service_info(attrs.get("service_name"), attrs.get("request_type"),
                                         attrs.get("reply_type"), attrs.get("request_topic_name"),
                                         attrs.get("reply_topic_name")))
                out["name"] = attrs.get("profile_name")
                return out
            root = ET.fromstring(str(value).strip() or "<dds/>")
            if kind == ObjectKind.PARTICIPANT:
                out["name"] = _xml_text(root, "name")
            else:
                out["topic"] = _xml_text(root, "topic", "name") or _xml_text(root, "name")
                out["type"] = _xml_text(root, "topic", "dataType") or _xml_text(root, "dataType")
                depth = _xml_text(root, "historyQos", "depth") or _xml_text(root, "history", "depth")
                if depth and depth.isdigit():
                    out["depth"] = int(depth)
                rel = _xml_text(root, "reliability", "kind")
                if rel is not None:
                    out["reliable"] = rel.upper().startswith("RELIABLE")
        elif fmt == REPRESENTATION_IN_BINARY:
            blob = bytes(value)
            if kind == ObjectKind.PARTICIPANT:
                b = payload_layout("participant_binary", le).parse(blob)
                out["name"] = b.qos_profile_reference or b.domain_reference
            elif kind == ObjectKind.TOPIC:
                b = payload_layout("topic_binary", le).parse(blob)
                out["topic"], out["type"] = b.topic_name, b.type_name or b.type_reference
            elif kind in (ObjectKind.PUBLISHER, ObjectKind.SUBSCRIBER):
                out["name"] = payload_layout("publisher_binary", le).parse(blob).name
            elif kind in (ObjectKind.REQUESTER, ObjectKind.REPLIER):
                b = payload_layout("requester_binary", le).parse(blob)
                out.update(_service_info(b.service_name, b.request_type, b.reply_type, b.request_topic_name,
                                         b.reply_topic_name))
            elif kind in (ObjectKind.DATAWRITER, ObjectKind.DATAREADER):
                name = "datawriter_binary" if kind == ObjectKind.DATAWRITER else "datareader_binary"
                b = payload_layout(name, le).parse(blob)
                out["topic_id"] = bytes(b.topic_id)
                if b.optional_qos:
                    out["reliable"] = bool(b.qos.base.qos_flags & QOS_RELIABLE)
                    if b.qos.base.optional_history_depth:
                        out["depth"] = b.qos.base.history_depth
    except Exception as exc:  # noqa: BLE001 (bad XML or a short blob: reported, not raised)
        out["error"] = f"{type(exc).__name__}"
    return out


# --------------------------------------------------------------------------- parsing


@dataclass
class Submessage:
    """One submessage as found in a datagram: header fields, payload bytes, decoded fields (or None)."""

    id: int
    flags: int
    length: int
    offset: int
    payload: bytes
    fields: Any = None
    problem: str | None = None

    @property
    def name(self) -> str:
        return NAMES.get(self.id, f"UNKNOWN_{self.id}")

    @property
    def little_endian(self) -> bool:
        return bool(self.flags & FLAG_E)


@dataclass
class Message:
    """A parsed XRCE message: header, submessages and the integrity flags it raised (§1.9.4)."""

    session_id: int
    stream_id: int
    sequence_nr: int
    client_key: bytes | None
    submessages: list[Submessage] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
    size: int = 0

    @property
    def ok(self) -> bool:
        return not self.flags


def header_size(session_id: int) -> int:
    return 4 if session_id >= 0x80 else 8


def is_zero_fill(datagram: bytes) -> bool:
    """Every byte after the 4-byte header is zero, or a run of >= 16 zeros sits where a payload is expected."""
    if len(datagram) <= 4:
        return False
    body = datagram[4:]
    if not body.strip(b"\x00"):
        return True
    return b"\x00" * 16 in datagram[8:] and datagram[4] == 0 and datagram[6:8] == b"\x00\x00"


def decode_payload(sub_id: int, flags: int, payload: bytes) -> tuple[Any, str | None]:
    """Decode one payload with its construct layout: ``(fields, None)`` or ``(None, reason)``; never raises."""
    name = NAMES.get(sub_id)
    if name is None:
        return None, "unknown submessage"
    try:
        return payload_layout(name, bool(flags & FLAG_E)).parse(payload), None
    except Exception as exc:  # noqa: BLE001 (construct raises many kinds; a decoder reports them)
        return None, f"{type(exc).__name__}"


def parse_message(datagram: bytes, *, decode: bool = True) -> Message:
    """Parse one datagram as an XRCE message; problems are flags, never exceptions.

    ``decode`` also decodes every known payload (``Submessage.fields``).
    """
    datagram = bytes(datagram)
    n = len(datagram)
    if n < 4:
        return Message(-1, -1, -1, None, flags=["xrce.malformed", "xrce.too_short"], size=n)
    sid, stream, seq = datagram[0], datagram[1], datagram[2] | datagram[3] << 8
    hs = header_size(sid)
    msg = Message(sid, stream, seq, datagram[4:8] if sid < 0x80 and n >= 8 else None, size=n)
    if n < hs:
        msg.flags.append("xrce.too_short")
        return msg
    if is_zero_fill(datagram):
        msg.flags.append("xrce.zero_fill")
    off = hs
    while n - off >= 4:
        sub_id, flags, length = datagram[off], datagram[off + 1], datagram[off + 2] | datagram[off + 3] << 8
        start = off + 4
        end = start + length
        sub = Submessage(sub_id, flags, length, off, b"")
        msg.submessages.append(sub)
        if end > n:
            sub.problem = "length beyond datagram"
            _flag(msg, "xrce.bad_length")
            sub.payload = datagram[start:n]
            break
        sub.payload = datagram[start:end]
        if sub_id in MIN_LENGTH and length < MIN_LENGTH[sub_id] and sub_id != SubmessageId.FRAGMENT:
            sub.problem = f"length {length} < {MIN_LENGTH[sub_id]}"
            _flag(msg, "xrce.bad_length")
        elif sub_id not in NAMES:
            _flag(msg, "xrce.unknown_submessage")
        elif decode and sub_id not in (SubmessageId.FRAGMENT,):
            sub.fields, sub.problem = decode_payload(sub_id, flags, sub.payload)
            if sub.problem:
                _flag(msg, "xrce.malformed")
        if sub_id == SubmessageId.CREATE_CLIENT:
            _check_create_client(msg, sub, datagram)
        off = align4(end)
        if length == 0 and sub_id == 0 and off < n and not datagram[off:].strip(b"\x00"):
            break  # a run of zeros parses as endless empty CREATE_CLIENTs (§1.3): one is enough
    trailing = n - off
    if trailing > 3:
        _flag(msg, "xrce.bad_length")
    return msg


def _check_create_client(msg: Message, sub: Submessage, datagram: bytes) -> None:
    """``xrce.bad_create_client``: cookie, zero key or major version, read as the agent reads them
    (16 bytes after the subheader whatever the length says, §1.9.2 E)."""
    body = datagram[sub.offset + 4: sub.offset + 20]
    if len(body) < 16 or body[:4] != COOKIE or body[8:12] == b"\x00\x00\x00\x00" or body[4] != 1:
        _flag(msg, "xrce.bad_create_client")


def _flag(msg: Message, name: str) -> None:
    if name not in msg.flags:
        msg.flags.append(name)


def looks_like_xrce(datagram: bytes) -> bool:
    """The sheet's heuristic (§3.1): header size, first submessage id <= 15 and its length fits."""
    n = len(datagram)
    if n < 8 or datagram[:4] == b"RTPS":
        return False
    hs = 4 if datagram[0] >= 0x80 else 8
    if n < hs + 4:
        return False
    sub_id = datagram[hs]
    length = datagram[hs + 2] | datagram[hs + 3] << 8
    return sub_id <= 15 and length <= n - hs - 4


# --------------------------------------------------------------------------- fast path


def scan(datagram: bytes) -> tuple[int, int, int, list[tuple[int, int, int, int]], int]:
    """The monitor's fast path: ``(session, stream, seq, [(id, flags, offset, length)...], trailing)``.

    ``offset`` is the payload's. Stops at a length beyond the datagram (that
    submessage is listed with its declared length, the caller checks). Never raises
    for input of at least 4 bytes; shorter input gives session -1.
    """
    n = len(datagram)
    if n < 4:
        return -1, -1, -1, [], n
    sid = datagram[0]
    off = 4 if sid >= 0x80 else 8
    subs = []
    append = subs.append
    unpack = _SUB.unpack_from
    while n - off >= 4:
        sub_id, flags, length = unpack(datagram, off)
        append((sub_id, flags, off + 4, length))
        end = off + 4 + length
        if end > n:
            return sid, datagram[1], datagram[2] | datagram[3] << 8, subs, 0
        off = (end + 3) & ~3
        if length == 0 and sub_id == 0 and not datagram[off:].strip(b"\x00"):
            off = n
            break
    return sid, datagram[1], datagram[2] | datagram[3] << 8, subs, max(0, n - off)


_SUB = struct.Struct("<BBH")


__all__ = [
    "COOKIE", "DEFAULT_AGENT_PORT", "DEFAULT_MTU", "FLAG_E", "FLAG_LAST_FRAGMENT", "FLAG_REPLACE", "FLAG_REUSE",
    "INFO_ACTIVITY", "INFO_CONFIGURATION", "LAYOUTS", "MIN_LENGTH", "NAMES", "OBJECT_AGENT", "OBJECT_CLIENT",
    "OBJECT_SESSION", "QOS_RELIABLE", "REPRESENTATION_AS_XML", "REPRESENTATION_BY_REFERENCE",
    "REPRESENTATION_IN_BINARY", "STREAM_BEST_EFFORT", "STREAM_NONE", "STREAM_RELIABLE", "Message", "MessageHeader",
    "ObjectKind", "Status", "Submessage", "SubmessageHeader", "SubmessageId", "acknack", "agent_representation",
    "align4", "binary_blob", "build_header", "build_message", "build_payload", "build_submessage",
    "client_representation", "create", "data", "decode_payload", "delete", "get_info", "header_size", "heartbeat",
    "info_agent", "is_zero_fill", "looks_like_xrce", "object_id", "object_text", "parse_message",
    "payload_layout", "read_data", "representation_info", "scan", "seq_newer", "service_topics", "split_object_id", "status", "status_agent", "timestamp",
    "timestamp_reply",
]
