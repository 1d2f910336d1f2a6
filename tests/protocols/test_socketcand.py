"""The socketcand text protocol, checked against python-can's own socketcand parser and the spec sheet."""

from __future__ import annotations

import pytest
from can.interfaces.socketcand.socketcand import (
    convert_ascii_message_to_can_message,
    convert_can_message_to_ascii_message,
)
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import socketcand as sc
from hilbench.protocols.can_frame import CanFrame, data_frame, error_frame
from hilbench.transports.can_messages import to_message


def test_frame_messages_as_the_spec_sheet_shows():
    assert sc.frame_message(data_frame(0x123, bytes.fromhex("DEADBEEF")), 1700000000.123456) == \
        "< frame 123 1700000000.123456 DEADBEEF >"
    assert sc.frame_message(data_frame(0x1ABCDEF0, b"\x01\x02", extended=True), 1700000000.223456) == \
        "< frame 1ABCDEF0 1700000000.223456 0102 >"
    assert sc.frame_message(data_frame(0x7FF, b""), 1700000000.323456) == "< frame 7FF 1700000000.323456  >"
    assert sc.frame_message(error_frame(0x004), 1700000000.523456) == "< error 004 1700000000.523456 >"
    # BCM mode: one byte per word, as state_bcm.c prints them.
    assert sc.frame_message(data_frame(0x123, b"\x11\x22"), 1.0, bcm=True) == "< frame 123 1.000000 11 22  >"


@given(st.integers(0, 0x1FFFFFFF), st.booleans(), st.binary(max_size=8), st.floats(0, 4e9))
def test_python_can_reads_every_frame_message(can_id, extended, data, t):
    if not extended:
        can_id &= 0x7FF
    frame = CanFrame(can_id, data, extended, False, False, len(data))
    msg = convert_ascii_message_to_can_message(sc.frame_message(frame, t))
    assert msg.arbitration_id == can_id and msg.is_extended_id == extended
    assert bytes(msg.data) == data and msg.dlc == len(data)
    assert msg.timestamp == pytest.approx(t, abs=1e-6)


def test_python_can_reads_error_reports():
    msg = convert_ascii_message_to_can_message(sc.frame_message(error_frame(0x040), 5.5))
    assert msg.is_error_frame and msg.arbitration_id == 0x040


@given(st.integers(0, 0x1FFFFFFF), st.booleans(), st.binary(max_size=8))
def test_commands_python_can_sends_parse(can_id, extended, data):
    if not extended:
        can_id &= 0x7FF
    text = convert_can_message_to_ascii_message(to_message(CanFrame(can_id, data, extended, False, False, len(data))))
    cmd = sc.parse_command(text)
    assert cmd.name == "send"
    assert cmd.frame == CanFrame(can_id, data, extended, False, False, len(data))
    assert sc.parse_command(sc.send_message(cmd.frame)).frame == cmd.frame


def test_command_parsing():
    assert sc.parse_command("< open can0 >") == sc.Command("open", value="can0")
    assert sc.parse_command("< open aaaaaaaaaaaaaaaaa >").name == "invalid"  # 17 characters
    assert sc.parse_command("< rawmode >").name == "rawmode"
    assert sc.parse_command("< send 123 3 de ad 1 >").frame == data_frame(0x123, b"\xde\xad\x01")
    assert sc.parse_command("< send 1ABCDEF0 0  >").frame == data_frame(0x1ABCDEF0, b"", extended=True)
    assert sc.parse_command("< send 123 2 de >").name == "invalid"  # DLC and bytes disagree: dropped
    assert sc.parse_command("< send 123 9 1 2 3 4 5 6 7 8 9 >").name == "invalid"
    assert sc.parse_command("< send zz 0 >").name == "invalid"
    add = sc.parse_command("< add 1 500000 123 2 11 22 >")
    assert add.name == "add" and add.interval == 1.5 and add.frame == data_frame(0x123, b"\x11\x22")
    flt = sc.parse_command("< filter 0 0 123 1 FF >")
    assert flt.name == "filter" and flt.mask == b"\xff"
    assert sc.parse_command("< subscribe 0 20000 123 >") == sc.Command("subscribe", interval=0.02, can_id=0x123)
    assert sc.parse_command("< unsubscribe 12345678 >") == sc.Command("unsubscribe", can_id=0x12345678, extended=True)
    assert sc.parse_command("< statistics 1000 >").value == "1000"
    assert sc.parse_command("< can0 B 500000 0 0 0 0 0 0 0 >").name == "configure"
    assert sc.parse_command("< frobnicate >").name == "unknown"
    assert sc.parse_command("< >").name == "unknown"


def test_splitter_handles_segments_and_garbage():
    s = sc.MessageSplitter()
    assert s.feed(b"< hi >< ok") == ["< hi >"]
    assert s.feed(b" >xx< echo >") == ["< ok >", "< echo >"]
    assert s.dropped == 2
    s2 = sc.MessageSplitter(max_message=50)
    assert s2.feed(b"<" + b"x" * 100) == []
    assert s2.dropped == 101
    assert s2.feed(b"< ok >") == ["< ok >"]


@given(st.binary(max_size=300))
def test_splitter_never_raises(data):
    s = sc.MessageSplitter(max_message=64)
    for msg in s.feed(data):
        sc.parse_command(msg)
        sc.parse_server_message(msg)


def test_server_messages_parse():
    m = sc.parse_server_message("< frame 123 1.500000 DEADBEEF >")
    assert m.kind == "frame" and m.frame == data_frame(0x123, bytes.fromhex("DEADBEEF")) and m.t_wall == 1.5
    assert sc.parse_server_message("< frame 123 1.0 11 22  >").frame.data == b"\x11\x22"
    assert sc.parse_server_message("< error 004 2.0 >").frame.error
    assert sc.parse_server_message("< error could not open bus >").kind == "error"
    assert sc.parse_server_message("< ok >").kind == "ok"


def test_beacon_is_what_python_can_detects():
    import xml.etree.ElementTree as ET

    root = ET.fromstring(sc.beacon("hilbench", "127.0.0.1", 29536, ["can0"]).decode())
    assert root.tag == "CANBeacon"
    assert root.find("URL").text == "can://127.0.0.1:29536"
    assert root.find("Bus").attrib["name"] == "can0"
