"""CAN frames: SocketCAN layout, exact wire length against can-utils, arbitration order."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import CanFrame, data_frame, error_frame, remote_frame

# (SocketCAN can_id word, data, bits without stuffing, worst case, exact) as can-utils' canframelen.c
# (CFL_NO_BITSTUFFING, CFL_WORSTCASE, CFL_EXACT) computes them; produced by a throw-away C harness
# linking linux-can/can-utils canframelen.c.
CANUTILS = [
    (0x00000000, "", 47, 55, 53),
    (0x000007FF, "", 47, 55, 50),
    (0x00000000, "0000000000000000", 111, 135, 127),
    (0x00000000, "FFFFFFFFFFFFFFFF", 111, 135, 127),
    (0x000007FF, "FFFFFFFFFFFFFFFF", 111, 135, 126),
    (0x00000182, "F40106FF9C090007", 111, 135, 119),
    (0x00000123, "DEADBEEF", 79, 95, 81),
    (0x00000702, "05", 55, 65, 58),
    (0x00000602, "4000100000000000", 111, 135, 124),
    (0x00000555, "DEADBEEF01020304", 111, 135, 116),
    (0x80000000, "", 67, 80, 74),
    (0x9FFFFFFF, "FFFFFFFFFFFFFFFF", 131, 160, 149),
    (0x98FF50E5, "DEAD", 83, 100, 86),
    (0x92ABCDEF, "F40106FF9C090007", 131, 160, 138),
    (0x80000000, "0000000000000000", 131, 160, 150),
]


@pytest.mark.parametrize(("word", "data", "none", "worst", "exact"), CANUTILS)
def test_frame_bits_match_can_utils(word, data, none, worst, exact):
    frame = cf.from_raw(word, len(data) // 2, bytes.fromhex(data))
    assert cf.frame_bits(frame, "none") == none
    assert cf.frame_bits(frame, "worst") == worst
    assert cf.frame_bits(frame) == exact


def test_spec_sheet_table_worst_case():
    # §7: worst case at 8 bytes 135 (standard) / 160 (extended) bits: 270 / 320 us at 500 kbit/s.
    assert cf.frame_bits(data_frame(0x100, bytes(8)), "worst") / 500_000 == pytest.approx(270e-6)
    assert cf.frame_bits(data_frame(0x100, bytes(8), extended=True), "worst") / 500_000 == pytest.approx(320e-6)


def test_stuffing_counts_runs_of_five():
    assert cf.stuff_count([0] * 5) == 1
    assert cf.stuff_count([0] * 4 + [1] * 4) == 0
    # After a stuff bit (1) four more ones make another run of five.
    assert cf.stuff_count([0] * 5 + [1] * 4) == 1 + 1


@given(st.integers(0, 0x7FF), st.binary(max_size=8))
def test_exact_is_between_bounds(can_id, data):
    f = data_frame(can_id, data)
    assert cf.frame_bits(f, "none") <= cf.frame_bits(f) <= cf.frame_bits(f, "worst")


@given(st.integers(0, cf.CAN_EFF_MASK), st.binary(max_size=8), st.booleans())
def test_pack_round_trip(can_id, data, remote):
    frame = remote_frame(can_id, len(data), extended=True) if remote else data_frame(can_id, data, extended=True)
    raw = cf.pack(frame)
    assert len(raw) == 16
    assert cf.unpack(raw) == frame
    assert cf.SocketCanFrame.parse(raw).can_id == cf.raw_can_id(frame)  # fast path and construct agree


def test_socketcan_layout_bytes():
    raw = cf.pack(data_frame(0x123, b"\xde\xad"))
    assert raw == bytes.fromhex("23010000" "02000000" "DEAD000000000000")
    assert cf.pack(data_frame(0x18FF50E5, b"\x01", extended=True))[:4] == (0x98FF50E5).to_bytes(4, "little")
    assert cf.pack(error_frame(cf.CAN_ERR_BUSOFF))[:4] == (0x20000040).to_bytes(4, "little")
    assert cf.SocketCanFrame.build({"can_id": 0x123, "len": 2, "len8_dlc": 0, "data": b"\xde\xad" + bytes(6)}) == raw


@given(st.binary(max_size=200))
def test_split_never_raises_and_counts_the_tail(data):
    frames, rest = cf.split(data)
    assert len(frames) == len(data) // 16
    assert rest == len(data) % 16


def test_arbitration_order():
    frames = [data_frame(0x200, b""), data_frame(0x100, b"\x01"), remote_frame(0x100, 1),
              data_frame(0x100 << 18, b"", extended=True), data_frame(0x7FF, b"")]
    ordered = sorted(frames, key=cf.arbitration_key)
    # Same base ID 0x100: standard data beats standard remote beats extended.
    assert ordered[:3] == [frames[1], frames[2], frames[3]]
    assert ordered[3:] == [frames[0], frames[4]]


def test_constructors_refuse_bad_frames():
    with pytest.raises(ValueError):
        data_frame(0x123, bytes(9))
    with pytest.raises(ValueError):
        data_frame(0x800, b"", extended=False)
    with pytest.raises(ValueError):
        remote_frame(0x1, 9)
    assert str(data_frame(0x123, b"\x01\x02")) == "123#0102"
    assert str(remote_frame(0x7DF, 8)) == "7DF#R8"
    assert cf.error_class_names(cf.CAN_ERR_BUSOFF | cf.CAN_ERR_RESTARTED) == ["bus-off", "restarted"]
    assert CanFrame(1, b"\x01").length == 1
