"""Slamtec RPLIDAR serial protocol (A1): requests, response descriptors, payloads, scan nodes, capsules.

Wire layout (spec sheet laser_scanners.md §1), little-endian::

    request     A5 CMD                                   (CMD bit 7 clear: no payload)
                A5 CMD SIZE PAYLOAD[SIZE] CHK            (CMD bit 7 set; CHK = XOR of every byte before it)
    descriptor  A5 5A LEN_MODE(u32: bits 0..29 length, 30..31 send mode) TYPE
    node (81)   quality<<2 | !S<<1 | S,  angle_q6<<1 | 1 (u16), distance_q2 (u16)
    capsule(82) A? 5? start_angle_q6|S<<15 (u16), 16 cabins of 5 bytes

The construct structures are the one definition of each layout: the emulated
A1 builds with them, the decoders parse with them. Scan nodes are also
encoded in bulk with numpy (:func:`encode_nodes`, a revolution at a time); a
test proves it agrees with ``ScanNode`` on every vector. The construct layouts are made when first
used (``_layouts()``): the monitor runs the decoders on every raw capture's first bytes.

Two incremental decoders never raise: :class:`RequestDecoder` frames what a
host sends (as the device does: by bit 7 of CMD, XOR checked) and
:class:`ResponseDecoder` what the device sends (descriptors, single
responses, node and capsule streams, resynchronising byte by byte and
skipping the ASCII boot banner a RESET prints).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from functools import cache
from typing import TYPE_CHECKING, Any, NamedTuple

from hilbench.protocols.lazy_layouts import lazy_layouts
from hilbench.protocols.problem import Problem

if TYPE_CHECKING:
    import numpy as np

SYNC = 0xA5
SYNC2 = 0x5A
BAUD = 115_200
DESCRIPTOR_SIZE = 7
NODE_SIZE = 5
CAPSULE_SIZE = 84
#: Send modes of a descriptor (bits 30..31 of LEN_MODE).
SINGLE, MULTIPLE = 0, 1


class Cmd(IntEnum):
    """Request codes (§1.3). Bit 7 set means the request carries SIZE, payload and checksum."""

    STOP = 0x25
    RESET = 0x40
    SCAN = 0x20
    FORCE_SCAN = 0x21
    EXPRESS_SCAN = 0x82
    GET_INFO = 0x50
    GET_HEALTH = 0x52
    GET_SAMPLERATE = 0x59
    GET_LIDAR_CONF = 0x84
    SET_LIDAR_CONF = 0x85
    HQ_SCAN = 0x83
    NEW_BAUDRATE_CONFIRM = 0x90
    HQ_MOTOR_SPEED_CTRL = 0xA8
    SET_MOTOR_PWM = 0xF0
    GET_ACC_BOARD_FLAG = 0xFF


class AnsType(IntEnum):
    """Descriptor TYPE values (§1.4)."""

    DEVINFO = 0x04
    DEVHEALTH = 0x06
    SAMPLERATE = 0x15
    GET_LIDAR_CONF = 0x20
    SET_LIDAR_CONF = 0x21
    MEASUREMENT = 0x81
    MEASUREMENT_CAPSULED = 0x82
    MEASUREMENT_HQ = 0x83
    MEASUREMENT_ULTRA_CAPSULED = 0x84
    MEASUREMENT_DENSE_CAPSULED = 0x85
    ACC_BOARD_FLAG = 0xFF


class Conf(IntEnum):
    """GET_LIDAR_CONF types (§1.5.4)."""

    DESIRED_ROT_FREQ = 0x01
    SCAN_MODE_COUNT = 0x70
    SCAN_MODE_US_PER_SAMPLE = 0x71
    SCAN_MODE_MAX_DISTANCE = 0x74
    SCAN_MODE_ANS_TYPE = 0x75
    SCAN_MODE_TYPICAL = 0x7C
    SCAN_MODE_NAME = 0x7F


HEALTH_STATUS = {0: "good", 1: "warning", 2: "error"}

# ----------------------------------------------------------------------------- construct layouts

if TYPE_CHECKING:  # (made by _layouts() when first used)
    from construct import Struct

    ShortRequest: Struct
    PayloadRequest: Struct
    Descriptor: Struct
    DeviceInfo: Struct
    DeviceHealth: Struct
    SampleRate: Struct
    ExpressRequest: Struct
    MotorPwm: Struct
    LidarConfAnswer: Struct
    DesiredRotFreq: Struct
    ScanNode: Struct
    Capsule: Struct


#: The construct layouts' names: module attributes, made when first used (:func:`_layouts`).
_LAYOUT_NAMES = ("ShortRequest", "PayloadRequest", "Descriptor", "DeviceInfo", "DeviceHealth", "SampleRate",
                 "ExpressRequest", "MotorPwm", "LidarConfAnswer", "DesiredRotFreq", "ScanNode", "Cabin", "Capsule")


@cache
def _layouts() -> dict[str, Any]:
    """The construct layouts (``_LAYOUT_NAMES``), made with construct's import when first used: the decoders
    run without them until a frame needs one (the monitor asks every instrument about a capture's first
    bytes, and must not import construct for that)."""
    from construct import (
        Array,
        BitsInteger,
        BitStruct,
        Byte,
        Bytes,
        Const,
        Flag,
        GreedyBytes,
        Int16ul,
        Int32ul,
        Struct,
    )

    #: A request without payload (CMD bit 7 clear).
    ShortRequest = Struct("sync" / Const(bytes([SYNC])), "cmd" / Byte)
    #: A request with payload; ``chk`` is the XOR of every byte before it (see :func:`request`).
    PayloadRequest = Struct(
        "sync" / Const(bytes([SYNC])),
        "cmd" / Byte,
        "size" / Byte,
        "payload" / Bytes(lambda ctx: ctx.size),
        "chk" / Byte,
    )
    #: The 7-byte response descriptor.
    Descriptor = Struct(
        "sync" / Const(bytes([SYNC, SYNC2])),
        "len_mode" / Int32ul,
        "type" / Byte,
    )
    DeviceInfo = Struct(
        "model" / Byte,
        "firmware_minor" / Byte,
        "firmware_major" / Byte,
        "hardware" / Byte,
        "serial" / Bytes(16),
    )
    DeviceHealth = Struct("status" / Byte, "error_code" / Int16ul)
    SampleRate = Struct("standard_us" / Int16ul, "express_us" / Int16ul)
    ExpressRequest = Struct("working_mode" / Byte, "working_flags" / Int16ul, "param" / Int16ul)
    MotorPwm = Struct("pwm" / Int16ul)
    LidarConfAnswer = Struct("type" / Int32ul, "value" / GreedyBytes)
    DesiredRotFreq = Struct("rpm" / Int16ul, "pwm_ref" / Int16ul)
    #: A standard scan node (type 81): bits as they lie in the 5 bytes.
    ScanNode = Struct(
        "b0" / BitStruct("quality" / BitsInteger(6), "not_start" / Flag, "start" / Flag),
        "angle" / Int16ul,  # angle_q6 << 1 | check bit
        "distance_q2" / Int16ul,
    )
    Cabin = Struct("d1" / Int16ul, "d2" / Int16ul, "dtheta" / Byte)
    #: A legacy express capsule (type 82): sync nibbles carry the checksum nibbles.
    Capsule = Struct(
        "s1" / Byte,
        "s2" / Byte,
        "start" / Int16ul,  # start_angle_q6 | S << 15
        "cabins" / Array(16, Cabin),
    )

    return {name: value for name, value in locals().items() if name in _LAYOUT_NAMES}


def layouts() -> None:
    """Make the construct layouts now (an emulator that builds its replies with them calls this when it is
    made, so that no client's first request waits for construct's import)."""
    _layouts()


__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)


# ----------------------------------------------------------------------------- building


def xor(data: bytes) -> int:
    """XOR of all bytes (the request checksum and the capsule checksum)."""
    # Too small for a library: one XOR fold.
    out = 0
    for b in data:
        out ^= b
    return out


def has_payload(cmd: int) -> bool:
    """Whether requests with this CMD carry SIZE, payload and checksum (bit 7, as the SDK frames them)."""
    return bool(cmd & 0x80)


def request(cmd: int, payload: bytes = b"") -> bytes:
    """A host request: ``A5 CMD`` or ``A5 CMD SIZE PAYLOAD CHK``."""
    if not has_payload(cmd):
        if payload:
            raise ValueError(f"command 0x{cmd:02X} carries no payload")
        return _layouts()["ShortRequest"].build({"cmd": cmd})
    head = bytes([SYNC, cmd, len(payload)]) + payload
    return _layouts()["PayloadRequest"].build({"cmd": cmd, "size": len(payload), "payload": payload, "chk": xor(head)})


def descriptor(length: int, mode: int, ans_type: int) -> bytes:
    """A response descriptor: ``A5 5A LEN_MODE TYPE``."""
    return _layouts()["Descriptor"].build({"len_mode": (length & 0x3FFFFFFF) | (mode << 30), "type": ans_type})


def info_payload(model: int, firmware: tuple[int, int], hardware: int, serial: bytes) -> bytes:
    """GET_INFO's 20 bytes; ``firmware`` is (major, minor)."""
    return _layouts()["DeviceInfo"].build({"model": model, "firmware_major": firmware[0],
                                           "firmware_minor": firmware[1], "hardware": hardware, "serial": serial})


def health_payload(status: int, error_code: int) -> bytes:
    return _layouts()["DeviceHealth"].build({"status": status, "error_code": error_code})


def samplerate_payload(standard_us: int, express_us: int) -> bytes:
    return _layouts()["SampleRate"].build({"standard_us": standard_us, "express_us": express_us})


def conf_answer(conf_type: int, value: bytes) -> bytes:
    """A GET_LIDAR_CONF answer: the u32 type echoed, then the value."""
    return _layouts()["LidarConfAnswer"].build({"type": conf_type, "value": value})


def node(quality: int, angle_q6: int, distance_q2: int, start: bool) -> bytes:
    """One standard scan node (the reference for :func:`encode_nodes`)."""
    return _layouts()["ScanNode"].build({"b0": {"quality": quality & 0x3F, "not_start": not start, "start": start},
                                         "angle": ((angle_q6 & 0x7FFF) << 1) | 1, "distance_q2": distance_q2 & 0xFFFF})


def encode_nodes(quality: np.ndarray, angle_q6: np.ndarray, distance_q2: np.ndarray,
                 start: np.ndarray) -> bytes:
    """Many standard scan nodes at once (numpy); byte-identical to :func:`node` for each."""
    import numpy as np  # here: the emulated scanner needs it, a monitor sniffing a capture does not

    n = len(angle_q6)
    out = np.empty((n, NODE_SIZE), np.uint8)
    s = start.astype(np.uint8)
    out[:, 0] = ((quality.astype(np.uint16) & 0x3F) << 2).astype(np.uint8) | ((1 - s) << 1) | s
    a = ((angle_q6.astype(np.uint32) & 0x7FFF) << 1) | 1
    out[:, 1] = a & 0xFF
    out[:, 2] = a >> 8
    d = distance_q2.astype(np.uint32) & 0xFFFF
    out[:, 3] = d & 0xFF
    out[:, 4] = d >> 8
    return out.tobytes()


def capsule(start_angle_q6: int, distances_mm: list[int] | np.ndarray, new_scan: bool,
            dtheta_q3: list[int] | None = None) -> bytes:
    """One legacy express capsule of 32 distances (mm, 14 bits); dθ = 0 unless given (§1.7)."""
    d = [int(x) & 0x3FFF for x in distances_mm]
    if len(d) != 32:
        raise ValueError("a capsule carries 32 samples")
    dt = [int(x) & 0x3F for x in (dtheta_q3 or [0] * 32)]
    cabins = []
    for k in range(16):
        t1, t2 = dt[2 * k], dt[2 * k + 1]
        cabins.append({"d1": (d[2 * k] << 2) | (t1 >> 4), "d2": (d[2 * k + 1] << 2) | (t2 >> 4),
                       "dtheta": (t1 & 0xF) | ((t2 & 0xF) << 4)})
    body = _layouts()["Capsule"].build({"s1": 0xA0, "s2": 0x50,
                                        "start": (start_angle_q6 & 0x7FFF) | (int(new_scan) << 15), "cabins": cabins})
    chk = xor(body[2:])
    return bytes([0xA0 | (chk & 0xF), 0x50 | (chk >> 4)]) + body[2:]


# ----------------------------------------------------------------------------- parsed items


def _code_name(codes: type[IntEnum], code: int) -> str:
    """A code's enum name, or its hex for a code the enum does not know."""
    try:
        return codes(code).name
    except ValueError:
        return f"0x{code:02X}"


class Request(NamedTuple):
    """A host request the device would act on."""

    cmd: int
    payload: bytes
    raw: bytes

    @property
    def name(self) -> str:
        return _code_name(Cmd, self.cmd)


class Response(NamedTuple):
    """A descriptor and (for single responses) its payload; ``fields`` parsed when the type is known."""

    ans_type: int
    length: int
    mode: int
    payload: bytes
    fields: dict[str, Any] | None
    raw: bytes

    @property
    def name(self) -> str:
        return _code_name(AnsType, self.ans_type)


class Node(NamedTuple):
    """One measurement: ``angle`` degrees clockwise from the heading, ``distance`` mm (0: invalid)."""

    start: bool
    quality: int
    angle: float
    distance: float


class CapsuleItem(NamedTuple):
    """One express capsule (checksum good); ``distances`` mm, ``dtheta`` in q3 degrees."""

    start_angle: float
    new_scan: bool
    distances: tuple[int, ...]
    dtheta: tuple[int, ...]
    raw: bytes


def parse_node(raw: bytes) -> Node | None:
    """A node from 5 bytes, or None if its flags fail (S == S̄ or C == 0)."""
    b0, b1 = raw[0], raw[1]
    if (b0 & 1) == ((b0 >> 1) & 1) or not b1 & 1:
        return None
    angle_q6 = (b1 >> 1) | (raw[2] << 7)
    return Node(bool(b0 & 1), b0 >> 2, angle_q6 / 64.0, (raw[3] | raw[4] << 8) / 4.0)


def parse_capsule(raw: bytes) -> CapsuleItem | None:
    """An express capsule from 84 bytes, or None if its sync nibbles or checksum fail."""
    if len(raw) != CAPSULE_SIZE or raw[0] >> 4 != 0xA or raw[1] >> 4 != 0x5:
        return None
    if xor(raw[2:]) != ((raw[0] & 0xF) | ((raw[1] & 0xF) << 4)):
        return None
    c = _layouts()["Capsule"].parse(raw)
    dist, dth = [], []
    for cab in c.cabins:
        dist += [cab.d1 >> 2, cab.d2 >> 2]
        dth += [((cab.d1 & 3) << 4) | (cab.dtheta & 0xF), ((cab.d2 & 3) << 4) | (cab.dtheta >> 4)]
    return CapsuleItem((c.start & 0x7FFF) / 64.0, bool(c.start >> 15), tuple(dist), tuple(dth), bytes(raw))


def capsule_samples(prev: CapsuleItem, cur: CapsuleItem) -> list[tuple[float, int]]:
    """The 32 (angle °, distance mm) samples of ``prev``, placed between its start angle and ``cur``'s (SDK rule)."""
    diff = cur.start_angle - prev.start_angle
    if diff < 0:
        diff += 360.0
    return [((prev.start_angle + diff * k / 32.0 - prev.dtheta[k] / 8.0) % 360.0, prev.distances[k])
            for k in range(32)]


def parse_payload(ans_type: int, payload: bytes) -> dict[str, Any] | None:
    """Fields of a single-response payload of a known type (None otherwise)."""
    try:
        if ans_type == AnsType.DEVINFO and len(payload) == 20:
            i = _layouts()["DeviceInfo"].parse(payload)
            return {"model": i.model, "firmware": (i.firmware_major, i.firmware_minor), "hardware": i.hardware,
                    "serial": i.serial.hex().upper()}
        if ans_type == AnsType.DEVHEALTH and len(payload) == 3:
            h = _layouts()["DeviceHealth"].parse(payload)
            return {"status": h.status, "error_code": h.error_code}
        if ans_type == AnsType.SAMPLERATE and len(payload) == 4:
            s = _layouts()["SampleRate"].parse(payload)
            return {"standard_us": s.standard_us, "express_us": s.express_us}
        if ans_type == AnsType.GET_LIDAR_CONF and len(payload) >= 4:
            c = _layouts()["LidarConfAnswer"].parse(payload)
            return {"type": c.type, "value": bytes(c.value)}
    except Exception:  # noqa: BLE001 (a decoder reports, never raises)
        return None
    return None


# ----------------------------------------------------------------------------- decoders

#: Longest request payload a device accepts (SIZE is one byte).
MAX_PAYLOAD = 255
#: Longest single response a host decoder accepts (bounded, whatever the descriptor says).
MAX_SINGLE = 1024


class RequestDecoder:
    """Frames host requests as the device does; bad checksums and stray bytes become :class:`~hilbench.protocols.problem.Problem` s."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped = 0
        self.bad_checksum = 0

    def feed(self, data: bytes) -> list[Request | Problem]:
        buf = self._buf
        buf += data
        out: list[Request | Problem] = []
        i = 0
        n = len(buf)
        garbage_from = None
        while i < n:
            if buf[i] != SYNC:
                if garbage_from is None:
                    garbage_from = i
                i += 1
                continue
            if i + 2 > n:
                break
            cmd = buf[i + 1]
            if not has_payload(cmd):
                end = i + 2
            else:
                if i + 3 > n:
                    break
                end = i + 3 + buf[i + 2] + 1
                if end > n:
                    break
            if garbage_from is not None:
                out.append(Problem("garbage", bytes(buf[garbage_from:i])))
                self.dropped += i - garbage_from
                garbage_from = None
            raw = bytes(buf[i:end])
            if has_payload(cmd) and xor(raw[:-1]) != raw[-1]:
                self.bad_checksum += 1
                out.append(Problem("checksum", raw, f"request 0x{cmd:02X}"))
            else:
                out.append(Request(cmd, raw[3:-1] if has_payload(cmd) else b"", raw))
            i = end
        if garbage_from is not None:
            out.append(Problem("garbage", bytes(buf[garbage_from:i])))
            self.dropped += i - garbage_from
        del buf[:i]
        return out

    def reset(self) -> None:
        """Forget a partial request (the device drops one older than 5 s)."""
        self._buf.clear()


_ANS_TYPES = frozenset(int(t) for t in AnsType)


def _plausible_descriptor(buf: bytearray, i: int) -> bool:
    """Whether the 7 bytes at ``i`` are a descriptor a device sends: a known TYPE, a single response of
    bounded length or a stream."""
    len_mode = struct.unpack_from("<I", buf, i + 2)[0]
    length, mode = len_mode & 0x3FFFFFFF, len_mode >> 30
    return buf[i + 6] in _ANS_TYPES and (mode == MULTIPLE or (mode == SINGLE and length <= MAX_SINGLE))


class ResponseDecoder:
    """Decodes what an RPLIDAR sends: descriptors with their payloads, node and capsule streams.

    Emits :class:`Response`, :class:`Node`, :class:`CapsuleItem` and :class:`~hilbench.protocols.problem.Problem`
    items. In a node stream every position is tried as a node (S != S̄ and C == 1)
    or as a new descriptor (``A5 5A``, which can never start a valid node); other
    bytes are dropped and counted. ASCII text (a RESET's banner) is reported as one
    ``banner`` problem per line.
    """

    def __init__(self, max_buffer: int = 1 << 16) -> None:
        self._buf = bytearray()
        self.stream: int | None = None  # TYPE of the stream in progress
        self.dropped = 0
        self.bad_checksum = 0
        self.max_buffer = max_buffer

    def expect_stream(self, ans_type: int | None) -> None:
        """Start decoding as if a descriptor of ``ans_type`` had been seen (a capture that starts mid-scan)."""
        self.stream = ans_type

    def _drop(self, out: list, kind: str, raw: bytes, detail: str = "") -> None:
        self.dropped += len(raw)
        if out and isinstance(out[-1], Problem) and out[-1].kind == kind == "garbage":
            out[-1] = Problem(kind, out[-1].raw + raw, detail)
        else:
            out.append(Problem(kind, raw, detail))

    def feed(self, data: bytes) -> list[Response | Node | CapsuleItem | Problem]:
        buf = self._buf
        buf += data
        out: list = []
        i = 0
        n = len(buf)
        while i < n:
            b = buf[i]
            if b == SYNC and i + 1 < n and buf[i + 1] == SYNC2:
                if i + DESCRIPTOR_SIZE > n:
                    break
                len_mode = struct.unpack_from("<I", buf, i + 2)[0]
                length, mode, ans_type = len_mode & 0x3FFFFFFF, len_mode >> 30, buf[i + 6]
                if mode == SINGLE:
                    if length > MAX_SINGLE:
                        self._drop(out, "descriptor", bytes(buf[i:i + 2]), f"length {length}")
                        i += 2
                        continue
                    if i + DESCRIPTOR_SIZE + length > n:
                        break
                    payload = bytes(buf[i + 7:i + 7 + length])
                    out.append(Response(ans_type, length, mode, payload, parse_payload(ans_type, payload),
                                        bytes(buf[i:i + 7 + length])))
                    self.stream = None
                    i += DESCRIPTOR_SIZE + length
                    continue
                if mode == MULTIPLE:
                    out.append(Response(ans_type, length, mode, b"", None, bytes(buf[i:i + 7])))
                    self.stream = ans_type
                    i += DESCRIPTOR_SIZE
                    continue
                self._drop(out, "descriptor", bytes(buf[i:i + 2]), f"send mode {mode}")
                i += 2
                continue
            if self.stream == AnsType.MEASUREMENT:
                if i + NODE_SIZE > n:
                    break
                # After a lost byte the node grid is off: a new descriptor (the host's next request
                # answered) may start inside what would parse as a node. A5 5A can be a node's angle
                # bytes, so only a whole plausible descriptor wins over the node.
                j = buf.find(b"\xa5\x5a", i + 1, i + NODE_SIZE + 1)
                if j > 0:
                    if j + DESCRIPTOR_SIZE > n:
                        break
                    if _plausible_descriptor(buf, j):
                        self._drop(out, "garbage", bytes(buf[i:j]))
                        i = j
                        continue
                nd = parse_node(buf[i:i + NODE_SIZE])
                if nd is not None:
                    out.append(nd)
                    i += NODE_SIZE
                    continue
            elif self.stream == AnsType.MEASUREMENT_CAPSULED and b >> 4 == 0xA:
                if i + CAPSULE_SIZE > n:
                    break
                if buf[i + 1] >> 4 == 0x5:
                    cap = parse_capsule(bytes(buf[i:i + CAPSULE_SIZE]))
                    if cap is not None:
                        out.append(cap)
                        i += CAPSULE_SIZE
                        continue
                    self.bad_checksum += 1
                    self._drop(out, "checksum", bytes(buf[i:i + 2]), "express capsule")
                    i += 2
                    continue
            elif self.stream is None and b == 0x52 and buf[i:i + 3] == b"RP ":
                # A RESET's boot banner: skip to the end of the line.
                end = buf.find(b"\n", i)
                if end < 0:
                    if n - i < 256:
                        break
                    end = i + 255
                self._drop(out, "banner", bytes(buf[i:end + 1]))
                i = end + 1
                continue
            self._drop(out, "garbage", bytes(buf[i:i + 1]))
            i += 1
        del buf[:i]
        if len(buf) > self.max_buffer:  # never grow without bound
            self._drop(out, "truncated", bytes(buf))
            buf.clear()
        return out


@dataclass
class ScanAssembler:
    """Groups nodes (or express samples) into revolutions at each S = 1; yields finished revolutions."""

    min_points: int = 1

    def __post_init__(self) -> None:
        self.current: list[tuple[float, float, int]] = []
        self.started = False
        self._prev_capsule: CapsuleItem | None = None

    def add_node(self, nd: Node) -> list[list[tuple[float, float, int]]]:
        """Add a standard node; returns revolutions completed by it (angle °, distance mm, quality)."""
        done = []
        if nd.start:
            if self.started and len(self.current) >= self.min_points:
                done.append(self.current)
            self.current = []
            self.started = True
        if self.started:
            self.current.append((nd.angle, nd.distance, nd.quality))
        return done

    def add_capsule(self, cap: CapsuleItem) -> list[list[tuple[float, float, int]]]:
        """Add an express capsule; samples of the previous one are placed (SDK rule), revolutions at 0°."""
        done = []
        prev, self._prev_capsule = self._prev_capsule, cap
        if cap.new_scan:
            self._prev_capsule = cap
            self.current = []
            self.started = False
            return done
        if prev is None:
            return done
        last = self.current[-1][0] if self.current else None
        for angle, dist in capsule_samples(prev, cap):
            if last is not None and angle < last - 180.0:  # wrapped past 0°: a new revolution
                if self.started and len(self.current) >= self.min_points:
                    done.append(self.current)
                self.current = []
                self.started = True
            elif last is None and not self.started:
                self.started = True
            self.current.append((angle, float(dist), 47 if dist else 0))
            last = angle
        return done


__all__ = [
    "BAUD", "CAPSULE_SIZE", "DESCRIPTOR_SIZE", "HEALTH_STATUS", "MULTIPLE", "NODE_SIZE", "SINGLE", "SYNC", "SYNC2",
    "AnsType", "Capsule", "CapsuleItem", "Cmd", "Conf", "Descriptor", "DesiredRotFreq", "DeviceHealth",
    "DeviceInfo", "ExpressRequest", "LidarConfAnswer", "MotorPwm", "Node", "PayloadRequest", "Problem",
    "Request", "RequestDecoder", "Response", "ResponseDecoder", "SampleRate", "ScanAssembler", "ScanNode",
    "ShortRequest", "capsule", "capsule_samples", "conf_answer", "descriptor", "encode_nodes", "has_payload",
    "health_payload", "info_payload", "layouts", "node", "parse_capsule", "parse_node", "parse_payload", "request",
    "samplerate_payload", "xor",
]
