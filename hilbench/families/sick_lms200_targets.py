"""The SICK LMS 200's control commands as a fuzz target (:mod:`hilbench.bench.control_targets`):
``server-control-sick-lms200``, and the unit's part of ``server-control``. (Its telegram decoder has its own
target, :mod:`hilbench.protocols.sick_lms200_targets`.)"""

from __future__ import annotations

import random
from typing import Any

from hilbench.bench.control_targets import control_target

PROFILE: dict[str, Any] = {
    "scene": {"walls": [[[-2.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-2.0, 2.0], [-2.0, -2.0]]]},
    "endpoints": {"lms": {"type": "pty", "protocol": "sick-lms200", "baud": 9600}},
    "devices": [{"model": "lms200", "name": "lms", "endpoint": "lms", "pose": {"x": 0.5, "y": -0.3}}],
}


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the unit: its state, or a fault knob at its harmless value."""
    req: dict[str, Any] = {"cmd": rng.choice(("scanner_status", "scanner_fault"))}
    if rng.random() < 0.9:
        req["device"] = "lms"
    if req["cmd"] == "scanner_fault":
        req["knobs"] = rng.choice(({"nak_next": 0}, {"no_ack": False}, {"bad_crc_rate": 0.0}, {"status": 0}))
    return req


CONTROL = control_target("sick-lms200", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "request"]
