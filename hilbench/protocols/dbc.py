"""CAN message descriptions and their DBC text (the database format cantools and CAN tools read).

A :class:`Message` lists its :class:`Signal` s in byte order; this module
turns a list of them into a DBC database. Only what hilbench's layouts use is
written: little-endian (Intel) byte-aligned signals, scale and offset, units,
ranges, comments, value tables and the ``GenMsgCycleTime`` attribute.

The text is written here rather than through cantools because
``hilbench/protocols`` stays free of I/O-heavy dependencies (construct,
crcmod and the standard library only), and cantools is an optional extra;
the tests load every generated database with cantools.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Signal:
    """One signal: ``bits`` wide, little-endian, from bit ``start`` (Intel numbering); physical = raw * ``scale``.

    ``od`` is the object dictionary entry ``(index, subindex)`` a CANopen PDO
    maps it to (None for frames that are not PDOs); ``choices`` names raw values.
    """

    name: str
    start: int
    bits: int
    signed: bool = False
    scale: float = 1.0
    unit: str = ""
    comment: str = ""
    choices: tuple[tuple[int, str], ...] = ()
    od: tuple[int, int] | None = None

    @property
    def offset(self) -> int:
        """The byte the signal starts in."""
        return self.start // 8

    @property
    def raw_range(self) -> tuple[int, int]:
        if self.signed:
            return -(1 << (self.bits - 1)), (1 << (self.bits - 1)) - 1
        return 0, (1 << self.bits) - 1

    @property
    def physical_range(self) -> tuple[float, float]:
        lo, hi = self.raw_range
        return lo * self.scale, hi * self.scale


@dataclass(frozen=True)
class Message:
    """One CAN message: identifier, length, sender, receivers, signals, cycle time (0 = on event)."""

    name: str
    can_id: int
    length: int
    sender: str
    receivers: tuple[str, ...]
    signals: tuple[Signal, ...]
    comment: str = ""
    cycle_ms: int = 0
    extended: bool = False
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    def signal(self, name: str) -> Signal:
        for s in self.signals:
            if s.name == name:
                return s
        raise KeyError(name)


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _num(x: float) -> str:
    """A number as DBC writes it (no trailing ``.0``, no exponent for ordinary values)."""
    if float(x).is_integer():
        return str(int(x))
    text = f"{x:.10f}".rstrip("0").rstrip(".")
    return text


def _quote(text: str) -> str:
    return text.replace("\\", "\\\\").replace('"', '\\"')


def check_name(name: str) -> str:
    """A DBC identifier (letters, digits, underscore); ValueError otherwise."""
    if not _NAME.fullmatch(name):
        raise ValueError(f"not a DBC identifier: {name!r}")
    return name


def dbc_text(messages: list[Message], nodes: list[str], *, comment: str = "") -> str:
    """The DBC database of ``messages`` sent and received by ``nodes``."""
    for n in nodes:
        check_name(n)
    lines = ['VERSION ""', "", "", "NS_ :", "\tCM_", "\tBA_DEF_", "\tBA_", "\tVAL_", "\tBA_DEF_DEF_", "",
             "BS_:", "", f"BU_: {' '.join(nodes)}", ""]
    for m in messages:
        check_name(m.name)
        frame_id = m.can_id | (0x80000000 if m.extended else 0)
        lines.append(f"BO_ {frame_id} {m.name}: {m.length} {m.sender}")
        for s in m.signals:
            check_name(s.name)
            lo, hi = s.physical_range
            receivers = ",".join(m.receivers) or "Vector__XXX"
            lines.append(f" SG_ {s.name} : {s.start}|{s.bits}@1{'-' if s.signed else '+'} "
                         f"({_num(s.scale)},0) [{_num(lo)}|{_num(hi)}] \"{_quote(s.unit)}\" {receivers}")
        lines.append("")
    if comment:
        lines.append(f'CM_ "{_quote(comment)}";')
    for m in messages:
        frame_id = m.can_id | (0x80000000 if m.extended else 0)
        if m.comment:
            lines.append(f'CM_ BO_ {frame_id} "{_quote(m.comment)}";')
        for s in m.signals:
            if s.comment:
                lines.append(f'CM_ SG_ {frame_id} {s.name} "{_quote(s.comment)}";')
    lines.append('BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;')
    lines.append('BA_DEF_DEF_ "GenMsgCycleTime" 0;')
    for m in messages:
        if m.cycle_ms:
            frame_id = m.can_id | (0x80000000 if m.extended else 0)
            lines.append(f'BA_ "GenMsgCycleTime" BO_ {frame_id} {m.cycle_ms};')
    for m in messages:
        frame_id = m.can_id | (0x80000000 if m.extended else 0)
        for s in m.signals:
            if s.choices:
                values = " ".join(f'{v} "{_quote(text)}"' for v, text in s.choices)
                lines.append(f"VAL_ {frame_id} {s.name} {values} ;")
    return "\n".join(lines) + "\n"


__all__ = ["Message", "Signal", "check_name", "dbc_text"]
