"""An emulated Micro XRCE-DDS agent (what ``micro_ros_agent udp4 --port 8888`` runs) on a datagram net.

It does what eProsima's agent does for a client over UDP (spec sheet §1, and
the agent's ``Processor``): answers GET_INFO pings out of and in session,
creates sessions (CREATE_CLIENT -> STATUS_AGENT with the payload's session id
in the header), keeps best-effort and reliable streams both ways (ACKNACK
after every reliable message and HEARTBEAT, HEARTBEATs every 200 ms while its
own reliable messages are unacknowledged, retransmission on NACK, FRAGMENT
reassembly and fragmentation above the client's MTU), creates entities by
reference, XML or binary, answers TIMESTAMP, deletes objects and clients, and
routes WRITE_DATA to every DATAREADER on the same topic (of any client,
itself included) whose READ_DATA asked for data, as the agent's DDS
participants do. A REQUESTER's request goes to every REPLIER of the same
request topic and type, prefixed with a sample identity (writer GUID and
sequence number); the REPLIER's reply carries that identity back and goes to
that requester only, prefixed with the original WRITE_DATA's request id and
object id, as the agent's Requester and Replier objects do. An optional bridge carries the same samples to and from RTPS.

Bad input never ends a session, with one exception the real agent has too
(§1.9.4): a datagram read as a CREATE_CLIENT with another key from the address
of a live session (Xu's zeroed datagram) deletes that session first. The
``zeroed`` setting ``"keep"`` keeps the session when that CREATE_CLIENT is
invalid anyway (key 0, bad cookie or version). Everything is counted
(:attr:`XrceAgent.counters`) and logged the way the agent logs it.

What a client may hold is bounded (the real agent's limits, and where it has
none, hilbench's; :meth:`~XrceAgent.limits`): at most ``max_sessions`` sessions
(:data:`MAX_SESSIONS`; a CREATE_CLIENT beyond takes the place of the session
idle longest if that one has been silent for :data:`CLIENT_DEAD_S`, the real
agent's CLIENT_DEAD_TIME, and is otherwise answered STATUS_AGENT
ERR_RESOURCES); a session silent for ``session_timeout`` seconds
(:data:`SESSION_TIMEOUT_S`; 0: never) is deleted, and one silent for
:data:`CLIENT_DEAD_S` gets no HEARTBEATs, as the real agent's dead clients;
a client that comes back creates its session again (micro-ROS's
``rmw_uros_ping_agent`` and CREATE_CLIENT). Per session: :data:`MAX_ENTITIES`
objects (:data:`MAX_ENTITIES_TOTAL` in all) with representations of at most
:data:`MAX_REPRESENTATION` bytes (a CREATE beyond either: STATUS ERR_RESOURCES),
:data:`SESSION_INPUT_BYTES` of reliable input waiting behind a gap or being
reassembled, :data:`SESSION_OUTPUT_BYTES` of reliable output unacknowledged
or waiting, :data:`SESSION_QUEUE_BYTES` of samples waiting for a READ_DATA;
beyond, messages and samples are dropped and counted. A FRAGMENT inside a
reassembled message (the real agent recurses into it) is followed
:data:`MAX_FRAGMENT_DEPTH` levels deep; a deeper one is dropped
(``fragment_nesting``): FRAGMENT has no request to answer with a STATUS.
"""

from __future__ import annotations

import logging
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Any

from hilbench.fakes.xrce_agent.entities import Entity, EntityError, entity_from_create, same
from hilbench.protocols import xrce_dds as x
from hilbench.protocols.xrce_streams import BestEffortInput, ReliableInput, ReliableOutput
from hilbench.transports.clock import WALL

log = logging.getLogger(__name__)
K = x.ObjectKind
S = x.SubmessageId
Address = tuple[str, int]
#: The agent's HEARTBEAT period (UAGENT_CONFIG_HEARTBEAT_PERIOD).
HEARTBEAT_PERIOD = 0.2
#: Samples a reader keeps while no READ_DATA asks for them (at most; its history depth decides).
MAX_QUEUED = 64
#: Requests whose reply is still awaited (their sample identity -> requester): oldest forgotten first.
MAX_PENDING_REQUESTS = 1024
#: Sessions at once (the real agent has no limit over UDP; each one costs memory).
MAX_SESSIONS = 64
#: A client silent this long is dead: no HEARTBEATs, and its place may go to a new client when all are taken
#: (the real agent's UAGENT_CONFIG_CLIENT_DEAD_TIME, 30 000 ms).
CLIENT_DEAD_S = 30.0
#: A session silent this long is deleted (0: never).
SESSION_TIMEOUT_S = 300.0
#: Objects per session and in all, and the longest representation a CREATE may carry (bytes).
MAX_ENTITIES = 256
MAX_ENTITIES_TOTAL = 2048  #: objects in all sessions
MAX_REPRESENTATION = 4096  #: bytes of a CREATE's representation
#: Bytes a session may hold: reliable input behind a gap or in reassembly, reliable output unacknowledged
#: or waiting for room, samples waiting for a READ_DATA.
SESSION_INPUT_BYTES = 256 * 1024
SESSION_OUTPUT_BYTES = 1024 * 1024  #: reliable output unacknowledged or waiting for room
SESSION_QUEUE_BYTES = 256 * 1024  #: samples waiting for a READ_DATA
#: Levels of FRAGMENTs inside reassembled messages followed.
MAX_FRAGMENT_DEPTH = 4


@dataclass
class Read:
    """An active READ_DATA: where DATA goes and how many samples are still wanted (None: unlimited)."""

    request_id: bytes
    stream_id: int
    remaining: int | None


@dataclass
class Session:
    """A client as the agent knows it (the agent's ProxyClient plus its session)."""

    key: bytes
    session_id: int
    address: Address
    mtu: int
    entities: dict[bytes, Entity] = field(default_factory=dict)
    be_in: dict[int, BestEffortInput] = field(default_factory=dict)
    rel_in: dict[int, ReliableInput] = field(default_factory=dict)
    be_out: dict[int, int] = field(default_factory=dict)
    rel_out: dict[int, ReliableOutput] = field(default_factory=dict)
    reads: dict[bytes, Read] = field(default_factory=dict)
    queued: dict[bytes, deque[bytes]] = field(default_factory=dict)
    queued_bytes: int = 0
    created: float = 0.0
    last_seen: float = 0.0
    samples_in: int = 0
    samples_out: int = 0
    little_endian: bool | None = None

    def header(self, stream_id: int, seq: int = 0) -> bytes:
        return x.build_header(self.session_id, stream_id, seq, self.key if self.session_id < 0x80 else None)

    def input_bytes(self) -> int:
        return sum(r.bytes for r in self.rel_in.values())

    def output_bytes(self) -> int:
        return sum(o.bytes for o in self.rel_out.values())

    def reset_streams(self) -> None:
        self.be_in.clear()
        self.rel_in.clear()
        self.be_out.clear()
        self.rel_out.clear()

    def topic_of(self, ent: Entity) -> tuple[str | None, str | None]:
        """A writer's or reader's topic and type (its own, or its TOPIC object's when created in binary)."""
        if ent.topic_id is not None:
            topic = self.entities.get(ent.topic_id)
            if topic is not None:
                return topic.topic, topic.type_name
        return ent.topic, ent.type_name

    def describe(self, now: float | None = None) -> dict[str, Any]:
        out = {"client_key": self.key.hex().upper(), "session_id": self.session_id,
               "address": f"{self.address[0]}:{self.address[1]}", "mtu": self.mtu,
               "entities": [e.describe() for e in list(self.entities.values())],
               "reading": [oid.hex().upper() for oid in list(self.reads)], "samples_in": self.samples_in,
               "samples_out": self.samples_out,
               "buffered": {"input": self.input_bytes(), "output": self.output_bytes(), "queued": self.queued_bytes}}
        if now is not None:
            out["idle_s"] = round(max(0.0, now - self.last_seen), 3)
        return out


class XrceAgent:
    """The agent as a device on a :class:`~hilbench.transports.datagram_medium.DatagramMedium`."""

    def __init__(self, name: str = "agent", *, zeroed: str = "teardown", refs: dict[str, dict[str, Any]] | None = None,
                 heartbeat_s: float = HEARTBEAT_PERIOD, log_size: int = 500, max_sessions: int = MAX_SESSIONS,
                 session_timeout: float = SESSION_TIMEOUT_S) -> None:
        if zeroed not in ("teardown", "keep"):
            raise ValueError(f"zeroed must be teardown or keep, got {zeroed!r}")
        self.name = name
        self.max_sessions = max_sessions
        self.session_timeout = session_timeout
        self.zeroed = zeroed
        self.refs = dict(refs or {})
        self.heartbeat_s = heartbeat_s
        self.port: Any = None
        self.bridge: Any = None
        self.sessions: dict[Address, Session] = {}
        self.by_key: dict[bytes, Session] = {}
        self.log: deque[str] = deque(maxlen=log_size)
        self.counters: dict[str, int] = dict.fromkeys((
            "datagrams", "replies", "malformed", "zero_fill", "zero_fill_foreign", "orphan", "takeovers",
            "sessions_created", "sessions_deleted", "invalid_create_client", "samples_routed", "samples_bridged",
            "retransmissions", "fragments_in", "fragments_out", "dropped_out", "too_big", "requests", "replies_routed",
            "replies_unmatched", "sessions_refused", "sessions_evicted", "sessions_expired", "fragment_nesting",
            "fragments_dropped", "input_dropped", "output_dropped", "samples_dropped", "entities_refused"), 0)
        self.faults = {"drop_next": 0, "corrupt_status_agent": 0}
        # sample identity of a request -> (requester's client key, requester object id, WRITE_DATA request id)
        self._pending: OrderedDict[bytes, tuple[bytes, bytes, bytes]] = OrderedDict()
        self._request_seq: dict[tuple[bytes, bytes], int] = {}
        self._running = False

    # ------------------------------------------------------------------ wiring

    def attach(self, net: Any) -> None:
        """Join a datagram net; the agent answers on the net's endpoint socket."""
        self.port = net.add_device(self)

    def start(self) -> None:
        self._running = True
        if self.port is not None:
            self.port.call_at(self.port.now() + self.heartbeat_s, self._heartbeats)

    def stop(self) -> None:
        self._running = False

    def _log(self, text: str) -> None:
        self.log.append(text)
        log.debug("%s: %s", self.name, text)

    # ------------------------------------------------------------------ output

    def _send(self, data: bytes, dst: Address) -> None:
        if self.faults["drop_next"] > 0:
            self.faults["drop_next"] -= 1
            self.counters["dropped_out"] += 1
            return
        self.counters["replies"] += 1
        if self.port is not None:
            self.port.send(data, dst)

    def _send_none(self, s: Session, sub_id: int, payload: bytes) -> None:
        self._send(s.header(x.STREAM_NONE) + x.build_submessage(sub_id, payload), s.address)

    def _send_stream(self, s: Session, stream_id: int, sub_id: int, payload: bytes) -> bool:
        """One submessage on an output stream; False if it could not be sent (too big for best effort)."""
        if stream_id == x.STREAM_NONE:
            self._send_none(s, sub_id, payload)
            return True
        header_len = 4 if s.session_id >= 0x80 else 8
        if stream_id < 0x80:
            if header_len + 4 + len(payload) > s.mtu:
                self.counters["too_big"] += 1
                return False
            seq = (s.be_out.get(stream_id, 0xFFFF) + 1) & 0xFFFF
            s.be_out[stream_id] = seq
            self._send(s.header(stream_id, seq) + x.build_submessage(sub_id, payload), s.address)
            return True
        out = s.rel_out.setdefault(stream_id, ReliableOutput())
        fits = s.output_bytes() + len(payload) <= SESSION_OUTPUT_BYTES
        if not out.room() or out.backlog or not fits:
            if not out.queue((sub_id, payload), room=fits):
                self.counters["output_dropped"] += 1
                return False
            return True
        self._send_reliable(s, stream_id, out, sub_id, payload)
        return True

    def _send_reliable(self, s: Session, stream_id: int, out: ReliableOutput, sub_id: int, payload: bytes) -> None:
        header_len = 4 if s.session_id >= 0x80 else 8
        whole = x.build_submessage(sub_id, payload)
        if header_len + len(whole) <= s.mtu:
            seq = out.next_seq()
            msg = s.header(stream_id, seq) + whole
            out.keep(seq, msg)
            self._send(msg, s.address)
            return
        # Larger than the client's MTU: FRAGMENTs of the serialized submessage, one per message (§1.1).
        room = s.mtu - header_len - 4
        for i in range(0, len(whole), room):
            piece = whole[i:i + room]
            last = i + room >= len(whole)
            seq = out.next_seq()
            msg = s.header(stream_id, seq) + x.build_submessage(
                S.FRAGMENT, piece, x.FLAG_E | (x.FLAG_LAST_FRAGMENT if last else 0))
            out.keep(seq, msg)
            self.counters["fragments_out"] += 1
            self._send(msg, s.address)

    def _flush_backlog(self, s: Session, stream_id: int) -> None:
        out = s.rel_out.get(stream_id)
        while out is not None and out.backlog and out.room():
            sub_id, payload = out.unqueue()
            self._send_reliable(s, stream_id, out, sub_id, payload)

    def _heartbeats(self) -> None:
        if not self._running:
            return
        now = self.port.now()
        self.port.call_at(now + self.heartbeat_s, self._heartbeats)  # first: nothing below can stop the timer
        self.expire(now)
        for s in list(self.by_key.values()):
            if now - s.last_seen >= CLIENT_DEAD_S:
                continue  # a dead client (the real agent sends it no HEARTBEATs)
            for stream_id, out in s.rel_out.items():
                hb = out.heartbeat()
                if hb is not None:
                    self._send_none(s, S.HEARTBEAT, x.heartbeat(hb[0], hb[1], stream_id))

    def expire(self, now: float) -> int:
        """Delete the sessions silent for ``session_timeout`` seconds; returns how many (the net's thread)."""
        if not self.session_timeout:
            return 0
        gone = [s for s in self.by_key.values() if now - s.last_seen > self.session_timeout]
        for s in gone:
            self.counters["sessions_expired"] += 1
            self._drop_session(s)
            self._log(f"destroy_session | client_key: 0x{s.key.hex().upper()}, idle {now - s.last_seen:.0f} s")
        return len(gone)

    # ------------------------------------------------------------------ input

    def on_datagram(self, data: bytes, src: Address, dst: Address, t: float) -> None:
        """One datagram from a client (the net's thread)."""
        self.counters["datagrams"] += 1
        src = (src[0], src[1])
        if len(data) < 4:
            self.counters["malformed"] += 1
            return
        zero = x.is_zero_fill(data)
        if zero:
            self.counters["zero_fill"] += 1
            if src not in self.sessions:
                self.counters["zero_fill_foreign"] += 1
        sid, stream, seq = data[0], data[1], data[2] | data[3] << 8
        hs = x.header_size(sid)
        if len(data) < hs + 4:
            self.counters["malformed"] += 1
            return
        if sid in (x.SESSION_NONE_WITH_KEY, x.SESSION_NONE_WITHOUT_KEY):
            sub_id = data[hs]
            if sub_id == S.CREATE_CLIENT:
                self._create_client(data, hs, src, t)
            elif sub_id == S.GET_INFO:
                self._ping(data, hs, src)
            else:
                self.counters["malformed"] += 1
            return
        s = self.by_key.get(data[4:8]) if sid < 0x80 else self.sessions.get(src)
        if s is None or (sid >= 0x80 and s.session_id != sid):
            self._unknown_client(data, hs, src)
            return
        s.last_seen = t
        if sid < 0x80 and s.address != src:  # a keyed client may move
            if self.sessions.get(s.address) is s:
                del self.sessions[s.address]
            s.address = src
            self.sessions[src] = s
        if stream == x.STREAM_NONE:
            self._process(s, data, hs, t)
        elif stream < 0x80:
            if s.be_in.setdefault(stream, BestEffortInput()).accept(seq):
                self._process(s, data, hs, t)
        else:
            rel = s.rel_in.setdefault(stream, ReliableInput())
            # A message ahead of a gap waits in the stream, within the session's budget (the next one in
            # order is handled at once and always taken, so a full budget never blocks the stream).
            if rel.next_in_order(seq) or s.input_bytes() + len(data) <= SESSION_INPUT_BYTES:
                rel.push(seq, data)
            else:
                self.counters["input_dropped"] += 1  # NACKed below: the client sends it again
            while (msg := rel.pop()) is not None:
                self._process(s, msg, hs, t)
            first, bitmap = rel.acknack()
            self._send_none(s, S.ACKNACK, x.acknack(first, bitmap, stream))

    def _unknown_client(self, data: bytes, hs: int, src: Address) -> None:
        sub_id = data[hs]
        if sub_id == S.DELETE and len(data) >= hs + 8 and data[hs + 7] & 0x0F == K.CLIENT:
            # The agent confirms deleting a client it does not know (the client's shutdown succeeds).
            self._send(data[:hs] + x.build_submessage(S.STATUS, x.status(data[hs + 4:hs + 6], data[hs + 6:hs + 8])),
                       src)
        elif sub_id == S.GET_INFO:
            self._ping(data, hs, src)
        else:
            self.counters["orphan"] += 1

    def _process(self, s: Session, msg: bytes, hs: int, t: float, depth: int = 0) -> None:
        """Every submessage of one message in order; stops at the first the agent cannot process. ``depth``:
        how many reassemblies or HEARTBEAT deliveries led here (bounded, see :data:`MAX_FRAGMENT_DEPTH`)."""
        _, stream, _, subs, _ = x.scan(msg)
        for sub_id, flags, off, length in subs:
            if off + length > len(msg):
                self.counters["malformed"] += 1
                return
            payload = msg[off:off + length]
            if s.little_endian is None:
                s.little_endian = bool(flags & x.FLAG_E)
            if not self._submessage(s, stream, sub_id, flags, payload, msg, off, t, depth):
                return

    def _submessage(self, s: Session, stream: int, sub_id: int, flags: int, payload: bytes, msg: bytes, off: int,
                    t: float, depth: int = 0) -> bool:
        if sub_id == S.WRITE_DATA:
            return self._write_data(s, flags, payload)
        if sub_id == S.FRAGMENT:
            rel = s.rel_in.get(stream)
            if rel is None:
                return False
            if depth >= MAX_FRAGMENT_DEPTH:
                self.counters["fragment_nesting"] += 1
                return False  # no request to answer: dropped with the rest of its message
            self.counters["fragments_in"] += 1
            limit = rel.bytes + SESSION_INPUT_BYTES - s.input_bytes()  # what this stream may still grow to
            dropped = rel.fragments_dropped
            whole = rel.fragment(msg[:x.header_size(msg[0])], payload, bool(flags & x.FLAG_LAST_FRAGMENT), limit)
            if rel.fragments_dropped != dropped:
                self.counters["fragments_dropped"] += 1
            if whole is not None:
                self._process(s, whole, x.header_size(whole[0]), t, depth + 1)
            return True
        if sub_id == S.RESET:
            s.reset_streams()
            return True
        if sub_id == S.CREATE_CLIENT:
            return False  # in session: the agent only accepts it session-less
        fields, problem = x.decode_payload(sub_id, flags, payload)
        if problem is not None:
            self.counters["malformed"] += 1
            return False
        if sub_id == S.CREATE:
            self._create(s, stream, flags, fields, len(payload))
        elif sub_id == S.DELETE:
            self._delete(s, stream, fields)
        elif sub_id == S.READ_DATA:
            self._read_data(s, fields)
        elif sub_id == S.ACKNACK:
            out = s.rel_out.get(fields.stream_id)
            if out is not None:
                bitmap = int.from_bytes(fields.nack_bitmap, "big")
                for again in out.nacked(fields.first_unacked, bitmap):
                    self.counters["retransmissions"] += 1
                    self._send(again, s.address)
                out.acknowledge(fields.first_unacked)
                self._flush_backlog(s, fields.stream_id)
        elif sub_id == S.HEARTBEAT:
            if fields.stream_id < 0x80:
                return True  # only reliable streams have HEARTBEATs (the agent ignores the rest)
            rel = s.rel_in.setdefault(fields.stream_id, ReliableInput())
            rel.heartbeat(fields.first_unacked, fields.last_unacked)
            while depth < MAX_FRAGMENT_DEPTH and (m := rel.pop()) is not None:
                self._process(s, m, x.header_size(m[0]), t, depth + 1)
            first, bitmap = rel.acknack()
            self._send_none(s, S.ACKNACK, x.acknack(first, bitmap, fields.stream_id))
        elif sub_id == S.TIMESTAMP:
            now = self._wall()
            recv = (int(now), int((now % 1) * 1e9))
            tr = self._wall()
            self._send_none(s, S.TIMESTAMP_REPLY, x.timestamp_reply(
                (int(tr), int((tr % 1) * 1e9)), recv,
                (fields.transmit.seconds, fields.transmit.nanoseconds)))
        elif sub_id == S.GET_INFO:
            self._send_none(s, S.INFO, x.info_agent(bytes(fields.request_id), bytes(fields.object_id), 1))
        else:
            return False
        return True

    # ------------------------------------------------------------------ sessions

    def _ping(self, data: bytes, hs: int, src: Address) -> None:
        fields, problem = x.decode_payload(S.GET_INFO, data[hs + 1], data[hs + 4:hs + 4 + 8])
        if problem is not None:
            self.counters["malformed"] += 1
            return
        impl = 1 if src in self.sessions else 0
        self._send(data[:hs] + x.build_submessage(S.INFO, x.info_agent(bytes(fields.request_id),
                                                                        bytes(fields.object_id), impl)), src)

    def _create_client(self, data: bytes, hs: int, src: Address, t: float) -> None:
        # The agent reads the CLIENT_Representation to the end of the datagram, whatever the length says (§1.9.2 E).
        flags = data[hs + 1]
        fields, problem = x.decode_payload(S.CREATE_CLIENT, flags, data[hs + 4:])
        if problem is not None:
            self.counters["malformed"] += 1
            self.counters["invalid_create_client"] += 1
            return
        key = bytes(fields.client_key)
        if key == b"\x00\x00\x00\x00" or bytes(fields.xrce_cookie) != x.COOKIE:
            result = x.Status.ERR_INVALID_DATA
        elif fields.xrce_version[0] != 1:
            result = x.Status.ERR_INCOMPATIBLE
        else:
            result = x.Status.OK
        old = self.sessions.get(src)
        if old is not None and old.key != key and (self.zeroed == "teardown" or result == x.Status.OK):
            # Replace check (§1.6 step 2): the address's session goes before anything else.
            self.counters["takeovers"] += 1
            self._log(f"delete_client | client_key: 0x{old.key.hex().upper()}")
            self._drop_session(old)
            self._log(f"destroy_session | client_key: 0x{old.key.hex().upper()}, address: {src[0]}:{src[1]}")
        if result != x.Status.OK:
            self.counters["invalid_create_client"] += 1
            what = "invalid client key" if result == x.Status.ERR_INVALID_DATA and key == bytes(4) else (
                "invalid cookie" if result == x.Status.ERR_INVALID_DATA else "incompatible version")
            self._log(f"create_client | {what} 0x{key.hex().upper()}")
        else:
            existing = self.by_key.get(key)
            if existing is not None and existing.session_id == fields.session_id:
                existing.reset_streams()
                if self.sessions.get(existing.address) is existing:
                    del self.sessions[existing.address]  # the client moved (a new socket after a restart)
                existing.address = src
                existing.mtu = max(64, fields.mtu)
                existing.last_seen = t
                self.sessions[src] = existing
            elif existing is None and len(self.by_key) >= self.max_sessions and not self._evict(t):
                result = x.Status.ERR_RESOURCES
                self.counters["sessions_refused"] += 1
                self._log(f"create_client | too many clients ({self.max_sessions}) 0x{key.hex().upper()}")
            else:
                if existing is not None:
                    self._drop_session(existing)
                s = Session(key, fields.session_id, src, max(64, fields.mtu), created=t, last_seen=t)
                self.by_key[key] = s
                self.sessions[src] = s
                self.counters["sessions_created"] += 1
                self._log(f"create_client | client_key: 0x{key.hex().upper()}, session_id: 0x{fields.session_id:02X}")
                self._log(f"establish_session | client_key: 0x{key.hex().upper()}, address: {src[0]}:{src[1]}")
        # STATUS_AGENT: the request's header with the payload's session id (X4, X6).
        session_id = fields.session_id
        if self.faults["corrupt_status_agent"] > 0:
            self.faults["corrupt_status_agent"] -= 1
            session_id = session_id & 0x80  # X4b: the header a client ignores
        header = x.build_header(session_id, 0, 0, key if session_id < 0x80 else None)
        self._send(header + x.build_submessage(S.STATUS_AGENT, x.status_agent(result)), src)

    def _evict(self, now: float) -> bool:
        """Make room for a new client: delete the session silent longest if it is dead (:data:`CLIENT_DEAD_S`)."""
        oldest = min(self.by_key.values(), key=lambda s: s.last_seen, default=None)
        if oldest is None or now - oldest.last_seen < CLIENT_DEAD_S:
            return False
        self.counters["sessions_evicted"] += 1
        self._drop_session(oldest)
        self._log(f"destroy_session | client_key: 0x{oldest.key.hex().upper()}, dead, its place taken")
        return True

    def _drop_session(self, s: Session) -> None:
        if self.sessions.get(s.address) is s:
            del self.sessions[s.address]
        if self.by_key.get(s.key) is s:
            del self.by_key[s.key]
        for ent in s.entities.values():
            self._bridge_entity(s, ent, removed=True)
        s.entities.clear()
        s.reads.clear()
        s.queued.clear()
        s.queued_bytes = 0
        s.reset_streams()
        for k in [k for k in self._request_seq if k[0] == s.key]:
            del self._request_seq[k]
        self.counters["sessions_deleted"] += 1

    # ------------------------------------------------------------------ entities

    def _create(self, s: Session, stream: int, flags: int, fields: Any, size: int = 0) -> None:
        rep = fields.object_representation
        oid = bytes((fields.object_id[0], (fields.object_id[1] & 0xF0) | (rep.kind & 0x0F)))
        reply_stream = x.STREAM_RELIABLE if stream >= 0x80 else x.STREAM_BEST_EFFORT
        status = x.Status.OK
        crowded = oid not in s.entities and (len(s.entities) >= MAX_ENTITIES or sum(
            len(o.entities) for o in self.by_key.values()) >= MAX_ENTITIES_TOTAL)
        if crowded or size > MAX_REPRESENTATION:
            self.counters["entities_refused"] += 1
            self._log(f"create_object | no resources for object_id: 0x{oid.hex().upper()}")
            self._send_stream(s, reply_stream, S.STATUS, x.status(bytes(fields.request_id), oid,
                                                                   x.Status.ERR_RESOURCES))
            return
        try:
            ent = entity_from_create(oid, rep, bool(flags & x.FLAG_E), self.refs)
            status = self._check_parent(s, ent)
        except EntityError as exc:
            ent, status = None, exc.status
            self._log(f"create_object | {exc} object_id: 0x{oid.hex().upper()}")
        if ent is not None and status == x.Status.OK:
            reuse, replace = bool(flags & x.FLAG_REUSE), bool(flags & x.FLAG_REPLACE)
            old = s.entities.get(oid)
            if old is None:
                self._add_entity(s, ent)
            elif not reuse:
                if replace:
                    self._remove_entity(s, oid)
                    self._add_entity(s, ent)
                else:
                    status = x.Status.ERR_ALREADY_EXISTS
            elif same(old, ent):
                status = x.Status.OK_MATCHED
            elif replace:
                self._remove_entity(s, oid)
                self._add_entity(s, ent)
            else:
                status = x.Status.ERR_MISMATCH
        self._send_stream(s, reply_stream, S.STATUS, x.status(bytes(fields.request_id), oid, status))

    def _check_parent(self, s: Session, ent: Entity) -> int:
        need = {K.TOPIC: K.PARTICIPANT, K.PUBLISHER: K.PARTICIPANT, K.SUBSCRIBER: K.PARTICIPANT,
                K.DATAWRITER: K.PUBLISHER, K.DATAREADER: K.SUBSCRIBER, K.REQUESTER: K.PARTICIPANT,
                K.REPLIER: K.PARTICIPANT}.get(ent.kind)
        if need is None:
            return x.Status.OK
        parent = s.entities.get(ent.parent or b"")
        if parent is None or parent.kind != need:
            self._log(f"create_object | unknown parent {ent.parent.hex().upper() if ent.parent else '-'}")
            return x.Status.ERR_UNKNOWN_REFERENCE
        if ent.kind in (K.DATAWRITER, K.DATAREADER) and ent.topic_id is not None and ent.topic_id not in s.entities:
            return x.Status.ERR_UNKNOWN_REFERENCE
        if ent.kind in (K.DATAWRITER, K.DATAREADER, K.TOPIC) and not (ent.topic or ent.topic_id):
            return x.Status.ERR_INVALID_DATA
        return x.Status.OK

    def _add_entity(self, s: Session, ent: Entity) -> None:
        s.entities[ent.object_id] = ent
        self._log(f"create_{ent.kind_name} | client_key: 0x{s.key.hex().upper()}, "
                  f"object_id: 0x{ent.object_id.hex().upper()}")
        self._bridge_entity(s, ent, removed=False)

    def _remove_entity(self, s: Session, oid: bytes) -> None:
        # Deleting an object deletes its children (a participant takes its topics, publishers ...).
        children = [o for o, e in s.entities.items() if e.parent == oid or e.topic_id == oid]
        for child in children:
            if child in s.entities:
                self._remove_entity(s, child)
        ent = s.entities.pop(oid, None)
        s.reads.pop(oid, None)
        s.queued_bytes -= sum(len(c) for c in s.queued.pop(oid, ()))
        self._request_seq.pop((s.key, oid), None)
        if ent is not None:
            self._bridge_entity(s, ent, removed=True)

    def _delete(self, s: Session, stream: int, fields: Any) -> None:
        oid = bytes(fields.object_id)
        if oid[1] & 0x0F == K.CLIENT:
            self._log(f"delete_client | client_key: 0x{s.key.hex().upper()}")
            self._drop_session(s)
            self._log(f"destroy_session | client_key: 0x{s.key.hex().upper()}")
            self._send_none(s, S.STATUS, x.status(bytes(fields.request_id), oid))
            return
        status = x.Status.OK if oid in s.entities else x.Status.ERR_UNKNOWN_REFERENCE
        self._remove_entity(s, oid)
        reply_stream = x.STREAM_RELIABLE if stream >= 0x80 else x.STREAM_BEST_EFFORT
        self._send_stream(s, reply_stream, S.STATUS, x.status(bytes(fields.request_id), oid, status))

    # ------------------------------------------------------------------ data

    def _write_data(self, s: Session, flags: int, payload: bytes) -> bool:
        if flags & x.FORMAT_MASK != x.FORMAT_DATA or len(payload) < 4:
            return False
        oid = payload[2:4]
        ent = s.entities.get(oid)
        if ent is not None and ent.kind == K.REQUESTER:
            return self._request(s, ent, payload[:2], payload[4:])
        if ent is not None and ent.kind == K.REPLIER:
            return self._reply(s, ent, payload[4:])
        if ent is None or ent.kind != K.DATAWRITER:
            return False
        s.samples_in += 1
        topic, type_name = s.topic_of(ent)
        self.route(topic, type_name, payload[4:], reliable=bool(ent.reliable))
        if self.bridge is not None:
            self.counters["samples_bridged"] += 1
            self.bridge.publish(topic, type_name, payload[4:], s, ent)
        return True

    def route(self, topic: str | None, type_name: str | None, cdr: bytes, *, reliable: bool = True) -> int:
        """Hand a sample to every matching reader of every client (as the agent's DDS participants do)."""
        n = 0
        for s in list(self.by_key.values()):
            for ent in list(s.entities.values()):
                if ent.kind != K.DATAREADER:
                    continue
                r_topic, r_type = s.topic_of(ent)
                if r_topic != topic or (r_type and type_name and r_type != type_name):
                    continue
                if ent.reliable and not reliable:
                    continue  # a RELIABLE reader does not match a BEST_EFFORT writer (DDS QoS rules)
                self._deliver(s, ent, cdr)
                n += 1
        self.counters["samples_routed"] += n
        return n

    def _request(self, s: Session, requester: Entity, request_id: bytes, cdr: bytes) -> bool:
        """A requester's WRITE_DATA: to every replier of its request topic, behind the request's sample
        identity (what the replier echoes in its reply so that the reply finds this requester)."""
        s.samples_in += 1
        self.counters["requests"] += 1
        key = (s.key, requester.object_id)
        seq = self._request_seq.get(key, 0) + 1
        self._request_seq[key] = seq
        # A GUID unique per client and requester object; entity kind 0x03: a writer without key (RTPS).
        guid = b"\x01\x0f" + s.key + b"\x00\x00" + requester.object_id + b"\x00\x00" + b"\x00\x00\x01\x03"
        self._pending[guid + seq.to_bytes(8, "big")] = (s.key, requester.object_id, request_id)
        while len(self._pending) > MAX_PENDING_REQUESTS:
            self._pending.popitem(last=False)
        topic, type_name = requester.extra.get("request_topic"), requester.extra.get("request_type")
        for other in list(self.by_key.values()):
            for ent in list(other.entities.values()):
                if ent.kind != K.REPLIER or ent.extra.get("request_topic") != topic:
                    continue
                if type_name and ent.extra.get("request_type") and ent.extra["request_type"] != type_name:
                    continue
                # SequenceNumber_t {int32 high; uint32 low} in the replier's byte order (it echoes it as is).
                order = "little" if other.little_endian is not False else "big"
                identity = guid + (seq >> 32).to_bytes(4, order) + (seq & 0xFFFFFFFF).to_bytes(4, order)
                self.counters["samples_routed"] += 1
                self._deliver(other, ent, identity + cdr)
        self.route(topic, type_name, cdr)  # plain readers of the request topic see the request too
        return True

    def _reply(self, s: Session, replier: Entity, payload: bytes) -> bool:
        """A replier's WRITE_DATA (sample identity + reply): to the requester that sent that request, behind
        the request id and object id of the requester's WRITE_DATA (the client's on_reply reads them)."""
        if len(payload) < 24:
            return False
        s.samples_in += 1
        identity, cdr = payload[:24], payload[24:]
        # The sequence number comes back in the byte order it was sent in: this replier's.
        order = "little" if s.little_endian is not False else "big"
        seq = int.from_bytes(identity[16:20], order, signed=True) << 32 | int.from_bytes(identity[20:24], order)
        pending = self._pending.pop(identity[:16] + seq.to_bytes(8, "big", signed=True), None)
        self.route(replier.extra.get("reply_topic"), replier.extra.get("reply_type"), cdr)
        if pending is None:
            self.counters["replies_unmatched"] += 1
            return True
        key, requester_oid, request_id = pending
        other = self.by_key.get(key)
        requester = other.entities.get(requester_oid) if other is not None else None
        if requester is None or requester.kind != K.REQUESTER:
            self.counters["replies_unmatched"] += 1
            return True
        self.counters["replies_routed"] += 1
        self._deliver(other, requester, request_id + requester_oid + cdr)
        return True

    def _deliver(self, s: Session, reader: Entity, cdr: bytes) -> None:
        read = s.reads.get(reader.object_id)
        if read is None:
            # Kept for its next READ_DATA: its history depth (KEEP_LAST drops the oldest), within the session's
            # budget (beyond it, the new sample is dropped).
            q = s.queued.setdefault(reader.object_id, deque(maxlen=min(MAX_QUEUED, max(1, reader.depth))))
            out = len(q[0]) if len(q) == q.maxlen else 0
            if s.queued_bytes - out + len(cdr) > SESSION_QUEUE_BYTES:
                self.counters["samples_dropped"] += 1
                return
            q.append(cdr)
            s.queued_bytes += len(cdr) - out
            return
        if self._send_stream(s, read.stream_id, S.DATA, x.data(read.request_id, reader.object_id, cdr)):
            s.samples_out += 1
        if read.remaining is not None:
            read.remaining -= 1
            if read.remaining <= 0:
                del s.reads[reader.object_id]

    def _read_data(self, s: Session, fields: Any) -> None:
        oid = bytes(fields.object_id)
        ent = s.entities.get(oid)
        if ent is None or ent.kind not in (K.DATAREADER, K.REQUESTER, K.REPLIER):
            self._send_stream(s, x.STREAM_RELIABLE, S.STATUS,
                              x.status(bytes(fields.request_id), oid, x.Status.ERR_UNKNOWN_REFERENCE))
            return
        if fields.optional_delivery_control:
            max_samples = fields.delivery_control.max_samples
            remaining = None if max_samples == 0xFFFF else max_samples
        else:
            remaining = 1  # the agent's default delivery control
        s.reads.pop(oid, None)
        if remaining == 0:
            return
        s.reads[oid] = Read(bytes(fields.request_id), fields.preferred_stream_id, remaining)
        waiting = list(s.queued.pop(oid, ()))
        s.queued_bytes -= sum(len(c) for c in waiting)
        for cdr in waiting:
            if oid in s.reads:
                self._deliver(s, ent, cdr)

    # ------------------------------------------------------------------ bridge

    def _bridge_entity(self, s: Session, ent: Entity, removed: bool) -> None:
        if self.bridge is not None and ent.kind in (K.DATAWRITER, K.DATAREADER):
            topic, type_name = s.topic_of(ent)
            self.bridge.entity(s, ent, topic, type_name, removed)

    # ------------------------------------------------------------------ status

    def set_faults(self, **knobs: int) -> dict[str, int]:
        """``drop_next``: outgoing datagrams to drop; ``corrupt_status_agent``: STATUS_AGENTs sent with
        header 0x80 (X4b, which the client ignores)."""
        for key, value in knobs.items():
            if key not in self.faults:
                raise KeyError(f"unknown fault knob {key!r} (expected one of: {', '.join(self.faults)})")
            self.faults[key] = int(value)
        return dict(self.faults)

    def limits(self) -> dict[str, Any]:
        """The agent's bounds (see the module docstring), as the manifest and ``status`` show them."""
        return {"sessions": self.max_sessions, "session_timeout_s": self.session_timeout,
                "client_dead_s": CLIENT_DEAD_S, "entities_per_session": MAX_ENTITIES, "entities": MAX_ENTITIES_TOTAL,
                "representation_bytes": MAX_REPRESENTATION, "session_input_bytes": SESSION_INPUT_BYTES,
                "session_output_bytes": SESSION_OUTPUT_BYTES, "session_queue_bytes": SESSION_QUEUE_BYTES,
                "fragment_depth": MAX_FRAGMENT_DEPTH}

    def _wall(self) -> float:
        """Unix time now, on the bench's clock (the wall clock for an agent not on a net)."""
        clock = self.port.clock if self.port is not None else WALL
        return clock.wall(clock.now())

    def status(self) -> dict[str, Any]:
        now = self.port.now() if self.port is not None else WALL.now()
        return {"name": self.name, "zeroed": self.zeroed, "counters": dict(self.counters),
                "sessions": [s.describe(now) for s in list(self.sessions.values())], "faults": dict(self.faults),
                "limits": self.limits(), "log": list(self.log)[-30:]}


__all__ = ["CLIENT_DEAD_S", "HEARTBEAT_PERIOD", "MAX_ENTITIES", "MAX_ENTITIES_TOTAL", "MAX_FRAGMENT_DEPTH",
           "MAX_REPRESENTATION", "MAX_SESSIONS", "SESSION_INPUT_BYTES", "SESSION_OUTPUT_BYTES", "SESSION_QUEUE_BYTES",
           "SESSION_TIMEOUT_S", "Read", "Session", "XrceAgent"]
