"""One analysis of a profiler's stamps: per-name statistics, window, quality, run-time report.

:func:`analyse` sorts the stamps by (t, arrival), decides which names are
tasks, pairs them (:mod:`~hilbench.profiler.pairing`), and computes the
statistics of :mod:`~hilbench.profiler.stats` per name. The result,
:class:`Analysis`, keeps the sorted stamps and intervals too, for the
Perfetto export and the Gantt charts, and turns into the ``--json`` document
with :meth:`Analysis.to_json`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hilbench.profiler.histogram import linear_histogram, px4_histogram
from hilbench.profiler.pairing import Pairing, pair
from hilbench.profiler.quality import decoder_counters, judge
from hilbench.profiler.settings import KERNEL_TASKS, ProfilerSettings
from hilbench.profiler.stats import (
    Jobs,
    duration_stats,
    jobs_of,
    net_durations,
    num,
    offenders,
    periodicity,
    periods_of,
    release_latency,
)

JSON_SCHEMA = 1


@dataclass
class Analysis:
    """Statistics of one trace (see the module docstring); ``tasks`` maps every name to its figures."""

    tasks: dict[str, dict]
    window: dict
    quality: dict
    runtime_stats: dict | None
    classification: str
    settings: ProfilerSettings
    names: list[str]
    t: np.ndarray  # sorted stamp times (µs, timeline)
    ids: np.ndarray
    begin: np.ndarray
    seg: np.ndarray
    pairing: Pairing
    net: np.ndarray
    owner: np.ndarray
    is_task: np.ndarray
    jobs: dict[str, Jobs] = field(default_factory=dict)
    deadline_misses: dict[str, list[tuple[int, float, float]]] = field(default_factory=dict)
    drop_marks: list[tuple[int, int]] = field(default_factory=list)
    window_starts: list[int] = field(default_factory=list)

    @property
    def task_names(self) -> list[str]:
        return [n for n, s in self.tasks.items() if s["kind"] == "task"]

    @property
    def function_names(self) -> list[str]:
        return [n for n, s in self.tasks.items() if s["kind"] == "function"]

    def intervals(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(begin, end) times of one name's closed intervals."""
        i = self.names.index(name)
        p = self.pairing
        lo, hi = np.searchsorted(p.name, [i, i + 1])
        return self.t[p.b_pos[lo:hi]], self.t[p.e_pos[lo:hi]]

    def to_json(self) -> dict:
        """The ``--json`` document: ``tasks``, ``window``, ``quality``, ``runtime_stats``."""
        s = self.settings
        return {
            "schema": JSON_SCHEMA,
            "tasks": self.tasks,
            "window": self.window,
            "quality": self.quality,
            "runtime_stats": self.runtime_stats,
            "classification": self.classification,
            "settings": {
                "tasks": sorted(s.tasks) if s.tasks is not None else None,
                "periods_us": s.periods, "merge_gaps_us": s.merge_gaps, "deadlines_us": s.deadlines,
                "budgets_us": s.budgets, "window_us": list(s.window) if s.window else None,
                "denominator": s.denominator, "reorder_us": s.reorder_us, "hist_tick_us": s.hist_tick_us,
            },
        }


# --------------------------------------------------------------------------- classification


def _report_names(reports) -> set[str]:
    out: set[str] = set()
    for _, rep in reports:
        out.update(r.name for r in rep.runtime)
        out.update(r.name for r in rep.tasks)
    return out


def classify(names: list[str], present: np.ndarray, settings: ProfilerSettings, reports,
             ids: np.ndarray, begin: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, str]:
    """Which names are tasks, and where that came from (``settings``, ``report`` or ``inferred``)."""
    if settings.tasks is not None:
        tasks, source = set(settings.tasks) | KERNEL_TASKS, "settings"
    elif reports:
        tasks, source = _report_names(reports) | KERNEL_TASKS, "report"
    else:
        return _infer(names, present, ids, begin, seg), "inferred"
    return np.array([nm in tasks for nm in names], dtype=bool), source


def _infer(names, present, ids, begin, seg) -> np.ndarray:
    """No report and no task list: a name whose intervals mostly nest inside another's is a function.

    Tasks run one at a time, so their slices are outermost; function scopes lie
    inside task slices. Kernel names, and names with no closed interval, are tasks.
    """
    n = len(names)
    lut = np.zeros(n, dtype=bool)
    if len(ids) == 0:
        return lut
    p = pair(ids, begin, seg, lut)  # everything LIFO
    delta = np.bincount(p.b_pos, minlength=len(ids)) - np.bincount(p.e_pos, minlength=len(ids))
    depth = np.cumsum(delta)
    level = depth[p.b_pos]
    outer = np.bincount(p.name, weights=(level == 1), minlength=n)
    total = np.bincount(p.name, minlength=n)
    lut = (total == 0) | (outer * 2 > total)  # a name with no closed interval yet: most likely a task
    for i, nm in enumerate(names):
        if nm in KERNEL_TASKS:
            lut[i] = True
    return lut


# --------------------------------------------------------------------------- analysis


def _tail_start(t: np.ndarray, cutoff: float, margin: float, block: int = 1 << 16) -> int:
    """An index before which no stamp is >= ``cutoff`` - arrival order is time order up to ``margin``.

    Walks back from the end a block at a time, so the live view's cost follows the window, not the store.
    """
    i = len(t)
    while i > 0:
        j = max(0, i - block)
        if t[j:i].max() < cutoff - margin:
            return i
        i = j
    return 0


def _select(profiler, settings: ProfilerSettings, last_us: float | None):
    t, ids, begin, seg = profiler.timeline.columns()
    if last_us is not None and len(t):
        k = _tail_start(t, profiler.timeline.global_end - last_us, settings.reorder_us)
        t, ids, begin, seg = t[k:], ids[k:], begin[k:], seg[k:]
    mask = None
    if settings.window is not None:
        a, b = settings.window
        mask = (t >= a) & (t <= b)
    if last_us is not None:
        m2 = t >= profiler.timeline.global_end - last_us
        mask = m2 if mask is None else mask & m2
    if mask is not None:
        return t[mask], ids[mask], begin[mask], seg[mask]
    return t.copy(), ids.copy(), begin.copy(), seg.copy()


def analyse(profiler, settings: ProfilerSettings, *, last_us: float | None = None) -> Analysis:
    """Analyse what ``profiler`` holds (see the module docstring)."""
    t, ids, begin, seg = _select(profiler, settings, last_us)
    if len(t) > 1 and not bool(np.all(t[1:] >= t[:-1])):
        o = np.argsort(t, kind="stable")
        t, ids, begin, seg = t[o], ids[o], begin[o], seg[o]
    names = list(profiler.names)
    n_names = len(names)
    counts = np.bincount(ids, minlength=n_names) if len(ids) else np.zeros(n_names, np.int64)
    present = counts > 0
    is_task, source = classify(names, present, settings, profiler.reports, ids, begin, seg)
    p = pair(ids, begin, seg, is_task)
    b_all = t[p.b_pos]
    e_all = t[p.e_pos]
    net, owner, fallback = net_durations(t, is_task, p.name, p.b_pos, p.e_pos, b_all, e_all)
    d_all = e_all - b_all
    iseg = seg[p.b_pos]

    window = _window(t, seg, profiler, settings)
    W = window["W_us"]
    grand_total = float(d_all.sum())
    bounds = np.searchsorted(p.name, np.arange(n_names + 1))
    per: dict[str, dict] = {}
    jobs: dict[str, Jobs] = {}
    misses: dict[str, list] = {}
    tick = settings.hist_tick_us
    # Names with no closed interval (a stamp whose name was damaged on the line makes one) all get the
    # same figures for the same settings: computed once, shared (thousands of them in a damaged trace;
    # each name gets its own top-level dict, the nested histograms are the same read-only objects).
    empty: dict[tuple, tuple[dict, Jobs | None]] = {}
    for i in np.flatnonzero(present).tolist():
        name = names[i]
        lo, hi = int(bounds[i]), int(bounds[i + 1])
        task = bool(is_task[i])
        key = None
        if hi == lo:
            key = (task, settings.periods.get(name), settings.deadlines.get(name), settings.budgets.get(name),
                   settings.merge_gap(name))
            hit = empty.get(key)
            if hit is not None:
                per[name] = dict(hit[0])
                if hit[1] is not None:
                    jobs[name] = hit[1]
                continue
        d, b, e, sg = d_all[lo:hi], b_all[lo:hi], e_all[lo:hi], iseg[lo:hi]
        st: dict = {"kind": "task" if task else "function"}
        st.update(duration_stats(d, b))
        st["share"] = float(d.sum()) / W * 100 if W else None
        st["thesis_pct"] = float(d.sum()) / grand_total * 100 if grand_total else None
        period = settings.periods.get(name)
        if task:
            jb = jobs_of(b, e, sg, settings.merge_gap(name))
            jobs[name] = jb
            acts, aseg = jb.a, jb.seg
            c_vals, r_vals = jb.c, jb.response
            st["jobs"] = len(jb)
            st["fragments_max"] = int(jb.fragments.max()) if len(jb) else 0
            st["merge_gap_us"] = settings.merge_gap(name)
        else:
            nd = net[lo:hi]
            fb = fallback[lo:hi]
            st["net_total_us"] = num(nd.sum()) if len(nd) else 0
            st["net_mean_us"] = float(nd.sum()) / len(nd) if len(nd) else None
            st["net_min_us"] = num(nd.min()) if len(nd) else None
            st["net_max_us"] = num(nd.max()) if len(nd) else None
            st["net_preemption_not_removed"] = int(fb.sum())
            own = owner[lo:hi]
            known = own[own >= 0]
            st["owner"] = names[int(np.bincount(known).argmax())] if len(known) else None
            acts, aseg = b, sg
            c_vals, r_vals = nd, d
        st.update(periodicity(acts, aseg, period))
        st["response_max_us"] = num(r_vals.max()) if len(r_vals) else None
        hist = {"duration": px4_histogram(d, tick), "duration_linear": linear_histogram(d, settings.linear_bins)}
        if period:
            lat = release_latency(acts, aseg, period)
            st["release_latency_min_us"] = num(lat.min()) if len(lat) else None
            st["release_latency_max_us"] = num(lat.max()) if len(lat) else None
            hist["latency"] = px4_histogram(lat, tick)
            hist["latency_linear"] = linear_histogram(lat, settings.linear_bins)
            hist["period_error"] = px4_histogram(np.abs(periods_of(acts, aseg) - period), tick)
        deadline = settings.deadlines.get(name, period)
        budget = settings.budgets.get(name, period)
        if deadline:
            miss = r_vals > deadline
            st["deadline_us"] = num(deadline)
            st["deadline_misses"] = int(miss.sum())
            st["deadline_offenders"] = offenders(miss, acts, r_vals, settings.offenders)
            hist["response"] = px4_histogram(r_vals, tick)
            hist["response_linear"] = linear_histogram(r_vals, settings.linear_bins)
            if miss.any():
                ends = (acts + r_vals)[miss]
                misses[name] = list(zip(ends.tolist(), r_vals[miss].tolist(), [deadline] * int(miss.sum()),
                                        strict=True))
        if budget:
            over = c_vals > budget
            st["budget_us"] = num(budget)
            st["overruns"] = int(over.sum())
            st["overrun_offenders"] = offenders(over, acts, c_vals, settings.offenders)
        st["histograms"] = hist
        per[name] = st
        if key is not None:
            empty[key] = (dict(st), jobs.get(name))

    order = sorted(per, key=lambda n: (per[n]["kind"] != "task", -per[n]["total_us"], n))
    per = {n: per[n] for n in order}
    task_share = sum(s["share"] or 0 for s in per.values() if s["kind"] == "task")
    window["task_share_sum"] = task_share
    window["untraced_pct"] = 100 - task_share if W else None

    quality = _quality(profiler, p, ids, is_task, len(t))
    runtime = _runtime(profiler, settings, names, is_task, p, d_all, iseg, t, seg)
    if runtime is not None and runtime.get("estimated_drops"):
        quality["estimated_drops"] = runtime["estimated_drops"]
    judge(quality)
    drop_marks = [m for s in profiler.timeline.segments for m in s.drop_marks]
    starts = [s.t_first for s in profiler.timeline.segments if s.t_first is not None and s.index > 0]
    return Analysis(per, window, quality, runtime, source, settings, names, t, ids, begin, seg, p, net, owner,
                    is_task, jobs, misses, drop_marks, starts)


def _window(t: np.ndarray, seg: np.ndarray, profiler, settings: ProfilerSettings) -> dict:
    out: dict = {"t_first_us": None, "t_last_us": None, "span_us": 0, "windows": 0}
    if len(t):
        starts = np.flatnonzero(np.concatenate(([True], seg[1:] != seg[:-1])))
        firsts = t[starts]
        lasts = np.maximum.reduceat(t, starts)
        out.update({"t_first_us": int(t[0]), "t_last_us": int(t[-1]), "span_us": int((lasts - firsts).sum()),
                    "windows": len(starts)})
        segs = set(seg[starts].tolist())
    else:
        segs = set()
    W: float = out["span_us"]
    denom = "span"
    if settings.denominator == "profiled":
        prof = [rep.profiled_for_us for s, rep in profiler.reports if s in segs and rep.profiled_for_us]
        if prof:
            W, denom = float(sum(prof)), "profiled for"
        else:
            denom = "span (no 'profiled for' line in the stream)"
    elif not isinstance(settings.denominator, str):
        W, denom = float(settings.denominator), "given"
    out["W_us"] = W
    out["denominator"] = denom
    return out


def _quality(profiler, p: Pairing, ids: np.ndarray, is_task: np.ndarray, n_stamps: int) -> dict:
    tl = profiler.timeline
    q = decoder_counters(profiler)
    segments = [s for s in tl.segments if s.stamps]
    suspected = 0
    for s in segments:
        if s.first_local is None or s.first_local <= profiler.settings.overrun_suspect_us:
            continue
        if s.index == 0 and profiler.settings.joined_mid_stream:
            continue
        suspected += 1
    q.update({
        "stamps": tl.count + tl.discarded,
        "stamps_analysed": n_stamps,
        "out_of_order": tl.out_of_order,
        "late_beyond_reorder": tl.late,
        "orphan_ends": int((~p.orphan_end_edge).sum()),
        "orphan_begins": int((~p.orphan_begin_edge).sum()),
        "edge_orphan_ends": int(p.orphan_end_edge.sum()),
        "edge_orphan_begins": int(p.orphan_begin_edge.sum()),
        "double_begins": len(p.double_begin_pos),
        "wraps": tl.wraps,
        "backward_jumps": tl.backward_jumps,
        "estimated_drops": 0,
        "suspected_overruns": suspected,
        "unreadable_lines": [{"line": b.raw[:80].decode("latin-1"), "reason": b.detail}
                             for b in profiler.first_bad_lines],
        "discarded_stamps": tl.discarded,
        "windows": len(segments),
    })
    return q


def _runtime(profiler, settings, names, is_task, p: Pairing, d_all, iseg, t, seg) -> dict | None:
    """The last run-time report beside the profiler's figures for the window it closed."""
    if not profiler.reports:
        return None
    seg_idx, rep = profiler.reports[-1]
    unit = settings.runtime_unit_us
    total_abs = rep.total_abs
    recomputed = rep.recomputed_percent()
    # The profiler's figures for that window (masks only when there are several windows).
    one = len(seg) > 0 and seg[0] == seg[-1] == seg_idx
    if one:
        totals = np.bincount(p.name, weights=d_all, minlength=len(names))
        span = int(t[-1] - t[0])
    else:
        in_seg = iseg == seg_idx
        totals = np.bincount(p.name[in_seg], weights=d_all[in_seg], minlength=len(names))
        sel = seg == seg_idx
        span = int(t[sel].max() - t[sel].min()) if sel.any() else 0
    # Hook stamps of that window, over the whole timeline (a --window selection must not change the estimate).
    _, tid, _, tseg = profiler.timeline.columns()
    if len(tid) and tseg[0] == tseg[-1] == seg_idx:
        hook = int(np.bincount(tid, minlength=len(names))[is_task].sum())
    else:
        hook = int(np.count_nonzero(is_task[tid[tseg == seg_idx]])) if len(tid) else 0
    est = None
    if rep.ctx_switches is not None and hook:
        est = max(0, rep.ctx_switches - hook)
    rows: dict[str, dict] = {}
    tasks_by_name = {r.name: r for r in rep.tasks}
    for r in rep.runtime:
        kernel_share = r.abs_time / total_abs * 100 if total_abs else None
        i = names.index(r.name) if r.name in names else None
        prof_total = float(totals[i]) if i is not None else 0.0
        prof_share = prof_total / span * 100 if span else None
        row = {
            "abs": r.abs_time,
            "abs_us": r.abs_time * unit,
            "pct_printed": r.percent,
            "pct_recomputed": recomputed.get(r.name),
            "kernel_share": kernel_share,
            "profiler_total_us": num(prof_total),
            "profiler_share": prof_share,
            "diff_pp": (prof_share - kernel_share) if prof_share is not None and kernel_share is not None else None,
        }
        tr = tasks_by_name.get(r.name)
        if tr is not None:
            row.update({"state": tr.state, "priority": tr.priority, "stack_hwm": tr.stack_hwm, "number": tr.number})
        rows[r.name] = row
    for tr in rep.tasks:
        if tr.name not in rows:
            rows[tr.name] = {"state": tr.state, "priority": tr.priority, "stack_hwm": tr.stack_hwm,
                             "number": tr.number}
    return {
        "window": seg_idx,
        "reports": len(profiler.reports),
        "complete": rep.complete,
        "free_heap": rep.free_heap,
        "ctx_switches": rep.ctx_switches,
        "hook_stamps": hook,
        "estimated_drops": est,
        "closing": rep.closing,
        "closing_us": rep.closing_us,
        "percent_header": rep.percent_header,
        "unit_us": unit,
        "total_abs": total_abs,
        "since_boot_us": total_abs * unit,
        "window_span_us": span,
        "pct_matches_recomputed": all(recomputed.get(r.name) == r.percent for r in rep.runtime),
        "tasks": rows,
    }
