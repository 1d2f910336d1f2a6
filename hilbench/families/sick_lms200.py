"""The SICK LMS 200 family: an emulated LMS 200 on a pty (protocol ``sick-lms200``).

Profile schema::

    [endpoints.lms]
    type = "pty"
    protocol = "sick-lms200"
    baud = 9600                     # the power-up rate (hosts switch with mode 40/41/48)

    [[devices]]
    model = "lms200"
    endpoint = "lms"
    pose = { x = 0.5, y = 0.3, heading = 0.0 }   # heading = the sensor's 90° beam
    variant = [180, 50]             # angle ° and resolution 1/100 °: [100|180, 100|50|25]
    units = "mm"                    # or "cm"
    no_echo = 8191                  # value reported when nothing returns (top of the 13-bit field)
    faults = { nak_next = 0, no_ack = false, bad_crc_rate = 0.0, refuse_modes = false, status = 16,
               truncate_next = 0, ignore_stop_once = false }

The LMS paces its own UART at the current link speed. Control commands:
``scanner_status``, ``scanner_fault``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench.bench.checks import Checker
from hilbench.families.scanner import (
    COMMON_DEVICE_KEYS,
    ScannerBusKind,
    ScannerFamily,
    ScannerSpec,
    ScannerUnits,
)
from hilbench.rules import PROBABILITY, SWITCH, Rule

if TYPE_CHECKING:
    from hilbench.fakes.scanners.sick_lms200 import SickLms200

LMS_MODELS = ("lms200", "LMS200", "sick-lms200")
LMS_KEYS = ("variant", "units", "no_echo")
#: LMS 200 measurement model: 8 m / 80 m ranges, about 1 cm systematic error at short range.
LMS_RANGE = {"min_range": 0.0, "max_range": 80.0, "sigma0": 0.005, "sigma_k": 0.0}
FAULTS = {
    "nak_next": Rule(int, 0, 1000), "no_ack": SWITCH, "bad_crc_rate": PROBABILITY, "refuse_modes": SWITCH,
    "status": Rule(int, 0, 255), "truncate_next": Rule(int, 0, 1000), "ignore_stop_once": SWITCH,
}


class SickLms200BusKind(ScannerBusKind):
    """An LMS 200's RS-232 port (a pty), at 9600 baud until the host changes it."""

    protocol = "sick-lms200"
    endpoint_types = ("pty",)

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        baud = 9600 if value is None else value
        if baud != 9600:
            c.fail(key, f"expected 9600 (an LMS 200 starts at 9600 baud; hosts change it with mode 40/41/48), "
                        f"got {baud!r}")
        return baud

    def summary(self, endpoint) -> str:
        dev = self.unit(endpoint)
        baud = dev.baud if dev is not None else endpoint.spec.baud
        return f"sick-lms200, {baud} baud now (9600 at power-up)"


class LmsUnits(ScannerUnits):
    """The emulated units of a running bench: ``bench.family("sick-lms200")``."""

    family_name = "sick-lms200"

    def unit(self, name: str | None = None) -> SickLms200:
        return self.device(name)


class SickLms200Family(ScannerFamily):
    """The emulated LMS 200, one per ``sick-lms200`` endpoint."""

    name = "sick-lms200"
    access = LmsUnits
    joins = ("sick-lms200",)
    device_keys = (*COMMON_DEVICE_KEYS, *LMS_KEYS)
    models = LMS_MODELS
    default_model = "lms200"
    fault_knobs = FAULTS
    control_commands = {"scanner_status": "what the unit is doing (link speed, mode, variant, units)",
                        "scanner_fault": "turn fault knobs: " + ", ".join(FAULTS)}

    def check_options(self, c: Checker, key: str, dev: dict[str, Any], endpoint,
                      common: dict[str, Any]) -> dict[str, Any]:
        from hilbench.protocols.sick_lms200 import VARIANTS

        variant = dev.get("variant", [180, 50])
        if not isinstance(variant, list) or tuple(variant) not in VARIANTS:
            known = ", ".join(f"[{a}, {r}]" for a, r in VARIANTS)
            c.fail(f"{key}.variant", f"expected one of {known}, got {variant!r}")
        return {"variant": tuple(variant),
                "units": c.choice(dev.get("units", "mm"), f"{key}.units", ("mm", "cm")),
                "no_echo": c.integer(dev.get("no_echo", 8191), f"{key}.no_echo", 0, 8191)}

    def make_scanner(self, bench, endpoint, spec: ScannerSpec, t: float):
        from hilbench.fakes.scanners.sick_lms200 import LmsConfig, LmsFaults, SickLms200

        o = spec.options
        config = LmsConfig(angle=o["variant"][0], resolution=o["variant"][1], units_mm=o["units"] == "mm",
                           no_echo=o["no_echo"], faults=LmsFaults(seed=spec.seed, **spec.faults))
        return SickLms200(*self.placement(bench, spec, LMS_RANGE), config, t0=t, body=spec.body)

    def describe_device(self, spec: ScannerSpec, device, endpoint, profile) -> dict[str, Any]:
        out = super().describe_device(spec, device, endpoint, profile)
        out.update({"variant": list(spec.options["variant"]), "units": spec.options["units"],
                    "baud": device.baud if device is not None else 9600})
        return out


BUS_KIND = SickLms200BusKind()
FAMILY = SickLms200Family()

__all__ = ["BUS_KIND", "FAMILY", "LmsUnits", "LMS_MODELS", "SickLms200BusKind", "SickLms200Family"]
