"""The blinker family: its profile keys, how it builds boards, what the manifest says of them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess


@dataclass
class BlinkerSpec(DeviceSpec):
    board_id: int = 1
    period_ms: float = 100.0


class BlinkerFamily(DeviceFamily):
    name = "blinker"
    joins = ("blink",)  # the bus kind of bus.py
    device_keys = ("model", "name", "endpoint", "board_id", "period_ms")
    models = ("acme-blinker",)
    device_word = "blinker"
    control_commands = {"blinks": "how many times the board blinked"}

    def check_devices(self, c, key, raw, endpoint, profile) -> list[BlinkerSpec]:
        c.choice(raw.get("model", "acme-blinker"), f"{key}.model", self.models)
        return [BlinkerSpec(
            name=raw.get("name", endpoint.name),
            endpoint=endpoint.name,
            model="acme-blinker",
            board_id=c.integer(raw.get("board_id", 1), f"{key}.board_id", 1, 99),
            period_ms=c.number(raw.get("period_ms", 100.0), f"{key}.period_ms", 1.0, 10_000.0),
        )]

    def build(self, bench, endpoint, devices: list[BlinkerSpec], t: float) -> None:
        from hilbench_example.device import Blinker

        for spec in devices:
            endpoint.add_device(spec.name, Blinker(spec.name, spec.board_id, spec.period_ms))  # onto the bus

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        for dev in devices.values():
            dev.start(t)

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for dev in devices.values():
            dev.stop()

    def describe_device(self, spec: BlinkerSpec, device, endpoint, profile) -> dict[str, Any]:
        return {**super().describe_device(spec, device, endpoint, profile), "board_id": spec.board_id,
                "period_ms": spec.period_ms}

    def control(self, bench, device, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        return {"blinks": device.blinks}


class Blinkers(FamilyAccess):
    """``bench.family("blinker")``: the blinker boards of a running bench."""

    family_name = "blinker"

    def blinker(self, name: str | None = None):
        """A board by profile name, or the only one."""
        return self.device(name)


BlinkerFamily.access = Blinkers
FAMILY = BlinkerFamily()
