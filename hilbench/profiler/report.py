"""The analysis as rich renderables: the per-name table, quality, the run-time report beside it, histograms,
and a comparison of two runs. ``--json`` output comes from :meth:`Analysis.to_json`, not from here."""

from __future__ import annotations

from rich import box
from rich.console import Group
from rich.table import Table
from rich.text import Text

from hilbench.profiler.analysis import Analysis
from hilbench.profiler.histogram import PX4_LABELS


def _f(x, digits: int | None = None) -> str:
    """Numbers for narrow columns: ints with separators; floats with 2, 1 or 0 decimals by size."""
    if x is None:
        return "-"
    if isinstance(x, int):
        return f"{x:,}"
    if digits is None:
        ax = abs(x)
        digits = 2 if ax < 100 else 1 if ax < 10_000 else 0
    return f"{x:,.{digits}f}"


def task_table(a: Analysis, *, only: list[str] | None = None, title: str | None = None,
               thesis: bool = False) -> Table:
    """One row per name: count, mean/min/max (max = observed WCET), total, share, frequency, period, jitter.

    Functions (cyan, ``fn`` prefix) follow the tasks; their net (self) mean is in its own column. With
    ``thesis`` the share is the thesis's % column (total over the sum of all totals) instead.
    """
    w = a.window
    t = Table(title=title or "Trace profile", title_justify="left", caption=_caption(a, thesis),
              caption_justify="left", header_style="bold", pad_edge=False, box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0))
    funcs = any(s["kind"] == "function" for s in a.tasks.values())
    cols = ["name", "n", "mean", "min", "max", "total", "thesis%" if thesis else "share%", "freq Hz", "period",
            "jit pp"] + (["net mean"] if funcs else [])
    for col in cols:
        t.add_column(col, justify="left" if col == "name" else "right", no_wrap=True)
    for name, s in a.tasks.items():
        if only and name not in only:
            continue
        fn = s["kind"] == "function"
        row = [f"fn {name}" if fn else name, _f(s["count"]), _f(s["mean_us"]), _f(s["min_us"]), _f(s["max_us"]),
               _f(s["total_us"]), _f(s["thesis_pct"] if thesis else s["share"], 3), _f(s["freq_hz"]),
               _f(s["period_mean_us"]), _f(s["jitter_us"])]
        if funcs:
            row.append(_f(s.get("net_mean_us")) if fn else "")
        t.add_row(*row, style="cyan" if fn else None)
    if w.get("untraced_pct") is not None and not thesis:
        t.add_row("(untraced)", "", "", "", "", "", _f(w["untraced_pct"], 3), "", "", "",
                  *([""] if funcs else []), style="dim")
    return t


def _caption(a: Analysis, thesis: bool = False) -> str:
    w = a.window
    share = ("thesis% = total / sum of all totals" if thesis
             else f"share% of W = {_f(w['W_us'])} µs ({w['denominator']})")
    parts = ["times in µs", share, f"{w['windows']} window(s)", f"tasks from {a.classification}"]
    fallbacks = sum(s.get("net_preemption_not_removed", 0) for s in a.tasks.values())
    if fallbacks:
        parts.append(f"{fallbacks} function interval(s) outside any task slice: net = gross - children "
                     "(preemption not removed)")
    return "; ".join(parts) + ". max is the observed maximum (WCET seen), not a bound."


def period_table(a: Analysis, *, only: list[str] | None = None) -> Table | None:
    """Names with a nominal period: jitter against it, release latency, misses, overruns."""
    rows = [(n, s) for n, s in a.tasks.items() if s.get("nominal_period_us") and (not only or n in only)]
    if not rows:
        return None
    t = Table(title="Periodicity against nominal periods (µs)", title_justify="left", header_style="bold",
              pad_edge=False, box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0),
              caption="J = jitter: peak-to-peak, max |p - T|, σ, p99-p1; lat = release latency min/max; "
                      "miss = missed activations; D = deadline misses (R > D); B = overruns (C > B)",
              caption_justify="left")
    for col in ("name", "T", "freq Hz", "p min", "p max", "J pp", "J abs", "J σ", "p99-p1", "lat", "miss", "D",
                "B"):
        t.add_column(col, justify="left" if col == "name" else "right", no_wrap=True)
    for n, s in rows:
        t.add_row(n, _f(s["nominal_period_us"]), _f(s["freq_hz"], 3), _f(s["period_min_us"]),
                  _f(s["period_max_us"]), _f(s["jitter_us"]), _f(s.get("jitter_abs_us")), _f(s["jitter_std_us"]),
                  _f(s["jitter_p99_p1_us"]),
                  f"{_f(s.get('release_latency_min_us'))}/{_f(s.get('release_latency_max_us'))}",
                  _f(s.get("missed_activations")), _f(s.get("deadline_misses")), _f(s.get("overruns")))
    return t


def histogram_table(a: Analysis, which: str = "duration", *, only: list[str] | None = None) -> Table:
    """PX4 buckets (``<=1 ... >1000``, plus ``early``) per name for ``duration``, ``latency`` or ``response``."""
    t = Table(title=f"{which} histogram, PX4 buckets (ticks of {a.settings.hist_tick_us:g} µs)",
              title_justify="left", header_style="bold", pad_edge=False, box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0))
    t.add_column("name", no_wrap=True)
    for label in (*PX4_LABELS, "early"):
        t.add_column(label, justify="right")
    for n, s in a.tasks.items():
        h = s["histograms"].get(which)
        if h is None or (only and n not in only):
            continue
        t.add_row(n, *(_f(h[label]) for label in (*PX4_LABELS, "early")))
    return t


def linear_histogram_table(a: Analysis, which: str = "duration", *, only: list[str] | None = None,
                           width: int = 30) -> Table:
    """Linear bins of ``duration``, ``latency`` or ``response`` per name, with a bar per bin."""
    t = Table(title=f"{which} histogram, linear bins (µs)", title_justify="left", header_style="bold",
              pad_edge=False, box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0))
    for col in ("name", "from", "to", "count", ""):
        t.add_column(col, justify="left" if col in ("name", "") else "right", no_wrap=True)
    for n, s in a.tasks.items():
        h = s["histograms"].get(f"{which}_linear")
        if not h or not h["counts"] or (only and n not in only):
            continue
        top = max(h["counts"]) or 1
        for k, c in enumerate(h["counts"]):
            t.add_row(n if k == 0 else "", _f(h["edges"][k]), _f(h["edges"][k + 1]), _f(c),
                      "#" * round(c / top * width))
    return t


def quality_text(a: Analysis) -> Text:
    q = a.quality
    items = [("stamps", q["stamps"]), ("out of order", q["out_of_order"]), ("late", q["late_beyond_reorder"]),
             ("orphan ends/begins", f"{q['orphan_ends']}/{q['orphan_begins']}"),
             ("edge orphans", f"{q['edge_orphan_ends']}/{q['edge_orphan_begins']}"),
             ("double begins", q["double_begins"]), ("wraps", q["wraps"]), ("backward jumps", q["backward_jumps"]),
             ("parse errors", q["parse_errors"]), ("drops (binary)", q["drops"]),
             ("est. drops", q["estimated_drops"]), ("windows", q["windows"])]
    if q["binary_words"]:
        items.append(("broken words / bad checks", f"{q['broken_words']}/{q['checks_failed']}"))
    text = Text("quality: ", style="bold")
    text.append("; ".join(f"{k} {_f(v) if isinstance(v, int) else v}" for k, v in items))
    for bad in q["unreadable_lines"]:
        text.append(f"\nunreadable: {bad['line']!r} ({bad['reason']})")
    if q["untrustworthy"]:
        text.append("\nUNTRUSTWORTHY: ", style="bold red")
        text.append("; ".join(q["reasons"]), style="red")
    return text


def runtime_table(a: Analysis) -> Table | None:
    """The board's own run-time statistics beside the profiler's shares, with the difference."""
    rs = a.runtime_stats
    if rs is None:
        return None
    t = Table(title="Run-time statistics of the board beside the profiler", title_justify="left",
              header_style="bold", pad_edge=False, box=box.SIMPLE_HEAD, padding=(0, 1, 0, 0),
              caption=f"kernel counters since boot ({_f(rs['since_boot_us'] / 1e6, 3)} s, 1 unit = "
                      f"{rs['unit_us']:.2f} µs; printed % truncated); profiler shares over the window "
                      f"({_f(rs['window_span_us'])} µs). ctx switches {_f(rs['ctx_switches'])}, hook stamps "
                      f"{_f(rs['hook_stamps'])}, est. drops {_f(rs['estimated_drops'])}, free heap "
                      f"{_f(rs['free_heap'])}, {rs['closing'] or 'no closing line'} {_f(rs['closing_us'])} µs",
              caption_justify="left")
    for col in ("task", "abs", "kern%", "exact%", "prof%", "diff pp", "S", "prio", "stack", "num"):
        t.add_column(col, justify="left" if col == "task" else "right", no_wrap=True)
    for name, r in rs["tasks"].items():
        pct = r.get("pct_printed")
        t.add_row(name, _f(r.get("abs")), "<1" if pct == 0 else _f(pct), _f(r.get("kernel_share"), 3),
                  _f(r.get("profiler_share"), 3), _f(r.get("diff_pp"), 3), r.get("state", "-"),
                  _f(r.get("priority")), _f(r.get("stack_hwm")), _f(r.get("number")))
    return t


def compare_table(cmp: dict, base_label: str = "base", other_label: str = "other") -> Table:
    """Per-name change from one run to another, in percent of the first (as the thesis reports it)."""
    t = Table(title=f"Comparison: this run ({other_label}) against the reference ({base_label})",
              title_justify="left", header_style="bold", pad_edge=False, box=box.SIMPLE_HEAD,
              padding=(0, 1, 0, 0),
              caption=f"change% = (this - ref) / ref x 100; sum of totals {_f(cmp['base_sum_us'])} -> "
                      f"{_f(cmp['other_sum_us'])} µs ({_f(cmp['diff_sum_us'])} µs)", caption_justify="left")
    for col in ("name", "total ref", "total this", "change%", "mean ref", "mean this", "diff mean",
                "share ref", "share this"):
        t.add_column(col, justify="left" if col == "name" else "right", no_wrap=True)
    for name, r in cmp["tasks"].items():
        ch = r["change_total_pct"]
        style = None if ch is None else ("green" if ch < 0 else "yellow" if ch > 0 else None)
        t.add_row(name, _f(r["base_total"]), _f(r["other_total"]), _f(ch) if ch is None else f"{ch:+.2f}",
                  _f(r["base_mean"]), _f(r["other_mean"]), _f(r["diff_mean"]), _f(r["base_share"], 3),
                  _f(r["other_share"], 3), style=style)
    return t


def full_report(a: Analysis, *, only: list[str] | None = None, histograms: tuple[str, ...] = (),
                title: str | None = None, thesis: bool = False) -> Group:
    """Everything the terminal shows after a run."""
    parts = [task_table(a, only=only, title=title, thesis=thesis)]
    pt = period_table(a, only=only)
    if pt is not None:
        parts.append(pt)
    for which in histograms:
        kind, _, style = which.partition(":")
        if style == "linear":
            parts.append(linear_histogram_table(a, kind, only=only))
        else:
            parts.append(histogram_table(a, kind, only=only))
    rt = runtime_table(a)
    if rt is not None:
        parts.append(rt)
    parts.append(quality_text(a))
    return Group(*parts)
