"""RTPS participants, endpoints and topics as the monitor sees them (spec sheet §2, §3.2).

Participants come from SPDP (GUID prefix, vendor, locators, lease, announcement
rate; a new prefix is an event, so is a restart: the same prefix with lower
sequence numbers), endpoints from SEDP (topic, type, reliability), and every
user DATA counts for its writer: samples, rate, sequence gaps of best-effort
writers (GAP-covered numbers are not lost), duplicates. The SPDP writer's
sequence number is exempt (FreeRTPS never increments it, §2.8).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

from hilbench.monitor.udp.flows import Rate, SeqStats
from hilbench.protocols import rtps as r

R = r.SubmessageId
_SN = struct.Struct("<iI")
_SN_BE = struct.Struct(">iI")


@dataclass
class Participant:
    prefix: bytes
    vendor: bytes = b""
    first_t: float | None = None
    last_t: float | None = None
    spdp: Rate = field(default_factory=Rate)
    locators: list[str] = field(default_factory=list)
    lease_s: float | None = None
    name: str | None = None
    datagrams: int = 0
    last_spdp_sn: int = 0
    restarts: int = 0


@dataclass
class RtpsEndpoint:
    guid: bytes
    writer: bool
    topic: str
    type_name: str
    reliable: bool


@dataclass
class WriterFlow:
    samples: Rate = field(default_factory=Rate)
    seq: SeqStats = field(default_factory=lambda: SeqStats(modulus=None))
    gaps: int = 0
    last_payload: bytes = b""


class RtpsState:
    """Every participant, endpoint and writer flow seen."""

    def __init__(self, events: Any, flag: Any, max_items: int = 4096) -> None:
        self.participants: dict[bytes, Participant] = {}
        self.endpoints: dict[bytes, RtpsEndpoint] = {}
        self.writers: dict[bytes, WriterFlow] = {}
        self.submessages: dict[str, int] = {}
        self.max_items = max_items
        self._event = events
        self._flag = flag

    def feed(self, t: float, data: bytes, src: str) -> None:
        n = len(data)
        if n < r.HEADER_SIZE:
            self._flag("rtps.too_short", t, src, f"{n}-byte datagram with the RTPS magic")
            return
        if data[4] != 2:
            self._flag("rtps.bad_version", t, src, f"protocol version {data[4]}.{data[5]}")
        prefix = data[8:20]
        p = self.participants.get(prefix)
        if p is None:
            if len(self.participants) >= self.max_items:
                return
            p = self.participants[prefix] = Participant(prefix, data[6:8], first_t=t)
        p.last_t = t
        p.datagrams += 1
        cur = prefix
        subs_ = self.submessages
        for sub_id, flags, off, length in r.scan(data):
            name = r.NAMES.get(sub_id, "VENDOR" if sub_id >= 0x80 else "UNKNOWN")
            subs_[name] = subs_.get(name, 0) + 1
            if off + length > n:
                self._flag("rtps.bad_length", t, src, f"{name} octetsToNextHeader {length} past the end")
                return
            if sub_id == R.DATA:
                self._data(t, cur, data, off, length, flags, src)
            elif sub_id == R.INFO_SRC and length >= 20:
                cur = data[off + 8:off + 20]
            elif sub_id == R.GAP and length >= 32:
                self._gap(cur, data, off, flags)

    def _data(self, t: float, prefix: bytes, data: bytes, off: int, length: int, flags: int, src: str) -> None:
        if length < 20:
            self._flag("rtps.bad_length", t, src, "DATA shorter than its fixed part")
            return
        le = flags & 1
        writer_id = data[off + 8:off + 12]
        high, low = (_SN if le else _SN_BE).unpack_from(data, off + 12)
        sn = (high << 32) | low
        if flags & r.FLAG_D and flags & r.FLAG_K:
            self._flag("rtps.data_and_key", t, src, "DATA with both D and K flags")
        if writer_id == r.SPDP_WRITER or writer_id in (r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER):
            self._discovery(t, prefix, data, off, length, writer_id, sn, src)
            return
        guid = prefix + writer_id
        w = self.writers.get(guid)
        if w is None:
            if len(self.writers) >= self.max_items:
                return
            w = self.writers[guid] = WriterFlow()
        w.samples.add(t, length - 24)
        ep = self.endpoints.get(guid)
        if ep is not None and ep.reliable:
            w.seq.reliable(sn)
        else:
            w.seq.best_effort(sn)
        # The serialized payload (after inline QoS, if any) for the last-value view.
        body = data[off:off + length]
        pos = 4 + (body[2] | body[3] << 8 if le else body[2] << 8 | body[3])
        if flags & r.FLAG_Q:
            _, used, _ = r.parse_parameters(body[pos:], bool(le))
            pos += used
        w.last_payload = body[pos:]

    def _discovery(self, t: float, prefix: bytes, data: bytes, off: int, length: int, writer_id: bytes, sn: int,
                   src: str) -> None:
        msg = r.parse_message(data[:r.HEADER_SIZE] + data[off - 4:off + length])
        if msg.flags:
            for f in msg.flags:
                self._flag(f, t, src, f"in {r.entity_text(writer_id)} DATA")
        sub = msg.submessages[0] if msg.submessages else None
        fields = (sub.fields or {}) if sub is not None else {}
        p = fields.get("parameters")
        if p is None:
            return
        if writer_id == r.SPDP_WRITER:
            guid = p.get("participant_guid")
            if guid is None:
                return
            part = self.participants.get(guid[:12])
            if part is None:
                if len(self.participants) >= self.max_items:
                    return
                part = self.participants[guid[:12]] = Participant(guid[:12], data[6:8], first_t=t)
            if not part.spdp.count:
                self._event(t, "rtps", f"new participant {r.guid_text(guid[:12])} "
                                       f"({r.VENDOR_NAMES.get(data[6:8], data[6:8].hex())}) from {src}")
            elif 0 < sn < part.last_spdp_sn:
                part.restarts += 1
                self._event(t, "rtps", f"participant {r.guid_text(guid[:12])} restarted (SPDP SN went back)")
            part.last_spdp_sn = sn
            part.spdp.add(t)
            part.lease_s = p.get("lease_s")
            part.name = p.get("name")
            part.locators = [f"{kind_name} {a}:{port}" for key, kind_name in (
                ("metatraffic_unicast_locator", "meta"), ("default_unicast_locator", "user"),
                ("metatraffic_multicast_locator", "meta-mc"), ("default_multicast_locator", "user-mc"))
                for _, a, port in p.get(key, [])]
            return
        guid = p.get("endpoint_guid")
        if guid is None or "topic" not in p:
            return
        new = guid not in self.endpoints
        if new and len(self.endpoints) >= self.max_items:
            return
        self.endpoints[guid] = RtpsEndpoint(guid, writer_id == r.SEDP_PUB_WRITER, p["topic"], p.get("type", ""),
                                        bool(p.get("reliable", writer_id == r.SEDP_PUB_WRITER)))
        if new:
            kind = "writer" if writer_id == r.SEDP_PUB_WRITER else "reader"
            self._event(t, "rtps", f"{kind} {r.guid_text(guid)} on {p['topic']!r} ({p.get('type', '')})")

    def _gap(self, prefix: bytes, data: bytes, off: int, flags: int) -> None:
        le = flags & 1
        writer_id = data[off + 4:off + 8]
        w = self.writers.get(prefix + writer_id)
        if w is None:
            return
        sh, sl = (_SN if le else _SN_BE).unpack_from(data, off + 8)
        bh, bl = (_SN if le else _SN_BE).unpack_from(data, off + 16)
        start, base = (sh << 32) | sl, (bh << 32) | bl
        w.gaps += max(0, base - start)
        if w.seq.last is not None and w.seq.last < base - 1:
            w.seq.last = base - 1  # declared irrelevant, not lost

    def topics(self) -> dict[str, dict[str, Any]]:
        """Per topic: writers, readers, samples and rate of its writers."""
        out: dict[str, dict[str, Any]] = {}
        for guid, ep in self.endpoints.items():
            t = out.setdefault(ep.topic, {"topic": ep.topic, "type": ep.type_name, "writers": [], "readers": [],
                                          "samples": 0, "lost": 0, "rate_hz": None})
            (t["writers"] if ep.writer else t["readers"]).append(r.guid_text(guid))
            w = self.writers.get(guid) if ep.writer else None
            if w is not None:
                t["samples"] += w.samples.count
                t["lost"] += w.seq.lost
                rate = w.samples.rate()
                if rate is not None:
                    t["rate_hz"] = round((t["rate_hz"] or 0) + rate, 3)
        return out


__all__ = ["RtpsEndpoint", "Participant", "RtpsState", "WriterFlow"]
