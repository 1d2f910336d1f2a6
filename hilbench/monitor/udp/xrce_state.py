"""XRCE sessions as the monitor sees them on the wire (spec sheet §1, §3.2, §1.9.4).

A session is keyed by its client and agent addresses (a capture without
addresses uses the source names). It records the handshake (ping, CREATE_CLIENT,
STATUS_AGENT), the entities the client created (object id -> kind, topic,
type from the CREATE's representation), each stream per direction (best-effort
gaps, reliable deliveries and retransmissions, NACKed sequence numbers, the
unacknowledged window from HEARTBEATs), WRITE_DATA/DATA sample rates per object
id (one topic endpoint each) and the integrity flags of §1.9.4. Everything is
fed by :class:`~hilbench.monitor.udp.tracker.UdpTracker` under the monitor's lock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hilbench.monitor.udp.flows import Rate, SeqStats
from hilbench.protocols import xrce_dds as x

S = x.SubmessageId
C2A, A2C = "c2a", "a2c"
#: Submessages only a client sends, and only an agent sends (to tell directions without addresses).
CLIENT_ONLY = {S.CREATE_CLIENT, S.CREATE, S.GET_INFO, S.DELETE, S.WRITE_DATA, S.READ_DATA, S.TIMESTAMP}
AGENT_ONLY = {S.STATUS_AGENT, S.STATUS, S.INFO, S.DATA, S.TIMESTAMP_REPLY}
STALL_REPEATS = 3


@dataclass
class XrceSession:
    """One client-agent pair."""

    client: str
    agent: str
    key: bytes | None = None
    session_id: int | None = None
    state: str = "new"  # new, pinging, establishing, established, rejected, closed, torn down
    first_t: float | None = None
    last_t: float | None = None
    established_t: float | None = None
    entities: dict[bytes, dict[str, Any]] = field(default_factory=dict)
    streams: dict[tuple[str, int], SeqStats] = field(default_factory=dict)
    samples: dict[tuple[str, bytes], Rate] = field(default_factory=dict)
    last_sample: dict[tuple[str, bytes], tuple[bytes, bool]] = field(default_factory=dict)
    windows: dict[tuple[str, int], int] = field(default_factory=dict)
    nacked: int = 0
    flags: dict[str, int] = field(default_factory=dict)
    submessages: dict[str, int] = field(default_factory=dict)
    datagrams: dict[str, int] = field(default_factory=lambda: {C2A: 0, A2C: 0})
    little_endian: bool | None = None
    hb_last: dict[tuple[str, int], tuple[int, int]] = field(default_factory=dict)
    hb_repeats: dict[tuple[str, int], int] = field(default_factory=dict)
    pending: dict[bytes, float] = field(default_factory=dict)  # request id -> time (CREATE/DELETE)
    latencies: dict[str, list[float]] = field(default_factory=dict)
    ping_t: float | None = None
    create_client_t: float | None = None
    resets: int = 0

    def flag(self, name: str) -> None:
        self.flags[name] = self.flags.get(name, 0) + 1

    def latency(self, kind: str, dt: float) -> None:
        vals = self.latencies.setdefault(kind, [])
        if len(vals) < 1000:
            vals.append(dt)

    def topic_of(self, oid: bytes) -> tuple[str | None, str | None]:
        ent = self.entities.get(oid)
        if ent is None:
            return None, None
        tid = ent.get("topic_id")
        if tid is not None and tid in self.entities:
            t = self.entities[tid]
            return t.get("topic"), t.get("type")
        return ent.get("topic"), ent.get("type")


class XrceState:
    """Every XRCE session on the wire, the agents seen, and events for the monitor's log."""

    def __init__(self, events: Any, flag: Any, agent_ports: set[int], max_sessions: int = 1024) -> None:
        self.sessions: dict[tuple[str, str], XrceSession] = {}
        self.agents: set[str] = set()
        self.agent_ports = agent_ports
        self.max_sessions = max_sessions
        self._event = events
        self._flag = flag
        self.dropped_sessions = 0

    # ------------------------------------------------------------------ one datagram

    def feed(self, t: float, data: bytes, src: str, dst: str, src_port: int | None, dst_port: int | None) -> None:
        sid, stream, seq, subs, trailing = x.scan(data)
        if sid < 0:
            self._flag("xrce.malformed", t, src, "datagram shorter than a header")
            return
        direction = self._direction(subs, src_port, dst_port)
        client, agent = (src, dst) if direction == C2A else (dst, src)
        s = self._session(client, agent, t)
        if s is None:
            return
        s.datagrams[direction] += 1
        s.last_t = t
        hs = 4 if sid >= 0x80 else 8
        n = len(data)
        if n < hs:
            self._flag("xrce.malformed", t, src, "header cut short", s)
            return
        if n >= 8 and not data[6] and not data[7] and x.is_zero_fill(data):  # (a zero-fill has a zero length there)
            self._flag("xrce.zero_fill", t, src, f"zeroed {n}-byte datagram from {src}", s)
        if trailing > 3:
            self._flag("xrce.bad_length", t, src, f"{trailing} bytes after the last submessage", s)
        if sid >= 0x81 and direction == C2A and s.state in ("torn down", "closed", "rejected"):
            # (A session never seen established may have started before the capture: no alarm for it.)
            self._flag("xrce.orphan_traffic", t, src, f"session 0x{sid:02X} traffic after the session {s.state}",
                       s)
        if stream:
            key = (direction, stream)
            st = s.streams.get(key)
            if st is None:
                st = s.streams[key] = SeqStats()
            if stream < 0x80:
                st.best_effort(seq)
            elif not st.reliable(seq):
                pass  # a retransmission: counted by the stream
        for sub_id, flags, off, length in subs:
            name = x.NAMES.get(sub_id, "UNKNOWN")
            s.submessages[name] = s.submessages.get(name, 0) + 1
            end = off + length
            if end > n:
                self._flag("xrce.bad_length", t, src, f"{name} length {length} beyond the datagram", s)
                break
            if sub_id in x.MIN_LENGTH and length < x.MIN_LENGTH[sub_id]:
                self._flag("xrce.bad_length", t, src, f"{name} length {length} < {x.MIN_LENGTH[sub_id]}", s)
                if sub_id == S.CREATE_CLIENT:
                    self._create_client(s, t, data, off, src)
                continue
            le = bool(flags & x.FLAG_E)
            if sub_id not in (S.FRAGMENT, S.RESET):
                if s.little_endian is None and direction == C2A:
                    s.little_endian = le
                elif direction == C2A and s.little_endian and not le:
                    self._flag("xrce.endianness_flip", t, src, f"{name} big-endian from a little-endian client", s)
            payload = data[off:end]
            self._submessage(s, t, direction, stream, sub_id, flags, payload, data, off, src)

    def _direction(self, subs: list, src_port: int | None, dst_port: int | None) -> str:
        if dst_port is not None and dst_port in self.agent_ports:
            return C2A
        if src_port is not None and src_port in self.agent_ports:
            return A2C
        for sub_id, *_ in subs:
            if sub_id in CLIENT_ONLY:
                if dst_port is not None:
                    self.agent_ports.add(dst_port)
                return C2A
            if sub_id in AGENT_ONLY:
                if src_port is not None:
                    self.agent_ports.add(src_port)
                return A2C
        return C2A

    def _session(self, client: str, agent: str, t: float) -> XrceSession | None:
        key = (client, agent)
        s = self.sessions.get(key)
        if s is None:
            if len(self.sessions) >= self.max_sessions:
                self.dropped_sessions += 1
                return None
            s = self.sessions[key] = XrceSession(client, agent, first_t=t)
            self.agents.add(agent)
        return s

    # ------------------------------------------------------------------ submessages

    def _submessage(self, s: XrceSession, t: float, direction: str, stream: int, sub_id: int, flags: int,
                    payload: bytes, data: bytes, off: int, src: str) -> None:
        if sub_id == S.WRITE_DATA or sub_id == S.DATA:
            oid = payload[2:4]
            key = (direction, oid)
            rate = s.samples.get(key)
            if rate is None:
                rate = s.samples[key] = Rate()
            rate.add(t, len(payload) - 4)
            s.last_sample[key] = (payload[4:], bool(flags & x.FLAG_E))
            return
        if sub_id == S.HEARTBEAT:
            first = payload[0] | payload[1] << 8 if flags & 1 else payload[0] << 8 | payload[1]
            last = payload[2] | payload[3] << 8 if flags & 1 else payload[2] << 8 | payload[3]
            key = (direction, payload[4])
            s.windows[key] = (last - first + 1) & 0xFFFF
            if s.hb_last.get(key) == (first, last):
                s.hb_repeats[key] = s.hb_repeats.get(key, 1) + 1
                if s.hb_repeats[key] == STALL_REPEATS:
                    self._flag("xrce.stalled_reliable", t, src,
                               f"{STALL_REPEATS} identical HEARTBEATs ({first}..{last} on 0x{payload[4]:02X}) "
                               "with no ACKNACK in between", s)
            else:
                s.hb_last[key] = (first, last)
                s.hb_repeats[key] = 1
            return
        if sub_id == S.ACKNACK:
            first = payload[0] | payload[1] << 8 if flags & 1 else payload[0] << 8 | payload[1]
            bitmap = payload[2] << 8 | payload[3]
            s.nacked += bin(bitmap).count("1")
            other = A2C if direction == C2A else C2A
            s.hb_last.pop((other, payload[4]), None)
            s.hb_repeats.pop((other, payload[4]), None)
            # The reliable message being acknowledged: latency from the last one of that stream.
            return
        if sub_id == S.GET_INFO:
            s.ping_t = t
            if s.state == "new":
                s.state = "pinging"
            return
        if sub_id == S.INFO:
            if s.ping_t is not None:
                s.latency("ping", t - s.ping_t)
                s.ping_t = None
            return
        if sub_id == S.CREATE_CLIENT:
            self._create_client(s, t, data, off, src)
            return
        if sub_id == S.STATUS_AGENT:
            status = payload[0]
            hdr_session = data[0]
            if s.create_client_t is not None:
                s.latency("create_client", t - s.create_client_t)
                s.create_client_t = None
            if status >= 0x80:
                if s.state != "torn down":  # after a takeover the rejection is of the zeroed request
                    s.state = "rejected"
                self._flag("xrce.agent_error", t, src, f"STATUS_AGENT {_status_name(status)}", s)
            elif s.session_id is not None and hdr_session != s.session_id:
                self._event(t, "xrce", f"{s.client}: STATUS_AGENT with header 0x{hdr_session:02X}, the client "
                                       f"expects 0x{s.session_id:02X} and ignores it (X4b)")
            else:
                s.state = "established"
                s.established_t = t
                self._event(t, "xrce", f"session 0x{s.session_id or 0:02X} key "
                                       f"{(s.key or b'').hex().upper()} established: {s.client} <-> {s.agent}")
            return
        if sub_id == S.CREATE:
            fields, problem = x.decode_payload(sub_id, flags, payload)
            if problem is not None:
                self._flag("xrce.malformed", t, src, f"CREATE: {problem}", s)
                return
            rep = fields.object_representation
            oid = bytes((fields.object_id[0], (fields.object_id[1] & 0xF0) | (rep.kind & 0x0F)))
            info = x.representation_info(rep.kind, rep.rep, bool(flags & x.FLAG_E))
            info["kind"] = _kind_name(rep.kind)
            info["created_t"] = t
            s.entities[oid] = info
            s.pending[bytes(fields.request_id)] = t
            return
        if sub_id == S.DELETE:
            oid = payload[2:4]
            s.pending[payload[0:2]] = t
            if oid == x.OBJECT_CLIENT:
                s.state = "closing"
            else:
                s.entities.pop(oid, None)
            return
        if sub_id == S.STATUS:
            req, oid, status = payload[0:2], payload[2:4], payload[4]
            t0 = s.pending.pop(req, None)
            if t0 is not None:
                s.latency("status", t - t0)
            ent = s.entities.get(oid)
            if ent is not None:
                ent["status"] = _status_name(status)
            if status >= 0x80:
                self._flag("xrce.agent_error", t, src, f"STATUS {_status_name(status)} for "
                                                      f"{x.object_text(oid)}", s)
            if oid == x.OBJECT_CLIENT and status < 0x80:
                s.state = "closed"
                self._event(t, "xrce", f"{s.client}: session closed (DELETE client)")
            return
        if sub_id == S.RESET:
            s.resets += 1
            self._event(t, "xrce", f"{s.client}: RESET of every stream")
            return

    def _create_client(self, s: XrceSession, t: float, data: bytes, off: int, src: str) -> None:
        body = data[off:off + 16]
        key = body[8:12] if len(body) >= 12 else b""
        sid = body[12] if len(body) >= 13 else None
        bad = len(body) < 16 or body[:4] != x.COOKIE or key == b"\x00\x00\x00\x00" or body[4] != 1
        if bad:
            self._flag("xrce.bad_create_client", t, src, f"CREATE_CLIENT cookie {body[:4]!r} key "
                                                         f"{key.hex().upper() or '-'}", s)
        if s.state == "established" and s.key is not None and key != s.key:
            self._flag("xrce.session_takeover", t, src,
                       f"CREATE_CLIENT key {key.hex().upper() or '-'} from {s.client}, which has session key "
                       f"{s.key.hex().upper()}: the agent tears that session down", s)
            s.state = "torn down"
            s.resets += 1
            return
        if s.state == "established" and key == s.key:
            s.resets += 1
            self._event(t, "xrce", f"{s.client}: CREATE_CLIENT again for the live session (streams reset)")
        if not bad:
            s.key, s.session_id = key, sid
            s.state = "establishing"
            s.create_client_t = t


def _kind_name(kind: int) -> str:
    try:
        return x.ObjectKind(kind).name.lower()
    except ValueError:
        return f"kind{kind}"


def _status_name(code: int) -> str:
    try:
        return x.Status(code).name
    except ValueError:
        return f"0x{code:02X}"


__all__ = ["A2C", "C2A", "XrceSession", "XrceState"]
