"""Classic CDR (XCDR1) and the ROS 2 messages the boards exchange, defined once with ``construct``.

CDR aligns every primitive to its own size, counted from an origin: the first
byte of the serialized payload (after RTPS's 4-byte encapsulation header; the
first byte of XRCE WRITE_DATA/DATA user data, spec sheet §1.8 and §2.6).
:func:`align` pads by the position in the stream being parsed or built, so a
structure parsed from (or built into) a buffer that starts at the origin is
aligned exactly as a DDS implementation aligns it.

Every layout exists in both byte orders from one definition: the factories
take ``le`` (little-endian, XRCE's E flag set, RTPS ``CDR_LE``) and are cached.
A ROS 2 type (:class:`RosType`) knows its ROS name (``std_msgs/msg/String``), its
DDS name (``std_msgs::msg::dds_::String_``, §2.10) and its layout;
:func:`ros_type` finds one by either name. Decoding never raises:
:meth:`RosType.try_decode` returns ``(value, None)`` or ``(None, reason)``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

from construct import (
    Adapter,
    Array,
    Bytes,
    Construct,
    Container,
    Float32b,
    Float32l,
    Float64b,
    Float64l,
    Int8sb,
    Int8ub,
    Int16sb,
    Int16sl,
    Int16ub,
    Int16ul,
    Int32sb,
    Int32sl,
    Int32ub,
    Int32ul,
    Int64sb,
    Int64sl,
    Int64ub,
    Int64ul,
    Padding,
    Struct,
)

#: RTPS encapsulation identifiers (2 octets, always big-endian on the wire), §2.6.
CDR_BE = 0x0000
CDR_LE = 0x0001
PL_CDR_BE = 0x0002
PL_CDR_LE = 0x0003
CDR2_BE = 0x0006
CDR2_LE = 0x0007
#: Encapsulations whose plain (non-parameter-list) payload decodes as XCDR1 for the types here.
PLAIN_ENCAPSULATIONS = {CDR_BE: False, CDR_LE: True, CDR2_BE: False, CDR2_LE: True}
#: Longest string or sequence a decoder accepts: a length field never drives a larger allocation.
MAX_LENGTH = 1 << 20


def align(n: int) -> Construct:
    """Zero padding up to the next multiple of ``n`` bytes from the stream's origin."""
    return Padding(lambda ctx: -ctx._io.tell() % n)


class _CdrString(Adapter):
    """A CDR string: u32 length including the NUL, the bytes, the NUL (§2.6); as ``str``."""

    def _decode(self, obj: Any, context: Any, path: Any) -> str:
        raw = obj.raw
        if raw.endswith(b"\x00"):
            raw = raw[:-1]
        return raw.decode("utf-8", errors="replace")

    def _encode(self, obj: Any, context: Any, path: Any) -> dict[str, Any]:
        raw = (obj if isinstance(obj, bytes) else str(obj).encode()) + b"\x00"
        return {"length": len(raw), "raw": raw}


class _Bool(Adapter):
    def _decode(self, obj: int, context: Any, path: Any) -> bool:
        return obj != 0

    def _encode(self, obj: Any, context: Any, path: Any) -> int:
        return 1 if obj else 0


def _bounded(ctx: Any) -> int:
    if ctx.length > MAX_LENGTH:
        raise ValueError(f"length {ctx.length} beyond {MAX_LENGTH}")
    return ctx.length


@functools.cache
def primitives(le: bool = True) -> dict[str, Construct]:
    """CDR primitives of one byte order, each aligned to its size (``string``: u32 length + bytes + NUL)."""
    u16, u32, u64 = (Int16ul, Int32ul, Int64ul) if le else (Int16ub, Int32ub, Int64ub)
    i16, i32, i64 = (Int16sl, Int32sl, Int64sl) if le else (Int16sb, Int32sb, Int64sb)
    f32, f64 = (Float32l, Float64l) if le else (Float32b, Float64b)

    def al(n: int, c: Construct) -> Construct:
        return _Aligned(n, c)

    string = _CdrString(Struct(align(4), "length" / u32, "raw" / Bytes(_bounded)))
    return {
        "bool": _Bool(Int8ub), "octet": Int8ub, "char": Int8ub, "uint8": Int8ub, "int8": Int8sb,
        "int16": al(2, i16), "uint16": al(2, u16), "int32": al(4, i32), "uint32": al(4, u32),
        "int64": al(8, i64), "uint64": al(8, u64), "float32": al(4, f32), "float64": al(8, f64),
        "string": string,
    }


class _Aligned(Adapter):
    """A primitive preceded by alignment padding; reads and writes the bare value."""

    def __init__(self, n: int, subcon: Construct) -> None:
        super().__init__(Struct(align(n), "v" / subcon))

    def _decode(self, obj: Any, context: Any, path: Any) -> Any:
        return obj.v

    def _encode(self, obj: Any, context: Any, path: Any) -> dict[str, Any]:
        return {"v": obj}


def sequence(element: Construct, le: bool = True) -> Construct:
    """A CDR sequence: aligned u32 count, then the elements."""
    u32 = primitives(le)["uint32"]
    return _Sequence(Struct("length" / u32, "elements" / Array(_bounded, element)))


class _Sequence(Adapter):
    def _decode(self, obj: Any, context: Any, path: Any) -> list[Any]:
        return list(obj.elements)

    def _encode(self, obj: Any, context: Any, path: Any) -> dict[str, Any]:
        return {"length": len(obj), "elements": list(obj)}


# --------------------------------------------------------------------------- ROS 2 messages

#: Field lists: (name, type) where type is a primitive, ``"T[]"`` (a sequence) or another message's ROS name.
MESSAGES: dict[str, tuple[tuple[str, str], ...]] = {
    "builtin_interfaces/msg/Time": (("sec", "int32"), ("nanosec", "uint32")),
    "std_msgs/msg/Header": (("stamp", "builtin_interfaces/msg/Time"), ("frame_id", "string")),
    "std_msgs/msg/String": (("data", "string"),),
    "std_msgs/msg/Bool": (("data", "bool"),),
    "std_msgs/msg/Int8": (("data", "int8"),),
    "std_msgs/msg/UInt8": (("data", "uint8"),),
    "std_msgs/msg/Int16": (("data", "int16"),),
    "std_msgs/msg/UInt16": (("data", "uint16"),),
    "std_msgs/msg/Int32": (("data", "int32"),),
    "std_msgs/msg/UInt32": (("data", "uint32"),),
    "std_msgs/msg/Int64": (("data", "int64"),),
    "std_msgs/msg/UInt64": (("data", "uint64"),),
    "std_msgs/msg/Float32": (("data", "float32"),),
    "std_msgs/msg/Float64": (("data", "float64"),),
    "geometry_msgs/msg/Vector3": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Point": (("x", "float64"), ("y", "float64"), ("z", "float64")),
    "geometry_msgs/msg/Quaternion": (("x", "float64"), ("y", "float64"), ("z", "float64"), ("w", "float64")),
    "geometry_msgs/msg/Pose": (("position", "geometry_msgs/msg/Point"),
                               ("orientation", "geometry_msgs/msg/Quaternion")),
    "geometry_msgs/msg/Pose2D": (("x", "float64"), ("y", "float64"), ("theta", "float64")),
    "geometry_msgs/msg/Twist": (("linear", "geometry_msgs/msg/Vector3"), ("angular", "geometry_msgs/msg/Vector3")),
    "geometry_msgs/msg/TwistStamped": (("header", "std_msgs/msg/Header"), ("twist", "geometry_msgs/msg/Twist")),
    "sensor_msgs/msg/LaserScan": (
        ("header", "std_msgs/msg/Header"), ("angle_min", "float32"), ("angle_max", "float32"),
        ("angle_increment", "float32"), ("time_increment", "float32"), ("scan_time", "float32"),
        ("range_min", "float32"), ("range_max", "float32"), ("ranges", "float32[]"), ("intensities", "float32[]")),
    # control_msgs/msg/MecanumDriveControllerState: the rover's micro-ROS firmware sends wheel data in it.
    "control_msgs/msg/MecanumDriveControllerState": (
        ("header", "std_msgs/msg/Header"), ("front_left_wheel_velocity", "float64"),
        ("back_left_wheel_velocity", "float64"), ("back_right_wheel_velocity", "float64"),
        ("front_right_wheel_velocity", "float64"), ("reference_velocity", "geometry_msgs/msg/Twist")),
    # eProsima's Micro XRCE-DDS examples: struct HelloWorld { unsigned long index; string message; }.
    "HelloWorld": (("index", "uint32"), ("message", "string")),
}


def dds_type_name(ros_name: str) -> str:
    """``std_msgs/msg/String`` -> ``std_msgs::msg::dds_::String_`` (§2.10); other names stay."""
    parts = ros_name.split("/")
    if len(parts) == 3:
        pkg, kind, typ = parts
        return f"{pkg}::{kind}::dds_::{typ}_"
    return ros_name


def ros_type_name(name: str) -> str:
    """The ROS name for a ROS name, a short ``pkg/Type`` or a DDS name; other names stay."""
    if "::dds_::" in name:
        pkg_kind, _, typ = name.partition("::dds_::")
        return pkg_kind.replace("::", "/") + "/" + typ.rstrip("_")
    parts = name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return name


@functools.cache
def message_struct(ros_name: str, le: bool = True) -> Construct:
    """The construct layout of a ROS message (byte order ``le``); KeyError for an unknown type."""
    fields = MESSAGES[ros_name]
    prims = primitives(le)
    subcons = []
    for fname, ftype in fields:
        if ftype.endswith("[]"):
            inner = ftype[:-2]
            elem = prims[inner] if inner in prims else message_struct(inner, le)
            subcons.append(fname / sequence(elem, le))
        elif ftype in prims:
            subcons.append(fname / prims[ftype])
        else:
            subcons.append(fname / message_struct(ftype, le))
    return Struct(*subcons)


@dataclass(frozen=True)
class RosType:
    """A ROS 2 message type: names and CDR layout."""

    ros_name: str

    @property
    def dds_name(self) -> str:
        return dds_type_name(self.ros_name)

    @property
    def short_name(self) -> str:
        """``std_msgs/String`` (how ``ros2 topic`` users write it)."""
        parts = self.ros_name.split("/")
        return f"{parts[0]}/{parts[2]}" if len(parts) == 3 else self.ros_name

    def encode(self, value: dict[str, Any], le: bool = True) -> bytes:
        """The CDR bytes of ``value`` (a dict of the fields; missing fields are zero or empty)."""
        return message_struct(self.ros_name, le).build(_fill(self.ros_name, value))

    def decode(self, data: bytes, le: bool = True) -> Container:
        """Parse CDR bytes (raises construct/Value errors; see :meth:`try_decode`)."""
        return message_struct(self.ros_name, le).parse(data)

    def try_decode(self, data: bytes, le: bool = True) -> tuple[dict[str, Any] | None, str | None]:
        """``(value, None)``, or ``(None, reason)`` for bytes that are not this type."""
        try:
            return _plain(self.decode(data, le)), None
        except Exception as exc:  # noqa: BLE001 (construct raises many kinds)
            return None, f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}".strip(": ")


def _fill(ros_name: str, value: Any) -> dict[str, Any]:
    out = {}
    value = value or {}
    for fname, ftype in MESSAGES[ros_name]:
        v = value.get(fname) if isinstance(value, dict) else getattr(value, fname, None)
        if ftype.endswith("[]"):
            inner = ftype[:-2]
            items = list(v or [])
            out[fname] = [_fill(inner, i) for i in items] if inner in MESSAGES else items
        elif ftype in MESSAGES:
            out[fname] = _fill(ftype, v)
        elif v is None:
            out[fname] = "" if ftype == "string" else (False if ftype == "bool" else 0)
        else:
            out[fname] = v
    return out


def _plain(obj: Any) -> Any:
    """construct Containers to plain dicts (JSON-able), without construct's private keys."""
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items() if not k.startswith("_")}
    if isinstance(obj, list):
        return [_plain(v) for v in obj]
    return obj


def ros_type(name: str) -> RosType | None:
    """The ROS type named ``name`` (ROS name, ``pkg/Type`` or DDS name), or None if unknown."""
    ros = ros_type_name(name)
    return RosType(ros) if ros in MESSAGES else None


def known_types() -> list[str]:
    """ROS names of every message type here."""
    return [n for n in MESSAGES if n.count("/") == 2 and not n.startswith("builtin_interfaces")]


__all__ = ["CDR_BE", "CDR_LE", "CDR2_BE", "CDR2_LE", "MAX_LENGTH", "MESSAGES", "PLAIN_ENCAPSULATIONS", "PL_CDR_BE",
           "PL_CDR_LE", "RosType", "align", "dds_type_name", "known_types", "message_struct", "primitives",
           "ros_type", "ros_type_name", "sequence"]
