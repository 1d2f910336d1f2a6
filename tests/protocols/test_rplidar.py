"""RPLIDAR protocol: the sheet's vectors (§1.4-1.7, §1.12), numpy/construct agreement, decoders on garbage."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import rplidar as rp
from hilbench.protocols.problem import Problem

H = bytes.fromhex


def test_requests():
    assert rp.request(rp.Cmd.GET_INFO) == H("A5 50")
    assert rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)) == H("A5 82 05 00 00 00 00 00 22")
    assert rp.request(rp.Cmd.SET_MOTOR_PWM, (660).to_bytes(2, "little")) == H("A5 F0 02 94 02 C1")
    assert rp.request(rp.Cmd.SET_MOTOR_PWM, bytes(2)) == H("A5 F0 02 00 00 57")
    assert rp.request(rp.Cmd.GET_LIDAR_CONF, H("70 00 00 00")) == H("A5 84 04 70 00 00 00 55")
    assert rp.request(rp.Cmd.GET_LIDAR_CONF, H("71 00 00 00 00 00")) == H("A5 84 06 71 00 00 00 00 00 56")


def test_descriptors():
    assert rp.descriptor(20, rp.SINGLE, rp.AnsType.DEVINFO) == H("A5 5A 14 00 00 00 04")
    assert rp.descriptor(3, rp.SINGLE, rp.AnsType.DEVHEALTH) == H("A5 5A 03 00 00 00 06")
    assert rp.descriptor(4, rp.SINGLE, rp.AnsType.SAMPLERATE) == H("A5 5A 04 00 00 00 15")
    assert rp.descriptor(5, rp.MULTIPLE, rp.AnsType.MEASUREMENT) == H("A5 5A 05 00 00 40 81")
    assert rp.descriptor(84, rp.MULTIPLE, rp.AnsType.MEASUREMENT_CAPSULED) == H("A5 5A 54 00 00 40 82")
    assert rp.descriptor(8, rp.SINGLE, rp.AnsType.GET_LIDAR_CONF) == H("A5 5A 08 00 00 00 20")


def test_payloads_and_exchange():
    info = rp.info_payload(0x18, (1, 29), 7, H("D8E0EDF9C7E29BD1A7E39EF24833431B"))
    assert info == H("18 1D 01 07 D8 E0 ED F9 C7 E2 9B D1 A7 E3 9E F2 48 33 43 1B")
    assert rp.samplerate_payload(508, 254) == H("FC 01 FE 00")
    assert rp.health_payload(2, 0x8001) == H("02 01 80")
    dec = rp.ResponseDecoder()
    items = dec.feed(rp.descriptor(20, 0, 4) + info + rp.descriptor(4, 0, 0x15) + H("FC 01 FE 00"))
    assert items[0].fields == {"model": 24, "firmware": (1, 29), "hardware": 7,
                               "serial": "D8E0EDF9C7E29BD1A7E39EF24833431B"}
    assert items[1].fields == {"standard_us": 508, "express_us": 254}


def test_nodes():
    vectors = [((47, 0, 4000, True), H("BD 01 00 A0 0F")), ((47, 5792, 4937, False), H("BE 41 2D 49 13")),
               ((0, 180 * 64, 0, False), H("02 01 5A 00 00"))]
    for (q, a, d, s), raw in vectors:
        assert rp.node(q, a, d, s) == raw
        n = rp.parse_node(raw)
        assert (n.start, n.quality, n.angle, n.distance) == (s, q, a / 64, d / 4)
    q, a, d, s = (np.array(x) for x in zip(*[v[0] for v in vectors], strict=True))
    assert rp.encode_nodes(q, a, d, s) == b"".join(v[1] for v in vectors)


@given(st.lists(st.tuples(st.integers(0, 63), st.integers(0, 0x7FFF), st.integers(0, 0xFFFF), st.booleans()),
                min_size=1, max_size=40))
def test_numpy_nodes_agree_with_construct(nodes):
    q, a, d, s = (np.array(x) for x in zip(*nodes, strict=True))
    assert rp.encode_nodes(q, a, d, s) == b"".join(rp.node(*n) for n in nodes)


def test_capsule_vector_and_sdk_placement():
    cap = rp.capsule(640, list(range(1000, 1032)), True)
    assert cap[:9] == H("A2 50 80 82 A0 0F A4 0F 00")
    item = rp.parse_capsule(cap)
    assert item.start_angle == 10.0 and item.new_scan and item.distances[:3] == (1000, 1001, 1002)
    nxt = rp.parse_capsule(rp.capsule(int(12.0 * 64), [2000] * 32, False))
    samples = rp.capsule_samples(item, nxt)
    assert samples[0] == (10.0, 1000) and samples[16][0] == 11.0
    bad = cap[:20] + bytes([cap[20] ^ 1]) + cap[21:]
    assert rp.parse_capsule(bad) is None


def test_response_decoder_skips_banner_and_resyncs():
    dec = rp.ResponseDecoder()
    banner = b"RP LIDAR System.\r\nFirmware Ver 1.29 - rtm, HW Ver 7\r\nModel: 18\r\n"
    stream = banner + rp.descriptor(5, 1, 0x81) + rp.node(10, 64, 400, True) + b"\x00\x00" + rp.node(9, 128, 40, False)
    items = dec.feed(stream)
    nodes = [i for i in items if isinstance(i, rp.Node)]
    assert [n.angle for n in nodes] == [1.0, 2.0]
    assert {i.kind for i in items if isinstance(i, Problem)} == {"banner", "garbage"}
    assert dec.dropped == len(banner) + 2


def test_request_decoder_checks_xor():
    dec = rp.RequestDecoder()
    good = rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5))
    items = dec.feed(b"\x00" + good[:4])
    items += dec.feed(good[4:] + good[:-1] + b"\x23" + rp.request(rp.Cmd.STOP))
    kinds = [type(i).__name__ if not isinstance(i, Problem) else i.kind for i in items]
    assert kinds == ["garbage", "Request", "checksum", "Request"]
    assert dec.bad_checksum == 1


@settings(max_examples=200)
@given(st.binary(max_size=600), st.sampled_from([None, 0x81, 0x82]))
def test_decoders_never_raise(data, stream):
    dec = rp.ResponseDecoder()
    dec.expect_stream(stream)
    items = dec.feed(data)
    assert sum(len(i.raw) for i in items if isinstance(i, Problem)) <= len(data)
    rp.RequestDecoder().feed(data)


def test_a_descriptor_inside_a_misaligned_node_wins():
    """A node stream that lost a byte, then the answer to EXPRESS_SCAN: the descriptor starts inside what
    would parse as a node (the grid is off by the lost byte); the decoder must switch to capsules."""
    n = 6
    nodes = rp.encode_nodes(np.full(n, 40), np.arange(n) * 640, np.full(n, 4000), np.zeros(n, dtype=bool))
    damaged = nodes[:-1]  # the last node lost a byte: the grid now ends 4 bytes into a node
    caps = [rp.capsule(64 * 10 * k, [1000] * 32, k == 0) for k in range(3)]
    bad = bytearray(caps[2])
    bad[10] ^= 0x5A
    stream = (rp.descriptor(5, rp.MULTIPLE, rp.AnsType.MEASUREMENT) + damaged
              + rp.descriptor(84, rp.MULTIPLE, rp.AnsType.MEASUREMENT_CAPSULED) + caps[0] + caps[1] + bytes(bad))
    dec = rp.ResponseDecoder()
    items = dec.feed(stream)
    assert sum(isinstance(x, rp.CapsuleItem) for x in items) == 2
    assert dec.stream == rp.AnsType.MEASUREMENT_CAPSULED and dec.bad_checksum == 1
    # a node whose angle bytes are A5 5A stays a node: only a whole plausible descriptor wins
    odd = bytes([0x3E, 0xA5, 0x5A, 0x00, 0x10])
    dec = rp.ResponseDecoder()
    dec.expect_stream(rp.AnsType.MEASUREMENT)
    assert [type(x).__name__ for x in dec.feed(odd + nodes)] == ["Node"] * (1 + n)
