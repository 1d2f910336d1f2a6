"""The micro-ROS agent's control commands as a fuzz target (:mod:`hilbench.bench.control_targets`):
``server-control-micro-ros-agent``, and the agent's part of ``server-control``. (The agent's datagram
interface has its own target, :mod:`hilbench.fakes.xrce_agent.targets`.)"""

from __future__ import annotations

import random
from typing import Any

from hilbench.bench.control_targets import control_target

PROFILE: dict[str, Any] = {
    "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0}},
    "devices": [{"model": "micro-ros-agent", "name": "agent", "endpoint": "agent"}],
}


def request(rng: random.Random) -> dict[str, Any]:
    """One request a client sends the agent (its name left out now and then: the only agent answers)."""
    req: dict[str, Any] = {"cmd": rng.choice(("status", "fault"))}
    if rng.random() < 0.7:
        req["device"] = "agent"
    if req["cmd"] == "fault":
        req["knobs"] = rng.choice(({"drop_next": 0}, {"corrupt_status_agent": 0}))
    return req


CONTROL = control_target("micro-ros-agent", PROFILE, request)

__all__ = ["CONTROL", "PROFILE", "request"]
