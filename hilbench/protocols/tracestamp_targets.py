"""The trace-stamp decoders (text, binary words, both mixed on one UART) as fuzz targets
(:mod:`hilbench.fuzzing`), with a board's clean trace output of each kind to mutate. Registered in
``pyproject.toml`` (``hilbench.fuzz_targets``); the trace profiler's own target
(:mod:`hilbench.profiler.targets`) feeds on :func:`stream_traffic`."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp_stream import StreamDecoder
from hilbench.protocols.vel2d_targets import BOARD_LINE

NAMES = ["IDLE", "hal_fetch", "wheel_ctrl", "odometry", "pose_control", "tsink", "pid"]


def schedule(rng: random.Random, t: int = 0):
    """Stamps of a plausible FreeRTOS schedule, endlessly: ``(name index, µs, begin)``. IDLE runs between
    task slices; now and then a function scope inside a slice, or tsink preempting it."""
    while True:
        task = rng.randrange(1, 5)
        t += rng.randrange(20, 400)
        yield 0, t, False
        yield task, t, True
        k = rng.random()
        if k < 0.3:
            t += rng.randrange(1, 10)
            yield 6, t, True  # a function scope ("pid") inside the slice
            t += rng.randrange(1, 20)
            yield 6, t, False
        elif k < 0.4:
            t += rng.randrange(1, 10)
            yield task, t, False  # tsink preempts the slice
            yield 5, t, True
            t += rng.randrange(1, 10)
            yield 5, t, False
            yield task, t, True
        t += rng.randrange(5, 30)
        yield task, t, False
        yield 0, t, True


def text_traffic(rng: random.Random, size: int) -> bytes:
    """A board's text output: stamp lines in either dialect, a log line now and then, a run-time report."""
    out = bytearray()
    dialect = rng.choice(["branch", "thesis"])
    stamps = schedule(rng, rng.randrange(1 << 20))
    t = 0
    while len(out) < size:
        k = rng.random()
        if k < 0.989:
            name, t, begin = next(stamps)
            out += ts.format_stamp(NAMES[name], t, begin, dialect)
        elif k < 0.999:
            out += ts.format_log(t / 1e6, rng.choice(["INFO", "ERROR"]), f"[recv vel] [{rng.random():f}]")
        else:
            out += _report(rng, t)
    return bytes(out)


def binary_traffic(rng: random.Random, size: int, *, table: bool = True) -> bytes:
    """hilbench's binary stamp words with their name table, TIME, DROPS and CHECK words."""
    out = bytearray(tb.name_table(dict(enumerate(NAMES))) if table else b"")
    ins = tb.CheckInserter()
    payloads = [tb.control_payload(tb.Op.WINDOW_START, 1)]
    ins.restart()
    stamps = schedule(rng)
    hi = -1
    while len(out) + 4 * len(payloads) < size:
        name, t, begin = next(stamps)
        if t >> tb.HI_SHIFT != hi:
            hi = t >> tb.HI_SHIFT
            payloads.append(tb.time_payload(t))
        if rng.random() < 0.001:  # an overflow now and then: DROPS, then TIME to unwrap again
            payloads.append(tb.control_payload(tb.Op.DROPS, rng.randrange(1, 100)))
            payloads.append(tb.time_payload(t))
        payloads.append(tb.stamp_payload(name, begin, t))
    body = ins.add_list(payloads) + ins.close() + [tb.control_payload(tb.Op.WINDOW_STOP, 1)]
    return bytes(out + tb.encode_payloads(body))


def stream_traffic(rng: random.Random, size: int) -> bytes:
    """Text and binary on one UART as the board sends them in binary mode: windows of words after
    their name table, log lines between the words, a run-time report after each window."""
    out = bytearray()
    while len(out) < size:
        window = rng.randrange(min(16_384, max(64, size // 8)), min(131_072, max(128, size // 2)))
        out += tb.name_table(dict(enumerate(NAMES)))
        words = binary_traffic(rng, window, table=False)
        pos = 0
        while pos < len(words):
            n = 4 * rng.randrange(16, 512)
            out += words[pos : pos + n]
            pos += n
            if rng.random() < 0.2:
                out += ts.format_log(pos / 1e6, "INFO", f"[recv vel] [{rng.random():f} 0.0 0.0]")
        out += _report(rng, pos)
    return bytes(out)


def _report(rng: random.Random, t: int) -> bytes:
    """The run-time statistics block a board prints after a window."""
    rows = tuple(ts.RuntimeRow(n, rng.randrange(1, 10_000), 0) for n in NAMES[:6])
    tasks = tuple(ts.TaskRow(n, "B", 24, 400, k + 1) for k, n in enumerate(NAMES[:6]))
    return ts.format_report(ts.RuntimeReport(195_696, t // 50, rows, tasks, "output took", t, "%%", True))


def _units(item) -> int:
    """Good units of a decoded item: the stamps of a batch, one for any other good item, none for damage."""
    if type(item) is ts.StampBatch:
        return item.count
    return 0 if type(item) is Problem else 1


def _text() -> Counting:
    dec = ts.TextDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.parse_errors)


def _binary() -> Counting:
    dec = tb.WordDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.broken_words)


def _stream() -> Counting:
    dec = StreamDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.text.parse_errors + dec.words.broken_words)


TRACESTAMP_TEXT = FuzzTarget("tracestamp-text", "trace stamps as text (stamp lines, logs, reports)", _text,
                                BOARD_LINE, "12.5 Mbit/s UART", text_traffic)
TRACESTAMP_BINARY = FuzzTarget("tracestamp-binary", "binary trace stamp words", _binary, BOARD_LINE,
                                  "12.5 Mbit/s UART", binary_traffic)
TRACESTAMP_STREAM = FuzzTarget("tracestamp-stream", "text and binary stamps mixed on one UART", _stream,
                                  BOARD_LINE, "12.5 Mbit/s UART", stream_traffic)

__all__ = ["BOARD_LINE", "NAMES", "TRACESTAMP_BINARY", "TRACESTAMP_STREAM", "TRACESTAMP_TEXT", "binary_traffic",
           "schedule", "stream_traffic", "text_traffic"]
