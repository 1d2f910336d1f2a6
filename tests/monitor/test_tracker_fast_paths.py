"""The tracker's fast paths change nothing: reply slots filled by the decoder give the state items give."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.monitor.servo_bus.summary import summary
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814
from hilbench.protocols.dynamixel import ReplySlots


class ItemsOnly(BusTracker):
    """The tracker with its reply slots never armed: every packet reaches it as an item."""

    def _arm(self) -> ReplySlots:
        slots = self._slots
        slots.clear()
        return slots


class Counting(BusTracker):
    """The tracker as it is, counting the replies its decoders slotted."""

    slotted = 0

    def _settle_fills(self) -> None:
        Counting.slotted += len(self._slots.fills)
        super()._settle_fills()


def state(tr: BusTracker) -> tuple:
    """Everything observable, exactly (the summary rounds; the raw facts do not)."""
    devices = [
        (d.id, d.state, d.health, d.consecutive, d.misses, d.seen_t, d.owed_since, d.extra_replies, list(d.lat),
         d.lat_n, d.lat_sum, d.observations(), d.last_seen, tr.replies(d), d.requests, d.alert, d.last_error)
        for d in sorted(tr.devices.values(), key=lambda d: d.id)
    ]
    log = [(e.t, e.kind, e.device, e.text, e.repeats) for e in tr.log.entries]
    counters = (tr.items, tr.statuses, tr.problem_items, tr.unanswered, tr.unexpected, tr.bad_replies,
                tr.requests_expecting_replies, tr.counts, dict(tr.log.counts), tr.problems(), tr.crc_errors)
    return summary(tr, errors=10_000), devices, log, counters


def replay(cls: type[BusTracker], data: bytes, cuts: list[int], timed: bool) -> BusTracker:
    tr = cls(baud=2_000_000, timestamps=timed)
    pos = 0
    for k, n in enumerate(cuts):
        tr.feed(0.02 * (k + 1) if timed else 0.0, "bus", data[pos : pos + n])
        pos += n
    tr.feed(0.02 * (len(cuts) + 1) if timed else 0.0, "bus", data[pos:])
    tr.finish()
    return tr


def traffic(seed: int, cycles: int) -> bytes:
    """Wolfgang-like cycles with every way a reply can go wrong: lost, corrupted, late, doubled, erring."""
    rnd = random.Random(seed)
    ids = list(range(1, rnd.randint(2, 8)))
    gone = rnd.choice(ids)  # drops out for a while: disconnected, then back
    away = range(rnd.randrange(cycles), rnd.randrange(cycles) + 12)
    out = []
    for c in range(cycles):
        read = rnd.choice([(132, 4), (144, 3), (70, 1), (0, 2)])  # (0, 2): the model number, a special field
        out.append(dxl.instruction_packet_unstuffed(0xFE, I.SYNC_READ, bytes((read[0], 0, read[1], 0, *ids))))
        order = ids[:]
        if rnd.random() < 0.1:
            rnd.shuffle(order)
        for i in order:
            r = rnd.random()
            if r < 0.1 or (i == gone and c in away):
                continue  # lost
            data = bytes(rnd.randrange(256) for _ in range(read[1]))
            if r < 0.13:
                data = data[:-1]  # wrong length
            if r < 0.15:
                data = b"\xff\xff\xfd" + data[3:]  # stuffed on the wire
            pkt = dxl.status_packet(i, 0x80 if r > 0.98 else (4 if r > 0.97 else 0), data)
            if 0.15 < r < 0.2:
                pkt = pkt[:-1] + bytes((pkt[-1] ^ 1,))  # CRC failure
            out.append(pkt)
            if 0.2 < r < 0.23:
                out.append(pkt)  # said twice
        if rnd.random() < 0.3:
            out.append(dxl.instruction_packet_unstuffed(0x65, I.READ, b"\x24\x00\x10\x00"))  # never answered
        if rnd.random() < 0.4:
            out.append(dxl.instruction_packet_unstuffed(
                0xFE, I.SYNC_WRITE, b"\x74\x00\x04\x00" + b"".join(bytes((i, 0, 8, 0, 0)) for i in ids)))
        if rnd.random() < 0.05:
            out.append(bytes(rnd.randrange(256) for _ in range(rnd.randrange(40))))
    return b"".join(out)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10**6), st.lists(st.integers(1, 9000), max_size=8), st.booleans())
def test_reply_slots_give_the_state_items_give(seed, cuts, timed):
    data = traffic(seed, 150)
    assert state(replay(BusTracker, data, cuts, timed)) == state(replay(ItemsOnly, data, cuts, timed))


def test_reply_slots_are_used_on_synthetic_traffic():
    data = traffic(7, 400)
    cuts = [4096] * (len(data) // 4096)
    Counting.slotted = 0
    assert state(replay(Counting, data, cuts, True)) == state(replay(ItemsOnly, data, cuts, True))
    assert Counting.slotted > 300


def test_reply_slots_give_the_state_items_give_on_the_capture(wolfgang_capture):
    for chunk, timed in ((4096, True), (65536, False)):
        cuts = [chunk] * (len(wolfgang_capture) // chunk)
        Counting.slotted = 0
        fast = replay(Counting, wolfgang_capture, cuts, timed)
        assert state(fast) == state(replay(ItemsOnly, wolfgang_capture, cuts, timed))
        assert fast.statuses == 21_069 and Counting.slotted > 17_000
