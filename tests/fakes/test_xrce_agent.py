"""The emulated Micro XRCE-DDS agent with hilbench's own client and raw spec vectors over 127.0.0.1:
handshake bytes, routing, reliability, fragments, time, faults, zeroed datagrams and fuzz."""

from __future__ import annotations

import importlib.util
import random
import socket
import time
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from hilbench.fakes.xrce_client import XrceClient
from hilbench.protocols import cdr
from hilbench.protocols import xrce_dds as x
from hilbench.pytest_plugin import wait_until

spec = importlib.util.spec_from_file_location("udp_vectors", Path(__file__).resolve().parents[1] / "udp_vectors.py")
V = importlib.util.module_from_spec(spec)
spec.loader.exec_module(V)
STRING = cdr.ros_type("std_msgs/String")


def agent_profile(**device) -> dict:
    dev = {"model": "micro-ros-agent", "name": "agent", **device}
    return {"schema": 1, "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0}},
            "devices": [dev]}


@pytest.fixture
def agent_bench(hilbench_bench):
    """Factory: a started bench of one agent (``agent_bench(refs=...)``), stopped after the test."""
    return lambda **device: hilbench_bench(parse_profile(agent_profile(**device), "agent.toml"), port_state=False)


class Raw:
    """A UDP socket on 127.0.0.1 speaking raw datagrams to the agent."""

    def __init__(self, bench: Bench) -> None:
        self.addr = tuple(bench.endpoint().port.address)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)

    def send(self, data: bytes) -> None:
        self.sock.sendto(data, self.addr)

    def recv(self) -> bytes:
        return self.sock.recvfrom(65536)[0]

    def ask(self, data: bytes) -> bytes:
        self.send(data)
        return self.recv()

    def close(self) -> None:
        self.sock.close()


def running(client: XrceClient) -> bool:
    return client.state == "running"


def test_handshake_replies_are_the_sheets_bytes(agent_bench) -> None:
    b = agent_bench()
    raw = Raw(b)
    try:
        assert raw.ask(V.X["X1"]) == V.X["X2"]  # ping out of session: INFO, implementation_status 0
        assert raw.ask(V.X["X3"]) == V.X["X4"]  # CREATE_CLIENT: STATUS_AGENT with header 0x81
        pong = x.parse_message(raw.ask(V.X["X1"])).submessages[0].fields
        assert pong.implementation_status == 1  # now the address has a session
        assert raw.ask(V.X["X19"]) == V.X["X20"]  # DELETE client: STATUS OK, session gone
        assert not b.family("micro-ros-agent").agent().sessions
        assert raw.ask(V.X["X5"]) == V.X["X6"]  # session 0x01: key in every header
    finally:
        raw.close()


def test_participant_by_reference_and_its_status(agent_bench) -> None:
    b = agent_bench(refs={"default_xrce_participant": {}})
    raw = Raw(b)
    try:
        raw.ask(V.X["X3"])
        raw.send(V.X["X9"])
        replies = {raw.recv(), raw.recv()}  # the agent's ACKNACK for the reliable message, and the STATUS
        assert V.X["X11"] in replies and V.X["X12"] in replies
        raw.send(V.X["X13"])  # the client acknowledges the STATUS: no HEARTBEATs follow
        s = next(iter(b.family("micro-ros-agent").agent().sessions.values()))
        wait_until(lambda: not s.rel_out[0x80].history, 2)
        assert s.entities[b"\x00\x11"].kind == x.ObjectKind.PARTICIPANT
    finally:
        raw.close()


def test_unknown_reference_is_an_error_status(agent_bench) -> None:
    b = agent_bench()
    raw = Raw(b)
    try:
        raw.ask(V.X["X3"])
        raw.send(V.X["X9"])
        msgs = [x.parse_message(raw.recv()) for _ in range(2)]
        status = [m.submessages[0].fields for m in msgs if m.submessages[0].name == "STATUS"][0]
        assert status.status == x.Status.ERR_DDS_ERROR  # the middleware has no such profile
    finally:
        raw.close()


def test_publisher_to_subscriber_both_qos_and_a_client_reading_itself(agent_bench) -> None:
    b = agent_bench()
    addr = tuple(b.endpoint().port.address)
    got, own = [], []
    pub = XrceClient(addr, client_key=0x11111111, name="pub")
    w_be = pub.publish_on("rt/chatter", STRING.dds_name)
    w_rel = pub.publish_on("rt/reliable", STRING.dds_name, reliable=True)
    pub.subscribe("rt/chatter", STRING.dds_name, lambda d, le: own.append(STRING.decode(d).data))
    sub = XrceClient(addr, client_key=0x22222222, name="sub")
    sub.subscribe("rt/chatter", STRING.dds_name, lambda d, le: got.append(("be", STRING.decode(d).data)))
    sub.subscribe("rt/reliable", STRING.dds_name, lambda d, le: got.append(("rel", STRING.decode(d).data)),
                  reliable=True)
    try:
        sub.start()
        pub.start()
        agent = b.family("micro-ros-agent").agent()
        wait_until(lambda: running(pub) and running(sub) and sum(len(s.reads) for s in agent.sessions.values()) == 3)
        for i in range(5):
            pub.write(w_be, STRING.encode({"data": f"be {i}"}))
            pub.write(w_rel, STRING.encode({"data": f"rel {i}"}))
        wait_until(lambda: len(got) == 10 and len(own) == 5)
        assert [v for k, v in got if k == "be"] == [f"be {i}" for i in range(5)]
        assert [v for k, v in got if k == "rel"] == [f"rel {i}" for i in range(5)]
        assert own == [f"be {i}" for i in range(5)]
        assert pub.time_offset_ns is not None and abs(pub.time_offset_ns) < 100_000_000
    finally:
        pub.close()
        sub.close()
    wait_until(lambda: not b.family("micro-ros-agent").agent().sessions)  # both deleted their sessions (X19)


def test_a_reliable_reader_does_not_match_a_best_effort_writer(agent_bench) -> None:
    b = agent_bench()
    addr = tuple(b.endpoint().port.address)
    got = []
    pub = XrceClient(addr, name="pub")
    w = pub.publish_on("rt/t", STRING.dds_name)
    sub = XrceClient(addr, name="sub")
    sub.subscribe("rt/t", STRING.dds_name, lambda d, le: got.append(d), reliable=True)
    try:
        sub.start()
        pub.start()
        wait_until(lambda: running(pub) and running(sub) and any(s.reads for s in b.family("micro-ros-agent").agent().sessions.values()))
        pub.write(w, STRING.encode({"data": "x"}))
        wait_until(lambda: pub.counters["samples_out"] == 1 and b.family("micro-ros-agent").agent().counters["datagrams"] > 0)
        time.sleep(0.2)  # nothing may arrive: give a wrongly routed sample its chance to show
        assert got == [] and b.family("micro-ros-agent").agent().counters["samples_routed"] == 0
    finally:
        pub.close()
        sub.close()


def test_retransmission_on_nack_and_heartbeats_while_unacknowledged(agent_bench) -> None:
    b = agent_bench(refs={"default_xrce_participant": {}})
    raw = Raw(b)
    try:
        raw.ask(V.X["X3"])
        raw.send(V.X["X9"])
        first = {raw.recv(), raw.recv()}
        assert V.X["X12"] in first
        # Never acknowledged: the agent heartbeats (first 0, last 0, stream 0x80) about every 200 ms.
        hb = raw.recv()
        assert hb == x.build_message(0x81, 0, 0, [(11, 1, x.heartbeat(0, 0, 0x80))])
        raw.send(x.build_message(0x81, 0, 0, [(10, 1, x.acknack(0, 0x0001, 0x80))]))  # NACK seq 0
        again = raw.recv()
        while again != V.X["X12"]:
            again = raw.recv()
        assert b.family("micro-ros-agent").agent().counters["retransmissions"] >= 1
    finally:
        raw.close()


def test_fragmented_write_is_reassembled(agent_bench) -> None:
    b = agent_bench()
    addr = tuple(b.endpoint().port.address)
    got = []
    sub = XrceClient(addr, name="sub")
    sub.subscribe("rt/big", STRING.dds_name, lambda d, le: got.append(STRING.decode(d).data), reliable=True)
    pub = XrceClient(addr, name="pub", mtu=508)
    w = pub.publish_on("rt/big", STRING.dds_name, reliable=True)
    try:
        sub.start()
        pub.start()
        wait_until(lambda: running(pub) and running(sub) and any(s.reads for s in b.family("micro-ros-agent").agent().sessions.values()))
        session = next(s for s in b.family("micro-ros-agent").agent().sessions.values() if s.key == pub.key)
        big = STRING.encode({"data": "A" * 1500})
        whole = x.build_submessage(x.SubmessageId.WRITE_DATA, x.data(b"\x00\x40", w.writer, big))
        with pub._lock:  # send it as the client library does: FRAGMENTs on the reliable stream
            for i in range(0, len(whole), 400):
                last = i + 400 >= len(whole)
                pub._send_reliable(x.SubmessageId.FRAGMENT, whole[i:i + 400],
                                   x.FLAG_E | (x.FLAG_LAST_FRAGMENT if last else 0))
        wait_until(lambda: got == ["A" * 1500])
        assert b.family("micro-ros-agent").agent().counters["fragments_in"] == 4
        assert b.family("micro-ros-agent").agent().counters["fragments_out"] >= 4  # the 1.5 kB DATA went back to the reader fragmented
        assert session.samples_in == 1
    finally:
        pub.close()
        sub.close()


def test_a_client_is_running_once_its_writers_exist(agent_bench) -> None:
    """"running" means it can publish: its DATAWRITER exists on the agent. (It used to say so as soon as its
    session did: a write then was dropped unsent, and a caller's reliable messages took the creations' turn.)"""
    b = agent_bench()
    agent = b.family("micro-ros-agent").agent()
    pub = XrceClient(tuple(b.endpoint().port.address), name="pub")
    w = pub.publish_on("rt/early", STRING.dds_name, reliable=True)
    try:
        pub.start()
        wait_until(lambda: running(pub), interval=0.0001)  # (the first look that sees it)
        writers = [e for s in list(agent.sessions.values()) for e in list(s.entities.values())
                   if e.kind == x.ObjectKind.DATAWRITER]
        assert w.writer and len(writers) == 1
    finally:
        pub.close()


def test_a_reader_recovers_the_last_message_lost_on_its_reliable_stream(agent_bench) -> None:
    """The agent's DATA to the reader is the newest message on that stream and is lost: nothing after it shows
    a gap, so only the agent's HEARTBEAT (it announces its last sequence number) can make the reader NACK it."""
    b = agent_bench()
    addr = tuple(b.endpoint().port.address)
    got = []
    sub = XrceClient(addr, name="sub")
    sub.subscribe("rt/lossy", STRING.dds_name, lambda d, le: got.append(STRING.decode(d).data), reliable=True)
    pub = XrceClient(addr, name="pub")
    w = pub.publish_on("rt/lossy", STRING.dds_name, reliable=True)
    agent = b.family("micro-ros-agent").agent()
    try:
        sub.start()
        pub.start()
        # Quiet: every reliable message both ways acknowledged, so the agent sends nothing of its own.
        wait_until(lambda: running(pub) and running(sub) and any(s.reads for s in agent.sessions.values())
                   and not pub._rel_out.history and not sub._rel_out.history
                   and all(not o.history for s in agent.sessions.values() for o in s.rel_out.values()))
        agent.faults["drop_next"] = 1  # the next datagram the agent sends: the DATA to the reader
        pub.write(w, STRING.encode({"data": "once"}))
        wait_until(lambda: got == ["once"])
        assert agent.counters["dropped_out"] == 1 and agent.counters["retransmissions"] >= 1
    finally:
        pub.close()
        sub.close()


def test_zeroed_datagram_from_a_sessions_address_tears_it_down(agent_bench) -> None:
    b = agent_bench()
    raw = Raw(b)
    try:
        assert raw.ask(V.X["X3"]) == V.X["X4"]
        reply = raw.ask(V.X["X21"])  # Xu's zeroed datagram from the same address
        m = x.parse_message(reply)
        assert m.session_id == 0x00 and m.client_key == b"\x00\x00\x00\x00"  # as the agent source builds it
        assert m.submessages[0].fields.status == x.Status.ERR_INVALID_DATA
        a = b.family("micro-ros-agent").agent()
        assert not a.sessions and a.counters["takeovers"] == 1 and a.counters["zero_fill"] == 1
        log = list(a.log)
        assert any(line.startswith("delete_client | client_key: 0x60C93570") for line in log)
        assert any("invalid client key 0x00000000" in line for line in log)
        # The board's HEARTBEATs now go into the void: no ACKNACK comes back.
        raw.send(V.X["X10"])
        raw.sock.settimeout(0.3)
        with pytest.raises(socket.timeout):
            raw.recv()
        assert a.counters["orphan"] == 1
    finally:
        raw.close()


def test_zeroed_setting_keep_keeps_the_session(agent_bench) -> None:
    b = agent_bench(zeroed="keep")
    raw = Raw(b)
    try:
        raw.ask(V.X["X3"])
        raw.ask(V.X["X21"])
        a = b.family("micro-ros-agent").agent()
        assert len(a.sessions) == 1 and a.counters["takeovers"] == 0 and a.counters["zero_fill"] == 1
        # The session answers the board's HEARTBEAT, NACKing the message it never got (seq 0).
        assert raw.ask(V.X["X10"]) == x.build_message(0x81, 0, 0, [(10, 1, x.acknack(0, 0x0001, 0x80))])
    finally:
        raw.close()


def test_zeroed_datagrams_from_other_addresses_never_end_a_session(agent_bench) -> None:
    b = agent_bench()
    raw, other = Raw(b), Raw(b)
    try:
        raw.ask(V.X["X3"])
        for _ in range(3):
            other.ask(V.X["X21"])
        a = b.family("micro-ros-agent").agent()
        assert len(a.sessions) == 1 and a.counters["zero_fill_foreign"] == 3
    finally:
        raw.close()
        other.close()


def test_status_agent_fault_knob_makes_the_client_retry(agent_bench) -> None:
    b = agent_bench(faults={"corrupt_status_agent": 1})
    raw = Raw(b)
    try:
        assert raw.ask(V.X["X3"]) == V.X["X4b"]
        assert raw.ask(V.X["X3"]) == V.X["X4"]
    finally:
        raw.close()
    c = XrceClient(tuple(b.endpoint().port.address), name="c")
    try:
        b.family("micro-ros-agent").agent().set_faults(corrupt_status_agent=1)
        c.start()
        wait_until(lambda: running(c), 5)
        assert c.counters["create_client"] == 2  # the X4b reply was ignored, the resend 1 s later worked
    finally:
        c.close()


def test_fuzzed_datagrams_never_stop_the_agent(agent_bench) -> None:
    b = agent_bench(refs={"default_xrce_participant": {}})
    addr = tuple(b.endpoint().port.address)
    rng = random.Random(16)
    got = []
    c = XrceClient(addr, name="c")
    w = c.publish_on("rt/f", STRING.dds_name, reliable=True)
    c.subscribe("rt/f", STRING.dds_name, lambda d, le: got.append(STRING.decode(d).data), reliable=True)
    fuzz = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fuzz.bind(("127.0.0.1", 0))
    try:
        c.start()
        wait_until(lambda: running(c) and any(s.reads for s in b.family("micro-ros-agent").agent().sessions.values()))
        vectors = list(V.X.values())
        before = b.family("micro-ros-agent").agent().counters["datagrams"]
        for i in range(3000):
            if i % 100 == 0:  # in bursts the socket buffer holds: every datagram reaches the agent
                wait_until(lambda n=i: b.family("micro-ros-agent").agent().counters["datagrams"] - before >= n, 10)
            kind = i % 3
            if kind == 0:
                data = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 80)))
            else:
                data = bytearray(rng.choice(vectors))
                for _ in range(rng.randint(1, 4)):
                    data[rng.randrange(len(data))] = rng.getrandbits(8)
                data = bytes(data[:rng.randint(1, len(data))]) if kind == 2 else bytes(data)
            fuzz.sendto(data, addr)
        wait_until(lambda: b.family("micro-ros-agent").agent().counters["datagrams"] - before >= 3000, 10)
        c.write(w, STRING.encode({"data": "still here"}))
        wait_until(lambda: got == ["still here"], 5)
        assert b.endpoint().medium._thread.is_alive()
        assert b.endpoint().medium.stats.callback_errors == 0
    finally:
        fuzz.close()
        c.close()


def test_manifest_says_agent_host_and_port(agent_bench) -> None:
    b = agent_bench()
    ep = b.manifest()["endpoints"][0]
    assert (ep["type"], ep["protocol"], ep["role"], ep["host"]) == ("udp", "xrce-dds", "agent", "127.0.0.1")
    assert ep["port"] == b.endpoint().port.address[1] > 0


class RawSession(Raw):
    """A raw client with a session (id 0x81) speaking on best-effort stream 1 (no acknowledgements)."""

    def __init__(self, bench: Bench, key: bytes) -> None:
        super().__init__(bench)
        self.seq = 0
        reply = x.parse_message(self.ask(x.build_header(0x80) + x.build_submessage(
            x.SubmessageId.CREATE_CLIENT, x.client_representation(key, 0x81))))
        assert reply.submessages[0].fields.status == x.Status.OK

    def say(self, sub_id: int, payload: bytes, flags: int = x.FLAG_E) -> None:
        self.seq += 1
        self.send(x.build_message(0x81, x.STREAM_BEST_EFFORT, self.seq, [(sub_id, flags, payload)]))

    def next(self, name: str):
        while True:
            for sub in x.parse_message(self.recv()).submessages:
                if sub.name == name:
                    return sub


def test_requester_and_replier_as_the_agent_pairs_them(agent_bench) -> None:
    """eProsima's RequestAdder/ReplyAdder XML (attributes with no space between them, which the agent's
    XML parser accepts) and rmw_microxrcedds' binary form: a request reaches the replier behind a sample
    identity; the reply carrying it reaches that requester only, behind its WRITE_DATA's request id."""
    b = agent_bench()
    S = x.SubmessageId
    participant = x.object_id(1, x.ObjectKind.PARTICIPANT)
    part_xml = {"representation": {"format": x.REPRESENTATION_AS_XML,
                                   "value": "<dds><participant><rtps><name>p</name></rtps></participant></dds>"},
                "domain_id": 0}
    requester, replier = x.object_id(1, x.ObjectKind.REQUESTER), x.object_id(1, x.ObjectKind.REPLIER)
    svc = 'profile_name="my_requester"service_name="adder"request_type="req"reply_type="rep"'
    clients = [RawSession(b, bytes.fromhex(k)) for k in ("0000000A", "0000000B", "0000000C")]
    rep_c, req_c, other = clients
    try:
        for c in clients:
            c.say(S.CREATE, x.create(b"\x00\x01", participant, x.ObjectKind.PARTICIPANT, part_xml),
                  x.FLAG_E | x.FLAG_REPLACE)
            assert c.next("STATUS").fields.status == x.Status.OK
        rep_c.say(S.CREATE, x.create(b"\x00\x02", replier, x.ObjectKind.REPLIER, {
            "representation": {"format": x.REPRESENTATION_AS_XML, "value": f"<dds><replier {svc}></replier></dds>"},
            "participant_id": participant}), x.FLAG_E | x.FLAG_REPLACE)
        assert rep_c.next("STATUS").fields.status == x.Status.OK
        blob = x.binary_blob("requester_binary", {
            "service_name": "adder", "request_type": "req", "reply_type": "rep",
            "optional_request_topic_name": True, "request_topic_name": "adder_Request",
            "optional_reply_topic_name": False, "reply_topic_name": None})
        for c in (req_c, other):
            c.say(S.CREATE, x.create(b"\x00\x02", requester, x.ObjectKind.REQUESTER, {
                "representation": {"format": x.REPRESENTATION_IN_BINARY, "value": blob},
                "participant_id": participant}), x.FLAG_E | x.FLAG_REPLACE)
            assert c.next("STATUS").fields.status == x.Status.OK
        for c, oid in ((rep_c, replier), (req_c, requester), (other, requester)):
            c.say(S.READ_DATA, x.read_data(b"\x00\x03", oid, x.STREAM_BEST_EFFORT))
        agent = b.family("micro-ros-agent").agent()
        wait_until(lambda: sum(len(s.reads) for s in agent.sessions.values()) == 3)
        req_c.say(S.WRITE_DATA, x.data(b"\x12\x34", requester, b"\x02\x00\x00\x00\x03\x00\x00\x00"))
        request = rep_c.next("DATA").payload
        assert request[2:4] == replier and request[4 + 24:] == b"\x02\x00\x00\x00\x03\x00\x00\x00"
        identity = request[4:4 + 24]
        rep_c.say(S.WRITE_DATA, x.data(b"\x00\x09", replier, identity + b"\x05" + bytes(7)))
        reply = req_c.next("DATA").payload
        # DATA: READ_DATA's request id and object, then the request's WRITE_DATA request id and object.
        assert reply == b"\x00\x03" + requester + b"\x12\x34" + requester + b"\x05" + bytes(7)
        wait_until(lambda: agent.counters["replies_routed"] == 1)
        other.sock.settimeout(0.3)
        with pytest.raises(TimeoutError):
            other.next("DATA")  # the other requester's reader gets neither the request nor the reply
        rep_c.say(S.WRITE_DATA, x.data(b"\x00\x0a", replier, identity + bytes(8)))  # answered already
        wait_until(lambda: agent.counters["replies_unmatched"] == 1)
    finally:
        for c in clients:
            c.close()
