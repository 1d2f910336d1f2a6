"""Timeline: 32-bit cycle counter wraps, sampling windows (reports, binary markers, time resets), late
stamps, binary drops, chunking independence, bounded memory."""

from __future__ import annotations

import numpy as np
import pytest

from hilbench.profiler.settings import ProfilerSettings
from hilbench.profiler.timeline import WRAP_US
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb

NAMES = [b"IDLE", b"ctrl"]


def periodic_text(period_us: int, n: int, dur_us: int = 10, t0: int = 1) -> tuple[bytes, np.ndarray]:
    """IDLE/ctrl alternating, ctrl every period; text times are the board's raw (wrapping) µs."""
    a = t0 + period_us * np.arange(n, dtype=np.int64)
    t = np.stack([a, a, a + dur_us, a + dur_us], axis=1).ravel()
    ids = np.tile([0, 1, 1, 0], n)
    begin = np.tile([False, True, False, True], n)
    cycles = (t * 216) % (1 << 32)  # the counter the board reads, then truncated to µs
    raw = cycles // 216
    return b"".join(ts.format_stamps(NAMES, ids, raw, begin)), t


def test_cycle_counter_wraps_are_unwrapped(spec):
    data, t = periodic_text(250_000, 200)  # 50 s: two wraps of 19.88 s
    a, p = spec.profile(data, ProfilerSettings(periods={"ctrl": 250_000}), chunk=4096)
    assert a.quality["wraps"] == 2 and a.quality["backward_jumps"] == 0 and a.quality["out_of_order"] == 0
    c = a.tasks["ctrl"]
    assert c["count"] == 200 and c["min_us"] >= 9 and c["max_us"] <= 11  # ±1 µs of truncation
    assert abs(c["period_mean_us"] - 250_000) < 0.01 and c["jitter_us"] <= 2 and c["missed_activations"] == 0
    assert abs(a.window["span_us"] - (t[-1] - t[0])) <= 1
    assert t[-1] > 2 * WRAP_US


def test_late_stamp_across_a_wrap_lands_before_it(spec):
    w = int(WRAP_US)
    data = ts.format_stamp("A", w - 20, True) + ts.format_stamp("A", 5, False) + ts.format_stamp("B", 30, True) \
        + ts.format_stamp("B", w - 10, False)  # B's end arrives late, from before the wrap... then a wrap again
    a, _ = spec.profile(data, ProfilerSettings(tasks=frozenset({"A", "B"})))
    b, e = a.intervals("A")
    assert (e - b).tolist() == [25]  # 19,884,087 -> 19,884,112 (the wrap adds 2^32/216)
    assert a.quality["wraps"] == 1 and a.quality["out_of_order"] == 1


def test_windows_from_reports_and_time_resets(spec):
    win, _ = periodic_text(20_000, 50, t0=0)  # 0.98 s: longer than the reorder window
    report = spec.REPORT_65
    a, p = spec.profile(win + report + win + report + win)
    assert a.quality["windows"] == 3 and a.quality["backward_jumps"] == 0
    assert a.tasks["ctrl"]["count"] == 150 and a.tasks["ctrl"]["activations"] == 150
    assert a.tasks["ctrl"]["period_max_us"] == 20_000  # no period spans two windows
    assert a.window["span_us"] == 3 * (49 * 20_000 + 10)
    assert [s.reason for s in p.timeline.segments] == ["start", "report", "report"]
    assert a.runtime_stats["window"] == 1 and a.runtime_stats["reports"] == 2
    # Without a report between them, the second window is a time reset: counted, still split.
    b, _ = spec.profile(win + win)
    assert b.quality["windows"] == 2 and b.quality["backward_jumps"] == 1 and b.quality["untrustworthy"]
    assert b.tasks["ctrl"]["count"] == 100 and b.quality["out_of_order"] == 0


def test_late_beyond_reorder_window_and_suspected_overrun(spec):
    win, _ = periodic_text(100_000, 20, t0=50_000)  # first stamp 50 ms from the window start
    late = ts.format_stamp("IDLE", 600_000, False)
    a, _ = spec.profile(win + late)
    assert a.quality["late_beyond_reorder"] == 1 and a.quality["suspected_overruns"] == 1
    assert a.quality["untrustworthy"]
    ok, _ = spec.profile(win, ProfilerSettings(joined_mid_stream=True))
    assert ok.quality["suspected_overruns"] == 0


def binary_stream(ids, t, begin, names, *, drops_after: int | None = None, drops: int = 0,
                  window: int = 1) -> bytes:
    """A binary window built with the protocol module's encoders: TIME words whenever t >> 15 changes."""
    payloads = [tb.control_payload(tb.Op.WINDOW_START, window), tb.time_payload(0)]
    hi = 0
    for k, (i, tt, b) in enumerate(zip(ids, t, begin, strict=True)):
        if tt >> tb.HI_SHIFT != hi:
            hi = tt >> tb.HI_SHIFT
            payloads.append(tb.time_payload(tt))
        payloads.append(tb.stamp_payload(i, b, tt))
        if drops_after == k:
            payloads += tb.drops_payloads(drops) + [tb.time_payload(tt)]
    ins = tb.CheckInserter()
    body = ins.add(np.array(payloads, np.uint32))
    tail = ins.close() + [tb.control_payload(tb.Op.WINDOW_STOP, window)]
    return tb.name_table(dict(enumerate(names))) + tb.encode_payloads(np.concatenate([body, tail]))


def test_binary_windows_drops_and_text_report_mixed(spec):
    n = 2000
    a0 = 1000 * np.arange(n, dtype=np.int64) + 7
    t = np.stack([a0, a0, a0 + 12, a0 + 12], axis=1).ravel()
    ids = np.tile([0, 1, 1, 0], n)
    begin = np.tile([False, True, False, True], n)
    w1 = binary_stream(ids, t, begin, ["IDLE", "ctrl"], drops_after=4001, drops=9000)
    w2 = binary_stream(ids, t, begin, ["IDLE", "ctrl"], window=2)
    a, p = spec.profile(w1 + spec.REPORT_65 + w2, ProfilerSettings(periods={"ctrl": 1000}), chunk=1000)
    q = a.quality
    assert q["drops"] == 9000 and q["checks_failed"] == 0 and q["broken_words"] == 0 and q["untrustworthy"]
    assert q["windows"] == 2 and q["windows_started"] == 2 and q["binary_stamps"] == 2 * 4 * n
    c = a.tasks["ctrl"]
    assert c["count"] == 2 * n and c["mean_us"] == 12 and c["period_min_us"] == c["period_max_us"] == 1000
    assert c["missed_activations"] == 0 and c["freq_hz"] == pytest.approx(1000)
    assert sum(n for _, n in a.drop_marks) == 9000 and {t for t, _ in a.drop_marks} == {1_000_007}
    assert a.classification == "report"


def test_chunking_does_not_change_the_result(spec):
    data = spec.lines(spec.TRACE_64) + spec.REPORT_65 + spec.lines(spec.LISTING_34)
    whole, _ = spec.profile(data, spec.SETTINGS_64)
    bytewise, _ = spec.profile(data, spec.SETTINGS_64, chunk=1)
    assert whole.to_json() == bytewise.to_json()


def test_memory_bound_discards_the_oldest_stamps(spec):
    data, _ = periodic_text(1000, 3000)
    a, p = spec.profile(data, ProfilerSettings(max_stamps=4000), chunk=5000)
    assert p.timeline.count <= 4000 and a.quality["discarded_stamps"] == 12000 - p.timeline.count
    assert a.quality["untrustworthy"] and abs(a.tasks["ctrl"]["count"] - p.timeline.count / 4) <= 1
