"""A FreeRTPS node's RTPS participant as a fuzz target (:mod:`hilbench.fuzzing`, kind ``server``).

A session is what another DDS participant sends a node over unicast, framed in one byte stream
(:func:`~hilbench.fuzzing.frame_datagram`; the sender byte picks its metatraffic or user port, or a
second participant's): SPDP announcements, SEDP publications and subscriptions for the node's topic,
user DATA (with INFO_TS) to its reader, HEARTBEATs, ACKNACKs for its writers, GAPs; now and then a
locator a hostile peer would plant (a port beyond 65535). Each session meets
a fresh :class:`~hilbench.fakes.rtps_participant.RtpsParticipant` (the bench's own, with a reliable
writer and a reader on ``rt/chatter``) through ``on_datagram``; what it sends goes through the checks a
UDP socket's ``sendto`` makes, and its timers (SPDP announcements, HEARTBEATs) run once after the
session, so a locator the session planted is used as the node would use it. ``good`` counts the
datagrams the node sent, ``dropped`` what it counted as malformed or foreign.
"""

from __future__ import annotations

import random

from hilbench.fuzzing import LINK_100M, DatagramFrames, FuzzTarget, NetPort, TracebackWatch, frame_datagram
from hilbench.protocols import rtps as r

STRING = "std_msgs::msg::dds_::String_"
TOPIC = "rt/chatter"
#: The node under test: domain 0, participant index 0 (ports 7410/7411), FreeRTPS's GUID prefix form.
PREFIX = bytes.fromhex("2C2F2C4D5901235100000000")
#: The sending participants' GUID prefixes and their (metatraffic, user) unicast ports.
PEERS = ((bytes.fromhex("010F0A0B0C0D0E0F10111213"), 7412, 7413), (bytes.fromhex("010F99999999999999999999"), 7414,
                                                                       7415))
WRITER, READER = b"\x00\x00\x01\x03", b"\x00\x00\x02\x04"  # the peer's user endpoints
NODE_WRITER, NODE_READER = b"\x00\x00\x01\x03", b"\x00\x00\x02\x04"  # the node's (FreeRTPS numbers from 1)


def _cdr_string(text: str) -> bytes:
    raw = text.encode() + b"\x00"
    return r.CDR_LE + b"\x00\x00" + len(raw).to_bytes(4, "little") + raw


def participant_session(rng: random.Random, size: int) -> bytes:
    """Discovery then traffic from one or two peers (about ``size`` bytes, framed)."""
    out = bytearray()
    sn: dict[tuple[int, bytes], int] = {}

    def nxt(peer: int, writer: bytes) -> int:
        sn[(peer, writer)] = sn.get((peer, writer), 0) + 1
        return sn[(peer, writer)]

    while len(out) < size:
        peer = rng.randrange(len(PEERS))
        prefix, meta, user = PEERS[peer]
        guid = prefix + r.ENTITYID_PARTICIPANT
        k = rng.random()
        ts = r.info_ts(1_700_000_000 + rng.randrange(100), rng.randrange(1 << 32))
        if k < 0.15:
            # now and then a locator no socket can reach (a port beyond 65535, as a spoofed SPDP has)
            hostile = rng.random() < 0.02
            body = r.spdp_payload(prefix, meta_port=rng.choice((70000, 2**31 - 1)) if hostile else meta,
                                  user_port=user, lease_s=rng.choice((10, 100)), vendor_id=b"\x01\x0f", domain_id=0)
            msg = r.message(prefix, ts, r.data(r.ENTITYID_UNKNOWN, r.SPDP_WRITER, nxt(peer, r.SPDP_WRITER), body,
                                               inline_qos=r.key_hash_qos(guid)), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer)
        elif k < 0.3:
            pub = rng.random() < 0.5
            writer = r.SEDP_PUB_WRITER if pub else r.SEDP_SUB_WRITER
            ep = prefix + (WRITER if pub else READER)
            body = r.sedp_payload(ep, TOPIC, STRING, reliable=rng.random() < 0.5, vendor_id=b"\x01\x0f",
                                  unicast=("127.0.0.1", user), participant_guid=guid)
            msg = r.message(prefix, r.info_dst(PREFIX), ts,
                            r.data(writer[:3] + b"\xc7", writer, nxt(peer, writer), body), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer)
        elif k < 0.6:
            msg = r.message(prefix, ts, r.data(r.ENTITYID_UNKNOWN, WRITER, nxt(peer, WRITER),
                                               _cdr_string(f"hello {rng.randrange(1000)}")), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer + 1)
        elif k < 0.75:
            last = sn.get((peer, WRITER), 0)
            msg = r.message(prefix, r.info_dst(PREFIX), r.heartbeat(NODE_READER, WRITER, 1, last,
                                                                    rng.randrange(1, 100)), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer + 1)
        elif k < 0.9:
            target = rng.choice((NODE_WRITER, r.SEDP_PUB_WRITER, r.SEDP_SUB_WRITER))
            reader = READER if target == NODE_WRITER else target[:3] + b"\xc7"
            base = rng.randrange(1, 4)
            msg = r.message(prefix, r.info_dst(PREFIX), r.acknack(reader, target, base, [base] if rng.random() < 0.3
                                                                  else [], rng.randrange(1, 100)), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer + (target == NODE_WRITER))
        else:
            msg = r.message(prefix, r.info_dst(PREFIX), r.gap(NODE_READER, WRITER, 1, 2), vendor_id=b"\x01\x0f")
            out += frame_datagram(msg, 2 * peer + 1)
    return bytes(out)


class _ParticipantSession:
    def __init__(self) -> None:
        from hilbench.fakes.rtps_participant import RtpsParticipant

        self.net = NetPort()
        self.node = RtpsParticipant("fuzz-node", self.net, domain_id=0, participant_index=0, guid_prefix=PREFIX,
                                    peers=["127.0.0.1"], max_index=2)
        self.node.add_writer(TOPIC, STRING, reliable=True)
        self.node.add_reader(TOPIC, STRING, lambda data, le, guid, ts: None, reliable=True)
        self.node.start()
        self.frames = DatagramFrames()
        self.t = 0.0
        self.watch = TracebackWatch.shared()
        self.watch.clear()

    def _datagrams(self, items: list[tuple[int, bytes]]) -> None:
        node = self.node
        for source, datagram in items:
            self.t += 1e-4
            prefix, meta, user = PEERS[(source // 2) % len(PEERS)]
            src = ("127.0.0.1", user if source % 2 else meta)
            dst = ("127.0.0.1", node.ports["user_unicast"] if source % 2 else node.ports["metatraffic_unicast"])
            node.on_datagram(datagram, src, dst, self.t)

    def feed(self, data: bytes) -> None:
        self._datagrams(self.frames.feed(data))

    def finish(self) -> None:
        self._datagrams(self.frames.feed(b"", final=True))
        self.net.run_timers()  # announcements and HEARTBEATs to whatever the session made the node know
        self.node.write(next(iter(self.node.writers.values())), _cdr_string("after")[4:])
        self.node.describe()
        self.node.stop()
        self.watch.check()

    def good(self) -> int:
        return self.net.sent

    def dropped(self) -> int:
        c = self.node.counters
        return self.frames.skipped + c["malformed"] + c["foreign"]


PARTICIPANT = FuzzTarget("server-rtps", "FreeRTPS node's RTPS participant: a peer's discovery and traffic",
                            _ParticipantSession, LINK_100M, "100 Mbit/s Ethernet link of 100-byte datagrams",
                            participant_session, kind="server", max_input=1024)

__all__ = ["PARTICIPANT", "participant_session"]
