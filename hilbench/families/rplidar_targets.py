"""The RPLIDAR's control commands as a fuzz target (:mod:`hilbench.bench.control_targets`):
``server-control-rplidar``, and the unit's part of ``server-control``. (Its response decoder has its own
target, :mod:`hilbench.protocols.rplidar_targets`.)"""

from __future__ import annotations

import random
from typing import Any

from hilbench.bench.control_targets import control_target

PROFILE: dict[str, Any] = {
    "scene": {"walls": [[[-2.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-2.0, 2.0], [-2.0, -2.0]]]},
    "endpoints": {"lidar": {"type": "pty", "protocol": "rplidar", "baud": 115_200}},
    "devices": [{"model": "rplidar-a1", "name": "lidar", "endpoint": "lidar", "pose": {"x": 0.1, "y": 0.0},
                 "motor": "always"}],
}


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the unit: its state, a fault knob at its harmless value, DTR."""
    req: dict[str, Any] = {"cmd": rng.choice(("scanner_status", "scanner_fault", "dtr"))}
    if rng.random() < 0.9:
        req["device"] = "lidar"
    if req["cmd"] == "scanner_fault":
        req["knobs"] = rng.choice(({"burst": False}, {"stall": False}, {"corrupt_rate": 0.0}, {"health_status": 0}))
    if req["cmd"] == "dtr":
        req["dtr"] = rng.random() < 0.5
    return req


CONTROL = control_target("rplidar", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "request"]
