"""The rover board's control commands as a fuzz target (:mod:`hilbench.bench.control_targets`):
``server-control-stm32-rover``, and the board's part of ``server-control``."""

from __future__ import annotations

import random
from typing import Any

from hilbench.bench.control_targets import control_target

PROFILE: dict[str, Any] = {
    "endpoints": {"rover": {"type": "pty", "protocol": "vel2d", "baud": 115_200}},
    "devices": [{"model": "stm32f767-rover", "name": "rover", "endpoint": "rover", "preset": "freertos-50-30",
                 "output": "v3"}],
}
COMMANDS = ("status", "button", "reset", "fault", "log", "wait_report", "micro_ros")
#: Commands that change the board's state and wait for it to settle (milliseconds each): rare in sessions, so a
#: session costs about what its parsing and dispatch cost.
SLOW = ("button", "reset")


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the board (its name left out now and then: the only board answers)."""
    cmd = rng.choice(COMMANDS)
    while cmd in SLOW and rng.random() < 0.9:
        cmd = rng.choice(COMMANDS)
    req: dict[str, Any] = {"cmd": cmd}
    if rng.random() < 0.7:
        req["device"] = "rover"
    if cmd == "fault":
        req["knobs"] = rng.choice(({"drop_rate": 0.0}, {"corrupt_next": 1}, {"stall": 0.0}, {"drop_next": 0}))
    if cmd == "wait_report":
        req.update(timeout=rng.choice((0, 0.001, 5, 3600)), after=rng.randrange(0, 10))
    if cmd == "micro_ros" and rng.random() < 0.3:
        req["zeroed_next"] = rng.randrange(0, 3)
    return req


CONTROL = control_target("stm32-rover", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "request"]
