"""The RPLIDAR family: an emulated Slamtec RPLIDAR A1 on a pty (protocol ``rplidar``), and the scene.

Profile schema::

    [scene]                         # owned by this family; see hilbench.families.scanner
    walls = [ [[-3.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]] ]

    [endpoints.lidar]
    type = "pty"
    protocol = "rplidar"
    baud = 115_200                  # the A1's UART; a host at another rate is heard as garbage

    [[devices]]
    model = "rplidar-a1"            # A1M8
    endpoint = "lidar"
    pose = { x = 0.5, y = 0.3, heading = 0.0 }
    motor = "dtr"                   # "dtr": runs while DTR is cleared (the dev kit's adapter);
                                    # "always": MOTOCTL tied high / a robot's UART; "off"
    spin_up = 0.5                   # s from motor start to a stable speed (SCAN waits for it)
    rpm = 330                       # 5.5 Hz nominal; speed_wander = 0.02 per revolution
    firmware = [1, 29]              # >= 1.24: the SDK discovers scan modes with GET_LIDAR_CONF
    typical_mode = 1                # 0 Standard, 1 Express (what the SDK's typical scan uses)
    seed = 0
    noise = { sigma0_mm = 0.5, sigma_k = 0.005, dropout = 0.0 }
    faults = { stall = false, health_status = 0, health_code = 0, sticky = false, corrupt_rate = 0.0,
               bad_flags_rate = 0.0, drop_byte_rate = 0.0, burst = false, out_of_range_angle = false }

The A1 paces its own UART, so the endpoint's medium delivers at once.
Control commands: ``scanner_status``, ``scanner_fault`` (knobs as above), ``dtr`` (set the
adapter's DTR as a host would: ``{"dtr": false}`` runs the motor).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlRequestError
from hilbench.families.scanner import (
    COMMON_DEVICE_KEYS,
    ScannerBusKind,
    ScannerFamily,
    ScannerSpec,
    ScannerUnits,
    check_scene,
)
from hilbench.rules import PROBABILITY, SWITCH, Rule

if TYPE_CHECKING:
    from hilbench.fakes.scanners.rplidar import RplidarA1

RPLIDAR_MODELS = ("rplidar-a1", "A1M8", "rplidar-a1m8")
RPLIDAR_KEYS = ("motor", "spin_up", "rpm", "speed_wander", "firmware", "typical_mode")
#: The A1's measurement model (datasheet: 0.15-12 m, < 1 % of the distance beyond 1.5 m).
A1_RANGE = {"min_range": 0.15, "max_range": 12.0, "sigma0": 0.0005, "sigma_k": 0.005}
FAULTS = {
    "stall": SWITCH, "health_status": Rule(int, 0, 2), "health_code": Rule(int, 0, 0xFFFF), "sticky": SWITCH,
    "corrupt_rate": PROBABILITY, "bad_flags_rate": PROBABILITY, "drop_byte_rate": PROBABILITY, "burst": SWITCH,
    "out_of_range_angle": SWITCH,
}


class RplidarBusKind(ScannerBusKind):
    """An RPLIDAR's UART (a pty)."""

    protocol = "rplidar"
    endpoint_types = ("pty",)

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        return c.integer(115_200 if value is None else value, key, 1200, 4_000_000)

    def summary(self, endpoint) -> str:
        dev = self.unit(endpoint)
        motor = dev.config.motor if dev is not None else "?"
        return f"rplidar A1, {endpoint.spec.baud} baud, motor {motor}"


class RplidarUnits(ScannerUnits):
    """The emulated units of a running bench: ``bench.family("rplidar")``."""

    family_name = "rplidar"

    def unit(self, name: str | None = None) -> RplidarA1:
        return self.device(name)


class RplidarFamily(ScannerFamily):
    """The emulated RPLIDAR A1, one per ``rplidar`` endpoint; owns the profile's ``[scene]`` table."""

    name = "rplidar"
    access = RplidarUnits
    joins = ("rplidar",)
    device_keys = (*COMMON_DEVICE_KEYS, *RPLIDAR_KEYS)
    models = RPLIDAR_MODELS
    default_model = "rplidar-a1"
    profile_tables = ("scene",)
    fault_knobs = FAULTS
    control_commands = {
        "scanner_status": "what the unit is doing (state, motor, health, revolutions)",
        "scanner_fault": "turn fault knobs: stall, health_status, health_code, sticky, corrupt_rate, bad_flags_rate, "
                 "drop_byte_rate, burst, out_of_range_angle",
        "dtr": "set the adapter's DTR as a host would (false runs the motor)",
    }

    def check_table(self, c: Checker, name: str, raw: Any) -> Any:
        return check_scene(c, raw, name)

    def check_options(self, c: Checker, key: str, dev: dict[str, Any], endpoint,
                      common: dict[str, Any]) -> dict[str, Any]:
        from hilbench.fakes.scanners.rplidar import MOTOR_POLICIES

        firmware = dev.get("firmware", [1, 29])
        if (not isinstance(firmware, list) or len(firmware) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in firmware)):
            c.fail(f"{key}.firmware", f"expected [major, minor] (e.g. [1, 29]), got {firmware!r}")
        return {
            "motor": c.choice(dev.get("motor", "dtr"), f"{key}.motor", MOTOR_POLICIES),
            "spin_up": c.number(dev.get("spin_up", 0.5), f"{key}.spin_up", 0.0, 10.0),
            "rpm": c.number(dev.get("rpm", 330.0), f"{key}.rpm", 60.0, 600.0),
            "speed_wander": c.number(dev.get("speed_wander", 0.02), f"{key}.speed_wander", 0.0, 0.2),
            "firmware": tuple(firmware),
            "typical_mode": c.integer(dev.get("typical_mode", 1), f"{key}.typical_mode", 0, 1),
        }

    # ------------------------------------------------------------------ bench (the A1 paces its own UART)

    def make_scanner(self, bench, endpoint, spec: ScannerSpec, t: float):
        from hilbench.fakes.scanners.rplidar import RplidarA1, RplidarConfig, RplidarFaults

        o = spec.options
        config = RplidarConfig(rpm=o["rpm"], motor=o["motor"], spin_up=o["spin_up"],
                               speed_wander=o["speed_wander"], firmware=o["firmware"],
                               typical_mode=o["typical_mode"], baud=endpoint.spec.baud,
                               faults=RplidarFaults(seed=spec.seed, **spec.faults))
        dev = RplidarA1(*self.placement(bench, spec, A1_RANGE), config, t0=t, body=spec.body)
        lines = getattr(endpoint.port, "port_state", None)
        if lines is not None:
            dev.dtr = lines.dtr  # the line's level now; changes arrive as on_port_event events
        return dev

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: ScannerSpec, device, endpoint, profile) -> dict[str, Any]:
        out = super().describe_device(spec, device, endpoint, profile)
        out.update({"motor": spec.options["motor"], "firmware": list(spec.options["firmware"]),
                    "baud": profile.endpoints[spec.endpoint].baud})
        return out

    # ------------------------------------------------------------------ control channel

    def control(self, bench, device, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "dtr":
            value = req.get("dtr")
            if not isinstance(value, bool):
                raise ControlRequestError("dtr: expected true or false")
            # The same path as hilbench run's shim: the host port's modem lines, heard by the device.
            ports = [h for h in device.port.medium.hosts if getattr(h, "port_state", None) is not None]
            if not ports:
                device.port.call_at(None, lambda: device.set_dtr(value))
            for host in ports:
                host.port_state.host_sets(dtr=value)
            return {"ok": True, "dtr": value}
        return super().control(bench, device, cmd, req)

    def apply_faults(self, device, knobs: dict[str, Any]) -> None:
        super().apply_faults(device, knobs)
        if "health_status" in knobs or "health_code" in knobs:
            device.set_health(device.faults.health_status, device.faults.health_code)


BUS_KIND = RplidarBusKind()
FAMILY = RplidarFamily()

__all__ = ["BUS_KIND", "FAMILY", "RplidarUnits", "RPLIDAR_MODELS", "RplidarBusKind", "RplidarFamily"]
