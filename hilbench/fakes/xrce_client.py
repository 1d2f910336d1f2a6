"""A Micro XRCE-DDS client as micro-ROS (``rmw_microxrcedds``) runs it on a board, over UDP.

The subset of spec sheet §3.3 (a) that a real agent (eProsima's, micro-ROS's)
or hilbench's accepts: ping (GET_INFO) until the agent answers, CREATE_CLIENT
with a non-zero key and session 0x81 (resent every second, ten times), time
sync (TIMESTAMP), entities created in binary on reliable stream 0x80 (the way
``rmw_microxrcedds`` does), READ_DATA per subscription, WRITE_DATA on the
best-effort (0x01) or reliable (0x80) output stream, and both reliable
streams kept as the client library keeps them: up to four unacknowledged
messages, a HEARTBEAT every 100 ms while any are, NACKed ones resent, every
agent message and HEARTBEAT answered with an ACKNACK. DATA arrives at the
subscription's callback with its raw CDR.

On the wall clock the session runs on its own thread with a UDP socket. With ``net=`` (the bench's own
:class:`~hilbench.transports.datagram_medium.DatagramMedium`, on a virtual clock) the same session code
runs as a bench participant (:class:`~hilbench.transports.participant.Participant`): its thread holds a
baton while it runs, gets it back in events of the bench's loop (a datagram for it, a deadline), and its
datagrams go to and come from the net in process, so everything it does happens at deterministic virtual
instants. (A thread with a baton rather than a state machine: the blocking session code stays the one
implementation of both modes, and only its waits, its clock and its socket differ.)

Fault knob (Xu's cache-coherency bug, §1.9.4): :meth:`XrceClient.zero_next`
makes the next datagrams leave zero-filled after their first byte (``0x80``),
as the board's DMA sent stale RAM; ``zero_after_session`` does it to the first
datagram after the session is established, as in Xu's log.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import random
import selectors
import socket
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hilbench.protocols import xrce_dds as x
from hilbench.protocols.xrce_streams import ReliableInput
from hilbench.transports.clock import WALL
from hilbench.transports.medium_loop import WakePipe
from hilbench.transports.participant import Participant

log = logging.getLogger(__name__)
K = x.ObjectKind
S = x.SubmessageId
#: The client library's reliable history and HEARTBEAT interval (UXR_CONFIG_MIN_HEARTBEAT_TIME_INTERVAL).
HISTORY = 4
HEARTBEAT_S = 0.1
#: FRAGMENTs inside reassembled messages followed at most (deeper nests are dropped, never a RecursionError).
MAX_FRAGMENT_DEPTH = 4
#: micro-ROS's entity creation timeout.
CREATION_TIMEOUT_S = 1.0
#: Datagrams an in-process client keeps unread (a socket's receive buffer; more are dropped, as UDP does).
INBOX = 256


@dataclass
class Subscription:
    """A datareader with its callback(cdr, little_endian)."""

    topic: str
    type_name: str
    callback: Callable[[bytes, bool], None]
    reliable: bool = False
    reader: bytes = b""
    received: int = 0


@dataclass
class Publication:
    topic: str
    type_name: str
    reliable: bool = False
    writer: bytes = b""
    sent: int = 0


@dataclass
class _RelOut:
    first_unacked: int = 0
    last_sent: int = 0xFFFF
    history: dict[int, bytes] = field(default_factory=dict)
    waiting: list[bytes] = field(default_factory=list)  # submessages waiting for room (bounded)


class _SocketLink:
    """The wall clock's transport: a UDP socket, connected to the agent, waited on with poll."""

    def __init__(self, client: XrceClient) -> None:
        self.client = client
        host = client.agent[0]
        try:
            local = "127.0.0.1" if ipaddress.ip_address(host).is_loopback else ""
        except ValueError:
            local = ""
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((local, 0))  # one source port for the whole session (the agent keys it)
        # Connected, as the client library's UDP transport is: only the agent's datagrams are heard.
        with contextlib.suppress(OSError):
            self.sock.connect(client.agent)
        self.sock.setblocking(False)
        self.sel = selectors.DefaultSelector()  # (poll, as the library: any descriptor number)
        self.sel.register(self.sock, selectors.EVENT_READ)
        self.sel.register(client._waker.fd, selectors.EVENT_READ)
        self.thread: threading.Thread | None = None

    def start(self, target: Callable[[], None]) -> None:
        self.thread = threading.Thread(target=target, name=f"xrce-{self.client.name}", daemon=True)
        self.thread.start()

    def send(self, msg: bytes) -> None:
        self.sock.sendto(msg, self.client.agent)

    def recv(self, timeout: float) -> bytes | None:
        try:
            ready = [key.fileobj for key, _ in self.sel.select(max(0.0, timeout))]
        except (OSError, ValueError, KeyError):
            return None
        if self.sock in ready:
            try:
                data, _ = self.sock.recvfrom(65536)
            except OSError:
                return None
            return data
        return None

    def sleep(self, seconds: float) -> None:
        self.client._stop.wait(seconds)

    def stop(self) -> None:
        self.client._waker.wake()
        if self.thread is not None:
            self.thread.join(timeout=5)
            self.thread = None

    def close(self) -> None:
        self.sel.close()
        self.sock.close()

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()[:2]


class _NetLink:
    """Virtual time: the bench's own datagram net, in process, the session's thread a bench participant."""

    def __init__(self, client: XrceClient, net: Any) -> None:
        self.client = client
        self.net = net
        # A real socket only reserves the client's address (no program outside can take it); nothing is
        # read from it or sent through it.
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address: tuple[str, int] = self.sock.getsockname()[:2]
        self.inbox: deque[bytes] = deque()
        self.participant = Participant(net.call_at, net.clock, f"xrce-{client.name}")
        net.vt_connect(self.address, self._arrived)

    @property
    def thread(self) -> threading.Thread | None:
        return self.participant.thread

    def _arrived(self, data: bytes, src: tuple[str, int]) -> None:
        # (the loop's thread: the net sent it to this client's address)
        if tuple(src) != tuple(self.client.agent) or len(self.inbox) >= INBOX:
            return  # connected: only the agent's datagrams are heard; a full buffer drops, as UDP does
        self.inbox.append(data)
        self.participant.notify()

    def start(self, target: Callable[[], None]) -> None:
        self.participant.start(target)

    def send(self, msg: bytes) -> None:
        if self.client._stop.is_set():
            return  # (a stopped participant runs on its own to its end: it sends nothing more)
        if not self.net.vt_inject(msg, self.address, self.client.agent):
            raise OSError(f"no socket of net {self.net.name!r} at {self.client.agent}")

    def recv(self, timeout: float) -> bytes | None:
        if not self.inbox:
            self.participant.wait(timeout, news=True)
        return self.inbox.popleft() if self.inbox else None

    def sleep(self, seconds: float) -> None:
        self.participant.wait(seconds, news=False)

    def stop(self) -> None:
        self.participant.stop()
        self.participant.join(timeout=5)

    def close(self) -> None:
        self.net.vt_disconnect(self.address)
        self.sock.close()


class XrceClient:
    """One client session to an agent at ``agent`` (``(host, port)``); runs its own thread. With ``net``
    (the bench's datagram net, on a virtual clock, holding a socket at ``agent``) the thread is a bench
    participant and its datagrams stay in process (see the module docstring)."""

    def __init__(self, agent: tuple[str, int], *, client_key: int | None = None, domain_id: int = 0,
                 mtu: int = x.DEFAULT_MTU, name: str = "xrce-client", zero_after_session: bool = False,
                 on_event: Callable[[str, str], None] | None = None, net: Any = None) -> None:
        self.agent = (agent[0], agent[1])
        self.net = net
        #: The session's clock: the net's (virtual) with ``net``, else the wall clock.
        self.clock = net.clock if net is not None else WALL
        self.key = (client_key or random.randint(1, 0xFFFFFFFF)).to_bytes(4, "big")
        self.domain_id = domain_id
        self.mtu = mtu
        self.name = name
        self.zero_after_session = zero_after_session
        self.on_event = on_event or (lambda level, text: None)
        self.session_id = 0x81
        self.state = "stopped"
        self.subscriptions: list[Subscription] = []
        self.publications: list[Publication] = []
        self.counters = dict.fromkeys(("datagrams_out", "datagrams_in", "pings", "create_client", "sessions",
                                       "heartbeats", "acknacks", "retransmissions", "samples_out", "samples_in",
                                       "zeroed", "creation_failures", "time_syncs"), 0)
        self.time_offset_ns: int | None = None
        self._zero = 0
        self._lock = threading.RLock()
        self._link: _SocketLink | _NetLink | None = None
        self._stop = threading.Event()
        self._waker = WakePipe()  # ends the thread's wait when it stops
        self._reset_session()

    # ------------------------------------------------------------------ set-up

    def subscribe(self, topic: str, type_name: str, callback: Callable[[bytes, bool], None], *,
                  reliable: bool = False) -> Subscription:
        sub = Subscription(topic, type_name, callback, reliable)
        self.subscriptions.append(sub)
        return sub

    def publish_on(self, topic: str, type_name: str, *, reliable: bool = False) -> Publication:
        pub = Publication(topic, type_name, reliable)
        self.publications.append(pub)
        return pub

    def _reset_session(self) -> None:
        self._be_out = 0xFFFF
        self._rel_out = _RelOut()
        # The agent's own stream model: it NACKs up to what a HEARTBEAT announced, as uxr_compute_acknack
        # does, so a lost last message is sent again (acknowledging only what arrived never asks for it).
        self._rel_in = ReliableInput()
        self._be_in_last = 0xFFFF
        self._request = 10
        self._pending_status: dict[bytes, int | None] = {}
        self._zeroed_after = False

    # ------------------------------------------------------------------ running

    def start(self) -> None:
        if self._link is not None:
            return
        self._link = _NetLink(self, self.net) if self.net is not None else _SocketLink(self)
        self._stop.clear()
        self._link.start(self._run)

    def stop(self, delete: bool = True) -> None:
        """End the session (DELETE of the client, X19, when it is established) and the thread."""
        if delete and self.state in ("creating", "running"):
            with contextlib.suppress(OSError):
                self._send_raw(x.build_message(self.session_id, 0, 0, [(S.DELETE, x.FLAG_E,
                                                                         x.delete(b"\x00\x02", x.OBJECT_CLIENT))]))
        self._stop.set()
        link = self._link
        if link is not None:
            link.stop()
            link.close()
            self._link = None
        self.state = "stopped"

    def close(self) -> None:
        self.stop()
        self._waker.close()

    @property
    def _thread(self) -> threading.Thread | None:
        """The session's thread (None when stopped)."""
        return self._link.thread if self._link is not None else None

    @property
    def local_address(self) -> tuple[str, int] | None:
        return self._link.address if self._link is not None else None

    def zero_next(self, n: int = 1) -> None:
        """The next ``n`` datagrams leave zeroed after their first byte (the DMA/cache fault)."""
        self._zero = max(0, int(n))

    def _event(self, level: str, text: str) -> None:
        self.on_event(level, text)

    # ------------------------------------------------------------------ output

    def _send_raw(self, msg: bytes) -> None:
        link = self._link
        if link is None:
            return
        if self._zero > 0 or (self.zero_after_session and self.state in ("creating", "running") and not self._zeroed_after):
            if self._zero > 0:
                self._zero -= 1
            else:
                self._zeroed_after = True
            self.counters["zeroed"] += 1
            # What the Ethernet DMA read from RAM while the message sat in the D-cache: zeros after byte 0.
            msg = bytes([0x80]) + b"\x00" * (max(24, len(msg)) - 1)
        try:
            link.send(msg)
            self.counters["datagrams_out"] += 1
        except OSError:
            pass

    def _send_none(self, sub_id: int, payload: bytes) -> None:
        self._send_raw(x.build_message(self.session_id, 0, 0, [(sub_id, x.FLAG_E, payload)]))

    def _next_request(self) -> bytes:
        rid = self._request
        self._request = 10 if self._request >= 0xFFFF else self._request + 1
        return rid.to_bytes(2, "big")

    def _send_reliable(self, sub_id: int, payload: bytes, flags: int = x.FLAG_E) -> None:
        out = self._rel_out
        unacked = (out.last_sent - out.first_unacked + 1) & 0xFFFF
        sub = (sub_id, flags, payload)
        if unacked >= HISTORY:
            if len(out.waiting) < 256:
                out.waiting.append(sub)  # type: ignore[arg-type]
            return
        out.last_sent = (out.last_sent + 1) & 0xFFFF
        msg = x.build_message(self.session_id, x.STREAM_RELIABLE, out.last_sent, [sub])
        out.history[out.last_sent] = msg
        self._send_raw(msg)

    def write(self, pub: Publication, cdr: bytes) -> None:
        """Publish raw CDR (no encapsulation) on ``pub``: WRITE_DATA on 0x01 or 0x80 (thread-safe)."""
        with self._lock:
            if self.state != "running" or not pub.writer:
                return
            payload = x.data(self._next_request(), pub.writer, cdr)
            if pub.reliable:
                self._send_reliable(S.WRITE_DATA, payload)
            else:
                self._be_out = (self._be_out + 1) & 0xFFFF
                self._send_raw(x.build_message(self.session_id, x.STREAM_BEST_EFFORT, self._be_out,
                                               [(S.WRITE_DATA, x.FLAG_E, payload)]))
            pub.sent += 1
            self.counters["samples_out"] += 1

    # ------------------------------------------------------------------ the session's life

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if self._session():
                    self._serve()
                if not self._stop.is_set():
                    self._sleep(1.0)  # the firmware's retry after a failed start
        except Exception:  # noqa: BLE001 (a client thread must not die silently)
            log.exception("%s: client failed", self.name)

    def _recv(self, timeout: float) -> bytes | None:
        link = self._link
        if link is None:
            return None
        data = link.recv(timeout)
        if data is not None:
            self.counters["datagrams_in"] += 1
        return data

    def _sleep(self, seconds: float) -> None:
        """The firmware's pauses (ends early when the client stops)."""
        link = self._link
        if link is not None:
            link.sleep(seconds)

    def _wait_for(self, pred: Callable[[bytes], Any], timeout: float) -> Any:
        deadline = self.clock.now() + timeout
        while not self._stop.is_set():
            left = deadline - self.clock.now()
            if left <= 0:
                return None
            data = self._recv(min(left, HEARTBEAT_S))
            if data is not None:
                got = pred(data)
                if got:
                    return got
            self._housekeeping()
        return None

    def _session(self) -> bool:
        with self._lock:
            self._reset_session()
            self.state = "pinging"
        # 1. ping until the agent answers (rmw_uros_ping_agent(50, 1) every 500 ms).
        ping = x.build_message(0x80, 0, 0, [(S.GET_INFO, x.FLAG_E, x.get_info())])
        while not self._stop.is_set():
            self._send_raw(ping)
            self.counters["pings"] += 1
            if self._wait_for(self._is_pong, 0.05):
                break
            self._event("INFO", "agent not responding yet, retrying...")
            self._sleep(0.5)
        if self._stop.is_set():
            return False
        self._event("INFO", "agent responded. continuing initialization...")
        # 2. CREATE_CLIENT, every second, up to ten times.
        self.state = "connecting"
        cc = x.build_message(0x80, 0, 0, [(S.CREATE_CLIENT, x.FLAG_E, x.client_representation(
            self.key, self.session_id, self.mtu))])
        for _ in range(10):
            self._send_raw(cc)
            self.counters["create_client"] += 1
            if self._wait_for(self._is_status_agent, 1.0):
                break
        else:
            self._event("ERROR", "session creation failed: no STATUS_AGENT")
            return False
        with self._lock:
            self.state = "creating"
        self.counters["sessions"] += 1
        # 3. Entities in binary, on the reliable stream, each answered with STATUS.
        if not self._create_entities():
            self.counters["creation_failures"] += 1
            self._event("ERROR", "entity creation failed (no STATUS within 1000 ms)")
            with self._lock:
                self.state = "failed"
            return False
        # "running" once its writers and readers exist: a write before that was dropped unsent (the writer
        # had no object id yet), and a caller's own reliable messages could take the creations' turn.
        with self._lock:
            self.state = "running"
        # 4. Time sync (rmw_uros_sync_session(1000)).
        self._send_none(S.TIMESTAMP, x.timestamp(*divmod(self._wall_ns(), 1_000_000_000)))
        self._wait_for(self._is_timestamp_reply, 1.0)
        return True

    def _create_entities(self) -> bool:
        with self._lock:
            reqs: list[bytes] = []
            part = x.object_id(1, K.PARTICIPANT)
            reqs.append(self._create(part, K.PARTICIPANT, {"representation": _binary("participant_binary", {
                "optional_domain_reference": False, "domain_reference": None,
                "optional_qos_profile_reference": False, "qos_profile_reference": None}),
                "domain_id": self.domain_id}))
            topics: dict[tuple[str, str], bytes] = {}
            n = 0
            for ep in [*self.publications, *self.subscriptions]:
                key = (ep.topic, ep.type_name)
                if key not in topics:
                    n += 1
                    topics[key] = x.object_id(n, K.TOPIC)
                    reqs.append(self._create(topics[key], K.TOPIC, {"representation": _binary("topic_binary", {
                        "topic_name": ep.topic, "optional_type_reference": False, "type_reference": None,
                        "optional_type_name": True, "type_name": ep.type_name}), "participant_id": part}))
            group = {"optional_name": False, "name": None, "optional_qos": False, "qos": None}
            # Each publication gets a publisher and a datawriter, each subscription a subscriber and a datareader.
            for eps, writer, group_kind, group_name, kind, name in (
                    (self.publications, True, K.PUBLISHER, "publisher", K.DATAWRITER, "datawriter"),
                    (self.subscriptions, False, K.SUBSCRIBER, "subscriber", K.DATAREADER, "datareader")):
                for i, ep in enumerate(eps, start=1):
                    g = x.object_id(i, group_kind)
                    reqs.append(self._create(g, group_kind, {"representation": _binary(f"{group_name}_binary", group),
                                                             "participant_id": part}))
                    oid = x.object_id(i, kind)
                    setattr(ep, "writer" if writer else "reader", oid)
                    reqs.append(self._create(oid, kind, {"representation": _binary(f"{name}_binary", {
                        "topic_id": topics[(ep.topic, ep.type_name)], "optional_qos": True,
                        "qos": _qos(ep.reliable, writer=writer)}), f"{group_name}_id": g}))
        deadline = self.clock.now() + CREATION_TIMEOUT_S * max(1, len(reqs) // 4)
        while self.clock.now() < deadline and not self._stop.is_set():
            if all(self._pending_status.get(r) is not None for r in reqs):
                break
            data = self._recv(HEARTBEAT_S)
            if data is not None:
                self._handle(data)
            self._housekeeping()
        if not all(self._pending_status.get(r) is not None and self._pending_status[r] < 0x80 for r in reqs):
            return False
        with self._lock:
            for sub in self.subscriptions:
                stream = x.STREAM_RELIABLE if sub.reliable else x.STREAM_BEST_EFFORT
                self._send_reliable(S.READ_DATA, x.read_data(self._next_request(), sub.reader, stream))
        return True

    def _create(self, oid: bytes, kind: int, rep: dict[str, Any]) -> bytes:
        req = self._next_request()
        self._pending_status[req] = None
        self._send_reliable(S.CREATE, x.create(req, oid, kind, rep), x.FLAG_E | x.FLAG_REPLACE)
        return req

    def _serve(self) -> None:
        while not self._stop.is_set() and self.state == "running":
            data = self._recv(HEARTBEAT_S)
            if data is not None:
                self._handle(data)
            self._housekeeping()

    # ------------------------------------------------------------------ input

    def _is_pong(self, data: bytes) -> bool:
        msg = x.parse_message(data)
        for sub in msg.submessages:
            if sub.id == S.INFO and sub.fields is not None and sub.fields.optional_activity:
                return sub.fields.activity.info.availability > 0
        return False

    def _is_status_agent(self, data: bytes) -> bool:
        # The client only takes a STATUS_AGENT whose header carries its session id (X4b is ignored).
        if not data or data[0] != self.session_id:
            return False
        msg = x.parse_message(data)
        for sub in msg.submessages:
            if sub.id == S.STATUS_AGENT and sub.fields is not None:
                if sub.fields.status == x.Status.OK:
                    return True
                self._event("ERROR", f"agent refused the session: status 0x{sub.fields.status:02X}")
        return False

    def _is_timestamp_reply(self, data: bytes) -> bool:
        t3 = self._wall_ns()
        msg = x.parse_message(data)
        for sub in msg.submessages:
            if sub.id == S.TIMESTAMP_REPLY and sub.fields is not None:
                f = sub.fields

                def ns(tm: Any) -> int:
                    return tm.seconds * 1_000_000_000 + tm.nanoseconds

                t0, t1, t2 = ns(f.originate), ns(f.receive), ns(f.transmit)
                self.time_offset_ns = ((t0 + t3) - (t1 + t2)) // 2
                self.counters["time_syncs"] += 1
                return True
        self._handle(data)
        return False

    def _handle(self, data: bytes) -> None:
        if len(data) < 4 or data[0] != self.session_id:
            return
        stream, seq = data[1], data[2] | data[3] << 8
        with self._lock:
            if stream == 0:
                self._process(data)
            elif stream < 0x80:
                if x.seq_newer(seq, self._be_in_last):
                    self._be_in_last = seq
                    self._process(data)
            else:
                self._rel_in.push(seq, data)
                self._deliver_reliable()

    def _deliver_reliable(self) -> None:
        """Process what is now in order on the reliable input, then say what is still missing."""
        while (msg := self._rel_in.pop()) is not None:
            self._process(msg)
        first, bitmap = self._rel_in.acknack()
        self._send_none(S.ACKNACK, x.acknack(first, bitmap, x.STREAM_RELIABLE))
        self.counters["acknacks"] += 1

    def _process(self, data: bytes, depth: int = 0) -> None:
        _, _, _, subs, _ = x.scan(data)
        for sub_id, flags, off, length in subs:
            payload = data[off:off + length]
            if len(payload) < length:
                return
            if sub_id == S.FRAGMENT:
                if depth >= MAX_FRAGMENT_DEPTH:
                    return
                whole = self._rel_in.fragment(data[:x.header_size(data[0])], payload,
                                              bool(flags & x.FLAG_LAST_FRAGMENT))
                if whole is not None:
                    self._process(whole, depth + 1)
            elif sub_id == S.STATUS and length >= 6:
                req, status = payload[0:2], payload[4]
                if req in self._pending_status:
                    self._pending_status[req] = status
            elif sub_id == S.DATA and length >= 4:
                oid = payload[2:4]
                for sub in self.subscriptions:
                    if sub.reader == oid:
                        sub.received += 1
                        self.counters["samples_in"] += 1
                        try:
                            sub.callback(payload[4:], bool(flags & x.FLAG_E))
                        except Exception:
                            log.exception("%s: callback of %s failed", self.name, sub.topic)
            elif sub_id == S.ACKNACK and length >= 5:
                first = payload[0] | payload[1] << 8
                bitmap = payload[2] << 8 | payload[3]
                out = self._rel_out
                for i in range(16):
                    if bitmap >> i & 1 and (m := out.history.get((first + i) & 0xFFFF)) is not None:
                        self.counters["retransmissions"] += 1
                        self._send_raw(m)
                while x.seq_newer(first, out.first_unacked):
                    out.history.pop(out.first_unacked, None)
                    out.first_unacked = (out.first_unacked + 1) & 0xFFFF
                while out.waiting and ((out.last_sent - out.first_unacked + 1) & 0xFFFF) < HISTORY:
                    sub_id_w, flags_w, payload_w = out.waiting.pop(0)
                    self._send_reliable(sub_id_w, payload_w, flags_w)
            elif sub_id == S.HEARTBEAT:
                hb, problem = x.decode_payload(sub_id, flags, payload)
                if problem is None and hb.stream_id == x.STREAM_RELIABLE:
                    self._rel_in.heartbeat(hb.first_unacked, hb.last_unacked)
                    self._deliver_reliable()

    def _wall_ns(self) -> int:
        """Unix time now in ns, on the session's clock (the agent's TIMESTAMP_REPLY uses the same mapping)."""
        clock = self.clock
        return int(clock.wall(clock.now()) * 1e9)

    def _housekeeping(self) -> None:
        now = self.clock.now()
        if now - getattr(self, "_hb_t", 0.0) < HEARTBEAT_S:
            return
        self._hb_t = now
        with self._lock:
            out = self._rel_out
            if out.history:
                self._send_none(S.HEARTBEAT, x.heartbeat(out.first_unacked, out.last_sent, x.STREAM_RELIABLE))
                self.counters["heartbeats"] += 1

    def status(self) -> dict[str, Any]:
        return {"agent": f"{self.agent[0]}:{self.agent[1]}", "client_key": self.key.hex().upper(),
                "session_id": f"0x{self.session_id:02X}", "state": self.state,
                "local": f"{self.local_address[0]}:{self.local_address[1]}" if self.local_address else None,
                "time_offset_ns": self.time_offset_ns, "counters": dict(self.counters),
                "publications": [{"topic": p.topic, "type": p.type_name, "sent": p.sent} for p in self.publications],
                "subscriptions": [{"topic": s.topic, "type": s.type_name, "received": s.received}
                                  for s in self.subscriptions]}


def _binary(blob: str, fields: dict[str, Any]) -> dict[str, Any]:
    """An entity's representation in binary (little-endian, as the micro-ROS client writes it)."""
    return {"format": x.REPRESENTATION_IN_BINARY, "value": x.binary_blob(blob, fields, True)}


def _qos(reliable: bool, writer: bool) -> dict[str, Any]:
    base = {"qos_flags": (x.QOS_RELIABLE if reliable else 0) | x.QOS_HISTORY_KEEP_LAST,
            "optional_history_depth": True, "history_depth": 1 if not reliable else 10,
            "optional_deadline_msec": False, "deadline_msec": None, "optional_lifespan_msec": False,
            "lifespan_msec": None, "optional_user_data": False, "user_data": None}
    if writer:
        return {"base": base, "optional_ownership_strength": False, "ownership_strength": None}
    return {"base": base, "optional_timebasedfilter_msec": False, "timebasedfilter_msec": None,
            "optional_contentbased_filter": False, "contentbased_filter": None}


__all__ = ["CREATION_TIMEOUT_S", "HEARTBEAT_S", "HISTORY", "Publication", "Subscription", "XrceClient"]
