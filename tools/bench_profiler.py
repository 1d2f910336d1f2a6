#!/usr/bin/env python3
"""Trace profiler benchmark; prints one JSON object per figure (see DESIGN.md §10).

Stamps per second the profiler ingests (decodes, unwraps, stores) and
analyses (sorts, pairs, computes every statistic), for text and binary
input, as a ratio to the fastest stamp stream a 12.5 Mbit/s UART can carry
in that format: 12.5e6 / 10 bits per byte (8N1) = 1.25 MB/s, divided by the
bytes per stamp of the benchmark's own stream. Targets: >= 10x for text,
more for binary.

The stream is a synthetic FreeRTOS schedule made with numpy: IDLE between
slices of five tasks, a nested function scope inside wheel_ctrl, and 10 % of
the slices preempted by tsink; text in the branch dialect (raw times that
wrap as the cycle counter does), binary as hilbench's words with TIME and
CHECK words, both followed by a run-time statistics report.

Usage: tools/bench_profiler.py [--stamps N] [--repeats R] [--chunk BYTES]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from hilbench.profiler.ingest import Profiler
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols.tracestamp import RuntimeReport, RuntimeRow, TaskRow

UART_BYTES_PER_S = 12.5e6 / 10  # 12.5 Mbit/s, 8N1
NAMES = ["IDLE", "hal_fetch", "wheel_ctrl", "odometry", "pose_control", "tsink", "pid"]
TASKS = NAMES[:6]


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 3), "unit": unit, "reference": round(reference, 3),
                      "ratio": round(ratio, 3), **extra}), flush=True)


def schedule(n_stamps: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids, t µs, begin) of a plausible schedule with about ``n_stamps`` stamps, in time order."""
    rng = np.random.default_rng(seed)
    n = n_stamps // 5
    task = rng.integers(1, 5, n)  # hal_fetch .. pose_control
    dur = rng.integers(6, 30, n)
    gap = rng.integers(20, 400, n)
    start = np.concatenate(([1], 1 + np.cumsum(dur + gap)[:-1]))
    pre = rng.random(n) < 0.1  # tsink preempts some slices in their middle
    # Per slice: IDLE out, T in, [pid in], [T out, tsink in, tsink out, T in], [pid out], then T out, IDLE in.
    slots = 8
    ids = np.full((n, slots), -1, np.int32)
    t = np.zeros((n, slots), np.int64)
    b = np.zeros((n, slots), bool)
    mid = start + dur // 2
    end = start + dur + np.where(pre, 4, 0)
    is_wc = task == 2
    ids[:, 0], t[:, 0], b[:, 0] = 0, start, False
    ids[:, 1], t[:, 1], b[:, 1] = task, start, True
    ids[:, 2] = np.where(is_wc, 6, -1)
    t[:, 2], b[:, 2] = start + 1, True
    ids[:, 3] = np.where(pre, task, -1)
    t[:, 3], b[:, 3] = mid, False
    ids[:, 4] = np.where(pre, 5, -1)
    t[:, 4], b[:, 4] = mid, True
    ids[:, 5] = np.where(pre, 5, -1)
    t[:, 5], b[:, 5] = mid + 4, False
    ids[:, 6] = np.where(pre, task, -1)
    t[:, 6], b[:, 6] = mid + 4, True
    ids[:, 7] = np.where(is_wc, 6, -1)
    t[:, 7], b[:, 7] = end - 1, False
    keep = ids.ravel() >= 0
    ids_f, t_f, b_f = ids.ravel()[keep], t.ravel()[keep], b.ravel()[keep]
    tail_ids = np.stack([task, np.zeros(n, np.int32)], axis=1).ravel()
    tail_t = np.stack([end, end], axis=1).ravel()
    tail_b = np.tile([False, True], n)
    # interleave: each slice's body then its tail
    body_len = keep.reshape(n, slots).sum(axis=1)
    pos_body = np.repeat(np.cumsum(body_len + 2) - body_len - 2, body_len) + _ranks(body_len)
    pos_tail = np.repeat(np.cumsum(body_len + 2) - 2, 2) + np.tile([0, 1], n)
    total = int(body_len.sum()) + 2 * n
    out_ids = np.empty(total, np.int32)
    out_t = np.empty(total, np.int64)
    out_b = np.empty(total, bool)
    out_ids[pos_body], out_t[pos_body], out_b[pos_body] = ids_f, t_f, b_f
    out_ids[pos_tail], out_t[pos_tail], out_b[pos_tail] = tail_ids, tail_t, tail_b
    return out_ids, out_t, out_b


def _ranks(lengths: np.ndarray) -> np.ndarray:
    """0..len-1 for each group, concatenated."""
    starts = np.cumsum(lengths) - lengths
    return np.arange(int(lengths.sum())) - np.repeat(starts, lengths)


def report(ctx: int, span_us: int) -> bytes:
    rows = tuple(RuntimeRow(n, span_us // 93 // len(TASKS), 0) for n in TASKS)
    tasks = tuple(TaskRow(n, "B", 24, 400, k + 1) for k, n in enumerate(TASKS))
    return ts.format_report(RuntimeReport(195_696, ctx, rows, tasks, "output took", span_us, "%%", True))


def text_stream(ids, t, b) -> bytes:
    raw = (t * 216 % (1 << 32)) // 216  # what the board prints: the cycle counter wraps
    names = [n.encode() for n in NAMES]
    hook = int(np.isin(ids, np.arange(6)).sum())
    return b"".join(ts.format_stamps(names, ids, raw, b)) + report(hook, int(t[-1]))


def binary_stream(ids, t, b) -> bytes:
    hi = t >> tb.HI_SHIFT
    new_hi = np.flatnonzero(np.concatenate(([True], hi[1:] != hi[:-1])))
    stamp_p = tb.stamp_payloads(ids, b, t)
    time_p = np.array([tb.time_payload(int(x)) for x in t[new_hi]], np.uint32)
    payloads = np.insert(stamp_p, new_hi, time_p)
    payloads = np.concatenate(([tb.control_payload(tb.Op.WINDOW_START, 1)], payloads))
    ins = tb.CheckInserter()
    body = ins.add(payloads)
    tail = np.array(ins.close() + [tb.control_payload(tb.Op.WINDOW_STOP, 1)], np.uint32)
    hook = int(np.isin(ids, np.arange(6)).sum())
    return tb.name_table(dict(enumerate(NAMES))) + tb.encode_payloads(np.concatenate((body, tail))) + \
        report(hook, int(t[-1]))


def measure(data: bytes, chunk: int) -> tuple[float, float, Profiler, object]:
    p = Profiler()
    t0 = time.perf_counter()
    for i in range(0, len(data), chunk):
        p.feed(data[i : i + chunk])
    p.finish()
    t1 = time.perf_counter()
    a = p.analyse()
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, p, a


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stamps", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--chunk", type=int, default=65536, help="bytes per feed() call (default 64 KiB)")
    args = ap.parse_args()
    ids, t, b = schedule(args.stamps)
    n = len(t)
    for fmt, data, target in (("text", text_stream(ids, t, b), 10), ("binary", binary_stream(ids, t, b), 10)):
        bytes_per_stamp = len(data) / n
        reference = UART_BYTES_PER_S / bytes_per_stamp
        ingest, analyse = [], []
        for _ in range(args.repeats):
            ti, ta, p, a = measure(data, args.chunk)
            ingest.append(ti)
            analyse.append(ta)
        assert a.quality["stamps"] == n and a.quality["orphan_ends"] == 0 and a.quality["estimated_drops"] == 0
        assert a.tasks["wheel_ctrl"]["count"] > 0 and a.tasks["pid"]["kind"] == "function"
        ti, ta = statistics.median(ingest), statistics.median(analyse)
        extra = {"stamps": n, "bytes_per_stamp": round(bytes_per_stamp, 2), "repeats": args.repeats,
                 "wraps": a.quality["wraps"]}
        emit(f"profiler_{fmt}_ingest", n / ti, "stamps/s", reference, n / ti / reference, **extra)
        emit(f"profiler_{fmt}_analyse", n / ta, "stamps/s", reference, n / ta / reference, **extra)
        total = [x + y for x, y in zip(ingest, analyse, strict=True)]
        tt = statistics.median(total)
        emit(f"profiler_{fmt}_ingest_and_analyse", n / tt, "stamps/s", reference, n / tt / reference,
             target_ratio=target, best_ratio=round(n / min(total) / reference, 3), **extra)
    # The live view's refresh: analysing the last second of a long stream must stay cheap.
    p = measure(text_stream(ids, t, b), args.chunk)[2]
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        p.analyse(last_us=1_000_000)
        times.append(time.perf_counter() - t0)
    emit("profiler_live_refresh_last_1s", statistics.median(times) * 1e3, "ms", 100.0,
         statistics.median(times) * 1e3 / 100.0, note="reference: the 100 ms between refreshes at 10/s",
         stamps_stored=p.timeline.count)
    bench_rough(ids, t, b)


def bench_rough(ids, t, b) -> None:
    """The stamp decoders and the whole profiler on 1 MB of noise and on this benchmark's traces (the first
    MB) with 1 % of the bytes damaged, against a 12.5 Mbit/s UART (tools/rough.py)."""
    from rough import measure

    from hilbench.profiler.targets import PROFILER
    from hilbench.protocols.tracestamp_targets import TRACESTAMP_BINARY, TRACESTAMP_STREAM, TRACESTAMP_TEXT

    text, binary = text_stream(ids, t, b)[:1_000_000], binary_stream(ids, t, b)[:1_000_000]
    measure(TRACESTAMP_TEXT, seed=text, seed_name="a text trace", prefix="profiler_rough_")
    measure(TRACESTAMP_BINARY, seed=binary, seed_name="a binary trace", prefix="profiler_rough_")
    measure(TRACESTAMP_STREAM, seed=binary, seed_name="a binary trace", prefix="profiler_rough_")
    for seed, name in ((text, "text"), (binary, "binary")):
        measure(PROFILER, seed=seed, seed_name=f"a {name} trace", prefix=f"profiler_rough_{name}_")


if __name__ == "__main__":
    main()
