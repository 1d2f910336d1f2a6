"""`hilbench labgrid env` without labgrid: each served endpoint gets the driver its bus kind names (the generic
labgrid modules name no family), and the environment imports the module that registers it."""

from __future__ import annotations

from hilbench import registry
from hilbench.bench.bus import BusKind, LabgridDriver
from hilbench.labgrid.config import DRIVERS_MODULE, environment


def _manifest(*endpoints: dict) -> dict:
    served = [{"baud": 1_000_000, "rfc2217": f"rfc2217://127.0.0.1:{40_000 + i}", **ep}
              for i, ep in enumerate(endpoints)]
    return {"name": "lab", "endpoints": served, "control": "127.0.0.1:39999"}


def _drivers(env: dict) -> dict[str, dict]:
    return {name: spec for entry in env["targets"]["main"]["drivers"] for name, spec in entry.items()
            if name != "SerialDriver"}


def test_the_bus_kind_names_the_endpoint_driver_and_its_module():
    env = environment(_manifest({"name": "arm", "protocol": "dynamixel", "protocol_version": 2},
                                {"name": "old", "protocol": "dynamixel", "protocol_version": 1},
                                {"name": "lidar", "protocol": "rplidar"}))
    # a Protocol 2.0 bus gets the Dynamixel family's driver; a 1.0 bus (which it cannot speak) and a scanner none
    assert _drivers(env) == {
        "DynamixelDriver": {"name": "arm-dxl", "bindings": {"console": "arm-console"}},
        "BenchControlDriver": {"name": "bench-control", "bindings": {"console": "control-console"}},
    }
    assert env["imports"] == [DRIVERS_MODULE, "hilbench.labgrid.dynamixel"]


def test_an_outside_bus_kind_brings_its_own_labgrid_driver():
    class BlinkBus(BusKind):
        protocol = "blink-lg"

        def labgrid_driver(self, endpoint):
            return LabgridDriver("acme_lab.labgrid", "BlinkDriver", "-blink")

    registry.bus_kinds.register("blink-lg", BlinkBus())
    try:
        env = environment(_manifest({"name": "b", "protocol": "blink-lg"}, {"name": "c", "protocol": "blink-lg"}))
    finally:
        registry.bus_kinds.unregister("blink-lg")
    assert [e for e in env["targets"]["main"]["drivers"] if "BlinkDriver" in e] == [
        {"BlinkDriver": {"name": "b-blink", "bindings": {"console": "b-console"}}},
        {"BlinkDriver": {"name": "c-blink", "bindings": {"console": "c-console"}}}]
    assert env["imports"] == [DRIVERS_MODULE, "acme_lab.labgrid"]  # once
