"""SICK LMS 200 telegrams: the sheet's CRC trace and verified telegrams (§2.3, §2.7), decoder robustness."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import sick_lms200 as lms
from hilbench.protocols.checksums import sick_crc16
from hilbench.protocols.problem import Problem

H = bytes.fromhex


def test_crc_trace():
    assert sick_crc16(H("02")) == 0x0002
    assert sick_crc16(H("02 00")) == 0x0204
    assert sick_crc16(H("02 00 01 00 31")) == 0x1215


def test_requests():
    assert lms.request(lms.Cmd.STATUS) == H("02 00 01 00 31 15 12")
    assert lms.request(lms.Cmd.RESET) == H("02 00 01 00 10 34 12")
    assert lms.request(lms.Cmd.READ_CONFIG) == H("02 00 01 00 74 50 12")
    assert lms.mode_request(0x24) == H("02 00 02 00 20 24 34 08")
    assert lms.mode_request(0x25) == H("02 00 02 00 20 25 35 08")
    assert lms.request(lms.Cmd.SCAN, b"\x01") == H("02 00 02 00 30 01 31 18")
    assert lms.mode_request(0x42) == H("02 00 02 00 20 42 52 08")
    assert lms.mode_request(0x41) == H("02 00 02 00 20 41 51 08")
    assert lms.mode_request(0x40) == H("02 00 02 00 20 40 50 08")
    assert lms.mode_request(0x48) == H("02 00 02 00 20 48 58 08")
    assert lms.mode_request(0x00) == H("02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53 BE C5")
    assert lms.variant_request(180, 50) == H("02 00 05 00 3B B4 00 32 00 3B 1F")
    assert lms.variant_request(100, 100) == H("02 00 05 00 3B 64 00 64 00 1D 0F")
    assert lms.variant_request(180, 100) == H("02 00 05 00 3B B4 00 64 00 97 49")
    assert lms.variant_request(100, 25) == H("02 00 05 00 3B 64 00 19 00 E7 72")
    config = H("00 00 00 00 00 0D 00 00 00 02 02") + bytes(21)
    assert lms.request(lms.Cmd.WRITE_CONFIG, config) == H("02 00 21 00 77") + config + H("20 CB")
    assert config[lms.CONFIG_UNITS] == 0  # the public telegram sets units = cm


def test_replies():
    assert lms.reply(0xA0, b"\x00") == H("02 80 03 00 A0 00 10 16 0A")
    assert lms.reply(0xA0, b"\x01") == H("02 80 03 00 A0 01 10 14 0B")
    assert lms.reply(0xBB, lms.VariantReply.build({"accepted": 1, "angle": 180, "resolution": 50})) == \
        H("02 80 07 00 BB 01 B4 00 32 00 10 03 9D")
    scan = lms.reply(0xB0, lms.scan_data([1000, 1001, 1002, 1003, 1004], True))
    assert scan == H("02 80 0E 00 B0 05 40 E8 03 E9 03 EA 03 EB 03 EC 03 10 6B A9")
    long_ = lms.reply(0xB0, lms.scan_data([2000] * 181, True))
    assert len(long_) == 372 and long_[:7] == H("02 80 6E 01 B0 B5 40") and long_[-3:] == H("10 95 9D")
    cm = lms.reply(0xB0, lms.scan_data([200] * 101, False))
    assert len(cm) == 212 and cm[:7] == H("02 80 CE 00 B0 65 00") and cm[-3:] == H("10 14 C4")
    assert lms.count_word(361, True) == 0x4169


def test_decoder_frames_both_directions():
    dec = lms.Decoder()
    stream = b"\x06" + lms.reply(0xA0, b"\x00") + b"\xff" + lms.request(lms.Cmd.SCAN, b"\x01")
    bad = bytearray(lms.reply(0xB0, lms.scan_data([5, 6], True)))
    bad[-1] ^= 1
    items = dec.feed(stream + bytes(bad) + b"\x15")
    kinds = [type(i).__name__ if not isinstance(i, Problem) else i.kind for i in items]
    assert kinds[:4] == ["Handshake", "Frame", "garbage", "Frame"]
    assert "crc" in kinds and dec.bad_crc == 1
    assert lms.Decoder().feed(b"\x15") == [lms.Handshake(False)]
    mode = items[1]
    assert mode.is_reply and mode.status == 0x10 and mode.fields() == {"accepted": True}
    good = lms.Decoder().feed(lms.reply(0xB0, lms.scan_data([1000, 1001], True)))
    assert good[0].fields()["values"] == [1000, 1001] and good[0].fields()["units"] == 1


@given(st.binary(max_size=800))
def test_decoder_never_raises(data):
    dec = lms.Decoder()
    dec.feed(data)
    dec.feed(data[::-1])
    assert len(dec._buf) <= lms.MAX_LEN + 8 or dec._buf[:1] == b"\x02"
