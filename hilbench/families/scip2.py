"""The SCIP 2.0 family: emulated Hokuyo units on TCP (UST-10LX) or a pty (URG-04LX), protocol ``scip2``.

Profile schema::

    [endpoints.ust]
    type = "tcp"                    # 127.0.0.1, a free port unless port = 10940 is given
    protocol = "scip2"

    [endpoints.urg]
    type = "pty"                    # USB CDC-ACM style: the baud rate does not matter
    protocol = "scip2"

    [[devices]]
    model = "ust-10lx"              # or "urg-04lx"
    endpoint = "ust"
    pose = { x = 0.5, y = 0.3, heading = 0.0 }   # heading = the front step (AFRT)
    clock_offset_ms = 0             # start of the 24-bit ms clock (16_700_000 tests the wrap soon)
    faults = { bad_sum_next = 0, truncate_next = 0, unstable_next = 0, burst = false }

Each reply goes out whole (one write), scans every 60000/rpm ms. Control
commands: ``scanner_status``, ``scanner_fault``.
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
from hilbench.rules import SWITCH, Rule

if TYPE_CHECKING:
    from hilbench.fakes.scanners.scip import ScipScanner

SCIP_MODELS = ("ust-10lx", "urg-04lx", "UST-10LX", "URG-04LX")
SCIP_KEYS = ("clock_offset_ms",)
FAULTS = {"bad_sum_next": Rule(int, 0, 1000), "truncate_next": Rule(int, 0, 1000), "unstable_next": Rule(int, 0, 1000),
          "burst": SWITCH}


class Scip2BusKind(ScannerBusKind):
    """A SCIP 2.0 unit's TCP port (UST-10LX) or USB serial port (URG-04LX)."""

    protocol = "scip2"
    endpoint_types = ("tcp", "pty")
    unit_paces_link = False  # each reply goes out whole

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int | None:
        if value is None:
            return None
        return c.integer(value, key, 1200, 12_000_000)

    def summary(self, endpoint) -> str:
        dev = self.unit(endpoint)
        return f"scip2, {dev.unit.name if dev is not None else '?'}"


class ScipUnits(ScannerUnits):
    """The emulated units of a running bench: ``bench.family("scip2")``."""

    family_name = "scip2"

    def unit(self, name: str | None = None) -> ScipScanner:
        return self.device(name)


class Scip2Family(ScannerFamily):
    """The emulated SCIP 2.0 units, one per ``scip2`` endpoint."""

    name = "scip2"
    access = ScipUnits
    joins = ("scip2",)
    device_keys = (*COMMON_DEVICE_KEYS, *SCIP_KEYS)
    models = SCIP_MODELS
    default_model = "ust-10lx"
    fault_knobs = FAULTS
    control_commands = {"scanner_status": "what the unit is doing (laser, continuous scans, clock)",
                        "scanner_fault": "turn fault knobs: " + ", ".join(FAULTS)}

    def check_options(self, c: Checker, key: str, dev: dict[str, Any], endpoint,
                      common: dict[str, Any]) -> dict[str, Any]:
        model = common["model"].lower()
        if endpoint.type == "tcp" and model == "urg-04lx":
            c.fail(f"{key}.model", "a URG-04LX has no Ethernet port: put it on a pty endpoint")
        common["model"] = model
        return {"clock_offset_ms": c.integer(dev.get("clock_offset_ms", 0), f"{key}.clock_offset_ms", 0,
                                             (1 << 24) - 1)}

    def make_scanner(self, bench, endpoint, spec: ScannerSpec, t: float):
        from hilbench.fakes.scanners.scip import MODELS, ScipConfig, ScipFaults, ScipScanner

        port = endpoint.port
        unit = MODELS[spec.model]
        defaults = {"min_range": unit.dmin / 1000, "max_range": unit.dmax / 1000, "sigma0": unit.sigma0,
                    "sigma_k": 0.0}
        config = ScipConfig(clock_offset_ms=spec.options["clock_offset_ms"],
                            faults=ScipFaults(seed=spec.seed, **spec.faults))
        connected = (lambda p=port: p.client is not None) if hasattr(port, "client") else None
        session = (lambda p=port: p.connections) if hasattr(port, "connections") else None
        return ScipScanner(*self.placement(bench, spec, defaults), unit, config, t0=t, body=spec.body,
                           connected=connected, session=session)

    def describe_device(self, spec: ScannerSpec, device, endpoint, profile) -> dict[str, Any]:
        out = super().describe_device(spec, device, endpoint, profile)
        if endpoint is not None:
            out.update({k: v for k, v in endpoint.port.describe().items() if k in ("host", "port", "path")})
        return out


BUS_KIND = Scip2BusKind()
FAMILY = Scip2Family()

__all__ = ["BUS_KIND", "FAMILY", "ScipUnits", "SCIP_MODELS", "Scip2BusKind", "Scip2Family"]
