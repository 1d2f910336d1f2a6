"""Dashboard views of laser-scanner trackers: the newest scan as a polar plot, the request/reply log, errors.

Screens are ASCII only and exactly as tall as asked. :func:`polar_lines` is
also what ``hilbench lidar`` draws.
"""

from __future__ import annotations

import numpy as np
from rich.console import Group
from rich.text import Text

VIEWS = ("scan", "log", "errors")
TITLES = {"scan": "Scan", "log": "Requests and replies", "errors": "Errors"}


def polar_lines(angles: np.ndarray, ranges: np.ndarray, width: int, height: int,
                max_range: float | None = None) -> list[str]:
    """A top view of one scan: the sensor at the centre ('+'), straight ahead up, left to the left.

    ``angles`` counter-clockwise from straight ahead (rad), ``ranges`` in metres (0: none).
    Characters are about twice as tall as wide, so x is stretched by two.
    """
    width, height = max(8, width), max(4, height)
    grid = [[" "] * width for _ in range(height)]
    r = np.asarray(ranges, dtype=float)
    a = np.asarray(angles, dtype=float)
    ok = r > 0
    if max_range is None:
        max_range = float(np.percentile(r[ok], 98)) if ok.any() else 1.0
    max_range = max(max_range, 1e-3)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    scale = min(cx / 2, cy) / max_range
    # Straight ahead is up: screen x = -y_sensor (left is left), screen y = x_sensor.
    sx = cx - 2 * scale * r[ok] * np.sin(a[ok])
    sy = cy - scale * r[ok] * np.cos(a[ok])
    for x, y in zip(np.round(sx).astype(int), np.round(sy).astype(int), strict=False):
        if 0 <= x < width and 0 <= y < height:
            grid[y][x] = "*"
    grid[int(round(cy))][int(round(cx))] = "+"
    return ["".join(row) for row in grid]


def _pad(lines: list[Text], height: int) -> Group:
    lines = lines[:height]
    lines += [Text("")] * (height - len(lines))
    return Group(*lines)


def _line(text: str, style: str = "", width: int = 80) -> Text:
    t = Text(text, style=style)
    t.no_wrap = True
    t.truncate(width, overflow="ellipsis")
    return t


class ScannerViews:
    """The scanner view set (:class:`~hilbench.dashboard.app.ViewSet`)."""

    views = VIEWS
    titles = TITLES
    letters = {"s": "scan", "l": "log", "e": "errors"}

    def render(self, dash, width: int, height: int) -> Group:
        tr = dash.tracker
        rate = tr.scan_rate
        pps = tr.points_per_scan
        head = [
            _line(f" hilbench monitor  {dash.source}  [{dash.status()}]  {TITLES[dash.view]}", "bold", width),
            _line(f" {tr.protocol}: scans {tr.scans}  rate {f'{rate:.2f} Hz' if rate else '-'}  points/scan "
                  f"{f'{pps:.0f}' if pps is not None else '-'}  health {tr.health}  requests {tr.requests}  "
                  f"replies {tr.replies}", width=width),
            _line(f" checksum failures {tr.checksum_failures}  dropped bytes {tr.dropped_bytes}  "
                  f"errors {tr.error_count}", "red" if tr.error_count else "", width),
        ]
        body_h = height - len(head) - 1
        body: list[Text] = []
        if dash.view == "scan":
            s = tr.last_scan
            if s is None:
                body = [_line(" no scan yet", width=width)]
            else:
                body = [_line(ln, width=width) for ln in polar_lines(s.angles, s.ranges, width - 1, body_h)]
        else:
            entries = list(tr.log if dash.view == "log" else tr.errors)
            entries.reverse()  # newest first
            t0 = tr.t0 or 0.0
            for e in entries[dash.scroll:dash.scroll + body_h]:
                mark = {"host": "->", "device": "<-", "error": "!!"}[e.direction]
                body.append(_line(f" {e.t - t0:9.3f} {mark} {e.text}", "red" if e.direction == "error" else "",
                                  width))
        keys = _line(" 1-3 / s l e: views   Up/Down: scroll   q: quit", "dim", width)
        return _pad([*head, *body[:body_h], *[Text("")] * max(0, body_h - len(body)), keys], height)

    def navigate(self, dash, key: str) -> bool:
        return False


VIEW_SET = ScannerViews()

__all__ = ["TITLES", "VIEWS", "VIEW_SET", "ScannerViews", "polar_lines"]
