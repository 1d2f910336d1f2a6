"""Text trace output: stamp dialects, the §3.8 classifier and its TAB pitfall, report blocks, log lines,
the incremental decoder on mixed streams, and agreement of the vectorised path with the per-line one."""

from __future__ import annotations

import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import tracestamp as ts
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp import (
    UNREADABLE,
    LogMessage,
    RuntimeReport,
    Stamp,
    StampBatch,
    TextDecoder,
)
from tests.stm32_vectors import LISTING_34, LISTING_35, LISTING_38, LISTING_39, REPORT_65, TRACE_64, lines


def decode(data: bytes, chunk: int | None = None) -> tuple[list, TextDecoder]:
    dec = TextDecoder()
    out = []
    step = chunk or max(1, len(data))
    for i in range(0, len(data), step):
        out += dec.feed(data[i : i + step])
    return out + dec.flush(), dec


def test_both_dialects_and_names_with_spaces():
    assert ts.parse_stamp("wheel_ctrl 96 1") == Stamp("wheel_ctrl", 96, True)
    assert ts.parse_stamp(b"wheel_ctrl 96 in\r\n") == Stamp("wheel_ctrl", 96, True)
    assert ts.parse_stamp("IDLE 1 0") == Stamp("IDLE", 1, False)
    assert ts.parse_stamp("Tmr Svc 12 out") == Stamp("Tmr Svc", 12, False)
    assert ts.parse_stamp("a 1 2 1") == Stamp("a 1", 2, True)  # split off the last two tokens
    for bad in ("wheel_ctrl 96", "wheel_ctrl x in", "wheel_ctrl 96 maybe", "96 in", "tsink\tB 32 1",
                "12:00:00 [INFO]: x 5 1"):
        assert ts.parse_stamp(bad) is None, bad


def test_format_stamp_dialects_and_lengths():
    assert ts.format_stamp("wheel_ctrl", 96, True) == b"wheel_ctrl 96 in\n"
    assert ts.format_stamp("wheel_ctrl", 96, False, "thesis") == b"wheel_ctrl 96 0\n"
    names = [b"IDLE", b"Tmr Svc", b"hal_fetch"]
    ids = np.array([0, 1, 2, 2, 0])
    t = np.array([0, 9, 10, 99999, 1234567890])
    b = np.array([True, False, True, False, True])
    for dialect in ("thesis", "branch"):
        formatted = ts.format_stamps(names, ids, t, b, dialect)
        lengths = ts.stamp_line_lengths(np.array([len(n) for n in names]), ids, t, b, dialect)
        assert [len(x) for x in formatted] == lengths.tolist()
        assert [ts.parse_stamp(x) for x in formatted] == [
            Stamp(names[i].decode(), int(tt), bool(bb)) for i, tt, bb in zip(ids, t, b, strict=True)]


@pytest.mark.parametrize(
    "line,kind",
    [
        ("=============================================", "separator"), ("---", "separator"),
        ("free heap:\t\t195696", "report"), ("Task\t\tTime\t\t%%", "report"), ("Task\t\tTime\t\t%", "report"),
        ("tsink          \tB\t32\t483\t1\r", "report"), ("IDLE           \t201086\t\t95%\r", "report"),
        ("output took 18779120 us", "closing"), ("profiled for 18881864 us", "closing"),
        ("00:00:12 [INFO]: [recv vel] [100.000000 -200.000000 0.300000]", "log"),
        ("00:00:12 [ERROR]: crc mismatch!", "log"), ("@id 3 Tmr Svc", "meta"), ("@tsb 1", "meta"),
        ("wheel_ctrl 96 in", "stamp"), ("Tmr Svc 0 1", "stamp"), ("", "blank"),
        ("tsink\tB 32 483 1", "error"),  # §3.8's pitfall: with a TAB it is never a stamp
        ("hello world", "error"), ("==", "error"), ("@id x", "error"),
    ],
)
def test_classifier(line, kind):
    assert ts.classify(line) == kind


def test_vtasklist_row_is_not_a_stamp_even_when_split_on_whitespace():
    row = b"tsink          \tB\t32\t483\t1\r\n"
    assert " ".join(row.decode().split()) == "tsink B 32 483 1"  # what naive splitting would see
    items, dec = decode(b"=====\n" + row)
    assert dec.stamp_lines == 0 and dec.parse_errors == 0
    assert items[0].tasks == (ts.TaskRow("tsink", "B", 32, 483, 1),)


def test_report_block_of_the_spec():
    assert len(REPORT_65) == 723 and REPORT_65.count(b"\n") == 26
    items, dec = decode(REPORT_65)
    (rep,) = items
    assert isinstance(rep, RuntimeReport) and rep.complete
    assert (rep.free_heap, rep.ctx_switches, rep.output_took_us, rep.profiled_for_us) == (195696, 76148, 18779120,
                                                                                           None)
    assert len(rep.runtime) == 9 and rep.total_abs == 211_638
    assert rep.recomputed_percent() == {r.name: r.percent for r in rep.runtime}
    assert rep.recomputed_percent()["IDLE"] == 95 and rep.recomputed_percent()["profile"] == 4
    assert [t.name for t in rep.tasks][-1] == "Tmr Svc" and len(rep.tasks) == 9
    assert rep.tasks[0] == ts.TaskRow("profile", "X", 24, 900, 7)
    assert dec.stamp_lines == 0 and dec.parse_errors == 0 and dec.report_lines == 26 and dec.reports == 1
    assert ts.format_report(rep) == REPORT_65  # the board side prints the same bytes


def test_report_split_at_every_byte_and_interleaved_with_stamps_and_logs():
    stamps = b"wheel_ctrl 5 in\nwheel_ctrl 9 out\n"
    cut = REPORT_65.index(b"\n", 200) + 1  # the board writes whole lines
    data = REPORT_65[:cut] + stamps + b"00:00:01 [INFO]: hi\n" + REPORT_65[cut:]
    for chunk in (1, 7, 64):
        items, dec = decode(data, chunk)
        reports = [i for i in items if isinstance(i, RuntimeReport)]
        assert len(reports) == 1 and reports[0].complete and len(reports[0].tasks) == 9
        assert [i for i in items if isinstance(i, Stamp)] == [Stamp("wheel_ctrl", 5, True),
                                                               Stamp("wheel_ctrl", 9, False)]
        assert LogMessage("00:00:01", "INFO", "hi") in items and dec.parse_errors == 0


def test_thesis_report_variant_and_percent_header():
    rep = RuntimeReport(4688, 126810, (ts.RuntimeRow("IDLE", 1179311, 88), ts.RuntimeRow("Tmr Svc", 0, 0)),
                        (ts.TaskRow("IDLE", "R", 0, 108, 4),), "profiled for", 18881864, "%", True)
    raw = ts.format_report(rep, separator_width=20)
    assert raw.count(b"====================\n") == 3  # the closing line is framed by separators
    items, dec = decode(b"IDLE 1 0\n" + raw + b"profile 2 1\n")
    got = [i for i in items if isinstance(i, RuntimeReport)]
    assert got == [rep] and got[0].profiled_for_us == 18881864 and got[0].percent_header == "%"
    assert dec.stamp_lines == 2 and dec.parse_errors == 0


def test_incomplete_reports_are_still_returned():
    # Joined in the middle (no opening separator) and cut before the closing line.
    items, _ = decode(REPORT_65[REPORT_65.index(b"hal_fetch"):REPORT_65.index(b"output")])
    (rep,) = items
    assert not rep.complete and rep.closing is None and len(rep.runtime) == 7 and len(rep.tasks) == 9
    # A second report starts before the first one's closing line arrived.
    items, _ = decode(REPORT_65[: REPORT_65.index(b"output")] + REPORT_65)
    reports = [i for i in items if isinstance(i, RuntimeReport)]
    assert [r.complete for r in reports] == [False, True]


@pytest.mark.parametrize(
    "text,count,orders",
    [(LISTING_34, 11, "unsorted"), (LISTING_35, 13, "sorted"), (LISTING_38, 19, "sorted"),
     (LISTING_39, 26, "sorted"), (TRACE_64, 32, "unsorted")],
)
def test_thesis_listings_decode(text, count, orders):
    data = lines(text)
    items, dec = decode(data)
    assert len(items) == count == dec.stamp_lines and dec.parse_errors == 0
    times = [s.t_us for s in items]
    assert (times == sorted(times)) == (orders == "sorted")
    dialect = "branch" if " in" in text else "thesis"
    assert dec.dialects[dialect] == count


def test_log_lines_and_errors_never_raise():
    data = (b"00:00:12 [INFO]: [recv vel] [100.000000 -200.000000 0.300000]\n"
            b"00:00:13 [ERROR]: parsing velocity failed: insufficient bytes received\n"
            b"garbage here\n\xff\xfe\n")
    items, dec = decode(data)
    assert items[0] == LogMessage("00:00:12", "INFO", "[recv vel] [100.000000 -200.000000 0.300000]")
    assert items[1].level == "ERROR"
    assert [(type(i), i.kind, i.raw) for i in items[2:]] == [
        (Problem, UNREADABLE, b"garbage here"), (Problem, UNREADABLE, b"\xff\xfe")]
    assert items[2].detail == "not a stamp, log line or report line"
    assert dec.parse_errors == 2 and dec.log_lines == 2 and dec.lines == 4


def test_overlong_line_is_dropped_with_bounded_memory():
    dec = TextDecoder()
    out = dec.feed(b"x" * (ts.MAX_LINE + 10))
    assert [(type(i), i.kind, len(i.raw)) for i in out] == [(Problem, UNREADABLE, 80)] and dec.pending == 0
    out = dec.feed(b"y" * 100 + b"\nIDLE 5 in\n")  # the rest of the long line is skipped
    assert out == [Stamp("IDLE", 5, True)] and dec.parse_errors == 1


def corpus(seed: int, n: int = 3000) -> bytes:
    """A mixed stream with every kind of line and the awkward cases."""
    rnd = random.Random(seed)
    names = ["IDLE", "hal_fetch", "Tmr Svc", "a b c", "x", "1", "in", "veryverylongfunctionname_more_than_16"]
    extra = [b"tsink\tB 32 483 1", b"12:00:00 [INFO]: task 5 1", b"12:00:00 [info]: not a log 5 1", b"@id 3 x 5 1",
             b"", b"\r", b" 5 1", b"x  5 1", b"x 5  1", b"x 05 in", b"x 5 in\r", b"x 99999999999999999 in",
             b"x 5 inn", b"x -5 in", b"=====", b"output took 5 us", b"free heap:\t\t5", b"\xc3\xa9t\xc3\xa9 5 1",
             b"12:00:00 [X]: 5 1", b"ab:cd:ef [ 5 1"]
    out = []
    for _ in range(n):
        r = rnd.random()
        if r < 0.8:
            tok = rnd.choice(["in", "out", "1", "0"])
            out.append(f"{rnd.choice(names)} {rnd.randrange(10**rnd.randrange(1, 12))} {tok}".encode())
        else:
            out.append(rnd.choice(extra))
    return b"\n".join(out) + b"\n"


@pytest.mark.parametrize("seed", [1, 2])
def test_vectorised_path_agrees_with_the_per_line_classifier(seed):
    data = corpus(seed)
    reference = []
    for line in data.split(b"\n")[:-1]:
        kind = ts.classify(line)
        reference.append(ts.parse_stamp(line) if kind == "stamp" else kind)
    dec = TextDecoder()
    items = dec.feed(data) + dec.flush()
    stamps = [r for r in reference if isinstance(r, Stamp)]
    assert [i for i in items if isinstance(i, Stamp)] == stamps
    assert dec.stamp_lines == len(stamps)
    assert dec.parse_errors == reference.count("error")
    assert dec.lines == len(reference)
    # feed_batch gives the same stamps as columns, in the same order.
    dec2 = TextDecoder()
    batches = dec2.feed_batch(data)
    assert list(ts.iter_stamps(batches)) == stamps
    assert all(type(b) is not Stamp for b in batches)
    assert sum(b.count for b in batches if type(b) is StampBatch) == len(stamps)
    assert any(type(b) is StampBatch and b.count > 10 for b in batches)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=60), st.integers(1, 50))
def test_random_bytes_never_raise_and_chunking_does_not_matter(parts, chunk):
    data = b"\n".join(parts)
    whole, d1 = decode(data)
    pieces, d2 = decode(data, chunk)
    assert whole == pieces
    assert (d1.lines, d1.stamp_lines, d1.parse_errors) == (d2.lines, d2.stamp_lines, d2.parse_errors)


def test_runtime_percentages():
    assert ts.runtime_percentages([9669, 201086, 81, 87, 49, 51, 615, 0, 0]) == [4, 95, 0, 0, 0, 0, 0, 0, 0]


_lines = st.one_of(
    st.builds(lambda n, t, e: f"{n} {t} {e}".encode(), st.sampled_from(["IDLE", "Tmr Svc", "x"]),
              st.integers(0, 10**30), st.sampled_from(["in", "out", "0", "1"])),
    st.binary(max_size=30),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(_lines, max_size=80), st.integers(1, 64))
def test_stamp_like_lines_with_any_time_never_raise(lines, chunk):
    """Times of any size (here up to 10^30) are stamps when they fit an int64, else bad lines."""
    data = b"\n".join(lines) + b"\n"
    whole, d1 = decode(data)
    pieces, _ = decode(data, chunk)
    assert whole == pieces
    batched = ts.TextDecoder().feed_batch(data * 3)  # enough lines for the vectorised path
    assert sum(b.count for b in batched if type(b) is StampBatch) + sum(
        type(b) is Stamp for b in batched) == 3 * d1.stamp_lines
    assert all(s.t_us < 10**18 for s in whole if type(s) is Stamp)
