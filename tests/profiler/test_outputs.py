"""What the profiler hands out: Perfetto JSON checked against the Trace Event Format's rules and the spec's
§6.6 sample, Gantt pictures (PNG, SVG, text), the live view's refresh cap, and the thesis's run comparison."""

from __future__ import annotations

import io
import json
import sys
import time

import numpy as np
import pytest
from rich.console import Console

from hilbench.errors import MissingExtra
from hilbench.profiler.compare import compare
from hilbench.profiler.export_perfetto import trace_document
from hilbench.profiler.gantt import render_gantt, text_gantt
from hilbench.profiler.ingest import Profiler
from hilbench.profiler.live import LiveView
from hilbench.profiler.settings import ProfilerSettings

PH = {"X", "B", "E", "i", "I", "C", "M", "b", "e", "n", "s", "t", "f", "P", "O", "N", "D"}


def validate_trace_events(doc) -> list[str]:
    """The Trace Event Format's rules that Perfetto enforces (independent of the exporter)."""
    problems = []
    events = doc["traceEvents"] if isinstance(doc, dict) else doc
    if isinstance(doc, dict) and doc.get("displayTimeUnit", "ms") not in ("ms", "ns"):
        problems.append("displayTimeUnit must be ms or ns")
    tracks: dict[tuple, list[tuple[float, float]]] = {}
    for k, e in enumerate(events):
        where = f"event {k} {e.get('name')!r}"
        if not isinstance(e.get("name"), str) or e.get("ph") not in PH or not isinstance(e.get("pid"), int):
            problems.append(f"{where}: needs name (str), ph, pid (int)")
            continue
        ph = e["ph"]
        if ph == "M":
            if e["name"] in ("process_name", "thread_name") and not isinstance(e.get("args", {}).get("name"), str):
                problems.append(f"{where}: metadata needs args.name")
            if e["name"].endswith("sort_index") and not isinstance(e.get("args", {}).get("sort_index"), int):
                problems.append(f"{where}: needs args.sort_index")
            if e["name"].startswith("thread") and "tid" not in e:
                problems.append(f"{where}: thread metadata needs tid")
            continue
        if not isinstance(e.get("ts"), int | float) or e["ts"] < 0:
            problems.append(f"{where}: ts must be a non-negative number of µs")
        if ph == "X":
            if not isinstance(e.get("dur"), int | float) or e["dur"] < 0 or "tid" not in e:
                problems.append(f"{where}: X needs dur >= 0 and tid")
            else:
                tracks.setdefault((e["pid"], e["tid"]), []).append((e["ts"], e["ts"] + e["dur"]))
        elif ph in ("i", "I"):
            if e.get("s", "t") not in ("t", "p", "g") or (e.get("s", "t") == "t" and "tid" not in e):
                problems.append(f"{where}: instant scope s must be t (with tid), p or g")
        elif ph == "C":
            args = e.get("args")
            if not args or not all(isinstance(v, int | float) for v in args.values()):
                problems.append(f"{where}: counter needs numeric series in args")
    for key, slices in tracks.items():  # strictly nested per track
        stack: list[float] = []
        for b, end in sorted(slices, key=lambda s: (s[0], -(s[1] - s[0]))):
            while stack and stack[-1] <= b:
                stack.pop()
            if stack and end > stack[-1]:
                problems.append(f"track {key}: slice {b}..{end} crosses its parent ending at {stack[-1]}")
            stack.append(end)
    return problems


SAMPLE_66 = [
    {"name": "process_name", "ph": "M", "pid": 1, "args": {"name": "stm32f767-rover"}},
    {"name": "thread_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "wheel_ctrl"}},
    {"name": "thread_name", "ph": "M", "pid": 1, "tid": 2, "args": {"name": "IDLE"}},
    {"name": "thread_name", "ph": "M", "pid": 1, "tid": 3, "args": {"name": "tsink"}},
    {"name": "thread_name", "ph": "M", "pid": 1, "tid": 101, "args": {"name": "fn pid"}},
    {"name": "wheel_ctrl", "cat": "task", "ph": "X", "ts": 3010, "dur": 10, "pid": 1, "tid": 1},
    {"name": "tsink", "cat": "task", "ph": "X", "ts": 3020, "dur": 10, "pid": 1, "tid": 3},
    {"name": "wheel_ctrl", "cat": "task", "ph": "X", "ts": 3030, "dur": 10, "pid": 1, "tid": 1},
    {"name": "pid", "cat": "func", "ph": "X", "ts": 3012, "dur": 23, "pid": 1, "tid": 101,
     "args": {"net_us": 13, "owner": "wheel_ctrl"}},
    {"name": "edge_orphan_end", "cat": "quality", "ph": "i", "s": "t", "ts": 0, "pid": 1, "tid": 2,
     "args": {"stamp": "IDLE"}},
    {"name": "deadline_miss", "cat": "quality", "ph": "i", "s": "t", "ts": 3040, "pid": 1, "tid": 1,
     "args": {"response_us": 30, "deadline_us": 25}},
    {"name": "cpu_share_pct", "ph": "C", "ts": 5011, "pid": 1, "args": {"IDLE": 98.36, "wheel_ctrl": 1.44, "tsink": 0.2}},
]


def test_perfetto_export_of_64_contains_the_66_sample_and_follows_the_rules(spec):
    a, _ = spec.profile(spec.lines(spec.TRACE_64), spec.SETTINGS_64)
    doc = json.loads(json.dumps(trace_document(a)))
    assert doc["displayTimeUnit"] == "ms" and validate_trace_events(doc) == []
    for e in SAMPLE_66:
        assert e in doc["traceEvents"], e
    xs = [e for e in doc["traceEvents"] if e["ph"] == "X"]
    assert len(xs) == a.pairing.count == 15  # every closed interval, one track per task or function


def test_perfetto_rebases_near_zero_and_turns_crossing_slices_into_instants(spec):
    # A recursive function whose stamps cross (f0 in, f0 in, ... ) cannot cross on one track; times far from 0.
    data = b"".join(b"%s %d %s\n" % (n, t, e) for n, t, e in [
        (b"A", 7_000_000, b"in"), (b"f", 7_000_001, b"in"), (b"g", 7_000_002, b"in"), (b"f", 7_000_003, b"out"),
        (b"g", 7_000_004, b"out"), (b"A", 7_000_010, b"out")])
    a, _ = spec.profile(data, ProfilerSettings(tasks=frozenset({"A"})))
    doc = trace_document(a)
    assert validate_trace_events(doc) == []
    assert min(e["ts"] for e in doc["traceEvents"] if "ts" in e) == 0
    # A validator that would miss crossing slices would be useless: check it catches one.
    bad = {"traceEvents": [{"name": "x", "ph": "X", "ts": 0, "dur": 5, "pid": 1, "tid": 1},
                           {"name": "y", "ph": "X", "ts": 3, "dur": 5, "pid": 1, "tid": 1}]}
    assert validate_trace_events(bad)


def test_export_of_an_emulated_overflowing_window_validates():
    """Lost stamps make orphans and double begins; the export must still be a valid, strictly nested trace."""
    from hilbench.fakes.stm32_board.board import Board
    from hilbench.fakes.stm32_board.presets import BoardConfig, make_preset

    board = Board(BoardConfig(make_preset("freertos-10000-5000"), output="binary", baud=2_000_000, window_ms=100))
    board.run_for(0.001)
    board.press_button()
    board.run_for(0.4)
    p = Profiler()
    p.feed(board.take_output())
    p.finish()
    a = p.analyse()
    assert a.quality["drops"] == board.truth.stamps_dropped > 0
    doc = trace_document(a)
    assert validate_trace_events(doc) == []
    names = {e["name"] for e in doc["traceEvents"]}
    assert {"drops", "double_begin", "orphan_end", "edge_orphan_end", "cpu_share_pct"} <= names
    drops = [e for e in doc["traceEvents"] if e["name"] == "drops"]
    assert sum(e["args"]["count"] for e in drops) == board.truth.stamps_dropped and drops[0]["s"] == "g"


def test_gantt_png_and_svg_contain_every_task(spec, tmp_path):
    a, _ = spec.profile(spec.lines(spec.LISTING_39))
    svg = tmp_path / "g.svg"
    drawn = render_gantt(a, svg)
    text = svg.read_text()
    assert drawn == ["profile", "IDLE", "tsink", "pose_control", "odometry", "hal_fetch", "wheel_ctrl"]
    for name in drawn:  # the row labels are text elements (svg.fonttype none)
        assert f">{name}</text>" in text, name
    assert "time (µs)" in text
    png = tmp_path / "g.png"
    render_gantt(a, png, window=(0, 120))
    import matplotlib.image as mpimg
    from matplotlib import colormaps

    img = mpimg.imread(png)
    assert img.shape[0] > 100 and img.shape[1] > 500
    pixels = img[:, :, :3].reshape(-1, 3)
    for row in range(len(drawn)):  # each row's bar colour is in the picture
        rgb = np.array(colormaps["tab10"](row)[:3])
        assert (np.abs(pixels - rgb).max(axis=1) < 0.02).sum() > 20, drawn[row]
    with pytest.raises(ValueError, match="png or .svg"):
        render_gantt(a, tmp_path / "g.jpg")


def test_gantt_without_matplotlib_says_how_to_get_it(spec, tmp_path, monkeypatch):
    a, _ = spec.profile(spec.lines(spec.LISTING_39))
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if hilbench[plot] were not installed
    with pytest.raises(MissingExtra, match=r"needs matplotlib: pip install 'hilbench\[plot\]'$"):
        render_gantt(a, tmp_path / "g.png")
    assert any("█" in line or "▌" in line for line in text_gantt(a))  # the text Gantt needs nothing


def test_text_gantt_marks_the_slices_where_they_are(spec):
    a, _ = spec.profile(spec.lines(spec.TRACE_64), spec.SETTINGS_64)
    lines = text_gantt(a, (3000, 3050), width=50)  # one column per µs
    rows = {ln.split("│")[0].strip(): ln.split("│")[1] for ln in lines[:4]}
    assert rows["wheel_ctrl"] == " " * 10 + "█" * 10 + " " * 10 + "█" * 10 + " " * 10
    assert rows["tsink"] == " " * 20 + "█" * 10 + " " * 20
    assert rows["pid"] == " " * 12 + "█" * 23 + " " * 15
    assert rows["IDLE"].startswith("█" * 10) and rows["IDLE"].endswith("█" * 10)


def test_live_view_refreshes_at_most_ten_times_a_second_and_shows_rates_and_gantt(spec):
    from hilbench.fakes.stm32_board.board import Board
    from hilbench.fakes.stm32_board.presets import BoardConfig, make_preset

    board = Board(BoardConfig(make_preset("freertos-1000"), output="v2", baud=2_000_000, window_ms=600))
    board.run_for(0.001)
    board.press_button()
    board.run_for(0.7)
    data = board.take_output()
    out = io.StringIO()
    p = Profiler()
    view = LiveView(p, Console(file=out, force_terminal=True, width=120), source="emulated", gantt_us=5000)
    chunks = [data[i : i + 2000] for i in range(0, len(data), 2000)]
    t0 = time.monotonic()
    with view:
        k = 0
        while time.monotonic() - t0 < 0.6:  # the caller ticks far more often than the view may draw
            if k < len(chunks):
                p.feed(chunks[k])
                k += 1
            view.tick()
    elapsed = time.monotonic() - t0
    assert 3 <= view.frames <= elapsed * 10 + 1
    text = out.getvalue()
    for name in ("wheel_ctrl", "hal_fetch", "IDLE", "rate Hz", "last 5 ms", "stamps/s"):
        assert name in text, name
    assert "█" in text or "▌" in text


def test_comparison_reproduces_the_thesis_cache_effect():
    """§4.2: (caches on - off) / off over the totals of Tables 8/9 and 4/5, and Table 10's differences."""
    t8 = {"tasks": {"odometry": {"total_us": 22_373, "mean_us": 24.01}, "pose_control": {"total_us": 30_579},
                    "wheel_ctrl": {"total_us": 70_285}, "IDLE": {"total_us": 14_706_086}}}
    t9 = {"tasks": {"odometry": {"total_us": 6_256, "mean_us": 6.84}, "pose_control": {"total_us": 9_043},
                    "wheel_ctrl": {"total_us": 19_559}, "IDLE": {"total_us": 17_276_974}}}
    c = compare(t8, t9)["tasks"]
    assert {n: round(r["change_total_pct"], 2) for n, r in c.items()} == \
        {"odometry": -72.04, "pose_control": -70.43, "wheel_ctrl": -72.17, "IDLE": 17.48}
    t4 = {"tasks": {"odom": {"total_us": 18_149}, "p_ctrl": {"total_us": 295_008}, "w_ctrl": {"total_us": 562_785},
                    "IDLE": {"total_us": 7_330_732}}}
    t5 = {"tasks": {"odom": {"total_us": 6_780, "mean_us": 3.74}, "p_ctrl": {"total_us": 69_301},
                    "w_ctrl": {"total_us": 191_027}, "IDLE": {"total_us": 14_540_662}}}
    c = compare(t4, t5)["tasks"]
    assert {n: round(r["change_total_pct"], 2) for n, r in c.items()} == \
        {"odom": -62.64, "p_ctrl": -76.51, "w_ctrl": -66.06, "IDLE": 98.35}
    # Table 10: micro-ROS (T5) against FreeRTOS (T9) with the micro-ROS names mapped: +524 µs, mean -3.10.
    t10 = compare(t9, t5, aliases={"odom": "odometry"})["tasks"]["odometry"]
    assert t10["diff_total"] == 524 and round(t10["diff_mean"], 2) == -3.10


def test_gantt_does_not_paint_a_short_frequent_task_as_a_solid_bar(tmp_path):
    """tsink runs 3 µs every millisecond: over a second that is 0.3 % busy, not a full row."""
    import matplotlib.image as mpimg
    from matplotlib import colormaps

    lines = []
    for k in range(1000):
        t = k * 1000
        lines += [f"IDLE {t} out", f"tsink {t} in", f"tsink {t + 3} out", f"IDLE {t + 3} in"]
    p = Profiler()
    p.feed(("\n".join(lines) + "\n").encode())
    p.finish()
    a = p.analyse()
    png = tmp_path / "g.png"
    drawn = render_gantt(a, png)
    pixels = mpimg.imread(png)[:, :, :3].reshape(-1, 3)

    def full(name: str) -> int:
        rgb = np.array(colormaps["tab10"](drawn.index(name))[:3])
        return int((np.abs(pixels - rgb).max(axis=1) < 0.02).sum())

    assert full("IDLE") > 10_000  # the idle task fills its row
    assert full("tsink") == 0  # tsink is shown pale, by how busy each pixel is


def test_unreadable_lines_are_quoted_in_the_quality_report():
    """The count of unreadable lines is exact; the first few are quoted (what a damaged start looked like)."""
    from hilbench.profiler.ingest import FIRST_BAD_LINES
    from hilbench.profiler.report import quality_text

    p = Profiler()
    bad = [b"garbage %d!" % k for k in range(FIRST_BAD_LINES + 3)]
    p.feed(b"IDLE 0 out\nwheel_ctrl 0 in\n" + b"\n".join(bad) + b"\nwheel_ctrl 10 out\nIDLE 10 in\n")
    p.finish()
    a = p.analyse()
    q = a.quality
    assert q["parse_errors"] == len(bad)
    assert [u["line"] for u in q["unreadable_lines"]] == [b.decode() for b in bad[:FIRST_BAD_LINES]]
    assert "unreadable: 'garbage 0!'" in quality_text(a).plain
    assert json.loads(json.dumps(a.to_json()))["quality"]["unreadable_lines"][0]["reason"]
