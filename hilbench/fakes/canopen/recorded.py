"""A CANopen node that does what a capture shows a real one doing (``model = "recorded-node"``).

:class:`RecordedNode` is a :class:`~hilbench.fakes.canopen.node.CanopenNode`
(boot-up, NMT, heartbeat, SDO server, EMCY, node guarding) whose application
is a recording: in OPERATIONAL it sends each :class:`RecordedPdo` at its
period with the payload the capture ended with, and its object dictionary
holds each :class:`RecordedObject` with the bytes an SDO upload returned
(writable where the host downloaded to it), so the host's uploads get the
answers the capture shows. :func:`recorded_entries` builds that dictionary,
adding the objects every node has (0x1000, 0x1001, 0x1003, 0x1017, 0x1018)
where the capture shows none.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hilbench.fakes.canopen.node import ERROR_HISTORY, CanopenNode
from hilbench.protocols import canopen as co
from hilbench.protocols import canopen_od as od

#: The data type of an object from the length of its value.
_TYPES = {1: od.UNSIGNED8, 2: od.UNSIGNED16, 3: od.UNSIGNED24, 4: od.UNSIGNED32}
#: Objects the node keeps itself (its heartbeat period, error register and error history).
OWN_OBJECTS = (0x1001, 0x1003, 0x1017)


@dataclass(frozen=True)
class RecordedPdo:
    """A PDO the node sends: its COB-ID, period and payload."""

    cob_id: int
    period_ms: int
    data: bytes


@dataclass(frozen=True)
class RecordedObject:
    """An object dictionary value as an SDO upload returned it (``access`` ``"rw"`` where the host wrote it)."""

    index: int
    subindex: int
    data: bytes
    access: str = "ro"


def _variable(obj: RecordedObject) -> od.Variable:
    data_type = _TYPES.get(len(obj.data), od.OCTET_STRING)
    default: Any = int.from_bytes(obj.data, "little") if data_type in _TYPES.values() else bytes(obj.data)
    return od.Variable(obj.index, obj.subindex, f"Object {obj.index:04X}sub{obj.subindex:X}", data_type, obj.access,
                       default)


def recorded_entries(objects: list[RecordedObject], heartbeat_ms: int) -> list[od.Entry]:
    """The dictionary of a recorded node: the objects given, in records where they have sub-indexes, and the
    objects every node has."""
    by_index: dict[int, dict[int, RecordedObject]] = {}
    for obj in objects:
        if obj.index not in OWN_OBJECTS:
            by_index.setdefault(obj.index, {})[obj.subindex] = obj
    entries: list[od.Entry] = [
        od.Variable(0x1001, 0, "Error register", od.UNSIGNED8, "ro", 0),
        od.Record(0x1003, "Pre-defined error field", (
            od.Variable(0x1003, 0, "Number of errors", od.UNSIGNED8, "rw", 0),
            *(od.Variable(0x1003, i, f"Standard error field {i}", od.UNSIGNED32, "ro", 0)
              for i in range(1, ERROR_HISTORY + 1))), array=True),
        od.Variable(0x1017, 0, "Producer heartbeat time", od.UNSIGNED16, "rw", heartbeat_ms),
    ]
    by_index.setdefault(0x1000, {}).setdefault(0, RecordedObject(0x1000, 0, bytes(4)))
    identity = by_index.setdefault(0x1018, {})
    for sub in range(1, 5):
        identity.setdefault(sub, RecordedObject(0x1018, sub, bytes(4)))
    for index, subs in sorted(by_index.items()):
        if set(subs) == {0}:
            entries.append(_variable(subs[0]))
            continue
        members = [_variable(o) for s, o in sorted(subs.items()) if s != 0]
        first = subs.get(0)
        sub0 = _variable(first) if first is not None and len(first.data) == 1 else od.sub0(index, max(subs))
        entries.append(od.Record(index, f"Object {index:04X}", (sub0, *members)))
    return entries


class RecordedNode(CanopenNode):
    """A node replaying what a capture shows: its heartbeat, its PDOs at their periods, its SDO values."""

    def __init__(self, name: str, node_id: int, *, heartbeat_ms: int = 1000, autostart: bool = False,
                 tpdos: list[RecordedPdo] | None = None, objects: list[RecordedObject] | None = None) -> None:
        super().__init__(name, node_id, recorded_entries(list(objects or []), heartbeat_ms), autostart=autostart)
        self.tpdos = list(tpdos or [])
        self.pdos_sent = 0

    def on_state(self, state: int, t: float) -> None:
        for pdo in self.tpdos:
            self.restart_timer(f"pdo-{pdo.cob_id:03X}")
            if state == co.OPERATIONAL and pdo.period_ms > 0:
                self._schedule(pdo, t + pdo.period_ms / 1000)

    def _schedule(self, pdo: RecordedPdo, t: float) -> None:
        self.call_at(t, lambda: self._send_pdo(pdo, t), timer=f"pdo-{pdo.cob_id:03X}")

    def _send_pdo(self, pdo: RecordedPdo, t: float) -> None:
        if self.state != co.OPERATIONAL:
            return
        self.pdos_sent += 1
        self.send(pdo.cob_id, pdo.data)
        period = pdo.period_ms / 1000
        nxt = t + period
        now = self.now()  # (the node's clock, as CanopenNode's heartbeat reads it)
        if nxt < now - period:  # far behind (a stalled machine): skip the backlog instead of bursting
            nxt = now + period
        self._schedule(pdo, nxt)

    def set_faults(self, **knobs: Any) -> dict[str, Any]:
        """Turn the node's fault knobs (``heartbeat_stop``, ``silent``, ``sdo_abort``); unknown ones raise."""
        for key in knobs:
            if key not in self.faults:
                raise ValueError(f"unknown fault knob {key!r} (a recorded node has {', '.join(self.faults)})")
        self.faults.update(knobs)
        return dict(self.faults)

    def status(self) -> dict[str, Any]:
        out = super().status()
        out["pdos_sent"] = self.pdos_sent
        out["tpdos"] = {f"0x{p.cob_id:03X}": p.period_ms for p in self.tpdos}
        return out


__all__ = ["OWN_OBJECTS", "RecordedNode", "RecordedObject", "RecordedPdo", "recorded_entries"]
