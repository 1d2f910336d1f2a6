"""The CANopen rover board's control commands as a fuzz target (:mod:`hilbench.bench.control_targets`):
``server-control-canopen``, and the node's part of ``server-control``."""

from __future__ import annotations

import random
from typing import Any

from hilbench.bench.control_targets import control_target

PROFILE: dict[str, Any] = {
    "endpoints": {"can": {"type": "can", "protocol": "can", "bitrate": 500_000}},
    "devices": [{"model": "stm32f767-rover-canopen", "name": "node", "endpoint": "can", "node_id": 2}],
}
COMMANDS = ("status", "nmt", "reset", "fault", "emcy", "bus")
#: A reboot waits for the node's boot-up: rare in sessions.
SLOW = ("reset",)


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the node (its name left out now and then: the only node answers)."""
    cmd = rng.choice(COMMANDS)
    while cmd in SLOW and rng.random() < 0.9:
        cmd = rng.choice(COMMANDS)
    req: dict[str, Any] = {"cmd": cmd}
    if rng.random() < 0.7:
        req["device"] = "node"
    if cmd == "nmt":
        req["state"] = rng.choice(("operational", "stopped", "pre-operational"))
    if cmd == "fault":
        req["knobs"] = rng.choice(({"silent": False}, {"heartbeat_stop": False}, {"sdo_abort": 0},
                                   {"stuck_odometry": False}))
    if cmd == "emcy" and rng.random() < 0.5:
        req.update(code=rng.choice((0x1000, 0x3100, 0xFF00)), register=0x80, data=rng.randbytes(2).hex())
    if cmd == "bus" and rng.random() < 0.5:
        req["knobs"] = rng.choice(({"error_rate": 0.0}, {"error_next": 0}, {"auto_recover": True}))
    return req


CONTROL = control_target("canopen", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "request"]
