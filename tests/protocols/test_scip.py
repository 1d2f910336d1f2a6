"""Hokuyo SCIP 2.0: sums, encodings and the verified exchanges of the sheet (§3.3-3.7)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import scip


def test_sums_and_status_lines():
    for status, line in (("00", b"00P\n"), ("99", b"99b\n"), ("0E", b"0Ee\n"), ("0L", b"0Ll\n"),
                         ("01", b"01Q\n"), ("10", b"10Q\n"), ("02", b"02R\n")):
        assert scip.status_line(status) == line
    assert scip.info_line("DMIN", "20") == b"DMIN:20;4\n"
    assert scip.info_line("DMAX", "5600") == b"DMAX:5600;_\n"
    assert scip.info_line("SERI", "H0614967") == b"SERI:H0614967;V\n"
    assert scip.check_line(b"DMIN:20;4", info=True) == b"DMIN:20"
    assert scip.check_line(b"DMIN:20;o", info=True) == b"DMIN:20"  # summed with the ';' (urg_library)
    assert scip.check_line(b"0?;" + scip.sum_char(b"0?;")) == b"0?;"  # ';' is data in data lines
    assert scip.check_line(b"00P") == b"00"
    assert scip.check_line(b"00Q") is None


def test_encodings():
    assert scip.encode(1234, 2) == b"CB"
    assert scip.encode(5432, 3) == b"1Dh"
    assert scip.encode(1000, 3) == b"0?X"
    assert scip.encode(16_000_000, 4) == b"m2@0"
    assert scip.encode(123456, 4) == b"0N90"
    assert scip.encode_values([1000, 1500, 2000], 3) == b"0?X0GL0O@"
    assert scip.decode(b"0N90") == 123456


def test_verified_replies():
    body = scip.timestamp_line(123456) + scip.data_lines(scip.encode_values([1000, 1500, 2000], 3))
    assert scip.reply(b"GD0044004601", "00", body) == b"GD0044004601\n00P\n0N90W\n0?X0GL0O@9\n\n"
    body2 = scip.timestamp_line(123456) + scip.data_lines(scip.encode_values([1000, 1500, 2000], 2))
    assert scip.reply(b"GS0044004601", "00", body2) == b"GS0044004601\n00P\n0N90W\n?XGLO@i\n\n"
    long_ = scip.timestamp_line(123456) + scip.data_lines(scip.encode_values(list(range(1000, 1300, 10)), 3))
    assert scip.reply(b"GD0000002900", "00", long_) == (
        b"GD0000002900\n00P\n0N90W\n0?X0?b0?l0@60@@0@J0@T0@^0@h0A20A<0AF0AP0AZ0Ad0An0B80BB0BL0BV0B`0J\n"
        b"Bj0C40C>0CH0CR0C\\0Cf0D00D:n\n\n")
    rep = scip.parse_reply(scip.reply(b"GD0000002900", "00", long_))
    assert rep.scan() == (123456, list(range(1000, 1300, 10)), None)
    assert scip.reply(b"BM", "02") == b"BM\n02R\n\n"
    assert scip.reply(b"%ST", "00", scip.data_lines(b"000")) == b"%ST\n00P\n000@\n\n"


def test_requests_with_construct_layouts():
    assert scip.request("GD", {"start": 44, "end": 46, "cluster": 1}) == b"GD0044004601\n"
    assert scip.request("MD", {"start": 0, "end": 3, "cluster": 0, "skip": 0, "scans": 2}) == b"MD0000000300002\n"
    req = scip.parse_request(b"GD0044004601;abc")
    assert (req.cmd, req.params, req.string) == ("GD", "0044004601", "abc")
    assert req.fields() == {"start": 44, "end": 46, "cluster": 1}
    assert scip.parse_request(b"%ST").cmd == "%ST"
    assert scip.parse_request(b"GDxx").fields() is None


def test_decoders_split_lines_and_replies():
    items = scip.RequestDecoder().feed(b"VV\r\nPP\rII\n")
    assert [i.cmd for i in items] == ["VV", "PP", "II"]
    dec = scip.ReplyDecoder()
    first = dec.feed(b"BM\n00P\n\nBM\n02R")
    assert [r.status for r in first] == ["00"]
    assert [r.status for r in dec.feed(b"\n\n")] == ["02"]


@given(st.binary(max_size=400))
def test_decoders_never_raise(data):
    scip.RequestDecoder().feed(data)
    for r in scip.ReplyDecoder().feed(data):
        if isinstance(r, scip.Reply):
            r.scan()
            r.info()
