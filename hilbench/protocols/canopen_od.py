"""A CANopen object dictionary described as data, its value codecs, and its EDS text (CiA 306).

A device's dictionary is a list of :class:`Variable` and :class:`Record`
(``array=True``: an ARRAY) entries. The same list feeds the emulated node's SDO server
(:mod:`hilbench.fakes.canopen`) and the EDS file tools import (the
``canopen`` package, CANopen configuration tools), so they cannot disagree.

Defaults may depend on the node id, written as in an EDS: ``"$NODEID+0x180"``.

The EDS writer emits a complete ``[DummyUsage]`` section (``Dummy0001`` to
``Dummy0007``): the ``canopen`` package reads all seven keys whenever the
section exists and fails on a missing one.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

# CiA 301 data types: code, struct format (None: variable length), size in bytes.
BOOLEAN = 0x0001
INTEGER8 = 0x0002
INTEGER16 = 0x0003
INTEGER32 = 0x0004
UNSIGNED8 = 0x0005
UNSIGNED16 = 0x0006
UNSIGNED32 = 0x0007
REAL32 = 0x0008
VISIBLE_STRING = 0x0009
OCTET_STRING = 0x000A
DOMAIN = 0x000F
INTEGER24 = 0x0010
UNSIGNED24 = 0x0016

TYPE_NAMES = {BOOLEAN: "BOOLEAN", INTEGER8: "INTEGER8", INTEGER16: "INTEGER16", INTEGER24: "INTEGER24",
              INTEGER32: "INTEGER32", UNSIGNED8: "UNSIGNED8", UNSIGNED16: "UNSIGNED16", UNSIGNED24: "UNSIGNED24",
              UNSIGNED32: "UNSIGNED32", REAL32: "REAL32", VISIBLE_STRING: "VISIBLE_STRING",
              OCTET_STRING: "OCTET_STRING", DOMAIN: "DOMAIN"}
#: Integer types: (bytes, signed).
INTEGERS = {BOOLEAN: (1, False), INTEGER8: (1, True), INTEGER16: (2, True), INTEGER24: (3, True),
            INTEGER32: (4, True), UNSIGNED8: (1, False), UNSIGNED16: (2, False), UNSIGNED24: (3, False),
            UNSIGNED32: (4, False)}
_REAL32 = struct.Struct("<f")

ACCESS = ("ro", "wo", "rw", "rwr", "rww", "const")


def type_size(data_type: int) -> int | None:
    """Bytes of a fixed-size type (None for strings and domains)."""
    if data_type in INTEGERS:
        return INTEGERS[data_type][0]
    if data_type == REAL32:
        return 4
    return None


def encode(data_type: int, value: Any) -> bytes:
    """A value's bytes (little-endian); ValueError if it does not fit the type."""
    if data_type in INTEGERS:
        size, signed = INTEGERS[data_type]
        return int(value).to_bytes(size, "little", signed=signed)
    if data_type == REAL32:
        return _REAL32.pack(float(value))
    if data_type == VISIBLE_STRING:
        return str(value).encode("latin-1")
    return bytes(value)


def decode(data_type: int, raw: bytes) -> Any:
    """A value from its bytes; ValueError if the length does not fit the type."""
    size = type_size(data_type)
    if size is not None and len(raw) != size:
        raise ValueError(f"{TYPE_NAMES.get(data_type, hex(data_type))} takes {size} bytes, got {len(raw)}")
    if data_type in INTEGERS:
        return int.from_bytes(raw, "little", signed=INTEGERS[data_type][1])
    if data_type == REAL32:
        return _REAL32.unpack(raw)[0]
    if data_type == VISIBLE_STRING:
        return raw.decode("latin-1")
    return bytes(raw)


def in_range(data_type: int, value: Any) -> bool:
    """Whether an integer ``value`` fits ``data_type`` (other types: always)."""
    if data_type not in INTEGERS:
        return True
    size, signed = INTEGERS[data_type]
    bits = 1 if data_type == BOOLEAN else 8 * size
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    return lo <= int(value) <= hi


def resolve(default: Any, node_id: int) -> Any:
    """A default with ``$NODEID`` replaced by the node id (``"$NODEID+0x180"`` -> 0x182 for node 2)."""
    if isinstance(default, str) and "$NODEID" in default:
        rest = default.replace(" ", "").replace("$NODEID", "").strip("+")
        return int(rest, 0) + node_id if rest else node_id
    return default


@dataclass(frozen=True)
class Variable:
    """One value: at ``index`` (a VAR object) or at ``index``/``subindex`` inside a record or array.

    ``factor`` and ``unit`` are what the ``canopen`` package reads as physical
    scaling (``.phys``); CiA 306 tools ignore them.
    """

    index: int
    subindex: int
    name: str
    data_type: int
    access: str = "ro"
    default: Any = 0
    pdo: bool = False
    factor: float = 1.0
    unit: str = ""
    description: str = ""
    low: int | None = None
    high: int | None = None


@dataclass(frozen=True)
class Record:
    """A RECORD (or, with ``array=True``, an ARRAY) object: sub-index 0 says the highest sub-index."""

    index: int
    name: str
    members: tuple[Variable, ...]
    array: bool = False

    @property
    def highest(self) -> int:
        return max(m.subindex for m in self.members)


Entry = Variable | Record


def sub0(index: int, highest: int, access: str = "ro") -> Variable:
    """The ``Highest sub-index supported`` (or ``Number of entries``) member of a record or array."""
    return Variable(index, 0, "Highest sub-index supported", UNSIGNED8, access, highest)


def variables(entries: list[Entry]) -> dict[tuple[int, int], Variable]:
    """Every value of a dictionary by ``(index, subindex)`` (a VAR object at sub-index 0)."""
    out: dict[tuple[int, int], Variable] = {}
    for e in entries:
        if isinstance(e, Record):
            for m in e.members:
                out[(e.index, m.subindex)] = m
        else:
            out[(e.index, 0)] = e
    return out


@dataclass
class DeviceInfo:
    """The ``[DeviceInfo]`` section and file facts of an EDS."""

    vendor_name: str
    vendor_number: int
    product_name: str
    product_number: int
    revision_number: int
    order_code: str = ""
    description: str = ""
    file_name: str = "device.eds"
    baud_rates: tuple[int, ...] = (10, 20, 50, 125, 250, 500, 800, 1000)
    rx_pdos: int = 0
    tx_pdos: int = 0
    comments: list[str] = field(default_factory=list)


MANDATORY = (0x1000, 0x1001, 0x1018)


def _value_text(var: Variable) -> str:
    default = var.default
    if isinstance(default, str) and "$NODEID" in default:
        return default
    if var.data_type == VISIBLE_STRING:
        return str(default)
    if var.data_type in (OCTET_STRING, DOMAIN):
        return bytes(default).hex()
    if var.data_type == REAL32:
        return repr(float(default))
    value = int(default)
    if var.data_type in INTEGERS and INTEGERS[var.data_type][1]:
        return str(value)
    size = INTEGERS.get(var.data_type, (4, False))[0]
    return f"0x{value:0{2 * size}X}"


def _var_lines(section: str, var: Variable) -> list[str]:
    lines = [f"[{section}]", f"ParameterName={var.name}", "ObjectType=0x7", f"DataType=0x{var.data_type:04X}",
             f"AccessType={var.access}", f"DefaultValue={_value_text(var)}", f"PDOMapping={int(var.pdo)}"]
    if var.low is not None:
        lines.append(f"LowLimit={var.low}")
    if var.high is not None:
        lines.append(f"HighLimit={var.high}")
    if var.factor != 1.0:
        lines.append(f"Factor={var.factor!r}")
    if var.unit:
        lines.append(f"Unit={var.unit}")
    if var.description:
        lines.append(f"Description={var.description}")
    return [*lines, ""]


def eds_text(entries: list[Entry], info: DeviceInfo) -> str:
    """The EDS (CiA 306 v4.0) of a dictionary: sections in index order, values with ``$NODEID`` kept."""
    entries = sorted(entries, key=lambda e: e.index)
    out = [
        "[FileInfo]", f"FileName={info.file_name}", "FileVersion=1", "FileRevision=0", "EDSVersion=4.0",
        f"Description={info.description}", "CreationTime=12:00AM", "CreationDate=01-01-2025",
        "CreatedBy=hilbench", "ModificationTime=12:00AM", "ModificationDate=01-01-2025", "ModifiedBy=hilbench", "",
        "[DeviceInfo]", f"VendorName={info.vendor_name}", f"VendorNumber=0x{info.vendor_number:08X}",
        f"ProductName={info.product_name}", f"ProductNumber=0x{info.product_number:08X}",
        f"RevisionNumber=0x{info.revision_number:08X}", f"OrderCode={info.order_code}",
    ]
    out += [f"BaudRate_{rate}={int(rate in info.baud_rates)}" for rate in (10, 20, 50, 125, 250, 500, 800, 1000)]
    out += ["SimpleBootUpMaster=0", "SimpleBootUpSlave=1", "Granularity=8", "DynamicChannelsSupported=0",
            "GroupMessaging=0", f"NrOfRXPDO={info.rx_pdos}", f"NrOfTXPDO={info.tx_pdos}", "LSS_Supported=0", ""]
    out += ["[DummyUsage]"] + [f"Dummy{i:04d}=0" for i in range(1, 8)] + [""]
    if info.comments:
        out += ["[Comments]", f"Lines={len(info.comments)}"]
        out += [f"Line{i}={line}" for i, line in enumerate(info.comments, 1)] + [""]
    groups = {
        "MandatoryObjects": [e for e in entries if e.index in MANDATORY],
        "OptionalObjects": [e for e in entries if (e.index not in MANDATORY and e.index < 0x2000)
                            or e.index >= 0x6000],
        "ManufacturerObjects": [e for e in entries if 0x2000 <= e.index < 0x6000],
    }
    for title, group in groups.items():
        out += [f"[{title}]", f"SupportedObjects={len(group)}"]
        out += [f"{i}=0x{e.index:04X}" for i, e in enumerate(group, 1)] + [""]
    for e in entries:
        if isinstance(e, Variable):
            out += _var_lines(f"{e.index:04X}", e)
            continue
        out += [f"[{e.index:04X}]", f"ParameterName={e.name}", f"ObjectType={'0x8' if e.array else '0x9'}",
                f"SubNumber={len(e.members)}", ""]
        for m in sorted(e.members, key=lambda m: m.subindex):
            out += _var_lines(f"{e.index:04X}sub{m.subindex:X}", m)
    return "\r\n".join(out) + "\r\n"


__all__ = [
    "BOOLEAN", "DOMAIN", "INTEGER16", "INTEGER24", "INTEGER32", "INTEGER8", "OCTET_STRING", "REAL32", "UNSIGNED16",
    "UNSIGNED24", "UNSIGNED32", "UNSIGNED8", "VISIBLE_STRING", "DeviceInfo", "Entry", "Record", "Variable",
    "decode", "eds_text", "encode", "in_range", "resolve", "sub0", "type_size", "variables",
]
