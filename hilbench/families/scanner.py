"""What the laser-scanner families share: poses, range models, fault knobs, and where the scene comes from.

Every scanner of a bench sees the bench's world (:mod:`hilbench.bench.world`):
its ``[world]`` geometry and bodies. Profiles written before the world have a
``[scene]`` table with the same geometry keys; the RPLIDAR family still owns
that table (it declares it in ``profile_tables``) and it loads as the world's
geometry::

    [scene]                 # or, today, the same keys in [world]
    walls = [ [[-3.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]] ]   # polylines, metres
    wall_reflectivity = 0.8
    boxes = [ { center = [1.0, 1.0], size = [0.4, 0.3], heading = 30.0, reflectivity = 0.5 } ]
    circles = [ { center = [-1.0, 0.5], radius = 0.1 } ]
    moving = [ { path = [[1.0, -1.0], [1.0, 1.0]], speed = 0.5, radius = 0.2 } ]   # or size = [w, h]

Each scanner device has ``pose = { x = 0.5, y = 0.3, heading = 0.0 }`` (metres;
heading in degrees counter-clockwise from +x, the sensor's straight-ahead; or
``theta`` in radians): its world pose, or with ``body = "NAME"`` its mount pose on that body. Optional:
``seed``, ``noise`` (``sigma0_mm``, ``sigma_k``, ``dropout``) and
``max_range`` overrides, and ``faults`` (family-specific knobs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlRequestError
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.bench.knobs import KnobRules, check_fault_table, check_knobs, requested_knobs
from hilbench.bench.world import MAX_EDGES, SCENE_KEYS, check_scene

COMMON_DEVICE_KEYS = ("model", "name", "endpoint", "pose", "seed", "noise", "max_range", "faults")
NOISE_KEYS = ("sigma0_mm", "sigma_k", "dropout")


def scene_of(profile) -> Any:
    """The profile's checked scene (its ``[world]`` geometry, or its ``[scene]``; an empty one without)."""
    from hilbench.fakes.scene import Scene

    world = getattr(profile, "world", None)
    if world is not None and world.scene is not None:
        return world.scene
    return profile.tables.get("scene") or Scene()


@dataclass
class ScannerSpec(DeviceSpec):
    """A scanner device of a profile: pose, measurement model overrides, fault knobs."""

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0
    seed: int = 0
    noise: dict[str, float] = field(default_factory=dict)
    max_range: float | None = None
    faults: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)


class ScannerBusKind(BusKind):
    """A scanner's port: one unit, which paces its own link (its UART, or whole replies at the times it
    decides), so the medium delivers at once."""

    max_devices = 1
    one_device_reason = "one unit per port"
    #: Whether the unit paces its link itself (its UART at the link speed), as the manifest says.
    unit_paces_link: bool = True

    def paced(self, spec, requested: bool) -> bool:
        return False

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        return {"paced": True} if self.unit_paces_link else {}

    def unit(self, endpoint) -> Any:
        """The endpoint's unit (None before it is built)."""
        return next(iter(endpoint.devices.values()), None)

    def device_at(self, endpoint, address: int):
        if not endpoint.devices:
            raise KeyError(f"endpoint {endpoint.name!r} has no scanner")
        return self.unit(endpoint)


class ScannerUnits(FamilyAccess):
    """A scanner family's units on a running bench: ``bench.family("rplidar").unit()``."""

    def unit(self, name: str | None = None) -> Any:
        """A unit by profile name, or the only one."""
        return self.device(name)


class ScannerFamily(DeviceFamily):
    """What scanner families share: the common device keys, building, the manifest entry and the control
    commands ``scanner_status`` and ``scanner_fault``; subclasses check their options
    (:meth:`check_options`) and make their devices (:meth:`make_scanner`)."""

    device_word = "scanner"
    access = ScannerUnits
    #: Fault knobs and their rules (:mod:`hilbench.rules`: SWITCH, or a Rule for a count, rate or time).
    fault_knobs: KnobRules = {}
    #: The family's default model name.
    default_model: str = ""

    def check_common(self, c: Checker, key: str, dev: dict[str, Any], endpoint) -> dict[str, Any]:
        """Model, name, pose, seed, noise, max_range and faults of a scanner entry."""
        model = c.choice(dev.get("model", self.default_model), f"{key}.model", self.models)
        name = dev.get("name", endpoint.name)
        if not isinstance(name, str) or not name:
            c.fail(f"{key}.name", f"expected a string, got {name!r}")
        pose = c.table(dev.get("pose", {}), f"{key}.pose")
        c.unknown(pose, f"{key}.pose", ("x", "y", "heading", "theta"))
        if "theta" in pose:  # (radians, as the world's poses; heading is degrees)
            if "heading" in pose:
                c.fail(f"{key}.pose", "expected heading (degrees) or theta (radians), not both")
            pose = {**pose, "heading": math.degrees(c.number(pose["theta"], f"{key}.pose.theta", -2 * math.pi,
                                                             2 * math.pi))}
        noise = c.table(dev.get("noise", {}), f"{key}.noise")
        c.unknown(noise, f"{key}.noise", NOISE_KEYS)
        for nk, hi in (("sigma0_mm", 1000.0), ("sigma_k", 1.0), ("dropout", 1.0)):
            if nk in noise:
                c.number(noise[nk], f"{key}.noise.{nk}", 0.0, hi)
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), self.fault_knobs)
        return {
            "model": model, "name": name,
            "x": c.number(pose.get("x", 0.0), f"{key}.pose.x", -1e4, 1e4),
            "y": c.number(pose.get("y", 0.0), f"{key}.pose.y", -1e4, 1e4),
            "heading": c.number(pose.get("heading", 0.0), f"{key}.pose.heading", -360.0, 360.0),
            "seed": c.integer(dev.get("seed", 0), f"{key}.seed", 0, 2**31),
            "noise": dict(noise),
            "max_range": c.number(dev["max_range"], f"{key}.max_range", 0.01, 1000.0) if "max_range" in dev
            else None,
            "faults": faults,
        }

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[ScannerSpec]:
        common = self.check_common(c, key, dev, endpoint)
        options = self.check_options(c, key, dev, endpoint, common)
        return [ScannerSpec(name=common.pop("name"), endpoint=endpoint.name, options=options, **common)]

    def check_options(self, c: Checker, key: str, dev: dict[str, Any], endpoint,
                      common: dict[str, Any]) -> dict[str, Any]:
        """The family's own keys of a scanner entry (``common``, already checked, may be amended)."""
        return {}

    def range_model(self, spec: ScannerSpec, defaults: dict[str, float]):
        """The device's range model: the model's defaults with the profile's overrides."""
        from hilbench.fakes.scene import RangeModel

        n = spec.noise
        return RangeModel(
            min_range=defaults["min_range"],
            max_range=spec.max_range or defaults["max_range"],
            sigma0=n.get("sigma0_mm", defaults["sigma0"] * 1000.0) / 1000.0,
            sigma_k=n.get("sigma_k", defaults["sigma_k"]),
            dropout=n.get("dropout", defaults.get("dropout", 0.0)),
            seed=spec.seed,
        )

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[ScannerSpec], t: float) -> None:
        for spec in devices:
            dev = self.make_scanner(bench, endpoint, spec, t)
            endpoint.add_device(spec.name, dev)

    def make_scanner(self, bench, endpoint, spec: ScannerSpec, t: float):
        """The emulated unit of ``spec`` (not yet attached to the endpoint's medium)."""
        raise NotImplementedError

    def placement(self, bench, spec: ScannerSpec, range_defaults: dict[str, float]) -> tuple[Any, ...]:
        """What every unit is built with, in order: its name, the bench's world, its pose (on its body, if
        it has one: give ``body=spec.body`` too) and its range model (the model's ``range_defaults`` with the
        profile's overrides)."""
        return spec.name, bench.world.world, pose_of(spec), self.range_model(spec, range_defaults)

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: ScannerSpec, device, endpoint, profile) -> dict[str, Any]:
        return {**super().describe_device(spec, device, endpoint, profile),
                "pose": {"x": spec.x, "y": spec.y, "heading": spec.heading}}

    # ------------------------------------------------------------------ control channel

    def control(self, bench, device, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "scanner_status":
            return {"status": device.status()}
        if cmd == "scanner_fault":
            knobs = check_knobs(requested_knobs(req), self.fault_knobs, whole_counts=False)
            device.port.call_at(None, lambda: self.apply_faults(device, knobs))
            return {"faults": {**{k: getattr(device.faults, k) for k in self.fault_knobs}, **knobs}}
        raise ControlRequestError(f"unknown command {cmd!r}")

    def apply_faults(self, device, knobs: dict[str, Any]) -> None:
        """Turn checked fault knobs of ``device`` (in its medium's thread)."""
        for k, v in knobs.items():
            setattr(device.faults, k, v)


def pose_of(spec: ScannerSpec):
    from hilbench.fakes.scene import Pose

    return Pose(spec.x, spec.y, spec.heading)


__all__ = ["COMMON_DEVICE_KEYS", "MAX_EDGES", "SCENE_KEYS", "ScannerBusKind", "ScannerFamily", "ScannerSpec",
           "ScannerUnits", "check_scene", "pose_of", "scene_of"]
