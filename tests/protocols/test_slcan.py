"""SLCAN (LAWICEL): the spec sheet's examples, the acceptance filter, a splitter that never raises."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import slcan
from hilbench.protocols.can_frame import data_frame, remote_frame


@pytest.mark.parametrize(("line", "frame"), [
    ("t1230", data_frame(0x123, b"")),
    ("t4563112233", data_frame(0x456, bytes.fromhex("112233"))),
    ("T12ABCDEF2AA55", data_frame(0x12ABCDEF, bytes.fromhex("AA55"), extended=True)),
    ("r1230", remote_frame(0x123, 0)),
    ("r1232", remote_frame(0x123, 2)),
    ("t12320102EA5F", data_frame(0x123, b"\x01\x02")),  # a trailing timestamp
    ("T1ABCDEF020102", data_frame(0x1ABCDEF0, b"\x01\x02", extended=True)),
])
def test_spec_sheet_frames(line, frame):
    assert slcan.parse_frame(line) == frame
    assert slcan.parse_command(line).frame == frame


def test_encoding_round_trips_and_timestamps():
    f = data_frame(0x123, bytes.fromhex("DEADBEEF"))
    assert slcan.encode_frame(f) == b"t1234DEADBEEF\r"
    assert slcan.encode_frame(f, 61_000) == b"t1234DEADBEEF03E8\r"  # wraps after 60 s
    assert slcan.encode_frame(remote_frame(0x7DF, 8)) == b"r7DF8\r"
    assert slcan.encode_frame(data_frame(0x18FF50E5, b"\x01\x02\x03", extended=True)) == b"T18FF50E53010203\r"


@pytest.mark.parametrize("line", ["t12", "t1239", "t1232DE", "tXYZ0", "t8000", "T1", "r123", "t1231ZZ"])
def test_malformed_frames_are_refused(line):
    cmd = slcan.parse_command(line)
    assert not cmd.valid and cmd.frame is None


def test_commands_and_bitrates():
    assert slcan.parse_command("S6") == slcan.Command("S", value="6")
    assert slcan.parse_command("") == slcan.Command("")
    assert slcan.BITRATES["6"] == 500_000 and slcan.BITRATES["7"] == 800_000  # LAWICEL, not python-can's 750 k
    assert slcan.bitrate_command(125_000) == "S4"
    with pytest.raises(ValueError):
        slcan.bitrate_command(123_456)


def test_splitter():
    s = slcan.LineSplitter(max_line=10)
    assert s.feed(b"C\rS6") == ["C"]
    assert s.feed(b"\r\rO\r\n") == ["S6", "", "O"]
    assert s.feed(b"t" + b"1" * 20 + b"\rV\r") == ["V"]
    assert s.dropped == 22


@given(st.binary(max_size=200))
def test_splitter_never_raises(data):
    for line in slcan.LineSplitter().feed(data):
        slcan.parse_command(line)


def test_acceptance_filter():
    everything = (0, 0xFFFFFFFF)
    assert slcan.acceptance(data_frame(0x123, b""), *everything)
    # Only standard ID 0x123, any data: code = ID << 21, mask = don't care everything but ID and RTR.
    code, mask = 0x123 << 21, 0x000FFFFF
    assert slcan.acceptance(data_frame(0x123, b"\x99"), code, mask)
    assert not slcan.acceptance(data_frame(0x124, b""), code, mask)
    assert not slcan.acceptance(remote_frame(0x123, 0), code, mask)
    ext = data_frame(0x1ABCDEF0, b"", extended=True)
    assert slcan.acceptance(ext, 0x1ABCDEF0 << 3, 0x3)
    assert not slcan.acceptance(ext, 0x1ABCDEF1 << 3, 0x3)
