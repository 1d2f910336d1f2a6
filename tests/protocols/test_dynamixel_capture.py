"""The real Wolfgang bus capture decodes as the data README and spec sheet §8 describe."""

from __future__ import annotations

import hashlib
from collections import Counter

from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.problem import Problem

MX64 = {1, 2, 3, 4, 5, 6, 19, 20}
MX106 = {8, 9, 13, 14, 15, 17, 11, 16, 18}


def decode(data: bytes, **kw) -> tuple[dxl.Decoder, list]:
    dec = dxl.Decoder(**kw)
    return dec, dec.feed(data) + dec.flush()


def test_capture_is_the_published_one(wolfgang_capture):
    assert len(wolfgang_capture) == 528_509
    assert hashlib.sha256(wolfgang_capture).hexdigest().startswith("9ef7e509f41bbdfd")


def test_packet_kinds_and_counts(wolfgang_capture):
    dec, items = decode(wolfgang_capture)
    packets = [i for i in items if not isinstance(i, Problem)]
    assert dec.packets == len(packets) == 23_478
    kinds = Counter(p.name for p in packets)
    assert kinds == {"status": 21_069, "sync_read": 1_057, "read": 889, "sync_write": 426, "write": 17, "ping": 20}
    sizes = Counter(len(p.raw) for p in packets if p.name == "status")
    assert sizes == {15: 20_658, 14: 206, 12: 187, 11: 18}
    assert all(p.error == 0 for p in packets if p.name == "status")
    assert sum(len(p.raw) for p in packets) == 411_985
    # every failure is counted, none stops the decoder
    assert sum(dec.problems.values()) == 952
    assert dec.bytes_in == len(wolfgang_capture)


def test_failures_split_as_the_sheet_counts_them_without_a_length_cap(wolfgang_capture):
    # The sheet's rule frames every candidate by LENGTH, whatever its size.
    dec, _ = decode(wolfgang_capture, max_length=0xFFFF)
    # The sheet counts LENGTH 0 candidates (31 of them) among its 948 CRC failures.
    assert dec.problems["crc"] + dec.problems["bad_length"] == 948
    assert dec.problems["bad_length"] == 31
    assert dec.problems["truncated"] == 4  # LENGTH past end of file
    assert dec.packets == 23_478


def test_instruction_details(wolfgang_capture):
    _, items = decode(wolfgang_capture)
    inst = [i for i in items if isinstance(i, dxl.InstructionPacket)]
    for p in inst:
        assert dxl.check_instruction(p) is None, p
    sync_reads = Counter((f.address, f.length) for f in (p.fields() for p in inst if p.name == "sync_read"))
    assert sync_reads == {(132, 4): 1038, (70, 1): 10, (144, 3): 9}
    reads = {(p.id, p.fields().address, p.fields().length) for p in inst if p.name == "read"}
    assert reads == {(101, 36, 16)}
    pos_reads = [p for p in inst if p.name == "sync_read" and p.fields().address == 132]
    assert all(list(p.fields().ids) == list(range(1, 21)) for p in pos_reads)
    goal_writes = [p for p in inst if p.name == "sync_write" and p.fields().address == 116]
    assert len(goal_writes) == 409
    torque = [p for p in inst if p.name == "write"]
    assert {(p.fields().address, p.fields().data) for p in torque} == {(64, b"\x00")}
    assert sorted(p.id for p in torque) == [i for i in range(1, 20) if i not in (3, 7)]
    assert sorted(p.id for p in inst if p.name == "ping") == list(range(1, 21))


def test_ping_models_and_the_silent_foot_sensor(wolfgang_capture):
    _, items = decode(wolfgang_capture)
    models = {}
    last = None
    for item in items:
        if isinstance(item, dxl.InstructionPacket):
            last = item
        elif isinstance(item, dxl.StatusPacket) and last is not None and last.name == "ping":
            reply = dxl.PingReply.parse(item.data)
            models[item.id] = (reply.model_number, reply.firmware)
    assert {i for i, (m, _) in models.items() if m == 311} == MX64
    assert {i for i, (m, _) in models.items() if m == 321} == MX106
    assert set(models) == MX64 | MX106  # 7, 10 and 12: their ping replies fail the CRC
    assert {i for i, (_, fw) in models.items() if fw == 42} == {11, 16, 18}
    assert not any(isinstance(i, dxl.StatusPacket) and i.id == 101 for i in items)


def test_values_are_in_the_ranges_the_sheet_reports(wolfgang_capture):
    _, items = decode(wolfgang_capture)
    positions = [int.from_bytes(i.data, "little", signed=True) for i in items
                 if isinstance(i, dxl.StatusPacket) and len(i.data) == 4]
    assert min(positions) == 1104 and max(positions) == 2969
