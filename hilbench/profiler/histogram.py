"""Histograms: PX4's high-resolution-timer latency buckets, and linear bins (spec §5.5).

PX4 (``hrt.c``: ``latency_buckets``) counts ISR latencies on a 1 MHz timer
into buckets with inclusive upper bounds of 1, 2, 5, 10, 20, 50, 100 and
1000 ticks plus an overflow bucket. A value goes into the first bucket whose
bound is at least the value; 0 lands in the first. PX4 latencies are never
negative; release latencies can be (an early release), so hilbench counts
those apart as ``early``.
"""

from __future__ import annotations

import numpy as np

PX4_BOUNDS = (1, 2, 5, 10, 20, 50, 100, 1000)
#: Most bins a fixed-width linear histogram gets (a width far below the range would allocate without bound).
MAX_BINS = 10_000
PX4_LABELS = tuple(f"<={b}" for b in PX4_BOUNDS) + (f">{PX4_BOUNDS[-1]}",)


def px4_counts(values, tick: float = 1.0) -> tuple[list[int], int]:
    """Counts per PX4 bucket (9, the last is overflow) and the count of negative values."""
    v = np.asarray(values, dtype=np.float64) / tick
    early = v < 0
    idx = np.searchsorted(np.asarray(PX4_BOUNDS, dtype=np.float64), v[~early], side="left")
    counts = np.bincount(idx, minlength=len(PX4_LABELS))
    return [int(c) for c in counts], int(np.count_nonzero(early))


def px4_histogram(values, tick: float = 1.0) -> dict[str, int]:
    """``{"<=1": n, ..., "<=1000": n, ">1000": n, "early": n}`` (``tick`` µs per tick)."""
    counts, early = px4_counts(values, tick)
    out = dict(zip(PX4_LABELS, counts, strict=True))
    out["early"] = early
    return out


def px4_lines(hist: dict[str, int]) -> list[str]:
    """The printed form: ``<=b: count`` rows, then ``>1000: count`` (and ``early`` if any)."""
    lines = [f"{label}: {hist[label]}" for label in PX4_LABELS]
    if hist.get("early"):
        lines.append(f"early: {hist['early']}")
    return lines


def linear_histogram(values, bins: int = 20, *, width: float | None = None,
                     lo: float | None = None, hi: float | None = None) -> dict[str, list]:
    """Equal-width bins over [lo, hi] (default: the data's range): ``{"edges": [...], "counts": [...]}``.

    ``width`` fixes the bin width instead of the count (bins start at ``lo``; at most
    :data:`MAX_BINS` of them, wider if the range needs more). Values that are not finite are left out.
    """
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return {"edges": [], "counts": []}
    lo = float(v.min()) if lo is None else lo
    hi = float(v.max()) if hi is None else hi
    if width is not None and width > 0:
        n = max(1, min(MAX_BINS, int(np.ceil((hi - lo) / width)) or 1))
        width = max(width, (hi - lo) / n)
        edges = lo + width * np.arange(n + 1)
        counts, edges = np.histogram(v, bins=edges)
    else:
        # Each bin a few float steps wide at least: durations of 2**48 us apart from each other by
        # less than that (a wrapped counter) would otherwise make bins numpy refuses.
        need = bins * 4 * float(np.spacing(max(abs(lo), abs(hi))))
        if not hi - lo > need:
            hi = lo + max(1.0, need)
        counts, edges = np.histogram(v, bins=bins, range=(lo, hi))  # equal bins: numpy's linear-time path
    return {"edges": [round(float(e), 6) for e in edges], "counts": [int(c) for c in counts]}
