"""Profile entries of recorded CANopen nodes (``model = "recorded-node"``), as ``profiles from-capture`` writes them.

::

    [[devices]]
    model = "recorded-node"          # a node doing what a capture shows (hilbench.fakes.canopen.recorded)
    name = "node2"
    node_id = 2
    heartbeat_ms = 1000              # 0: none
    autostart = false                # true: OPERATIONAL right after boot-up (no NMT start needed)
    tpdos = [                        # sent in OPERATIONAL, each at its period
      { cob_id = 0x182, period_ms = 20, data = "00 00 00 00 00 00 00 00" },
    ]
    objects = [                      # SDO uploads answer these bytes; "rw" where the host may write
      { index = 0x1018, subindex = 1, data = "4e 42 48 00" },
      { index = 0x2001, subindex = 0, data = "01", access = "rw" },
    ]
    faults = { heartbeat_stop = false, silent = false, sdo_abort = 0 }

Several nodes share an endpoint (one bus), beside the rover boards.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.checks import Checker
from hilbench.bench.family import DeviceSpec
from hilbench.bench.knobs import check_fault_table
from hilbench.rules import SWITCH, Rule

#: The model name a profile gives a recorded node.
RECORDED = "recorded-node"
#: Keys of a recorded node's entry beyond a rover board's.
RECORDED_KEYS = ("tpdos", "objects")
#: A recorded node's fault knobs (the generic node's).
FAULT_RULES = {"heartbeat_stop": SWITCH, "silent": SWITCH, "sdo_abort": Rule(int, 0, 0xFFFFFFFF)}
#: Largest object value kept (bytes): a segmented upload the capture shows in full, bounded.
MAX_OBJECT = 1024
MAX_ITEMS = 4096


@dataclass
class RecordedSpec(DeviceSpec):
    """A recorded node of a profile."""

    model: str = RECORDED
    node_id: int = 1
    heartbeat_ms: int = 1000
    autostart: bool = False
    tpdos: list[tuple[int, int, bytes]] = field(default_factory=list)
    objects: list[tuple[int, int, bytes, str]] = field(default_factory=list)
    faults: dict[str, Any] = field(default_factory=dict)


def _hex(c: Checker, value: Any, key: str, most: int) -> bytes:
    if not isinstance(value, str):
        c.fail(key, f"expected hex bytes such as \"01 02 03\", got {value!r}")
    try:
        data = bytes.fromhex(value)
    except ValueError:
        c.fail(key, f"expected hex bytes such as \"01 02 03\", got {value!r}")
    if len(data) > most:
        c.fail(key, f"at most {most} bytes, got {len(data)}")
    return data


def check_recorded(c: Checker, key: str, dev: dict[str, Any], endpoint_name: str) -> RecordedSpec:
    """A ``recorded-node`` entry, checked (one-line errors naming the key)."""
    for extra in ("setpoint_timeout_ms", "tpdo_periods_ms", "identity"):
        if extra in dev:
            c.fail(f"{key}.{extra}", f"a {RECORDED} has none (its objects and tpdos say what it does)")
    name = dev.get("name", endpoint_name)
    if not isinstance(name, str) or not name:
        c.fail(f"{key}.name", f"expected a string, got {name!r}")
    raw = dev.get("tpdos", [])
    if not isinstance(raw, list) or len(raw) > 512:
        c.fail(f"{key}.tpdos", "expected an array of at most 512 tables")
    tpdos = []
    for n, item in enumerate(raw):
        where = f"{key}.tpdos[{n}]"
        item = c.table(item, where)
        c.unknown(item, where, ("cob_id", "period_ms", "data"))
        cob = c.integer(item.get("cob_id"), f"{where}.cob_id", 1, 0x7FF)
        period = c.integer(item.get("period_ms", 0), f"{where}.period_ms", 1, 65535)
        tpdos.append((cob, period, _hex(c, item.get("data", ""), f"{where}.data", 8)))
    raw = dev.get("objects", [])
    if not isinstance(raw, list) or len(raw) > MAX_ITEMS:
        c.fail(f"{key}.objects", f"expected an array of at most {MAX_ITEMS} tables")
    objects = []
    seen: set[tuple[int, int]] = set()
    for n, item in enumerate(raw):
        where = f"{key}.objects[{n}]"
        item = c.table(item, where)
        c.unknown(item, where, ("index", "subindex", "data", "access"))
        index = c.integer(item.get("index"), f"{where}.index", 0x1000, 0xFFFF)
        sub = c.integer(item.get("subindex", 0), f"{where}.subindex", 0, 255)
        if (index, sub) in seen:
            c.fail(f"{where}.index", f"0x{index:04X} sub {sub} is listed twice")
        seen.add((index, sub))
        data = _hex(c, item.get("data", ""), f"{where}.data", MAX_OBJECT)
        if not data:
            c.fail(f"{where}.data", "expected at least one byte")
        access = c.choice(item.get("access", "ro"), f"{where}.access", ("ro", "rw"))
        objects.append((index, sub, data, access))
    node_id = c.integer(dev.get("node_id", 1), f"{key}.node_id", 1, 127)
    return RecordedSpec(
        name=name, endpoint=endpoint_name, node_id=node_id, address=node_id,
        heartbeat_ms=c.integer(dev.get("heartbeat_ms", 1000), f"{key}.heartbeat_ms", 0, 65535),
        autostart=c.boolean(dev.get("autostart", False), f"{key}.autostart"),
        tpdos=tpdos, objects=objects,
        faults=check_fault_table(c, f"{key}.faults", dev.get("faults", {}), FAULT_RULES),
    )


def build_recorded(spec: RecordedSpec):
    """The node of a checked entry (not yet attached to a bus)."""
    from hilbench.fakes.canopen.recorded import RecordedNode, RecordedObject, RecordedPdo

    node = RecordedNode(spec.name, spec.node_id, heartbeat_ms=spec.heartbeat_ms, autostart=spec.autostart,
                        tpdos=[RecordedPdo(*p) for p in spec.tpdos],
                        objects=[RecordedObject(*o) for o in spec.objects])
    node.set_faults(**spec.faults)
    return node


__all__ = ["RECORDED", "RECORDED_KEYS", "RecordedSpec", "build_recorded", "check_recorded"]
