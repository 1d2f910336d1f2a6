"""A minimal RTPS participant on 127.0.0.1 unicast: SPDP, SEDP, user writers and readers (spec sheet §2, §3.3c).

What a standard DDS participant (Cyclone DDS, Fast DDS) needs to discover and
talk to a FreeRTPS board, without multicast:

- two sockets on the standard unicast ports of the domain and participant
  index (metatraffic ``7410 + 250 d + 2 p``, user ``7411 + 250 d + 2 p``), and
  those exact locators in the SPDP announcement;
- SPDP DATA(p) every :attr:`~RtpsParticipant.spdp_period` to each peer's metatraffic unicast
  ports (every participant index up to ``max_index`` of a peer host, or an
  explicit ``host:port``) instead of the multicast group, with an incrementing
  sequence number; an unknown participant's SPDP is answered at once;
- SEDP publications and subscriptions, reliable: DATA to each discovered
  participant, HEARTBEATs while unacknowledged, resent on NACK; the peer's SEDP
  is acknowledged (INFO_DST + ACKNACK, as R5);
- matching on exact topic and type names and compatible reliability;
- user DATA as INFO_TS + DATA (FreeRTPS's 60 + n byte messages) to each matched
  reader; reliable writers keep a history, HEARTBEAT and answer NACKs (GAP for
  what they no longer have); readers take DATA with or without INFO_TS and
  inline QoS and answer HEARTBEATs.

What a remote participant announces is checked before anything is sent to it:

- an announcement with an invalid locator (port 0 or above 65535, junk in an
  IPv4 address prefix: :func:`~hilbench.protocols.rtps.locator_problem`) is
  dropped whole, as Cyclone DDS drops it (``invalid_locators``);
- only UDPv4 unicast locators are used, at most :data:`MAX_LOCATORS` each, and
  only on ports from :data:`LOCATOR_PORTS` (the RTPS port base up: below it are
  the machine's services, never a participant's; ``locators_refused``); traffic
  goes only to loopback: a participant that announces no loopback locator is
  reached at 127.0.0.1 on its ports (a DDS on this machine announcing its LAN
  address listens there too; ``non_loopback_locators``), multicast never;
- at most :data:`MAX_REMOTES` participants are kept (a newcomer beyond is
  ignored until a lease ends: ``participants_refused``) with at most
  :data:`MAX_REMOTE_ENDPOINTS` writers and readers (:data:`MAX_REMOTE_ENDPOINTS_EACH`
  per participant; ``endpoints_refused``); a participant is forgotten when it
  has sent nothing for its lease duration (the SPDP's, :data:`DEFAULT_LEASE_S`
  if it names none, at most :data:`MAX_LEASE_S`; ``participants_expired``);
- SEDP, HEARTBEATs and ACKNACKs of participants it does not know are ignored
  (``unknown_participant``), sequence numbers outside 1..2^62 are malformed.

Everything runs in the datagram net's thread (no locks).
"""

from __future__ import annotations

import ipaddress
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hilbench.protocols import rtps as r

log = logging.getLogger(__name__)
Address = tuple[str, int]
#: A reliable writer's history (samples kept for retransmission).
HISTORY = 32
#: A reader's per-writer memory of received sequence numbers (for ACKNACK bitmaps).
SEEN = 256
#: Remote participants kept at once; a newcomer beyond is ignored until one's lease ends.
MAX_REMOTES = 64
#: Remote writers and readers (from SEDP) kept per remote participant, and in all.
MAX_REMOTE_ENDPOINTS_EACH = 256
MAX_REMOTE_ENDPOINTS = 2048  #: in all
#: Unicast locators kept per participant or endpoint (the first usable ones).
MAX_LOCATORS = 4
#: Longest topic, type or participant name kept; an endpoint with a longer one is refused.
MAX_NAME = 256
#: The lease of an SPDP that names none (the DDS default), and the longest one honoured.
DEFAULT_LEASE_S = 100.0
MAX_LEASE_S = 300.0  #: the longest lease honoured
#: Ports a remote locator may name: from the RTPS port base PB (7400) up, where the standard mapping and
#: the ephemeral ports of participants that pick their own lie; below are the machine's services.
LOCATOR_PORTS = (r.PB, 65535)
#: Sequence numbers beyond this are not believed (they are signed 64-bit; ACKNACK windows need headroom).
MAX_SN = 2**62


def loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


@dataclass
class Remote:
    """A discovered participant."""

    prefix: bytes
    meta: list[Address]
    user: list[Address]
    lease_s: float = DEFAULT_LEASE_S
    last_spdp: float = 0.0
    last_seen: float = 0.0  # any message from it renews its lease, as in Cyclone DDS
    vendor_id: bytes = b""
    name: str | None = None
    spdp_count: int = 0
    endpoints: set[bytes] = field(default_factory=set)  # guids of its writers and readers we keep


@dataclass
class RemoteRtpsEndpoint:
    guid: bytes
    topic: str
    type_name: str
    reliable: bool
    writer: bool
    locators: list[Address] = field(default_factory=list)


@dataclass
class LocalWriter:
    """A user (or SEDP) writer: next SN, history, matched readers (guid -> ack state)."""

    entity_id: bytes
    topic: str
    type_name: str
    reliable: bool = False
    sn: int = 0
    history: deque[tuple[int, bytes]] = field(default_factory=lambda: deque(maxlen=HISTORY))
    matched: dict[bytes, int] = field(default_factory=dict)  # reader guid -> highest SN it acknowledged
    hb_count: int = 0
    sent: int = 0


@dataclass
class LocalReader:
    """A user reader: callback(payload_cdr, little_endian, writer_guid, info_ts)."""

    entity_id: bytes
    topic: str
    type_name: str
    callback: Callable[[bytes, bool, bytes, float | None], None]
    reliable: bool = False
    matched: set[bytes] = field(default_factory=set)
    received: int = 0


@dataclass
class _WriterState:
    """What a reader side knows of one remote writer: SNs seen, for ACKNACKs and duplicates."""

    seen: set[int] = field(default_factory=set)
    base: int = 1  # everything below arrived (or was declared irrelevant)
    count: int = 0

    def add(self, sn: int) -> bool:
        if sn < self.base or sn in self.seen:
            return False
        self.seen.add(sn)
        while self.base in self.seen:
            self.seen.discard(self.base)
            self.base += 1
        if len(self.seen) > SEEN:
            self.seen = set(sorted(self.seen)[-SEEN:])
        return True

    def skip_to(self, sn: int) -> None:
        if sn > self.base:
            self.seen = {s for s in self.seen if s >= sn}
            self.base = sn
            while self.base in self.seen:
                self.seen.discard(self.base)
                self.base += 1


class RtpsParticipant:
    """One participant on a datagram net (through a device's :class:`DatagramDevicePort <hilbench.transports.datagram_medium.DatagramDevicePort>`); see the module docstring."""

    def __init__(self, name: str, port: Any, *, domain_id: int, participant_index: int, guid_prefix: bytes,
                 peers: list[Address | str] | None = None, vendor_id: bytes = r.VENDOR_FREERTPS,
                 pl_vendor_id: bytes = b"\x2c\x2f", max_index: int = 9, spdp_period: float = 1.0,
                 heartbeat_period: float = 0.1, lease_s: int = 100, clock: str = "uptime",
                 entity_name: str | None = None, max_remotes: int = MAX_REMOTES) -> None:
        self.name = name
        self.port = port
        self.domain_id = domain_id
        self.index = participant_index
        self.prefix = guid_prefix
        self.vendor_id = vendor_id
        self.pl_vendor_id = pl_vendor_id
        self.max_index = max_index
        self.spdp_period = spdp_period  #: seconds between SPDP announcements
        self.heartbeat_period = heartbeat_period
        self.lease_s = lease_s
        self.clock = clock  # "wall", or anything else: uptime on FreeRTPS's fake epoch (a node's `clock` key)
        self.entity_name = entity_name
        self.max_remotes = max_remotes
        self.ports = r.ports(domain_id, participant_index)
        self.peers = list(peers if peers is not None else ["127.0.0.1"])
        self.meta_sock: Any = None
        self.user_sock: Any = None
        self.remotes: dict[bytes, Remote] = {}
        self.remote_endpoints: dict[bytes, RemoteRtpsEndpoint] = {}
        self.writers: dict[bytes, LocalWriter] = {}
        self.readers: dict[bytes, LocalReader] = {}
        self.sedp = {r.SEDP_PUB_WRITER: LocalWriter(r.SEDP_PUB_WRITER, "DCPSPublication", "", True),
                     r.SEDP_SUB_WRITER: LocalWriter(r.SEDP_SUB_WRITER, "DCPSSubscription", "", True)}
        self._sedp_key: dict[bytes, tuple[bytes, int]] = {}  # local endpoint id -> (sedp writer, sn)
        self._remote_writers: dict[tuple[bytes, bytes], _WriterState] = {}  # (writer guid, reader id)
        self._next_entity = 1
        self.spdp_sn = 0
        self.started = 0.0
        self.counters = dict.fromkeys(("datagrams", "malformed", "spdp_sent", "spdp_received", "sedp_sent",
                                       "sedp_received", "data_sent", "data_received", "acknacks_sent",
                                       "heartbeats_sent", "retransmissions", "non_loopback_locators",
                                       "foreign", "invalid_locators", "locators_refused", "unreachable",
                                       "participants_discovered", "participants_refused", "participants_expired",
                                       "endpoints_refused", "unknown_participant", "send_refused"), 0)
        self._running = False
        self._vendor = b""

    # ------------------------------------------------------------------ set-up

    @property
    def guid(self) -> bytes:
        return self.prefix + r.ENTITYID_PARTICIPANT

    def open(self) -> None:
        """Bind the metatraffic and user unicast sockets (OSError if a port is taken)."""
        self.meta_sock = self.port.open_socket("127.0.0.1", self.ports["metatraffic_unicast"])
        try:
            self.user_sock = self.port.open_socket("127.0.0.1", self.ports["user_unicast"])
        except OSError:
            self.meta_sock.close()
            raise

    def new_entity(self, kind: int) -> bytes:
        """The next user entity id (FreeRTPS numbers writers and readers with one counter from 1)."""
        eid = self._next_entity.to_bytes(3, "big") + bytes([kind])
        self._next_entity += 1
        return eid

    def add_writer(self, topic: str, type_name: str, *, reliable: bool = False,
                   partition: str | None = None) -> LocalWriter:
        w = LocalWriter(self.new_entity(r.KIND_WRITER_NO_KEY), topic, type_name, reliable)
        self.writers[w.entity_id] = w
        self._announce(w.entity_id, topic, type_name, reliable, writer=True, partition=partition)
        self._match_all()
        return w

    def add_reader(self, topic: str, type_name: str, callback: Callable[..., None], *,
                   reliable: bool = False, partition: str | None = None) -> LocalReader:
        rd = LocalReader(self.new_entity(r.KIND_READER_NO_KEY), topic, type_name, callback, reliable)
        self.readers[rd.entity_id] = rd
        self._announce(rd.entity_id, topic, type_name, reliable, writer=False, partition=partition)
        self._match_all()
        return rd

    def remove(self, entity_id: bytes) -> None:
        """Forget a local writer or reader (its announcement is disposed for participants found later)."""
        self.writers.pop(entity_id, None)
        self.readers.pop(entity_id, None)
        key = self._sedp_key.pop(entity_id, None)
        if key is not None:
            sedp, sn = key
            w = self.sedp[sedp]
            w.history = deque(((s, p) for s, p in w.history if s != sn), maxlen=None)

    def _announce(self, eid: bytes, topic: str, type_name: str, reliable: bool, writer: bool,
                  partition: str | None = None) -> None:
        w = self.sedp[r.SEDP_PUB_WRITER if writer else r.SEDP_SUB_WRITER]
        w.history = deque(w.history, maxlen=None)  # SEDP keeps every announcement
        w.sn += 1
        payload = r.sedp_payload(self.prefix + eid, topic, type_name, reliable=reliable, vendor_id=self.pl_vendor_id,
                                 unicast=("127.0.0.1", self.ports["user_unicast"]), participant_guid=self.guid,
                                 partition=partition)
        w.history.append((w.sn, payload))
        self._sedp_key[eid] = (w.entity_id, w.sn)
        if self._running:
            for remote in self.remotes.values():
                self._send_sedp(remote, w, [(w.sn, payload)])

    # ------------------------------------------------------------------ running

    def start(self) -> None:
        self._running = True
        self.started = self.port.now()
        self.port.call_at(None, self._spdp_tick)
        self.port.call_at(self.port.now() + self.heartbeat_period, self._heartbeat_tick)

    def stop(self) -> None:
        self._running = False

    def now_ts(self) -> tuple[int, int]:
        """INFO_TS time: FreeRTPS's fake epoch plus uptime (§2.6), or the wall clock."""
        if self.clock == "wall":
            return r.time_parts(self.port.clock.wall(self.port.now()))
        up = self.port.now() - self.started
        us = int(up * 1e6) & 0xFFFFFFFF  # the board's 32-bit microsecond counter wraps every 71.6 min
        return r.FREERTPS_EPOCH + us // 1_000_000, ((us % 1_000_000) << 32) // 1_000_000

    def _send(self, sock: Any, dst: Address, *subs: bytes) -> None:
        host, port_no = dst
        if not 0 < port_no < 65536:  # (remote locators are checked when heard; this guards the rest)
            self.counters["send_refused"] += 1
            return
        if not loopback(host):
            self.counters["non_loopback_locators"] += 1
            host = "127.0.0.1"  # this bench talks to loopback only
        self.port.send(r.message(self.prefix, *subs, vendor_id=self.vendor_id), (host, port_no), via=sock)

    def _usable(self, locators: list[tuple[int, str, int]]) -> list[Address]:
        """The announced locators this participant sends to (see the module docstring); counts the rest."""
        near: list[Address] = []
        far: list[Address] = []
        low, high = LOCATOR_PORTS
        for kind, host, port_no in locators:
            if kind != r.LOCATOR_KIND_UDPV4:
                continue  # IPv6, TCP, vendor kinds: not ours to reach (a receiver skips them)
            if not low <= port_no <= high:
                self.counters["locators_refused"] += 1
                continue
            try:
                addr = ipaddress.IPv4Address(host)
            except ValueError:
                continue
            if addr.is_loopback:
                near.append((host, port_no))
            elif addr.is_multicast or addr.is_unspecified or addr.packed == b"\xff" * 4:
                self.counters["locators_refused"] += 1
            else:
                far.append(("127.0.0.1", port_no))
        if not near and far:
            self.counters["non_loopback_locators"] += len(far)
        return list(dict.fromkeys(near or far))[:MAX_LOCATORS]

    def _spdp_targets(self) -> list[Address]:
        out: list[Address] = []
        for peer in self.peers:
            if isinstance(peer, tuple):
                out.append(peer)
                continue
            host, _, port_text = peer.rpartition(":") if ":" in peer else (peer, "", "")
            if port_text:
                out.append((host, int(port_text)))
                continue
            for i in range(self.max_index + 1):
                p = r.ports(self.domain_id, i)["metatraffic_unicast"]
                if not (loopback(peer) and i == self.index):
                    out.append((peer, p))
        for remote in self.remotes.values():
            out.extend(a for a in remote.meta if a not in out)
        return out

    def _spdp_message(self, final: bool = True) -> bytes:
        self.spdp_sn += 1
        payload = r.spdp_payload(self.prefix, meta_port=self.ports["metatraffic_unicast"],
                                 user_port=self.ports["user_unicast"], lease_s=self.lease_s,
                                 vendor_id=self.pl_vendor_id, domain_id=self.domain_id, name=self.entity_name)
        return r.info_ts(*self.now_ts()) + r.data(r.ENTITYID_UNKNOWN, r.SPDP_WRITER, self.spdp_sn, payload,
                                                  inline_qos=r.key_hash_qos(self.guid))

    def _spdp_tick(self) -> None:
        if not self._running:
            return
        now = self.port.now()
        self.port.call_at(now + self.spdp_period, self._spdp_tick)  # first: nothing below can stop the timer
        subs = self._spdp_message()
        for dst in self._spdp_targets():
            self._send(self.meta_sock, dst, subs)
            self.counters["spdp_sent"] += 1
        # SEDP is reliable: HEARTBEATs to each participant that has not acknowledged every announcement.
        for remote in list(self.remotes.values()):
            for w in self.sedp.values():
                if w.history and w.matched.get(remote.prefix + _sedp_reader(w.entity_id), 0) < w.sn:
                    self._sedp_heartbeat(remote, w)
        self._expire(now)

    def _expire(self, now: float) -> None:
        """Forget every participant silent for its lease duration (as real participants do)."""
        for prefix, remote in list(self.remotes.items()):
            if now - remote.last_seen > remote.lease_s:
                self._forget(prefix)
                self.counters["participants_expired"] += 1

    def _heartbeat_tick(self) -> None:
        if not self._running:
            return
        self.port.call_at(self.port.now() + self.heartbeat_period, self._heartbeat_tick)
        for w in self.writers.values():
            if w.reliable and w.history and any(acked < w.sn for acked in w.matched.values()):
                self._user_heartbeat(w)

    # ------------------------------------------------------------------ SEDP out

    def _send_sedp(self, remote: Remote, w: LocalWriter, items: list[tuple[int, bytes]]) -> None:
        reader = _sedp_reader(w.entity_id)
        for sn, payload in items:
            for dst in remote.meta[:1]:
                self._send(self.meta_sock, dst, r.info_dst(remote.prefix), r.info_ts(*self.now_ts()),
                           r.data(reader, w.entity_id, sn, payload))
                self.counters["sedp_sent"] += 1
        self._sedp_heartbeat(remote, w)

    def _sedp_heartbeat(self, remote: Remote, w: LocalWriter) -> None:
        first = w.history[0][0] if w.history else w.sn + 1
        w.hb_count += 1
        for dst in remote.meta[:1]:
            self._send(self.meta_sock, dst, r.info_dst(remote.prefix),
                       r.heartbeat(_sedp_reader(w.entity_id), w.entity_id, first, w.sn, w.hb_count))
            self.counters["heartbeats_sent"] += 1

    # ------------------------------------------------------------------ user data out

    def write(self, writer: LocalWriter, cdr: bytes, little_endian: bool = True) -> int:
        """Publish one sample (raw CDR without encapsulation) to every matched reader; returns how many."""
        writer.sn += 1
        payload = (r.CDR_LE if little_endian else b"\x00\x00") + b"\x00\x00" + cdr
        if writer.reliable:
            writer.history.append((writer.sn, payload))
        n = 0
        for guid in list(writer.matched):
            ep = self.remote_endpoints.get(guid)
            if ep is None:
                continue
            for dst in self._locators(ep)[:1]:
                self._send(self.user_sock, dst, r.info_ts(*self.now_ts()),
                           r.data(guid[12:], writer.entity_id, writer.sn, payload))
                self.counters["data_sent"] += 1
                n += 1
        writer.sent += 1
        return n

    def _user_heartbeat(self, w: LocalWriter) -> None:
        first = w.history[0][0] if w.history else w.sn + 1
        w.hb_count += 1
        for guid in list(w.matched):
            ep = self.remote_endpoints.get(guid)
            if ep is None or not ep.reliable:
                continue
            for dst in self._locators(ep)[:1]:
                self._send(self.user_sock, dst, r.info_dst(guid[:12]),
                           r.heartbeat(guid[12:], w.entity_id, first, w.sn, w.hb_count))
                self.counters["heartbeats_sent"] += 1

    def _locators(self, ep: RemoteRtpsEndpoint) -> list[Address]:
        if ep.locators:
            return ep.locators
        remote = self.remotes.get(ep.guid[:12])
        return remote.user if remote is not None else []

    # ------------------------------------------------------------------ matching

    def _match_all(self) -> None:
        for ep in self.remote_endpoints.values():
            self._match(ep)

    def _match(self, ep: RemoteRtpsEndpoint) -> None:
        if ep.writer:
            for rd in self.readers.values():
                if rd.topic == ep.topic and rd.type_name == ep.type_name and (ep.reliable or not rd.reliable):
                    rd.matched.add(ep.guid)
        else:
            for w in self.writers.values():
                if w.topic == ep.topic and w.type_name == ep.type_name and (w.reliable or not ep.reliable):
                    w.matched.setdefault(ep.guid, w.sn)

    def _unmatch(self, guid: bytes) -> None:
        for rd in self.readers.values():
            rd.matched.discard(guid)
        for w in self.writers.values():
            w.matched.pop(guid, None)

    def _forget(self, prefix: bytes) -> None:
        remote = self.remotes.pop(prefix, None)
        if remote is not None:
            remote.endpoints.clear()
        for guid in [g for g in self.remote_endpoints if g[:12] == prefix]:
            self._unmatch(guid)
            del self.remote_endpoints[guid]
        for key in [k for k in self._remote_writers if k[0][:12] == prefix]:
            del self._remote_writers[key]
        for w in self.sedp.values():
            for g in [g for g in w.matched if g[:12] == prefix]:
                del w.matched[g]

    # ------------------------------------------------------------------ input

    def on_datagram(self, data: bytes, src: Address, dst: Address, t: float) -> None:
        self.counters["datagrams"] += 1
        msg = r.parse_message(data)
        if msg.flags and ("rtps.bad_magic" in msg.flags or "rtps.too_short" in msg.flags):
            self.counters["foreign"] += 1  # FreeRTPS discards non-RTPS datagrams
            return
        if msg.flags:
            self.counters["malformed"] += 1
        if msg.guid_prefix == self.prefix:
            return  # our own message (a receiver drops those, §2.3)
        src_prefix = msg.guid_prefix
        known = self.remotes.get(src_prefix)
        if known is not None:
            known.last_seen = self.port.now()
        self._vendor = msg.vendor_id
        dest = None
        ts: float | None = None
        for sub in msg.submessages:
            if sub.problem or sub.fields is None and sub.id in (r.SubmessageId.DATA, r.SubmessageId.HEARTBEAT,
                                                                 r.SubmessageId.ACKNACK, r.SubmessageId.GAP):
                continue
            f = sub.fields or {}
            if sub.id == r.SubmessageId.INFO_DST:
                dest = f["guid_prefix"]
            elif sub.id == r.SubmessageId.INFO_SRC:
                src_prefix = f["guid_prefix"]
            elif sub.id == r.SubmessageId.INFO_TS:
                ts = None if f.get("invalidate") else f["seconds"] + f["fraction"] / 2**32
            elif dest not in (None, b"\x00" * 12, self.prefix):
                continue  # for another participant
            elif sub.id == r.SubmessageId.DATA:
                self._on_data(src_prefix, f, src, ts, sub.flags)
            elif sub.id == r.SubmessageId.HEARTBEAT:
                self._on_heartbeat(src_prefix, f, src)
            elif sub.id == r.SubmessageId.ACKNACK:
                self._on_acknack(src_prefix, f)
            elif sub.id == r.SubmessageId.GAP:
                state = self._remote_writers.get((src_prefix + f["writer_id"], f["reader_id"]))
                if state is not None and 0 < f["list_base"] < MAX_SN:
                    state.skip_to(f["list_base"])

    def _on_data(self, src_prefix: bytes, f: dict[str, Any], src: Address, ts: float | None, flags: int) -> None:
        writer_id, reader_id = f["writer_id"], f["reader_id"]
        if writer_id == r.SPDP_WRITER:
            self._on_spdp(src_prefix, f, src)
            return
        if not 0 < f["sn"] < MAX_SN:
            self.counters["malformed"] += 1
            return
        if writer_id in (r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER):
            if src_prefix not in self.remotes:
                self.counters["unknown_participant"] += 1  # (it announces itself first; SEDP is resent)
                return
            key = (src_prefix + writer_id, _sedp_reader(writer_id))
            state = self._remote_writers.setdefault(key, _WriterState())
            state.add(f["sn"])
            self.counters["sedp_received"] += 1
            self._on_sedp(src_prefix, writer_id == r.SEDP_PUB_WRITER, f, flags)
            return
        wguid = src_prefix + writer_id
        payload = f.get("payload")
        if payload is None or len(payload) < 4:
            return
        for rd in self.readers.values():
            if wguid not in rd.matched or reader_id not in (r.ENTITYID_UNKNOWN, rd.entity_id):
                continue
            state = self._remote_writers.setdefault((wguid, rd.entity_id), _WriterState())
            ep = self.remote_endpoints.get(wguid)
            if not state.add(f["sn"]) and ep is not None and ep.reliable:
                continue  # a retransmission we had already
            rd.received += 1
            self.counters["data_received"] += 1
            le = payload[1] & 1 == 1
            try:
                rd.callback(payload[4:], le, wguid, ts)
            except Exception:
                log.exception("%s: reader %s failed", self.name, rd.topic)

    def _on_spdp(self, prefix: bytes, f: dict[str, Any], src: Address) -> None:
        p = f.get("parameters") or {}
        guid = p.get("participant_guid") or (f.get("inline_qos") or {}).get("key_hash")
        if guid is None:
            return
        prefix = guid[:12]
        if prefix == self.prefix:
            return
        if "domain_id" in p and p["domain_id"] != self.domain_id:
            return
        self.counters["spdp_received"] += 1
        if p.get("locator_problems"):
            self.counters["invalid_locators"] += 1  # the whole announcement is invalid (Cyclone DDS)
            return
        announced = p.get("metatraffic_unicast_locator")
        # Without a metatraffic locator, answers go where it spoke from (the same rules apply).
        meta = self._usable(announced if announced else [(r.LOCATOR_KIND_UDPV4, src[0], src[1])])
        user = self._usable(p.get("default_unicast_locator", [])) or meta
        if not meta:
            self.counters["unreachable"] += 1
            return
        now = self.port.now()
        remote = self.remotes.get(prefix)
        new = remote is None
        if new:
            if len(self.remotes) >= self.max_remotes:
                self._expire(now)
            if len(self.remotes) >= self.max_remotes:
                self.counters["participants_refused"] += 1
                return
            remote = self.remotes[prefix] = Remote(prefix, meta, user)
            self.counters["participants_discovered"] += 1
        remote.meta, remote.user = meta, user
        lease = p.get("lease_s")
        remote.lease_s = min(lease, MAX_LEASE_S) if lease is not None and lease > 0 else DEFAULT_LEASE_S
        remote.vendor_id = self._vendor  # the header's (FreeRTPS's PL vendor id differs, §2.3)
        name = p.get("name")
        remote.name = name[:MAX_NAME] if name else None
        remote.last_spdp = remote.last_seen = now
        remote.spdp_count += 1
        if new:
            # Answer a newcomer at once, then tell it our endpoints (FreeRTPS's unicast catch-up).
            for dst in meta[:1]:
                self._send(self.meta_sock, dst, self._spdp_message())
                self.counters["spdp_sent"] += 1
            for w in self.sedp.values():
                if w.history:
                    self._send_sedp(remote, w, list(w.history))

    def _on_sedp(self, prefix: bytes, publication: bool, f: dict[str, Any], flags: int) -> None:
        p = f.get("parameters")
        if p is None:
            # A key-only DATA (dispose/unregister): the endpoint is gone.
            kh = (f.get("inline_qos") or {}).get("key_hash")
            if kh is not None and kh[:12] == prefix and kh in self.remote_endpoints:
                self._unmatch(kh)
                del self.remote_endpoints[kh]
                if (remote := self.remotes.get(prefix)) is not None:
                    remote.endpoints.discard(kh)
            return
        guid = p.get("endpoint_guid") or (f.get("inline_qos") or {}).get("key_hash")
        if guid is None or "topic" not in p or "type" not in p:
            return
        remote = self.remotes.get(guid[:12])
        if remote is None:
            self.counters["unknown_participant"] += 1  # an endpoint of a participant nobody announced
            return
        if p.get("locator_problems"):
            self.counters["invalid_locators"] += 1
            return
        full = len(remote.endpoints) >= MAX_REMOTE_ENDPOINTS_EACH or len(self.remote_endpoints) >= MAX_REMOTE_ENDPOINTS
        if (full and guid not in self.remote_endpoints) or max(len(p["topic"]), len(p["type"])) > MAX_NAME:
            self.counters["endpoints_refused"] += 1
            return
        locs = self._usable(p.get("unicast_locator", []))  # none usable: the participant's own
        ep = RemoteRtpsEndpoint(guid, p["topic"], p["type"], bool(p.get("reliable", publication)), publication, locs)
        if not publication and "reliable" not in p:
            ep.reliable = False  # a reader's default reliability is best effort
        self.remote_endpoints[guid] = ep
        remote.endpoints.add(guid)
        self._unmatch(guid)
        self._match(ep)

    def _on_heartbeat(self, src_prefix: bytes, f: dict[str, Any], src: Address) -> None:
        writer_id, reader_id = f["writer_id"], f["reader_id"]
        if not (0 < f["first_sn"] < MAX_SN and f["first_sn"] - 1 <= f["last_sn"] < MAX_SN):
            self.counters["malformed"] += 1  # (Cyclone DDS's validity rules for a HEARTBEAT)
            return
        wguid = src_prefix + writer_id
        targets: list[bytes] = []
        if writer_id in (r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER):
            if src_prefix not in self.remotes:
                self.counters["unknown_participant"] += 1
                return
            targets = [_sedp_reader(writer_id)]
        else:
            targets = [rd.entity_id for rd in self.readers.values() if wguid in rd.matched and
                       reader_id in (r.ENTITYID_UNKNOWN, rd.entity_id)]
        for rid in targets:
            state = self._remote_writers.setdefault((wguid, rid), _WriterState())
            state.skip_to(f["first_sn"])
            if f["final"] and state.base > f["last_sn"]:
                continue
            missing = [sn for sn in range(state.base, min(f["last_sn"], state.base + 255) + 1)
                       if sn not in state.seen]
            state.count += 1
            remote = self.remotes.get(src_prefix)
            if remote is None:
                continue  # (a matched writer's participant expired meanwhile)
            dsts = remote.meta if writer_id in (r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER) else remote.user
            sock = self.meta_sock if writer_id in (r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER) else self.user_sock
            for dst in dsts[:1]:
                self._send(sock, dst, r.info_dst(src_prefix),
                           r.acknack(rid, writer_id, state.base, missing, state.count, final=not missing))
                self.counters["acknacks_sent"] += 1

    def _on_acknack(self, src_prefix: bytes, f: dict[str, Any]) -> None:
        writer_id = f["writer_id"]
        w = self.sedp.get(writer_id) or self.writers.get(writer_id)
        remote = self.remotes.get(src_prefix)
        if w is None or remote is None:
            if w is not None:
                self.counters["unknown_participant"] += 1
            return
        if not 0 < f["base"] < MAX_SN:
            self.counters["malformed"] += 1
            return
        sedp = writer_id in self.sedp
        # A SEDP writer keeps one state per participant; a user writer only for readers it matched.
        rguid = src_prefix + (_sedp_reader(writer_id) if sedp else f["reader_id"])
        if not sedp and rguid not in w.matched:
            return
        w.matched[rguid] = max(w.matched.get(rguid, 0), f["base"] - 1)
        if not f["missing"]:
            return
        have = dict(w.history)
        dsts = remote.meta if sedp else self._locators(self.remote_endpoints.get(rguid) or
                                                       RemoteRtpsEndpoint(rguid, "", "", False, False))
        sock = self.meta_sock if sedp else self.user_sock
        lost = [sn for sn in f["missing"] if sn not in have]
        for dst in dsts[:1]:
            if lost:
                first_kept = min(have) if have else w.sn + 1
                self._send(sock, dst, r.info_dst(src_prefix), r.gap(f["reader_id"], writer_id, min(lost), first_kept))
            for sn in f["missing"]:
                if sn in have:
                    self._send(sock, dst, r.info_dst(src_prefix), r.info_ts(*self.now_ts()),
                               r.data(f["reader_id"], writer_id, sn, have[sn]))
                    self.counters["retransmissions"] += 1

    # ------------------------------------------------------------------ description

    def describe(self) -> dict[str, Any]:
        return {"guid_prefix": self.prefix.hex(), "domain_id": self.domain_id, "participant_index": self.index,
                "ports": {"metatraffic_unicast": self.ports["metatraffic_unicast"],
                          "user_unicast": self.ports["user_unicast"]},
                "peers": [r.guid_text(p) for p in list(self.remotes)],
                "remote_endpoints": len(self.remote_endpoints), "limits": limits(self.max_remotes)}

    def overflow(self) -> dict[str, Any]:
        """Its limits and the remote participants, endpoints and locators it refused or expired (the bench's
        ``overflow``: :mod:`hilbench.bench.overflow`), with the remote participants it keeps now."""
        c = self.counters
        return {"limits": limits(self.max_remotes), **{k: c[k] for k in OVERFLOW_COUNTERS},
                "remote_participants": len(self.remotes)}


#: A participant's counters of what its bounds turned away (:meth:`RtpsParticipant.overflow`).
OVERFLOW_COUNTERS = ("participants_refused", "participants_expired", "endpoints_refused", "locators_refused",
                     "invalid_locators", "send_refused")


def limits(max_remotes: int = MAX_REMOTES) -> dict[str, Any]:
    """A participant's bounds, as the manifest and ``status`` show them."""
    return {"participants": max_remotes, "endpoints": MAX_REMOTE_ENDPOINTS,
            "endpoints_per_participant": MAX_REMOTE_ENDPOINTS_EACH, "locators_per_participant": MAX_LOCATORS,
            "locator_ports": list(LOCATOR_PORTS), "default_lease_s": DEFAULT_LEASE_S, "max_lease_s": MAX_LEASE_S}


def _sedp_reader(writer_id: bytes) -> bytes:
    return writer_id[:3] + b"\xc7"


__all__ = ["DEFAULT_LEASE_S", "LOCATOR_PORTS", "MAX_LEASE_S", "MAX_LOCATORS", "MAX_REMOTES", "MAX_REMOTE_ENDPOINTS",
           "MAX_REMOTE_ENDPOINTS_EACH", "OVERFLOW_COUNTERS", "LocalReader", "LocalWriter", "Remote", "RemoteRtpsEndpoint", "RtpsParticipant",
           "limits", "loopback"]
