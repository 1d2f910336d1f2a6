"""Chrome / Perfetto trace-event JSON (spec sheet §5.7, sample §6.6) that ui.perfetto.dev opens.

Layout: pid 1 is the board. Each task gets its own tid (1, 2, ... in the order
of its first closed slice), each function name its own tid from 101 on (a
function interval can span a preemption, so it cannot share the task's
track). Closed intervals are ``X`` (complete) events with ``ts`` and ``dur``
in µs, rebased so the first stamp is at 0. Perfetto rejects overlapping
slices on one track, so each track is checked for strict nesting and any
slice that would cross another becomes an instant instead. Orphans, double
begins, deadline misses, binary drops and window starts are instants (``i``);
the window's CPU shares are one counter (``C``) at its end; ``M`` metadata
events name the process and threads and fix their order.
"""

from __future__ import annotations

import json
from typing import IO

import numpy as np

from hilbench.profiler.analysis import Analysis
from hilbench.transports.atomic_file import atomic_write

#: The process name when the caller gives none (``hilbench trace`` gives the trace instrument's device name).
BOARD_NAME = "board"
FUNCTION_TID_BASE = 101


def _num(x):
    f = float(x)
    return int(f) if f.is_integer() else round(f, 3)


def track_ids(a: Analysis) -> dict[str, int]:
    """tid per name: tasks 1.. then functions 101.., each in the order of its first closed interval."""
    p = a.pairing
    first: dict[int, int] = {}
    if p.count:
        # Position of each name's earliest closed interval begin.
        order = np.argsort(p.b_pos, kind="stable")
        names_in_order = p.name[order]
        uniq, idx = np.unique(names_in_order, return_index=True)
        first = {int(n): int(p.b_pos[order[i]]) for n, i in zip(uniq, idx, strict=True)}
    present = [a.names.index(n) for n in a.tasks]
    for i in present:  # names with no closed interval: by their first stamp
        if i not in first:
            hits = np.flatnonzero(a.ids == i)
            first[i] = int(hits[0]) + len(a.t) if len(hits) else 2 * len(a.t)
    ranked = sorted(present, key=lambda i: first[i])
    tids: dict[str, int] = {}
    nt = nf = 0
    base = max(FUNCTION_TID_BASE, sum(1 for i in present if a.is_task[i]) + 1)
    for i in ranked:
        if a.is_task[i]:
            nt += 1
            tids[a.names[i]] = nt
        else:
            tids[a.names[i]] = base + nf
            nf += 1
    return tids


def trace_events(a: Analysis, *, board: str = BOARD_NAME, pid: int = 1) -> list[dict]:
    """All events of the trace as dicts (see the module docstring)."""
    t0 = int(a.t[0]) if len(a.t) else 0
    tids = track_ids(a)
    ev: list[dict] = [{"name": "process_name", "ph": "M", "pid": pid, "args": {"name": board}}]
    for name, tid in tids.items():
        label = name if a.tasks[name]["kind"] == "task" else f"fn {name}"
        ev.append({"name": "thread_name", "ph": "M", "pid": pid, "tid": tid, "args": {"name": label}})
        ev.append({"name": "thread_sort_index", "ph": "M", "pid": pid, "tid": tid, "args": {"sort_index": tid}})
    p = a.pairing
    b_t = a.t[p.b_pos] - t0
    e_t = a.t[p.e_pos] - t0
    conflicts: list[dict] = []
    for name, tid in tids.items():
        i = a.names.index(name)
        lo, hi = np.searchsorted(p.name, [i, i + 1])
        if lo == hi:
            continue
        task = a.tasks[name]["kind"] == "task"
        b = b_t[lo:hi]
        d = e_t[lo:hi] - b
        order = np.lexsort((-d, b))  # by start, longer first: parents before children
        b, d = b[order], d[order]
        net, owner = a.net[lo:hi][order], a.owner[lo:hi][order]
        cat = "task" if task else "func"
        if len(b) < 2 or bool(np.all(b[1:] >= b[:-1] + d[:-1])):
            keep = np.ones(len(b), dtype=bool)  # disjoint: nothing to check (task slices always are)
        else:
            keep = _nested(b, d)
            for k in np.flatnonzero(~keep).tolist():
                conflicts.append({"name": "nesting_conflict", "cat": "quality", "ph": "i", "s": "t",
                                  "ts": int(b[k]), "pid": pid, "tid": tid,
                                  "args": {"stamp": name, "dur": int(d[k])}})
        bs, ds = b[keep].tolist(), d[keep].tolist()
        if task:
            ev.extend({"name": name, "cat": cat, "ph": "X", "ts": x, "dur": y, "pid": pid, "tid": tid}
                      for x, y in zip(bs, ds, strict=True))
        else:
            onames = [a.names[o] if o >= 0 else None for o in owner[keep].tolist()]
            ev.extend({"name": name, "cat": cat, "ph": "X", "ts": x, "dur": y, "pid": pid, "tid": tid,
                       "args": {"net_us": nt, "owner": on}}
                      for x, y, nt, on in zip(bs, ds, net[keep].tolist(), onames, strict=True))
    ev.extend(conflicts)
    for pos_arr, edge_arr, edge_name, lost_name in (
            (p.orphan_end_pos, p.orphan_end_edge, "edge_orphan_end", "orphan_end"),
            (p.orphan_begin_pos, p.orphan_begin_edge, "edge_orphan_begin", "orphan_begin")):
        for pos, edge in zip(pos_arr.tolist(), edge_arr.tolist(), strict=True):
            name = a.names[int(a.ids[pos])]
            if name in tids:
                ev.append({"name": edge_name if edge else lost_name, "cat": "quality", "ph": "i", "s": "t",
                           "ts": int(a.t[pos]) - t0, "pid": pid, "tid": tids[name], "args": {"stamp": name}})
    for pos in p.double_begin_pos.tolist():
        name = a.names[int(a.ids[pos])]
        ev.append({"name": "double_begin", "cat": "quality", "ph": "i", "s": "t", "ts": int(a.t[pos]) - t0,
                   "pid": pid, "tid": tids[name], "args": {"stamp": name}})
    for name, misses in a.deadline_misses.items():
        for end, resp, dl in misses:
            ev.append({"name": "deadline_miss", "cat": "quality", "ph": "i", "s": "t", "ts": _num(end - t0),
                       "pid": pid, "tid": tids[name], "args": {"response_us": _num(resp), "deadline_us": _num(dl)}})
    for t, count in a.drop_marks:
        ev.append({"name": "drops", "cat": "quality", "ph": "i", "s": "g", "ts": max(0, int(t) - t0), "pid": pid,
                   "args": {"count": count}})
    for t in a.window_starts:
        ev.append({"name": "window_start", "cat": "window", "ph": "i", "s": "g", "ts": max(0, int(t) - t0),
                   "pid": pid, "args": {}})
    if len(a.t):
        shares = {n: round(s["share"], 2) for n, s in a.tasks.items() if s["kind"] == "task" and s["share"] is not None}
        ev.append({"name": "cpu_share_pct", "ph": "C", "ts": int(a.t[-1]) - t0, "pid": pid, "args": shares})
    return ev


def _nested(b: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Which slices (sorted by start, longer first) nest strictly; a slice crossing its parent is dropped."""
    keep = np.ones(len(b), dtype=bool)
    stack: list[int] = []
    for k, (bk, dk) in enumerate(zip(b.tolist(), d.tolist(), strict=True)):
        ek = bk + dk
        while stack and stack[-1] <= bk:
            stack.pop()
        if stack and ek > stack[-1]:
            keep[k] = False
            continue
        stack.append(ek)
    return keep


def trace_document(a: Analysis, **kwargs) -> dict:
    """``{"traceEvents": [...], "displayTimeUnit": "ms"}``."""
    return {"traceEvents": trace_events(a, **kwargs), "displayTimeUnit": "ms"}


def write_trace(a: Analysis, out: str | IO[str], **kwargs) -> int:
    """Write the JSON document to a path or text file; return the number of events."""
    doc = trace_document(a, **kwargs)
    if isinstance(out, str):
        with atomic_write(out, "w") as f:  # a full disk or a kill leaves an old trace whole
            json.dump(doc, f, separators=(",", ":"))
    else:
        json.dump(doc, out, separators=(",", ":"))
    return len(doc["traceEvents"])
