"""The emulated XRCE agent against hostile clients on 127.0.0.1: nested FRAGMENTs, too many sessions, idle
sessions, entities beyond the limits, memory held for a client that never acknowledges."""

from __future__ import annotations

import socket

import pytest

from hilbench.bench.profile import parse_profile
from hilbench.fakes.xrce_agent import agent as agent_module
from hilbench.protocols import xrce_dds as x
from hilbench.pytest_plugin import wait_until
from tests.fakes.test_xrce_agent import agent_profile

S = x.SubmessageId


@pytest.fixture
def agent_bench(hilbench_bench):
    return lambda **device: hilbench_bench(parse_profile(agent_profile(**device), "agent.toml"), port_state=False)


class Client:
    """A raw XRCE client socket (session 0x81: no key in the headers) with its own key."""

    def __init__(self, bench, key: int) -> None:
        self.addr = tuple(bench.endpoint().port.address)
        self.key = key.to_bytes(4, "big")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)

    def ask(self, data: bytes) -> bytes:
        self.sock.sendto(data, self.addr)
        return self.sock.recvfrom(65536)[0]

    def create_client(self) -> int:
        """CREATE_CLIENT; the STATUS_AGENT's status."""
        reply = self.ask(x.build_message(0x80, 0, 0, [(S.CREATE_CLIENT, x.FLAG_E,
                                                        x.client_representation(self.key, 0x81))]))
        assert reply[4] == S.STATUS_AGENT
        return reply[8]

    def close(self) -> None:
        self.sock.close()


def nest(depth: int, seq: int = 0) -> bytes:
    """A reliable message holding a FRAGMENT whose reassembly holds a FRAGMENT ... ``depth`` levels deep, a
    GET_INFO at the bottom."""
    inner = x.build_submessage(S.GET_INFO, x.get_info())
    for _ in range(depth):
        inner = x.build_submessage(S.FRAGMENT, inner, x.FLAG_E | x.FLAG_LAST_FRAGMENT)
    return x.build_header(0x81, x.STREAM_RELIABLE, seq) + inner


def replies(c: Client, first: bytes) -> list[str]:
    """The submessage names of ``first`` and of what else the agent sent within 0.3 s."""
    names = [s.name for s in x.parse_message(first).submessages]
    c.sock.settimeout(0.3)
    try:
        while True:
            names += [s.name for s in x.parse_message(c.sock.recvfrom(65536)[0]).submessages]
    except TimeoutError:
        return names


def test_a_fragment_nested_2000_deep_is_dropped_and_counted(agent_bench) -> None:
    b = agent_bench()
    agent = b.family("micro-ros-agent").agent()
    c = Client(b, 0x11223344)
    try:
        assert c.create_client() == x.Status.OK
        assert replies(c, c.ask(nest(2000))) == ["ACKNACK"]  # 8 kB in one datagram: taken, acknowledged
        assert agent.counters["fragment_nesting"] == 1
        assert b.endpoint().medium.stats.callback_errors == 0  # no RecursionError (nor any other) reached the net
        # A nest within the limit is followed to its end: the GET_INFO at its bottom is answered.
        assert replies(c, c.ask(nest(agent_module.MAX_FRAGMENT_DEPTH, seq=1))) == ["INFO", "ACKNACK"]
        assert agent.counters["fragment_nesting"] == 1
    finally:
        c.close()


def test_sessions_are_bounded_and_silent_ones_expire(agent_bench) -> None:
    b = agent_bench(max_sessions=2, session_timeout=1)
    agent = b.family("micro-ros-agent").agent()
    assert b.manifest()["devices"][0]["limits"]["sessions"] == 2
    clients = [Client(b, 0x100 + i) for i in range(3)]
    try:
        assert [c.create_client() for c in clients] == [x.Status.OK, x.Status.OK, x.Status.ERR_RESOURCES]
        assert agent.counters["sessions_refused"] == 1 and len(agent.by_key) == 2
        # Silent for their second, the two sessions are deleted; the third client gets its session now.
        wait_until(lambda: not agent.by_key, 5)
        assert agent.counters["sessions_expired"] == 2
        assert clients[2].create_client() == x.Status.OK
        assert agent.status()["limits"]["session_timeout_s"] == 1
    finally:
        for c in clients:
            c.close()


def test_a_new_client_takes_the_place_of_a_dead_one(agent_bench, monkeypatch) -> None:
    monkeypatch.setattr(agent_module, "CLIENT_DEAD_S", 0.2)  # (30 s, as the real agent: too long for a test)
    b = agent_bench(max_sessions=1, session_timeout=0)
    agent = b.family("micro-ros-agent").agent()
    old, new = Client(b, 0x201), Client(b, 0x202)
    try:
        assert old.create_client() == x.Status.OK
        wait_until(lambda: agent.status()["sessions"][0]["idle_s"] > 0.3, 5)
        assert new.create_client() == x.Status.OK
        assert agent.counters["sessions_evicted"] == 1 and list(agent.by_key) == [new.key]
    finally:
        old.close()
        new.close()


def test_entities_beyond_the_limit_get_err_resources(agent_bench, monkeypatch) -> None:
    monkeypatch.setattr(agent_module, "MAX_ENTITIES", 2)
    b = agent_bench(refs={"p": {}})
    c = Client(b, 0x301)
    try:
        assert c.create_client() == x.Status.OK
        codes = []
        for i in range(3):
            create = x.create(bytes([0, i]), x.object_id(i + 1, x.ObjectKind.PARTICIPANT), x.ObjectKind.PARTICIPANT,
                              {"representation": {"format": x.REPRESENTATION_BY_REFERENCE, "value": "p"},
                               "domain_id": 0})
            reply = c.ask(x.build_message(0x81, x.STREAM_BEST_EFFORT, i, [(S.CREATE, x.FLAG_E, create)]))
            codes.append(x.parse_message(reply).submessages[0].fields.status)
        assert codes == [x.Status.OK, x.Status.OK, x.Status.ERR_RESOURCES]
        big = x.create(b"\x00\x09", x.object_id(1, x.ObjectKind.PARTICIPANT), x.ObjectKind.PARTICIPANT,
                       {"representation": {"format": x.REPRESENTATION_AS_XML, "value": "<dds>" + "x" * 5000 + "</dds>"},
                        "domain_id": 0})  # (replaces an existing object: the size alone refuses it)
        reply = c.ask(x.build_message(0x81, x.STREAM_BEST_EFFORT, 3, [(S.CREATE, x.FLAG_E | x.FLAG_REPLACE, big)]))
        assert x.parse_message(reply).submessages[0].fields.status == x.Status.ERR_RESOURCES
        assert b.family("micro-ros-agent").agent().counters["entities_refused"] == 2
    finally:
        c.close()


def test_reliable_input_waiting_behind_a_gap_is_bounded(agent_bench) -> None:
    b = agent_bench()
    agent = b.family("micro-ros-agent").agent()
    c = Client(b, 0x401)
    try:
        assert c.create_client() == x.Status.OK
        session = agent.by_key[c.key]
        big = x.build_submessage(S.WRITE_DATA, x.data(b"\x00\x01", b"\xff\xf5", bytes(30_000)))
        for seq in range(1, 16):  # 15 x 30 kB ahead of the missing message 0
            ack = x.parse_message(c.ask(x.build_header(0x81, x.STREAM_RELIABLE, seq) + big)).submessages[0]
        held = agent_module.SESSION_INPUT_BYTES // (len(big) + 4)
        assert agent.counters["input_dropped"] == 15 - held
        assert session.input_bytes() <= agent_module.SESSION_INPUT_BYTES
        assert ack.fields.first_unacked == 0  # still waiting for 0, which is always taken
        ack = x.parse_message(c.ask(x.build_header(0x81, x.STREAM_RELIABLE, 0) + big)).submessages[0]
        assert ack.fields.first_unacked == held + 1 and session.input_bytes() == 0
    finally:
        c.close()


def test_the_board_client_hears_only_its_agent_and_bounds_fragment_nests(agent_bench) -> None:
    from hilbench.fakes.xrce_client import XrceClient
    from hilbench.protocols import cdr

    string = cdr.ros_type("std_msgs/String")
    b = agent_bench()
    got: list[str] = []
    c = XrceClient(tuple(b.endpoint().port.address), name="board")
    sub = c.subscribe("rt/t", string.dds_name, lambda d, le: got.append(string.decode(d).data))
    w = c.publish_on("rt/t", string.dds_name)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        c.start()
        wait_until(lambda: c.state == "running" and any(s.reads for s in b.family("micro-ros-agent").agent().sessions.values()), 10)
        # A sample for its reader from another address: the connected socket never hears it (as the
        # client library's UDP transport, which connects to the agent).
        stranger.sendto(x.build_message(0x81, x.STREAM_BEST_EFFORT, 1000, [(S.DATA, x.FLAG_E, x.data(
            b"\x00\x01", sub.reader, string.encode({"data": "spoofed"})))]), c.local_address)
        c.write(w, string.encode({"data": "from the agent"}))
        wait_until(lambda: got, 5)
        assert got == ["from the agent"]
        c._process(nest(2000, seq=0))  # from the agent, it would be followed 4 levels deep, then dropped
        assert not c._rel_in.fragments and c._thread.is_alive()
    finally:
        stranger.close()
        c.close()
