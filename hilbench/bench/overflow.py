"""What a bench's bounded queues turned away: each server's limits and overflow counters, in one place.

Every per-client and per-device queue of a bench is bounded (docs/benchmarks/hostile-clients.md), and the
server that owns a queue counts what it refused, evicted, dropped, stalled on or timed out. :func:`overflow`
gathers those counters, read from each server's own ``status()`` (or ``counters()``), never counted a second
time, for the control channel's ``status`` and ``overflow`` commands and ``hilbench monitor``'s ``bench``
line::

    {"control": {"max_clients": 64, "refused": 0, "request_timeouts": 0, ...},
     "endpoints": {"can": {"tap": {"max_clients": 32, "max_buffer": 1048576, "bytes_dropped": 0, ...},
                           "socketcand": {"max_clients": 64, "refused": 0, "frames_dropped": 0, ...},
                           "medium": {"dropped_queue_full": 0},
                           "devices": {"rover": {...}}}}}

Per endpoint: ``tap`` (its traffic tap), each door of its host port that counts (a CAN port's ``socketcand``
server, a UDP port, a one-client TCP port), each network server (``rfc2217``), its line or bus
(``medium``: a CAN controller's full transmit queue) and ``devices`` whose family bounds a queue of its own
(:meth:`~hilbench.bench.family.DeviceFamily.overflow`: an XRCE agent's sessions, an RTPS participant's remote
participants, a board's receive FIFO).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

#: Keys of a server's status that count what overflowed (the limits are its ``max_*`` keys).
COUNTERS = frozenset((
    # clients: turned away, let go for a newcomer, accepted without a descriptor left
    "refused", "evicted", "out_of_descriptors",
    # data: dropped for a client (or a device) whose queue was full, replies dropped
    "bytes_dropped", "dropped", "dropped_bytes", "frames_dropped", "replies_dropped", "dropped_queue_full",
    # clients disconnected for taking nothing while their queue was full
    "stalled",
    # requests beyond a bound (socketcand: numbers out of range, too many subscriptions)
    "out_of_range", "too_many",
    # the control channel: timed out, idle, too long
    "request_timeouts", "reply_timeouts", "idle_closed", "too_long",
))


def pick(status: Mapping[str, Any]) -> dict[str, Any]:
    """A server's limits (``max_*``) and overflow counters (:data:`COUNTERS`), out of its status."""
    return {k: v for k, v in status.items() if k.startswith("max_") or k in COUNTERS}


def endpoint_overflow(bench: Any, ep: Any) -> dict[str, Any]:
    """One endpoint's servers, line and devices with their limits and overflow counters (see the module)."""
    out: dict[str, Any] = {}
    if ep.tap is not None:
        out["tap"] = pick(ep.tap.status())
    port = ep.port
    if hasattr(port, "status"):  # doors by kind (a CAN port: its socketcand server)
        out.update({kind: pick(st) for kind, st in port.status().items()})
    elif hasattr(port, "counters"):  # a UDP or TCP port's own
        out[port.kind] = pick(port.counters())
    for name, service in ep.services.items():
        if hasattr(service, "status"):
            out[name] = pick(service.status())
    stats = getattr(ep.medium, "stats", None)  # (a plug-in's medium may keep none)
    if dataclasses.is_dataclass(stats):
        medium = pick({f.name: getattr(stats, f.name) for f in dataclasses.fields(stats)})
        if medium:
            out["medium"] = medium
    devices = {}
    for name, device in ep.devices.items():
        own = bench.family_of(name).overflow(device, ep)
        if own:
            devices[name] = own
    if devices:
        out["devices"] = devices
    return out


def overflow(bench: Any, endpoint: str | None = None) -> dict[str, Any]:
    """The bench's overflow: the control channel's and each endpoint's (only ``endpoint``'s, if named)."""
    out: dict[str, Any] = {}
    if bench.control is not None:
        out["control"] = pick(bench.control.status())
    eps = [bench.endpoints[endpoint]] if endpoint is not None else list(bench.endpoints.values())
    out["endpoints"] = {ep.name: endpoint_overflow(bench, ep) for ep in eps}
    return out


def counted(entry: Mapping[str, Any]) -> dict[str, int]:
    """``{"tap.bytes_dropped": 12, ...}``: every overflow counter of an endpoint's entry (devices' too), by
    where it was counted, limits left out; for one-line reports."""
    out: dict[str, int] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, Mapping):
            for k, v in value.items():
                if k != "limits" and not k.startswith("max_"):
                    walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif isinstance(value, int) and not isinstance(value, bool):
            out[prefix] = value

    walk("", {k: v for k, v in entry.items() if k != "devices"})
    for name, dev in (entry.get("devices") or {}).items():
        walk(str(name), dev)
    return out


__all__ = ["COUNTERS", "counted", "endpoint_overflow", "overflow", "pick"]
