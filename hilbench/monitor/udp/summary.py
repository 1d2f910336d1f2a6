"""The UDP monitor's JSON summary and its printed form."""

from __future__ import annotations

import statistics
from typing import Any

from hilbench.monitor.udp.tracker import UdpTracker
from hilbench.protocols import cdr
from hilbench.protocols import rtps as r
from hilbench.protocols import xrce_dds as x


def _ms(vals: list[float]) -> dict[str, Any] | None:
    if not vals:
        return None
    return {"count": len(vals), "mean": round(statistics.fmean(vals) * 1e3, 3), "min": round(min(vals) * 1e3, 3),
            "max": round(max(vals) * 1e3, 3)}


def _value(type_name: str | None, raw: bytes, le: bool) -> Any:
    t = cdr.ros_type(type_name) if type_name else None
    if t is None:
        return None
    value, _ = t.try_decode(raw, le)
    return value


def xrce_summary(tr: UdpTracker) -> dict[str, Any]:
    timed = tr.timestamps
    sessions = []
    for s in tr.xrce.sessions.values():
        topics = []
        for (direction, oid), rate in s.samples.items():
            topic, type_name = s.topic_of(oid)
            raw, le = s.last_sample.get((direction, oid), (b"", True))
            topics.append({"object_id": oid.hex().upper(), "object": x.object_text(oid), "topic": topic,
                           "type": type_name, "direction": direction, **rate.summary(timed),
                           "last": _value(type_name, raw, le)})
        streams = []
        for (direction, sid), st in sorted(s.streams.items()):
            d = {"direction": direction, "stream_id": f"0x{sid:02X}",
                 "kind": "reliable" if sid >= 0x80 else "best-effort", **st.summary()}
            if sid >= 0x80:
                d["window"] = s.windows.get((direction, sid))
            streams.append(d)
        sessions.append({
            "client": s.client, "agent": s.agent, "client_key": s.key.hex().upper() if s.key else None,
            "session_id": f"0x{s.session_id:02X}" if s.session_id is not None else None, "state": s.state,
            "established_s": None if s.established_t is None or tr.t0 is None else round(s.established_t - tr.t0, 6),
            "datagrams": dict(s.datagrams), "submessages": dict(sorted(s.submessages.items())),
            "entities": [{"object_id": oid.hex().upper(), **{k: (v.hex().upper() if isinstance(v, bytes) else v)
                                                          for k, v in e.items() if k != "created_t"}}
                         for oid, e in s.entities.items()],
            "streams": streams, "topics": topics, "nacked": s.nacked, "resets": s.resets, "flags": dict(s.flags),
            "latency_ms": {k: _ms(v) for k, v in s.latencies.items() if timed},
        })
    return {"agents": sorted(tr.xrce.agents), "agent_ports": sorted(tr.agent_ports), "sessions": sessions}


def rtps_summary(tr: UdpTracker) -> dict[str, Any]:
    timed = tr.timestamps
    parts = []
    for p in tr.rtps.participants.values():
        parts.append({"guid_prefix": r.guid_text(p.prefix), "vendor": r.VENDOR_NAMES.get(p.vendor, p.vendor.hex()),
                      "name": p.name, "locators": p.locators, "lease_s": p.lease_s, "datagrams": p.datagrams,
                      "spdp": p.spdp.summary(timed), "restarts": p.restarts})
    endpoints = []
    for guid, ep in tr.rtps.endpoints.items():
        d = {"guid": r.guid_text(guid), "kind": "writer" if ep.writer else "reader", "topic": ep.topic,
             "type": ep.type_name, "reliable": ep.reliable}
        w = tr.rtps.writers.get(guid)
        if w is not None:
            d.update(samples=w.samples.summary(timed), sequence=w.seq.summary(), gap_declared=w.gaps)
            if len(w.last_payload) >= 4:
                d["last"] = _value(ep.type_name, w.last_payload[4:], w.last_payload[1] & 1 == 1)
        endpoints.append(d)
    unknown_writers = [{"guid": r.guid_text(g), "samples": w.samples.summary(timed), "sequence": w.seq.summary()}
                       for g, w in tr.rtps.writers.items() if g not in tr.rtps.endpoints]
    return {"participants": parts, "endpoints": endpoints, "topics": list(tr.rtps.topics().values()),
            "writers_without_discovery": unknown_writers, "submessages": dict(sorted(tr.rtps.submessages.items()))}


def summary(tr: UdpTracker, *, source: str, protocol: str, timestamps: str | None, errors: int = 50) -> dict[str, Any]:
    """The JSON summary of everything the tracker saw."""
    dur = tr.duration
    classes = {}
    for name, (n, nbytes) in tr.classes.items():
        if n:
            c = {"datagrams": n, "bytes": nbytes}
            rate = tr.rates[name].rate() if tr.timestamps else None
            if rate is not None:
                c["rate_hz"] = round(rate, 3)
            classes[name] = c
    return {
        "source": source, "protocol": protocol, "timestamps": timestamps,
        "duration_s": round(dur, 6) if dur is not None and tr.timestamps else None,
        "datagrams": tr.datagrams, "bytes": tr.bytes, "lost_bytes": tr.lost_bytes,
        "classes": classes, "flags": dict(sorted(tr.flags.items())),
        "zeroed_datagrams": tr.flags.get("xrce.zero_fill", 0),
        "senders": {k: {"datagrams": v[0], "bytes": v[1]} for k, v in sorted(tr.senders.items())},
        "xrce": xrce_summary(tr), "rtps": rtps_summary(tr),
        "events": [{"t": round(t - (tr.t0 or 0), 6) if tr.timestamps else None, "kind": k, "text": text}
                   for t, k, text in list(tr.events)[-errors:]],
        "events_total": tr.events_total,
    }


def print_summary(report: dict[str, Any], console: Any) -> None:
    """The summary as tables on a rich console."""
    from rich.table import Table

    console.print(f"[bold]{report['source']}[/]: {report['datagrams']} datagrams, {report['bytes']} bytes"
                  + (f" in {report['duration_s']:.3f} s" if report.get("duration_s") else ""), highlight=False)
    t = Table("class", "datagrams", "bytes", "rate/s", title="Traffic")
    for name, c in report["classes"].items():
        t.add_row(name, str(c["datagrams"]), str(c["bytes"]), str(c.get("rate_hz", "-")))
    console.print(t)
    if report["flags"]:
        f = Table("flag", "count", title="Integrity flags")
        for name, n in report["flags"].items():
            f.add_row(f"[bold red]{name}[/]" if name == "xrce.zero_fill" else name, str(n))
        console.print(f)
    xr = report["xrce"]
    if xr["sessions"]:
        s = Table("client", "agent", "key", "session", "state", "entities", "flags", title="XRCE sessions")
        for ses in xr["sessions"]:
            s.add_row(ses["client"], ses["agent"], str(ses["client_key"]), str(ses["session_id"]), ses["state"],
                      str(len(ses["entities"])), ", ".join(f"{k} {v}" for k, v in ses["flags"].items()) or "-")
        console.print(s)
        tp = Table("client", "object", "topic", "dir", "samples", "rate/s", title="XRCE topics")
        for ses in xr["sessions"]:
            for top in ses["topics"]:
                tp.add_row(ses["client"], top["object"], str(top["topic"]), top["direction"], str(top["count"]),
                           str(top.get("rate_hz", "-")))
        st = Table("client", "dir", "stream", "received", "lost", "dup", "retx", "window", title="XRCE streams")
        for ses in xr["sessions"]:
            for strm in ses["streams"]:
                st.add_row(ses["client"], strm["direction"], strm["stream_id"], str(strm["received"]),
                           str(strm["lost"]), str(strm["duplicates"]), str(strm["retransmissions"]),
                           str(strm.get("window", "-")))
        console.print(tp)
        console.print(st)
    rt = report["rtps"]
    if rt["participants"]:
        p = Table("participant", "vendor", "SPDP", "locators", title="RTPS participants")
        for part in rt["participants"]:
            p.add_row(part["guid_prefix"], part["vendor"], str(part["spdp"]["count"]), " ".join(part["locators"]))
        console.print(p)
        tt = Table("topic", "type", "writers", "readers", "samples", "lost", "rate/s", title="RTPS topics")
        for top in rt["topics"]:
            tt.add_row(top["topic"], top["type"], str(len(top["writers"])), str(len(top["readers"])),
                       str(top["samples"]), str(top["lost"]), str(top["rate_hz"] or "-"))
        console.print(tt)
    if report["events"]:
        console.print("[bold]Events[/] (last {}):".format(len(report["events"])))
        for e in report["events"]:
            when = f"{e['t']:10.6f}" if e["t"] is not None else "         -"
            console.print(f"  {when}  {e['kind']:<22} {e['text']}", highlight=False)


__all__ = ["print_summary", "rtps_summary", "summary", "xrce_summary"]
