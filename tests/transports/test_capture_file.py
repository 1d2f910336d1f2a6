"""Capture files: write, read back, raw dumps, damaged files."""

from __future__ import annotations

import io

import pytest

from hilbench.protocols import capture as cap
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.capture_parser import CaptureParser
from hilbench.transports.chunk import CaptureError, Chunk


def test_round_trip_keeps_times_sources_and_bytes(tmp_path):
    path = tmp_path / "bus.hbcap"
    chunks = [Chunk(1000.0, "host", b"\xff\xff\xfd\x00\x01"), Chunk(1000.000_25, "devices", b"\x02" * 70_000),
              Chunk(1000.5, "host", b"x"), Chunk(1000.6, "devices", b"", 12)]
    with CaptureWriter(path, baud=2_000_000, description="test bench") as w:
        for c in chunks:
            w.chunk(c)
    assert w.bytes == 5 + 70_000 + 1
    with CaptureReader(path) as r:
        assert r.info.baud == 2_000_000 and r.info.description == "test bench" and r.timestamps == "measured"
        got = list(r)
    # the 70 000-byte chunk was split into two records; times survive to the nanosecond
    assert [c.source for c in got] == ["host", "devices", "devices", "host", "devices"]
    assert got[1].data + got[2].data == b"\x02" * 70_000
    assert abs(got[1].t - 1000.000_25) < 2e-9 and got[0].t == 1000.0
    assert (got[4].lost, got[4].data) == (12, b"")


def test_raw_dumps_are_one_source_without_or_with_byte_time(tmp_path):
    path = tmp_path / "trace.bin"
    data = bytes(range(256)) * 3
    path.write_bytes(data)
    with CaptureReader(path) as r:
        assert r.is_raw and r.timestamps == "none"
        got = list(r)
    assert b"".join(c.data for c in got) == data and {c.source for c in got} == {"bus"}
    assert {c.t for c in got} == {0.0}
    with CaptureReader(path, raw_baud=1_000_000) as r:
        timed = list(r)
    assert r.timestamps == "synthetic" and all(len(c.data) <= 64 for c in timed)
    assert timed[-1].t == pytest.approx(len(data) * 10 / 1_000_000)  # byte time of the last byte


def test_a_recording_cut_off_mid_record_reads_up_to_the_cut(tmp_path):
    buf = io.BytesIO()
    w = CaptureWriter(buf, t0=0.0)
    w.write(1.0, "bus", b"a" * 10)
    w.write(2.0, "bus", b"b" * 10)
    w.flush()
    path = tmp_path / "cut.hbcap"
    path.write_bytes(buf.getvalue()[:-4])
    with CaptureReader(path) as r:
        got = list(r)
    assert [c.data for c in got] == [b"a" * 10] and r.truncated_bytes == cap.RECORD_HEADER_SIZE + 6


def test_unknown_record_kinds_are_skipped():
    head = cap.build_header(t0_monotonic=5.0)
    records = (cap.pack_record(cap.RecordKind.SOURCE, 0, 0, b"bus") + cap.pack_record(7, 0, 0, b"future")
               + cap.pack_record(cap.RecordKind.DATA, 0, 1_000_000_000, b"ok"))
    got = list(CaptureReader(io.BytesIO(head + records)))
    assert got == [Chunk(6.0, "bus", b"ok")]


def test_the_parser_takes_any_split_of_the_stream():
    buf = io.BytesIO()
    w = CaptureWriter(buf, t0=0.0)
    for k in range(1, 20):
        w.write(k * 0.001, f"s{k % 3}", bytes([k]) * k)
    whole = buf.getvalue()
    parser = CaptureParser()
    got = []
    for i in range(len(whole)):
        got += parser.feed(whole[i : i + 1])
    got += parser.finish()
    assert [c.data for c in got] == [bytes([k]) * k for k in range(1, 20)]
    assert [c.source for c in got[:4]] == ["s1", "s2", "s0", "s1"]


def test_a_damaged_header_is_one_clear_error(tmp_path):
    path = tmp_path / "bad.hbcap"
    path.write_bytes(cap.build_header()[:14])
    with pytest.raises(CaptureError, match="header cut short"):
        CaptureReader(path)
    newer = bytearray(cap.build_header())
    newer[8] = 2
    path.write_bytes(bytes(newer))
    with pytest.raises(CaptureError, match="newer than this hilbench reads"):
        CaptureReader(path)


def test_an_empty_recording_still_has_a_header(tmp_path):
    path = tmp_path / "empty.hbcap"
    CaptureWriter(path, baud=57_600).close()
    with CaptureReader(path) as r:
        assert r.info.baud == 57_600 and list(r) == []
