"""CANopen framing against the spec sheet's verified frames (§4)."""

from __future__ import annotations

from hilbench.protocols import canopen as co


def test_cob_ids():
    assert co.classify(0x000) == co.CobId("NMT", 0)
    assert co.classify(0x080) == co.CobId("SYNC", 0)
    assert co.classify(0x085) == co.CobId("EMCY", 5)
    assert co.classify(0x182) == co.CobId("TPDO1", 2)
    assert co.classify(0x202) == co.CobId("RPDO1", 2)
    assert co.classify(0x582) == co.CobId("SDO-TX", 2)
    assert co.classify(0x602) == co.CobId("SDO-RX", 2)
    assert co.classify(0x77F) == co.CobId("NMT-EC", 127)
    assert co.classify(0x7E5) == co.CobId("LSS", 0)
    assert co.classify(0x180) == co.CobId("other", 0)
    assert co.classify(0x182, extended=True) == co.CobId("other", 0)


def test_nmt_and_heartbeat():
    assert co.nmt_command(co.NMT_START, 5) == bytes.fromhex("0105")
    assert co.nmt_command(co.NMT_RESET_NODE) == bytes.fromhex("8100")
    hb = co.Heartbeat.parse(b"\x85")
    assert hb.toggle and hb.state == 5
    assert co.state_name(0x7F) == "PRE-OPERATIONAL" and co.state_name(0x05) == "OPERATIONAL"
    assert co.state_name(0x42).startswith("UNKNOWN")


def test_sdo_frames_from_the_spec_sheet():
    # read 0x1000:00 (device type) and its answer 0x00000192
    assert co.initiate(0x40, 0x1000, 0) == bytes.fromhex("4000100000000000")
    assert co.expedited_upload_response(0x1000, 0, (0x192).to_bytes(4, "little")) == bytes.fromhex("4300100092010000")
    # write 0x1017:00 = 250 ms (2 bytes) and its confirmation
    assert co.expedited_download_request(0x1017, 0, (250).to_bytes(2, "little")) == bytes.fromhex("2B171000FA000000")
    assert co.initiate(0x60, 0x1017, 0) == bytes.fromhex("6017100000000000")
    assert co.expedited_upload_response(0x1001, 0, b"\x00") == bytes.fromhex("4F01100000000000")
    assert co.expedited_size(0x4F) == 1 and co.expedited_size(0x4B) == 2 and co.expedited_size(0x47) == 3
    assert co.parse_initiate(bytes.fromhex("2B171000FA00")) == (0x2B, 0x1017, 0, b"\xfa\x00\x00\x00")


def test_aborts_and_segments():
    frame = co.sdo_abort(0x1018, 9, 0x06090011)
    assert frame == bytes.fromhex("8018100911000906")
    assert co.SdoAbort.parse(frame).code == 0x06090011
    assert co.abort_text(0x06090011) == "sub-index does not exist"
    seg = co.segment(1, b"abc", True, server=True)
    assert seg[0] == 0x00 | 0x10 | (4 << 1) | 1 and seg[1:4] == b"abc" and len(seg) == 8
    fields = co.SegmentCommand.parse(seg[:1])
    assert fields.toggle and fields.n == 4 and fields.last
    cmd = co.InitiateCommand.parse(b"\x43")
    assert cmd.cs == 2 and cmd.expedited and cmd.size_indicated and cmd.n == 0


def test_emcy():
    data = co.emcy_frame(0x8250, 0x11, b"\x01")
    assert data == bytes.fromhex("5082110100000000")
    assert co.Emcy.parse(data).code == 0x8250
    assert co.emcy_text(0x8250) == "RPDO timeout"
    assert co.emcy_text(0x2311).startswith("current, device output side")
    assert co.emcy_text(0xFF42).startswith("device specific")
