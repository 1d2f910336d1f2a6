"""Data-quality counters (spec sheet §5.6): what was read, what was lost, what is suspicious.

They are always reported. If any *loss* counter is non-zero the statistics are
flagged untrustworthy, with the reasons listed, because a lost stamp shortens
or lengthens an interval and moves a period.
"""

from __future__ import annotations

#: Counters that mean stamps were lost or damaged, with the reason printed for each.
LOSS_COUNTERS = {
    "drops": "the board reported dropped stamps (binary DROPS words)",
    "estimated_drops": "fewer hook stamps than the report's ctx switches",
    "orphan_ends": "ends without a begin inside the window (begins lost)",
    "orphan_begins": "begins left open inside the window (ends lost)",
    "double_begins": "tasks switched in twice (ends lost)",
    "parse_errors": "unreadable lines",
    "broken_words": "damaged binary words",
    "checks_failed": "binary CHECK words that disagreed",
    "suspected_overruns": "a window that does not start near 0 (record buffer overrun?)",
    "backward_jumps": "time jumped back with no wrap or window to explain it",
    "discarded_stamps": "oldest stamps discarded to bound memory",
    "late_beyond_reorder": "stamps later than the reorder window",
}


def judge(q: dict) -> dict:
    """Add ``untrustworthy`` and ``reasons`` to a quality dict."""
    reasons = [f"{key}={q[key]}: {why}" for key, why in LOSS_COUNTERS.items() if q.get(key)]
    q["untrustworthy"] = bool(reasons)
    q["reasons"] = reasons
    return q


def decoder_counters(profiler) -> dict:
    """What the stream decoders counted (text lines and binary words)."""
    text = profiler.decoder.text
    words = profiler.decoder.words
    wp = profiler.word_problems
    return {
        "bytes": profiler.decoder.bytes_in,
        "cut_bytes": profiler.cut_bytes,
        "lines": text.lines,
        "stamp_lines": text.stamp_lines,
        "log_lines": text.log_lines,
        "report_lines": text.report_lines,
        "meta_lines": text.meta_lines,
        "parse_errors": text.parse_errors,
        "reports": text.reports,
        "binary_words": words.words,
        "binary_stamps": words.stamps,
        "broken_words": words.broken_words,
        "checks_ok": words.checks_ok,
        "checks_failed": words.checks_failed,
        "unnamed_stamps": words.unnamed_stamps,
        "unsynced_stamps": words.unsynced_stamps,
        "reserved_words": wp.get("reserved_id", 0),
        "unknown_ops": wp.get("unknown_op", 0),
        "drops": words.drops,
        "windows_started": profiler.windows_started,
        "windows_stopped": profiler.windows_stopped,
    }
