"""The emulated Micro XRCE-DDS agent as a fuzz target (:mod:`hilbench.fuzzing`, kind ``server``).

A session is the datagrams micro-ROS clients send the agent, framed in one byte stream
(:func:`~hilbench.fuzzing.frame_datagram`; the frame's sender byte picks one of three client
addresses): pings, CREATE_CLIENT, entities created in binary on the reliable stream, READ_DATA,
WRITE_DATA on both streams, a reliable message cut into FRAGMENTs, ACKNACKs, HEARTBEATs, time
sync, a client deleted. Each session meets a fresh agent (:class:`~hilbench.fakes.xrce_agent.agent.XrceAgent`,
the bench's own) through ``on_datagram``, as the datagram net's thread hands it datagrams; what it
sends goes through the same checks a UDP socket's ``sendto`` makes, and its timers (HEARTBEATs) run
once after the session. ``good`` counts the datagrams the agent answered with, ``dropped`` what it
counted as malformed or from no known client.
"""

from __future__ import annotations

import random
from typing import Any

from hilbench.fuzzing import LINK_100M, DatagramFrames, FuzzTarget, NetPort, TracebackWatch, frame_datagram
from hilbench.protocols import xrce_dds as x

K = x.ObjectKind
S = x.SubmessageId
#: The clients' addresses (a frame's sender byte picks one).
CLIENTS = (("127.0.0.1", 40001), ("127.0.0.1", 40002), ("10.0.0.7", 2018))
AGENT = ("127.0.0.1", 8888)
STRING = "std_msgs::msg::dds_::String_"


def _binary(blob: str, fields: dict[str, Any]) -> dict[str, Any]:
    return {"format": x.REPRESENTATION_IN_BINARY, "value": x.binary_blob(blob, fields, True)}


def _qos(reliable: bool, writer: bool) -> dict[str, Any]:
    base = {"qos_flags": (x.QOS_RELIABLE if reliable else 0) | x.QOS_HISTORY_KEEP_LAST,
            "optional_history_depth": True, "history_depth": 10 if reliable else 1,
            "optional_deadline_msec": False, "deadline_msec": None, "optional_lifespan_msec": False,
            "lifespan_msec": None, "optional_user_data": False, "user_data": None}
    if writer:
        return {"base": base, "optional_ownership_strength": False, "ownership_strength": None}
    return {"base": base, "optional_timebasedfilter_msec": False, "timebasedfilter_msec": None,
            "optional_contentbased_filter": False, "contentbased_filter": None}


class _Client:
    """One scripted micro-ROS client: the datagrams it sends, in order."""

    def __init__(self, rng: random.Random, index: int) -> None:
        self.rng = rng
        self.index = index
        self.key = rng.randbytes(4)
        self.sid = rng.choice((0x81, 0x81, 0x01))  # 0x01: the key in every header
        self.rel = 0
        self.be = 0
        self.request = 10
        self.out: list[bytes] = []

    def message(self, stream: int, seq: int, subs: list[tuple[int, int, bytes]]) -> bytes:
        return x.build_message(self.sid, stream, seq, subs, self.key if self.sid < 0x80 else None)

    def req(self) -> bytes:
        self.request += 1
        return (self.request & 0xFFFF).to_bytes(2, "big")

    def reliable(self, sub: int, payload: bytes, flags: int = x.FLAG_E) -> None:
        whole = x.build_submessage(sub, payload, flags)
        if self.rng.random() < 0.1 and len(whole) > 8:  # cut into FRAGMENTs, as above a small MTU
            cut = self.rng.randrange(4, len(whole) - 2)
            for piece, last in ((whole[:cut], False), (whole[cut:], True)):
                self.out.append(self.message(x.STREAM_RELIABLE, self.rel, [
                    (S.FRAGMENT, x.FLAG_E | (x.FLAG_LAST_FRAGMENT if last else 0), piece)]))
                self.rel = (self.rel + 1) & 0xFFFF
            return
        self.out.append(self.message(x.STREAM_RELIABLE, self.rel, [(sub, flags, payload)]))
        self.rel = (self.rel + 1) & 0xFFFF

    def create(self, oid: bytes, kind: int, rep: dict[str, Any]) -> None:
        self.reliable(S.CREATE, x.create(self.req(), oid, kind, rep), x.FLAG_E | x.FLAG_REPLACE)

    def session(self) -> list[bytes]:
        rng = self.rng
        self.out.append(x.build_message(0x80, 0, 0, [(S.GET_INFO, x.FLAG_E, x.get_info())]))
        self.out.append(x.build_message(0x80, 0, 0, [(S.CREATE_CLIENT, x.FLAG_E, x.client_representation(
            self.key, self.sid, rng.choice((x.DEFAULT_MTU, 128, 512))))]))
        part, topic = x.object_id(1, K.PARTICIPANT), x.object_id(1, K.TOPIC)
        self.create(part, K.PARTICIPANT, {"representation": _binary("participant_binary", {
            "optional_domain_reference": False, "domain_reference": None,
            "optional_qos_profile_reference": False, "qos_profile_reference": None}), "domain_id": 0})
        self.create(topic, K.TOPIC, {"representation": _binary("topic_binary", {
            "topic_name": "rt/chatter", "optional_type_reference": False, "type_reference": None,
            "optional_type_name": True, "type_name": STRING}), "participant_id": part})
        group = {"optional_name": False, "name": None, "optional_qos": False, "qos": None}
        reliable = rng.random() < 0.5
        pub, writer = x.object_id(1, K.PUBLISHER), x.object_id(1, K.DATAWRITER)
        sub, reader = x.object_id(1, K.SUBSCRIBER), x.object_id(1, K.DATAREADER)
        self.create(pub, K.PUBLISHER, {"representation": _binary("publisher_binary", group), "participant_id": part})
        self.create(writer, K.DATAWRITER, {"representation": _binary("datawriter_binary", {
            "topic_id": topic, "optional_qos": True, "qos": _qos(reliable, True)}), "publisher_id": pub})
        self.create(sub, K.SUBSCRIBER, {"representation": _binary("subscriber_binary", group),
                                        "participant_id": part})
        self.create(reader, K.DATAREADER, {"representation": _binary("datareader_binary", {
            "topic_id": topic, "optional_qos": True, "qos": _qos(reliable, False)}), "subscriber_id": sub})
        self.reliable(S.READ_DATA, x.read_data(self.req(), reader, x.STREAM_RELIABLE if reliable
                                               else x.STREAM_BEST_EFFORT))
        self.out.append(self.message(0, 0, [(S.TIMESTAMP, x.FLAG_E, x.timestamp(1_700_000_000, 0))]))
        for i in range(rng.randrange(1, 12)):
            cdr = len(f"hello {i}").to_bytes(4, "little") + f"hello {i}".encode()
            k = rng.random()
            if k < 0.5:
                self.be = (self.be + 1) & 0xFFFF
                self.out.append(self.message(x.STREAM_BEST_EFFORT, self.be,
                                             [(S.WRITE_DATA, x.FLAG_E, x.data(self.req(), writer, cdr))]))
            elif k < 0.75:
                self.reliable(S.WRITE_DATA, x.data(self.req(), writer, cdr))
            elif k < 0.9:
                self.out.append(self.message(0, 0, [(S.ACKNACK, x.FLAG_E, x.acknack(rng.randrange(8), 0,
                                                                                   x.STREAM_RELIABLE))]))
            else:
                self.out.append(self.message(0, 0, [(S.HEARTBEAT, x.FLAG_E, x.heartbeat(0, self.rel,
                                                                                      x.STREAM_RELIABLE))]))
        if rng.random() < 0.3:
            self.reliable(S.DELETE, x.delete(self.req(), x.OBJECT_CLIENT))
        return self.out


def agent_session(rng: random.Random, size: int) -> bytes:
    """Sessions of up to three clients, their datagrams interleaved, framed (about ``size`` bytes)."""
    out = bytearray()
    while len(out) < size:
        clients = [(_Client(rng, i).session(), i) for i in range(rng.randrange(1, len(CLIENTS) + 1))]
        while any(c for c, _ in clients):
            datagrams, i = rng.choice([c for c in clients if c[0]])
            out += frame_datagram(datagrams.pop(0), i)
    return bytes(out)


class _AgentSession:
    def __init__(self) -> None:
        from hilbench.fakes.xrce_agent.agent import XrceAgent

        self.agent = XrceAgent("fuzz-agent", refs={"default_xrce_participant": {}})
        self.net = NetPort()
        self.agent.port = self.net
        self.agent.start()
        self.frames = DatagramFrames()
        self.t = 0.0
        self.watch = TracebackWatch.shared()
        self.watch.clear()

    def _datagrams(self, items: list[tuple[int, bytes]]) -> None:
        for source, datagram in items:
            self.t += 1e-4
            self.agent.on_datagram(datagram, CLIENTS[source % len(CLIENTS)], AGENT, self.t)

    def feed(self, data: bytes) -> None:
        self._datagrams(self.frames.feed(data))

    def finish(self) -> None:
        self._datagrams(self.frames.feed(b"", final=True))
        self.net.run_timers()
        self.agent.status()  # what `hilbench` shows of it must survive whatever it was told
        self.agent.stop()
        self.watch.check()

    def good(self) -> int:
        return self.net.sent

    def dropped(self) -> int:
        c = self.agent.counters
        return self.frames.skipped + c["malformed"] + c["orphan"]


AGENT_TARGET = FuzzTarget("server-xrce", "micro-ROS XRCE-DDS agent: clients' sessions of datagrams",
                             _AgentSession, LINK_100M, "100 Mbit/s Ethernet link of 100-byte datagrams",
                             agent_session, kind="server", max_input=1024)

__all__ = ["AGENT_TARGET", "CLIENTS", "agent_session"]
