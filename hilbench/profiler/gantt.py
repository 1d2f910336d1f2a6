"""Gantt charts of a trace: one row per task (then per function), like the thesis's figures.

- :func:`text_gantt`: lines of block characters for a terminal (the live view),
  no dependency;
- :func:`render_gantt`: a PNG or SVG through matplotlib, the optional extra
  ``hilbench[plot]``.

Both take a time window (µs on the analysis's timeline); without one the
picture covers the whole trace, or its first :data:`MAX_INTERVALS` intervals
if there are more (a chart of a million slices shows nothing anyway).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hilbench.errors import require
from hilbench.profiler.analysis import Analysis
from hilbench.transports.atomic_file import atomic_write

#: Intervals drawn at most (the picture covers the first ones).
MAX_INTERVALS = 50_000
#: Columns of the picture's time axis (about the plot area's width in pixels at the default size).
PIXELS = 1000
#: Opacity of a pixel that holds any sub-pixel slice (more with how busy it is).
MIN_ALPHA = 0.4


def default_window(a: Analysis, window: tuple[float, float] | None = None) -> tuple[float, float]:
    """The window to draw: the given one, the whole trace, or the span of the first MAX_INTERVALS intervals."""
    if window is not None:
        return window
    if len(a.t) == 0:
        return 0.0, 1.0
    t0, t1 = float(a.t[0]), float(a.t[-1])
    p = a.pairing
    if p.count > MAX_INTERVALS:
        ends = np.sort(a.t[p.e_pos])
        t1 = float(ends[MAX_INTERVALS - 1])
    return t0, t1 if t1 > t0 else t0 + 1.0


def rows(a: Analysis, names: list[str] | None = None) -> list[str]:
    """Row order: tasks by their first slice, then functions; names without intervals are left out."""
    from hilbench.profiler.export_perfetto import track_ids

    tids = track_ids(a)
    chosen = [n for n in sorted(tids, key=tids.get) if names is None or n in names]
    return [n for n in chosen if a.tasks[n]["count"]]


def _clipped(a: Analysis, name: str, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    b, e = a.intervals(name)
    keep = (e >= t0) & (b <= t1)
    return np.maximum(b[keep], t0), np.minimum(e[keep], t1)


def coverage(b: np.ndarray, e: np.ndarray, t0: float, t1: float, width: int) -> np.ndarray:
    """Fraction of each of ``width`` equal columns of [t0, t1] covered by intervals (clipped to 1)."""
    edges = np.linspace(t0, t1, width + 1)
    if len(b) == 0:
        return np.zeros(width)
    o = np.argsort(b, kind="stable")
    b, e = b[o].astype(np.float64), e[o].astype(np.float64)
    d = e - b
    before = np.cumsum(d) - d

    def run(x: np.ndarray) -> np.ndarray:
        j = np.searchsorted(b, x, side="right") - 1
        jj = np.maximum(j, 0)
        return np.where(j >= 0, before[jj] + np.clip(x - b[jj], 0, d[jj]), 0.0)

    r = run(edges)
    col = (t1 - t0) / width
    cov = np.diff(r) / col
    # Zero-length or very short slices still deserve a mark where they are.
    hit = np.zeros(width, dtype=bool)
    idx = np.clip(((b - t0) / col).astype(np.int64), 0, width - 1)
    hit[idx] = True
    return np.where((cov <= 0) & hit, 1e-9, np.clip(cov, 0, 1))


def text_gantt(a: Analysis, window: tuple[float, float] | None = None, *, width: int = 64,
               names: list[str] | None = None, label_width: int = 14) -> list[str]:
    """The chart as text lines: ``name │███  ▌  │`` (█ at least half a column busy, ▌ less)."""
    t0, t1 = default_window(a, window)
    out = []
    for name in rows(a, names):
        b, e = _clipped(a, name, t0, t1)
        cov = coverage(b, e, t0, t1, width)
        cells = "".join("█" if c >= 0.5 else "▌" if c > 0 else " " for c in cov.tolist())
        out.append(f"{name[:label_width]:<{label_width}}│{cells}│")
    span = t1 - t0
    left = f"{t0 / 1000:.3f} ms"
    right = f"{t1 / 1000:.3f} ms"
    axis = " " * label_width + "└" + "─" * width + "┘"
    labels = " " * (label_width + 1) + left + " " * max(1, width - len(left) - len(right)) + right
    out += [axis, labels + f"  ({span / 1000:.3f} ms)"]
    return out


def render_gantt(a: Analysis, path: str | Path, *, window: tuple[float, float] | None = None,
                 names: list[str] | None = None, title: str | None = None) -> list[str]:
    """Write a PNG or SVG Gantt chart; return the row names drawn.

    Raises :class:`~hilbench.errors.MissingExtra` without matplotlib, ValueError for another suffix.
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in ("png", "svg"):
        raise ValueError(f"{path}: the Gantt chart is written as .png or .svg")
    matplotlib = require("matplotlib", "plot", "a Gantt chart as PNG or SVG")
    matplotlib.use("Agg", force=False)
    plt = require("matplotlib.pyplot", "plot", "a Gantt chart as PNG or SVG")
    t0, t1 = default_window(a, window)
    drawn = rows(a, names)
    fig_h = 1.0 + 0.42 * max(1, len(drawn))
    with matplotlib.rc_context({"svg.fonttype": "none", "font.size": 9}):
        fig, ax = plt.subplots(figsize=(11, fig_h), dpi=110)
        colors = plt.get_cmap("tab10")
        scale, unit = (1.0, "µs") if t1 - t0 < 5000 else (1000.0, "ms")
        px = (t1 - t0) / PIXELS  # µs per column of the plot area
        faint = False
        for row, name in enumerate(drawn):
            b, e = _clipped(a, name, t0, t1)
            task = a.tasks[name]["kind"] == "task"
            color = colors(row % 10)
            y = len(drawn) - 1 - row
            wide = (e - b) >= px
            bars = np.column_stack(((b[wide] - t0) / scale, (e[wide] - b[wide]) / scale))
            ax.broken_barh(bars, (y - 0.35, 0.7), facecolors=color, edgecolors="none",
                           alpha=1.0 if task else 0.65, label=name)
            if not wide.all():
                # Slices narrower than a pixel: one strip whose opacity says how busy each pixel is.
                # Drawn as hairlines they would paint a 1 kHz, 3 µs task as a solid bar.
                cov = coverage(b[~wide], e[~wide], t0, t1, PIXELS)
                rgba = np.zeros((1, PIXELS, 4))
                rgba[..., :3] = color[:3]
                rgba[0, :, 3] = np.where(cov > 0, MIN_ALPHA + (1 - MIN_ALPHA) * np.clip(cov, 0, 1), 0.0)
                ax.imshow(rgba, extent=(0, (t1 - t0) / scale, y - 0.35, y + 0.35), aspect="auto",
                          interpolation="nearest", origin="lower")
                faint = True
            for end, _resp, _dl in a.deadline_misses.get(name, []):
                if t0 <= end <= t1:
                    ax.plot([(end - t0) / scale], [y + 0.42], marker="v", color="red", markersize=5)
        ax.set_yticks(range(len(drawn)))
        ax.set_yticklabels(list(reversed([n if a.tasks[n]["kind"] == "task" else f"fn {n}" for n in drawn])))
        ax.set_xlim(0, (t1 - t0) / scale)
        ax.set_ylim(-0.6, len(drawn) - 0.4)
        width = f"{px:,.0f}" if px >= 10 else f"{px:.2g}"
        note = f"; pale: slices under {width} µs, shaded by how busy each pixel is" if faint else ""
        ax.set_xlabel(f"time ({unit}) from t = {t0 / 1000:.3f} ms{note}")
        ax.grid(axis="x", alpha=0.3)
        ax.set_title(title or f"Trace {t0 / 1000:.3f}-{t1 / 1000:.3f} ms: {len(drawn)} rows")
        fig.tight_layout()
        try:
            with atomic_write(path) as f:  # a full disk or a kill leaves an old chart whole
                fig.savefig(f, format=fmt)
        finally:
            plt.close(fig)
    return drawn
