"""The bus tracker never raises, whatever the bus carries: valid traffic of every instruction mixed
with replies in and out of order, corrupted and cut packets, garbage, any chunking and timing; its
summary stays valid JSON and its counters stay consistent."""

from __future__ import annotations

import json

from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.monitor.servo_bus.summary import summary
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814

ids = st.integers(0, 0xFD)
addr = st.integers(0, 700)
small = st.integers(0, 8)
data = st.binary(max_size=12)

instruction = st.one_of(
    st.builds(lambda i: dxl.instruction_packet(i, I.PING), ids),
    st.builds(lambda i, a, n: dxl.instruction_packet(i, I.READ, bytes([a & 255, a >> 8, n, 0])), ids, addr, small),
    st.builds(lambda i, a, d: dxl.instruction_packet(i, I.WRITE, bytes([a & 255, a >> 8]) + d), ids, addr, data),
    st.builds(lambda a, n, xs: dxl.instruction_packet(0xFE, I.SYNC_READ, bytes([a & 255, a >> 8, n, 0, *xs])),
              addr, small, st.lists(st.integers(0, 252), max_size=6)),
    st.builds(lambda a, n, xs: dxl.instruction_packet(0xFE, I.FAST_SYNC_READ, bytes([a & 255, a >> 8, n, 0, *xs])),
              addr, small, st.lists(st.integers(0, 252), max_size=6)),
    st.builds(lambda es: dxl.instruction_packet(0xFE, I.BULK_READ, b"".join(
        bytes([i, a & 255, a >> 8, n, 0]) for i, a, n in es)), st.lists(st.tuples(ids, addr, small), max_size=4)),
    st.builds(lambda i, inst: dxl.instruction_packet(i, inst), ids,
              st.sampled_from([I.ACTION, I.REBOOT, I.FACTORY_RESET, I.CLEAR, 0x77])),
)
status = st.one_of(
    st.builds(dxl.status_packet, ids, st.integers(0, 255), data),
    st.builds(lambda sl: dxl.build_fast_reply(sl), st.lists(st.tuples(st.integers(0, 252), st.integers(0, 255),
                                                                       st.binary(min_size=4, max_size=4)),
                                                             min_size=1, max_size=4)),
)


def damage(raw: bytes, how: int) -> bytes:
    if how == 1 and len(raw) > 8:
        return raw[:-2] + bytes([raw[-2] ^ 0x5A, raw[-1]])  # bad CRC
    if how == 2:
        return raw[: len(raw) // 2]  # cut short
    return raw


piece = st.one_of(
    st.tuples(st.just("host"), instruction, st.integers(0, 4)),
    st.tuples(st.just("dev"), status, st.integers(0, 4)),
    st.tuples(st.sampled_from(["host", "dev"]), st.binary(max_size=20), st.just(0)),
)


@settings(max_examples=150, deadline=None)
@given(st.lists(piece, max_size=60), st.integers(1, 40), st.sampled_from([None, 57_600, 2_000_000]),
       st.lists(st.floats(0, 0.3), min_size=1, max_size=8))
def test_anything_on_the_bus_gives_a_consistent_summary(pieces, chunk, baud, gaps):
    tr = BusTracker(baud=baud, silence=0.5)
    t = 1000.0
    for k, (src, raw, how) in enumerate(pieces):
        raw = damage(raw, how)
        t += gaps[k % len(gaps)] * 1e-3
        for i in range(0, len(raw), chunk):
            tr.feed(t, src, raw[i : i + chunk])
        if k % 7 == 3:
            t += gaps[k % len(gaps)]
            tr.tick(t)
    tr.finish()
    doc = json.loads(json.dumps(summary(tr), allow_nan=False))
    for dev in doc["devices"].values():
        assert dev["replies"] >= 0 and dev["misses"] >= 0
        assert dev["state"] in ("connected", "disconnected", "unknown")
    assert doc["bytes"] == sum(len(damage(raw, how)) for _, raw, how in pieces)
