"""The CAN monitor's summary: one JSON-able document, and the same as text for a person.

Shape (``hilbench monitor SOURCE --summary --json`` on a CAN source)::

    {"source": "...", "protocol": "can", "bitrate": 500000, "timestamps": "measured", "duration_s": 5.0,
     "bytes": 51200, "frames": {"total": 3200, "data": 3190, "remote": 0, "extended": 0, "error": 10},
     "dropped_bytes": 0, "lost_frames": 0,
     "bus": {"load": 0.052, "mean_load": 0.05, "peak_load": 0.061, "frames_per_s": 640.0,
             "peak_frames_per_s": 655.0, "bits": 360000},
     "error_frames": {"total": 10, "classes": {"protocol": 8, "bus-error": 8, "bus-off": 1, ...}},
     "ids": {"0x182": {"label": "TPDO1 node 2", "name": "WheelEncoders_02", "count": 250, "rate_hz": 50.0,
                       "period_ms": {"mean": 20.0, "min": 19.9, "max": 20.1}, "jitter_ms": 0.03,
                       "max_gap_ms": 20.1, "dlc": 8, "dlc_changes": 0, "last": "00 00 ...",
                       "signals": {"enc_fr": 12, ...}, "decode_errors": 0, "sources": {"rover": 250}}, ...},
     "nodes": {"2": {"nmt_state": "OPERATIONAL", "heartbeats": 5, "heartbeat_period_ms": 1000,
                     "period_from": "sdo" | "measured" | null, "heartbeat_jitter_ms": 0.1,
                     "heartbeat_misses": 0, "lost": false, "losses": 0, "bootups": 1, "emcy": 2,
                     "last_emcy": {...}, "error_register": 0,
                     "sdo": {"uploads": 4, "downloads": 1, "aborts": 1}}},
     "sdo": {"transfers": 6, "aborts": 1, "last": [{"node": 2, "index": "0x1018", "subindex": 1,
             "name": "...", "direction": "upload", "kind": "expedited", "size": 4, "value": 4735566,
             "abort": null, "abort_text": null, "aborted_by": null, "duration_ms": 0.3}, ...]},
     "emcy": [{"t_s": 1.2, "node": 2, "text": "..."}, ...],
     "nmt_commands": 1,
     "events": {"counts": {"sdo": 6, ...}, "last": ["[+00:01.234] node 2 SDO upload ...", ...]}}

Times ``*_s`` count from the first frame; rates and loads are null when the
source has no times, loads also without a bitrate (``--baud``).
"""

from __future__ import annotations

from typing import Any

from hilbench.monitor.can.tracker import CanTracker
from hilbench.protocols import canopen as co
from hilbench.transports.line_load import is_unpaced


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(x, nd)


def _ms(x: float | None) -> float | None:
    return None if x is None else round(x * 1000, 3)


def stamp(tracker: CanTracker, t: float) -> str:
    """``[+MM:SS.mmm]`` from the first frame."""
    if tracker.t0 is None or not tracker.timestamps:
        return "[--:--.---]"
    dt = max(0.0, t - tracker.t0)
    return f"[+{int(dt // 60):02d}:{dt % 60:06.3f}]"


def _value(v: Any) -> Any:
    if isinstance(v, float):
        return round(v, 6)
    return v


def id_summary(tracker: CanTracker, stats) -> dict[str, Any]:
    """One identifier's entry of the summary."""
    iv = stats.intervals
    timed = tracker.timestamps and iv.n > 0
    return {
        "label": stats.label or None,
        "name": stats.name,
        "count": stats.count,
        "rate_hz": _r(stats.rate(), 3) if tracker.timestamps else None,
        "period_ms": {"mean": _ms(iv.mean), "min": _ms(iv.min), "max": _ms(iv.max)} if timed else None,
        "jitter_ms": _ms(iv.std) if timed and iv.n > 1 else None,
        "max_gap_ms": _ms(iv.max) if timed else None,
        "dlc": stats.dlc,
        "dlc_changes": stats.dlc_changes,
        "remote": stats.remote,
        "last": stats.data.hex(" ").upper(),
        "signals": {k: _value(v) for k, v in stats.signals.items()},
        "decode_errors": stats.decode_errors,
        "last_decode_error": stats.last_decode_error or None,
        "sources": dict(stats.sources),
    }


def node_summary(tracker: CanTracker, node) -> dict[str, Any]:
    """One CANopen node's entry of the summary."""
    period = node.period()
    return {
        "nmt_state": node.state_name,
        "heartbeats": node.heartbeats,
        "heartbeat_period_ms": _ms(period),
        "period_from": "sdo" if node.configured_ms else ("measured" if period else None),
        "heartbeat_jitter_ms": _ms(node.intervals.std) if node.intervals.n > 1 else None,
        "heartbeat_misses": node.misses,
        "lost": node.lost,
        "losses": node.losses,
        "bootups": node.bootups,
        "emcy": node.emcy,
        "last_emcy": ({**node.last_emcy, "t_s": _r(node.last_emcy["t"] - tracker.t0, 6)
                       if tracker.t0 is not None and tracker.timestamps else None}
                      if node.last_emcy else None),
        "error_register": node.error_register,
        "node_guarding_requests": node.guarding,
        "sdo": {"uploads": node.sdo_uploads, "downloads": node.sdo_downloads, "aborts": node.sdo_aborts},
    }


def transfer_summary(tracker: CanTracker, tr) -> dict[str, Any]:
    """One SDO transfer's entry of the summary."""
    value = tr.value()
    return {
        "node": tr.node,
        "index": f"0x{tr.index:04X}",
        "subindex": tr.subindex,
        "name": tracker.object_name(tr.node, tr.index, tr.subindex),
        "direction": tr.direction,
        "kind": tr.kind,
        "size": tr.size,
        "value": value,
        "data": bytes(tr.data).hex(" ").upper() if tr.data and value is None else None,
        "abort": f"0x{tr.abort:08X}" if tr.abort else None,
        "abort_text": co.abort_text(tr.abort) if tr.abort else None,
        "aborted_by": tr.aborted_by or None,
        "duration_ms": _ms(tr.t_end - tr.t_start) if tracker.timestamps and tr.t_end is not None else None,
    }


def summary(tracker: CanTracker, *, source: str = "", timestamps: str | None = None, errors: int = 50
            ) -> dict[str, Any]:
    """The JSON summary (see the module docstring); ``errors`` caps the event and transfer lists."""
    tr = tracker
    recent = tr.recent()
    t0 = tr.t0
    emcy = [{"t_s": _r(e.t - t0, 6) if t0 is not None and tr.timestamps else None, "node": e.node, "text": e.text}
            for e in tr.events if e.kind == "emcy"][-errors:]
    ids = sorted(tr.ids.values(), key=lambda s: (s.extended, s.can_id))
    return {
        "source": source,
        "protocol": "can",
        "bitrate": tr.baud,
        "timestamps": timestamps or ("measured" if tr.timestamps else "none"),
        "duration_s": _r(tr.duration(), 6),
        "bytes": tr.bytes,
        "frames": {"total": tr.frames, "data": tr.data_frames, "remote": tr.remote_frames,
                   "extended": tr.extended_frames, "error": tr.error_frames},
        "dropped_bytes": tr.dropped_bytes,
        "lost_frames": tr.lost_frames,
        "bus": {
            **_loads(tr),
            "frames_per_s": _r(recent[2] / recent[0], 1) if recent else None,
            "peak_frames_per_s": _r(tr.peak_fps, 1) if tr.timestamps else None,
            "bits": tr.bits,
        },
        "error_frames": {"total": tr.error_frames, "classes": dict(tr.error_classes)},
        "ids": {s.key: id_summary(tr, s) for s in ids},
        "ids_not_tracked": tr.ids_dropped,
        "nodes": {str(n): node_summary(tr, node) for n, node in sorted(tr.nodes.items())},
        "sdo": {"transfers": tr.transfer_count, "aborts": sum(1 for t in tr.transfers if t.abort),
                "last": [transfer_summary(tr, t) for t in list(tr.transfers)[-errors:]]},
        "emcy": emcy,
        "nmt_commands": tr.nmt_commands,
        "events": {"counts": dict(tr.event_counts),
                   "last": [f"{stamp(tr, e.t)} {e.text}" for e in list(tr.events)[-errors:]]},
    }


def _loads(tr: CanTracker) -> dict[str, Any]:
    """Load now, mean and peak; all null with ``unpaced`` true when one is more than the bus carries."""
    loads = (tr.load(), tr.mean_load(), tr.peak_load if tr.baud and tr.timestamps else None)
    unpaced = is_unpaced(*loads)
    return {**{k: None if unpaced else _r(v, 4) for k, v in zip(("load", "mean_load", "peak_load"), loads,
                                                                 strict=True)},
            "unpaced": unpaced}


def print_summary(report: dict[str, Any], console: Any) -> None:
    """The summary as a person reads it."""
    from rich.table import Table

    f = report["frames"]
    bus = report["bus"]
    rate = f"{report['bitrate']} bit/s" if report["bitrate"] else "bitrate unknown (--baud)"
    console.print(f"[bold]{report['source']}[/]: CAN, {rate}, {f['total']} frames "
                  f"({f['error']} error frames) in {report['duration_s'] or 0:.3f} s", highlight=False)
    if bus.get("unpaced"):
        console.print(f"bus unpaced (more bits per second than {rate}); {bus['frames_per_s'] or 0:.0f} frames/s",
                      highlight=False)
    elif bus["mean_load"] is not None:
        console.print(f"bus load {bus['load']:.1%} now, {bus['mean_load']:.1%} mean, {bus['peak_load']:.1%} peak; "
                      f"{bus['frames_per_s'] or 0:.0f} frames/s", highlight=False)
    if report["dropped_bytes"] or report["lost_frames"]:
        console.print(f"[yellow]dropped {report['dropped_bytes']} bytes, lost {report['lost_frames']} frames[/]")
    table = Table(title="identifiers", title_justify="left", box=None, pad_edge=False)
    for col in ("ID", "what", "count", "Hz", "period ms", "jitter ms", "last / signals"):
        table.add_column(col, no_wrap=col != "last / signals", justify="right" if col in ("count", "Hz") else "left")
    for key, s in report["ids"].items():
        period = s["period_ms"]["mean"] if s["period_ms"] else None
        signals = ", ".join(f"{k}={v}" for k, v in s["signals"].items()) or s["last"]
        table.add_row(key, s["name"] or s["label"] or "", str(s["count"]),
                      f"{s['rate_hz']:.1f}" if s["rate_hz"] else "-", f"{period:.2f}" if period else "-",
                      f"{s['jitter_ms']:.3f}" if s["jitter_ms"] is not None else "-", signals)
    console.print(table)
    if report["nodes"]:
        nodes = Table(title="CANopen nodes", title_justify="left", box=None, pad_edge=False)
        for col in ("node", "state", "heartbeats", "period ms", "misses", "boot-ups", "EMCY", "SDO up/down/abort"):
            nodes.add_column(col)
        for n, s in report["nodes"].items():
            nodes.add_row(n, s["nmt_state"], str(s["heartbeats"]), str(s["heartbeat_period_ms"] or "-"),
                          str(s["heartbeat_misses"]), str(s["bootups"]), str(s["emcy"]),
                          f"{s['sdo']['uploads']}/{s['sdo']['downloads']}/{s['sdo']['aborts']}")
        console.print(nodes)
    if report["error_frames"]["total"]:
        classes = ", ".join(f"{k} {v}" for k, v in report["error_frames"]["classes"].items())
        console.print(f"[red]error frames: {report['error_frames']['total']} ({classes})[/]", highlight=False)
    for line in report["events"]["last"][-15:]:
        console.print(f"  {line}", highlight=False)


__all__ = ["print_summary", "summary"]
