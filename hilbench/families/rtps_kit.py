"""What the families that speak RTPS share (a kit): the default domain and the ``peers`` profile key.

The FreeRTPS nodes (:mod:`hilbench.families.freertps`) and the micro-ROS agent's RTPS bridge
(:mod:`hilbench.families.micro_ros_agent`) are participants of one DDS domain; both read these the same way.
"""

from __future__ import annotations

from typing import Any

from hilbench.bench.checks import Checker

#: The default domain: non-zero, so the nodes do not meet a real DDS on the machine (domain 0).
DEFAULT_DOMAIN = 42


def check_peers(c: Checker, key: str, raw: Any) -> list[str]:
    """A list of peer hosts (``"127.0.0.1"``) or ``"host:port"`` strings (default: 127.0.0.1)."""
    if raw is None:
        return ["127.0.0.1"]
    if not isinstance(raw, list) or not raw:
        c.fail(key, f"expected a list of \"host\" or \"host:port\" strings, got {raw!r}")
    for i, peer in enumerate(raw):
        if not isinstance(peer, str) or not peer:
            c.fail(f"{key}[{i}]", f"expected \"host\" or \"host:port\", got {peer!r}")
        if ":" in peer:
            c.address(peer, f"{key}[{i}]")
    return list(raw)


__all__ = ["DEFAULT_DOMAIN", "check_peers"]
