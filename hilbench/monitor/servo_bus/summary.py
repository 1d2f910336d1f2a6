"""The monitor's summary: one JSON-able document of everything it tracked.

Shape (``hilbench monitor SOURCE --summary --json``)::

    {"source": "...", "protocol": "dynamixel", "baud": 2000000, "timestamps": "measured",
     "duration_s": 12.5, "bytes": 528509,
     "packets": {"ping": 20, "read": 889, ..., "status": 21069, ...},   # every instruction name
     "crc_errors": 948,
     "problems": {"crc": 917, "bad_length": 31, "truncated": 4, "stuffing": 0, "garbage_bytes": 116524},
     "devices": {"1": {"model": 311, "model_name": "MX-64(2.0)", "firmware": 41, "state": "connected",
                       "never_answered": false, "requests": 1485, "replies": 1104, "misses": 34, ...,
                       "latency_ms": {"min": .., "mean": .., "p99": .., "max": .., "n": ..} | null,
                       "values": {"present_position": {"raw": 2098, "value": 184.39, "unit": "deg",
                                                       "how": "read", "age_s": 0.01}, ...}}, ...},
     "models": {"MX-64(2.0)": {"connected": 8, "disconnected": 0, "unknown": 0, "ids": [...]}, ...},
     "bus": {"bytes_per_s": .., "load": .., "packets_per_s": {...}, "crc_errors": .., "unanswered": ..,
             "unexpected_replies": .., "invalid_instructions": .., "bad_replies": ..,
             "main_cycle": {"instruction": "sync_read", "address": 132, "length": 4, "ids": [...],
                            "count": 1038, "rate_hz": .., "period_ms": {...}, "jitter_ms": ..} | null},
     "errors": {"counts": {"crc": .., "missed_reply": .., ...}, "last": ["[+00:01.234] error: ...", ...]}}

Instruction names are the spec sheet's snake_case names (§2.1). Rates are
averages over the whole source; they are null when the source has no times.
"""

from __future__ import annotations

from typing import Any

from hilbench.monitor.servo_bus.bus_state import (
    ServoBusState as BusTracker,  # a Protocol 2.0 or 1.0-framed tracker
)
from hilbench.transports.line_load import is_unpaced


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(x, nd)


def device_summary(tracker: BusTracker, dev, now: float | None) -> dict[str, Any]:
    """One device's entry of the summary."""
    lat = dev.latency() if tracker.timestamps else None
    last_seen = dev.last_seen
    values = {}
    for fv in dev.fields(observed_only=True):
        f = fv.field
        values[f.key] = {
            "raw": fv.raw,
            "value": _r(fv.value, 4) if isinstance(fv.value, float) else fv.value,
            "unit": f.unit,
            "how": fv.how,
            "age_s": _r(now - fv.t, 3) if (now is not None and fv.t is not None and tracker.timestamps) else None,
        }
    return {
        "model": dev.model,
        "model_name": dev.model_name,
        "firmware": dev.firmware,
        "model_from": dev.model_from,
        "state": dev.state,
        "never_answered": dev.never_answered,
        "requests": dev.requests,
        "replies": tracker.replies(dev),
        "misses": dev.misses,
        "consecutive_misses": dev.consecutive,
        "disconnects": dev.disconnects,
        "crc_errors": dev.crc_errors,
        "error_statuses": dev.error_statuses,
        "last_error": dev.last_error,
        "alert": dev.alert,
        "hardware_error": dev.hardware_error,
        "hardware_error_bits": dev.hardware_error_bits,
        "last_seen_s": _r(last_seen - tracker.t0, 6)
        if (last_seen is not None and tracker.t0 is not None and tracker.timestamps)
        else None,
        "latency_ms": {k: (v if k == "n" else round(v * 1000, 4)) for k, v in lat.items()} if lat else None,
        "values": values,
    }


def summary(
    tracker: BusTracker,
    *,
    source: str = "",
    protocol: str = "",
    timestamps: str | None = None,
    errors: int = 50,
) -> dict[str, Any]:
    """Everything the tracker knows, as plain JSON types (``errors``: how many log lines to include)."""
    duration = tracker.duration
    timed = tracker.timestamps and duration > 0
    counts = tracker.packet_counts()
    devices = {str(i): device_summary(tracker, tracker.devices[i], tracker.t_last) for i in sorted(tracker.devices)}
    models = {}
    for name, devs in tracker.models().items():
        entry = {"connected": 0, "disconnected": 0, "unknown": 0, "ids": [d.id for d in devs]}
        for d in devs:
            entry[d.state] += 1
        models[name] = entry
    main = tracker.main_cycle()
    cycle = None
    if main is not None:
        cycle = {
            "instruction": main.name,
            "address": main.ranges[0][0] if main.ranges else None,
            "length": main.ranges[0][1] if main.ranges else None,
            "ids": list(main.ids),
            "count": main.count,
            "rate_hz": _r(1 / main.iv_mean, 2) if main.iv_n and main.iv_mean > 0 else None,
            "period_ms": {"mean": _r(main.iv_mean * 1000), "min": _r(main.iv_min * 1000), "max": _r(main.iv_max * 1000)}
            if main.iv_n
            else None,
            "jitter_ms": _r(main.jitter * 1000, 4) if main.iv_n > 1 else None,
        }
    bps = tracker.bytes / duration if timed else None
    load = bps * 10 / tracker.baud if bps is not None and tracker.baud else None
    unpaced = is_unpaced(load)
    bus = {
        "bytes_per_s": _r(bps, 1),
        "load": None if unpaced else _r(load, 4),
        "unpaced": unpaced,
        "packets_per_s": {k: round(v / duration, 2) for k, v in counts.items() if v} if timed else None,
        "crc_errors": tracker.crc_errors,
        "unanswered": tracker.unanswered,
        "unexpected_replies": tracker.unexpected,
        "bad_replies": tracker.bad_replies,
        "invalid_instructions": tracker.invalid_instructions,
        "dropped_input_bytes": tracker.dropped_input,
        "requests_expecting_replies": tracker.requests_expecting_replies,
        "main_cycle": cycle,
    }
    return {
        "source": source,
        "protocol": protocol,
        "baud": tracker.baud,
        "timestamps": timestamps or ("measured" if tracker.timestamps else "none"),
        "duration_s": _r(duration, 6),
        "bytes": tracker.bytes,
        "packets": counts,
        "crc_errors": tracker.crc_errors,
        "problems": tracker.problems(),
        "devices": devices,
        "models": models,
        "bus": bus,
        "errors": {"counts": {k: v for k, v in tracker.log.counts.items() if v}, "last": tracker.log.lines(errors)},
    }


def print_summary(report: dict, console) -> None:
    """The summary as a person reads it: the bus, then one line per device."""
    from rich import box
    from rich.table import Table

    bus = report["bus"]
    packets = ", ".join(f"{k} {v}" for k, v in report["packets"].items() if v)
    if report["timestamps"] == "none":
        when = "no times (a raw dump: --baud gives it byte time)"
    else:
        when = f"{report['duration_s'] or 0:.3f} s ({report['timestamps']} times)"
    console.print(f"[bold]{report['source']}[/]: {report['bytes']} bytes, {when}", highlight=False)
    console.print(f"packets: {packets or 'none'}", highlight=False)
    load = ", unpaced" if bus.get("unpaced") else f", load {bus['load']:.1%}" if bus["load"] is not None else ""
    rate = f"{bus['bytes_per_s'] / 1000:.1f} kB/s{load}; " if bus["bytes_per_s"] is not None else ""
    console.print(f"bus: {rate}CRC errors {report['crc_errors']}, unanswered requests {bus['unanswered']}, "
                  f"unexpected replies {bus['unexpected_replies']}", highlight=False)
    cycle = bus["main_cycle"]
    if cycle:
        hz = f" at {cycle['rate_hz']} Hz, jitter {cycle['jitter_ms']} ms" if cycle["rate_hz"] else ""
        console.print(f"main cycle: {cycle['instruction']} {cycle['address']}/{cycle['length']} of "
                      f"{len(cycle['ids'])} IDs, {cycle['count']} times{hz}", highlight=False)
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 0), pad_edge=False, header_style="bold", show_edge=False)
    for col in ("ID", "model", "fw", "state", "req", "replies", "missed", "CRC", "err", "lat ms"):
        table.add_column(col, justify="left" if col in ("model", "state") else "right", no_wrap=True)
    never = []
    for dev_id, d in report["devices"].items():
        lat = d["latency_ms"]
        if d["never_answered"]:
            never.append(dev_id)
        table.add_row(dev_id, d["model_name"], "-" if d["firmware"] is None else str(d["firmware"]), d["state"],
                      str(d["requests"]), str(d["replies"]), str(d["misses"]), str(d["crc_errors"]),
                      str(d["error_statuses"]), f"{lat['mean']:.3f}" if lat else "-")
    console.print(table)
    if never:
        console.print(f"never answered: ID {', '.join(never)}", highlight=False)
    for line in report["errors"]["last"][:10]:
        console.print(line, markup=False, highlight=False)
