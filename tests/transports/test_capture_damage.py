"""Damaged captures: cut short, corrupted, with times out of order. Everything readable is read, the
damage is reported as data-quality findings, and `--strict` makes it a non-zero exit."""

from __future__ import annotations

import io
import json
import random
import struct
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilbench.protocols import capture as cap
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.capture_parser import CaptureParser
from hilbench.transports.chunk import CaptureError
from tests.conftest import WOLFGANG_TRACE


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> bytes:
    """The Wolfgang trace as a capture with byte times (8258 records of 64 bytes)."""
    path = tmp_path_factory.mktemp("cap") / "w.hbcap"
    with (CaptureWriter(path, baud=2_000_000, protocol="dynamixel", timestamps="synthetic") as w,
          CaptureReader(WOLFGANG_TRACE, raw_baud=2_000_000) as r):
        for chunk in r:
            w.chunk(chunk)
    return path.read_bytes()


def records(data: bytes) -> list[int]:
    """Offsets of the records of a sound capture (the first is the SOURCE record naming "bus"; record
    k + 1 holds chunk k)."""
    pos = cap.HEADER_PREFIX_SIZE + cap.header_body_size(data)
    out = []
    while pos + cap.RECORD_HEADER_SIZE <= len(data):
        out.append(pos)
        pos += cap.RECORD_HEADER_SIZE + struct.unpack_from("<H", data, pos + 2)[0]
    return out


def read(data: bytes, chunk: int = 65536):
    parser = CaptureParser()
    out = []
    for i in range(0, len(data), chunk):
        out += parser.feed(data[i : i + chunk])
    out += parser.finish()
    return out, parser.quality()


def test_a_sound_capture_has_no_findings(clean):
    chunks, q = read(clean)
    assert len(chunks) == 8258 and sum(len(c.data) for c in chunks) == 528_509
    assert q == {"truncated_bytes": 0, "corrupt_bytes": 0, "corruptions": 0, "time_faults": 0, "time_resets": 0,
                 "unknown_records": 0, "findings": []}


def test_a_capture_cut_short_reads_up_to_the_cut(clean):
    offs = records(clean)
    cut = offs[4001] + 30  # inside the record of chunk 4000
    chunks, q = read(clean[:cut])
    whole, _ = read(clean)
    assert chunks == whole[:4000]
    assert q["truncated_bytes"] == 30
    assert q["findings"] == [f"truncated: the capture ends inside its last record at byte {offs[4001]} (30 of its "
                             "76 bytes; the recording was cut off)"]


@pytest.mark.parametrize("length", [0xFFFF, 0x4000, 65, 63, 0])
def test_a_damaged_record_length_costs_that_record_at_most(clean, length):
    offs = records(clean)
    bad = bytearray(clean)
    struct.pack_into("<H", bad, offs[101] + 2, length)  # the record of chunk 100
    chunks, q = read(bytes(bad))
    whole, _ = read(clean)
    got = {(c.t, c.data) for c in chunks}
    lost = [c for c in whole if (c.t, c.data) not in got]
    assert len(lost) <= 1 and (not lost or lost[0] == whole[100])  # at most the damaged record itself
    assert len(chunks) >= 8257 and q["corruptions"] == 1 and q["findings"]
    if length > 64:  # a length that runs over the next record is mended by it
        assert chunks[100] == whole[100]
        assert "has a damaged length" in q["findings"][0]


def test_the_name_record_with_a_damaged_length_is_mended(clean):
    offs = records(clean)
    bad = bytearray(clean)
    struct.pack_into("<H", bad, offs[0] + 2, 0x7FFF)  # the SOURCE record naming "bus"
    chunks, q = read(bytes(bad))
    assert len(chunks) == 8258 and {c.source for c in chunks} == {"bus"} and q["corruptions"] == 1


def test_noise_in_the_middle_is_skipped_and_counted(clean):
    offs = records(clean)
    noise = random.Random(1).randbytes(5000)
    bad = clean[: offs[3000]] + noise + clean[offs[3000] :]
    chunks, q = read(bad, chunk=4096)
    assert [c.data for c in chunks] == [c.data for c in read(clean)[0]]
    assert q["corrupt_bytes"] == 5000 and q["corruptions"] == 1
    assert q["findings"] == [f"corrupt: 5000 bytes from byte {offs[3000]} are no records (a damaged record); "
                             f"reading resumed at byte {offs[3000] + 5000}"]


def test_times_out_of_order_are_repaired_and_reported(clean):
    offs = records(clean)
    bad = bytearray(clean)
    rnd = random.Random(3)
    hit = sorted(rnd.sample(range(2, len(offs) - 2), 40))
    for k in hit:
        bad[offs[k] + 4 + rnd.randrange(4, 8)] ^= 1 << rnd.randrange(8)  # a high byte of t_ns: seconds to years
    chunks, q = read(bytes(bad))
    whole, _ = read(clean)
    assert [c.data for c in chunks] == [c.data for c in whole]  # every byte kept
    times = [c.t for c in chunks]
    assert all(b >= a for a, b in zip(times, times[1:], strict=False))  # in order again
    assert times[-1] - times[0] == pytest.approx(whole[-1].t - whole[0].t)  # the duration survives
    assert q["time_faults"] == 40 and q["findings"][0].startswith("time: the record at byte")


def test_joined_captures_continue_the_timeline(clean):
    chunks, q = read(clean + clean)
    whole, _ = read(clean)
    assert [c.data for c in chunks] == [c.data for c in whole] * 2
    assert q["time_resets"] == 1 and q["corrupt_bytes"] == cap.HEADER_PREFIX_SIZE + cap.header_body_size(clean)
    span = whole[-1].t - whole[0].t
    assert chunks[-1].t - chunks[0].t == pytest.approx(2 * span, abs=0.01)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32), cuts=st.lists(st.integers(1, 4000), max_size=30))
def test_mutated_captures_never_raise_and_read_the_same_in_any_split(seed, cuts):
    rnd = random.Random(seed)
    buf = io.BytesIO()
    w = CaptureWriter(buf, t0=0.0, baud=1_000_000)
    t = 0.0
    for _ in range(60):
        t += rnd.random() * 0.01
        w.write(t, rnd.choice(["host", "dev"]), rnd.randbytes(rnd.randrange(1, 40)))
    w.flush()
    data = bytearray(buf.getvalue())
    for _ in range(rnd.randrange(1, 12)):
        i = rnd.randrange(len(data))
        op = rnd.random()
        if op < 0.6:
            data[i] ^= 1 << rnd.randrange(8)
        elif op < 0.8:
            del data[i : i + rnd.randrange(1, 20)]
        else:
            data[i:i] = rnd.randbytes(rnd.randrange(1, 20))
    data = bytes(data)
    try:
        whole, q = read(data, chunk=len(data))
    except CaptureError as exc:  # a version field damaged into a newer version (2..16): refused, in one line
        assert "newer than this hilbench reads" in str(exc) and "\n" not in str(exc)
        with pytest.raises(CaptureError):
            read(data, chunk=7)
        return
    parser = CaptureParser()
    split, pos = [], 0
    for c in sorted(set(cuts)):
        split += parser.feed(data[pos:c])
        pos = c
    split += parser.feed(data[pos:]) + parser.finish()
    if parser.info is not None:  # a raw dump's chunks follow the reads; a capture's records do not
        assert split == whole and parser.quality() == q
    assert sum(len(c.data) for c in whole) <= len(data)


def hb(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True, timeout=120)


def test_monitor_reports_the_damage_and_strict_fails(clean, tmp_path):
    offs = records(clean)
    cut = tmp_path / "cut.hbcap"
    cut.write_bytes(clean[: offs[-1] + 20])
    plain = hb("monitor", str(cut), "--summary")
    assert plain.returncode == 0, plain.stderr
    assert "data quality: truncated: the capture ends inside its last record" in plain.stdout
    strict = hb("monitor", str(cut), "--summary", "--strict")
    assert strict.returncode == 3
    assert strict.stderr.splitlines() == [f"hilbench: error: {cut}: the input is damaged (1 data-quality "
                                          "finding(s)); --strict"]
    doc = json.loads(hb("monitor", str(cut), "--json").stdout)
    copy = hb("record", str(cut), str(tmp_path / "copy.hbcap"))
    assert copy.returncode == 0 and "data quality: truncated" in copy.stderr  # a copy says what it lost
    last = struct.unpack_from("<H", clean, offs[-1] + 2)[0]
    assert doc["data_quality"]["truncated_bytes"] == 20 and doc["bytes"] == 528_509 - last
    bad = bytearray(clean)
    for k in range(500, 8000, 500):
        bad[offs[k] + 4 + 7] ^= 0x40  # times years off
    mutated = tmp_path / "time.hbcap"
    mutated.write_bytes(bytes(bad))
    doc = json.loads(hb("monitor", str(mutated), "--json").stdout)
    assert doc["duration_s"] == pytest.approx(2.642, abs=0.001)  # not -43,910,095 s
    assert doc["data_quality"]["time_faults"] == 15 and doc["bytes"] == 528_509
    assert hb("monitor", str(mutated), "--json", "--strict").returncode == 3


def test_profile_reports_a_damaged_capture(spec_capture, tmp_path):
    data = spec_capture.read_bytes()
    cut = tmp_path / "cut.hbcap"
    cut.write_bytes(data[:-5])
    doc = json.loads(hb("trace", str(cut), "--json").stdout)
    assert doc["quality"]["untrustworthy"] and doc["quality"]["capture"]["truncated_bytes"] > 0
    assert any(r.startswith("capture truncated:") for r in doc["quality"]["reasons"])
    strict = hb("trace", str(cut), "--strict")
    assert strict.returncode == 3 and "capture truncated" in strict.stderr


@pytest.fixture
def spec_capture(tmp_path):
    """A rover board's trace as a capture (two windows of V1 text on a 1,152,000-baud UART)."""
    from hilbench.fakes.stm32_board import Board, BoardConfig, make_preset

    board = Board(BoardConfig(make_preset("freertos-100-50", True), output="v1", baud=1_152_000, window_ms=50))
    board.run_until(1_000)
    board.press_button()
    path = tmp_path / "rover.hbcap"
    with CaptureWriter(path, baud=1_152_000, protocol="vel2d", t0=0.0) as w:
        for step in range(1, 41):  # the board's output in 10 ms pieces, stamped when it was sent
            board.run_until(step * 10_000)
            data = board.take_output()
            if data:
                w.write(step * 0.01, "rover-board", data)
    return path
