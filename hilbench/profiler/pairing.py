"""Pairing begin and end stamps into intervals (spec sheet stm32_board.md §5.1).

Input: stamps sorted by (t, seq), as columns ``t`` (µs), ``ids`` (name ids),
``begin`` and ``seg`` (window number: no interval spans two windows).

- **Tasks** (hook stamps): a task is switched in at most once at a time, so a
  begin on an open task means its end was lost: a *double begin*, counted,
  and the older begin is discarded. An end pairs with the task's previous
  stamp when that is a begin.
- **Functions** (scope stamps): one LIFO stack per name; an end closes the
  newest open begin of its name.
- **Orphans**: an end with nothing open, or a begin still open at the end.
  An orphan end before any begin of its name in the window (for a task: its
  first stamp) is an *edge* orphan (running when sampling started); an orphan
  begin that is the last stamp of its name is an *edge* orphan (running when
  sampling stopped). Other orphans mean lost stamps.

:func:`pair` does this for all names at once with numpy: one stable sort
groups the stamps by name (time order kept), tasks pair by looking at their
neighbours, and functions pair by nesting level (after removing orphan ends,
the begins and ends at one level of one name alternate, so a sort by level
puts each end right after its begin). :func:`pair_reference` is the
definition, one stamp at a time with stacks; tests prove the two agree.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Pairing(NamedTuple):
    """Intervals and orphans. Intervals are sorted by (name id, begin position).

    Positions index the sorted stamp columns the pairing was computed from.
    """

    name: np.ndarray  # int32 name id per interval
    b_pos: np.ndarray  # int64
    e_pos: np.ndarray  # int64
    orphan_end_pos: np.ndarray
    orphan_end_edge: np.ndarray  # bool
    orphan_begin_pos: np.ndarray
    orphan_begin_edge: np.ndarray  # bool
    double_begin_pos: np.ndarray  # the discarded (older) begins

    @property
    def count(self) -> int:
        return len(self.name)


_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_B = np.zeros(0, dtype=bool)


def empty_pairing() -> Pairing:
    return Pairing(np.zeros(0, np.int32), _EMPTY_I, _EMPTY_I, _EMPTY_I, _EMPTY_B, _EMPTY_I, _EMPTY_B, _EMPTY_I)


def pair(ids: np.ndarray, begin: np.ndarray, seg: np.ndarray, is_task: np.ndarray) -> Pairing:
    """Pair sorted stamps; ``is_task[id]`` says which names follow the task rule."""
    n = len(ids)
    if n == 0:
        return empty_pairing()
    n_names = len(is_task)
    key = ids.astype(np.int16) if n_names < 32768 else ids
    g = np.argsort(key, kind="stable")  # grouped by name, time order kept (radix sort for int16)
    gn = ids[g]
    gb = begin[g]
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(gn[1:], gn[:-1], out=first[1:])
    if seg[0] != seg[-1]:  # several windows (seg never decreases in time order)
        gs = seg[g]
        first[1:] |= gs[1:] != gs[:-1]
    last = np.empty(n, dtype=bool)
    last[-1] = True
    last[:-1] = first[1:]
    task = is_task[gn]

    # ---- tasks: neighbours decide.
    prev_begin = np.zeros(n, dtype=bool)
    prev_begin[1:] = gb[:-1]
    prev_begin &= ~first
    next_begin = np.zeros(n, dtype=bool)
    next_begin[:-1] = gb[1:]
    next_begin &= ~last
    t_end = task & ~gb
    t_pair = np.flatnonzero(t_end & prev_begin)  # index of the end; its begin is index - 1
    t_oe = np.flatnonzero(t_end & ~prev_begin)
    t_oe_edge = first[t_oe]
    t_db = np.flatnonzero(task & gb & next_begin)
    t_ob = np.flatnonzero(task & gb & last)

    ib = [t_pair - 1]
    ie = [t_pair]
    oe = [t_oe]
    oe_edge = [t_oe_edge]
    ob = [t_ob]
    ob_edge = [np.ones(len(t_ob), dtype=bool)]

    # ---- functions: LIFO per name via nesting levels.
    fi = np.flatnonzero(~task)
    if len(fi):
        fb = gb[fi]
        ffirst = first[fi]
        gidx = np.cumsum(ffirst) - 1
        v = np.where(fb, 1, -1).astype(np.int64)
        s = np.cumsum(v)
        base = (s - v)[ffirst]  # running sum before each group
        s -= base[gidx]
        k = 2 * len(fi) + 2
        shift = k * gidx
        rm = np.minimum.accumulate(s - shift) + shift  # running minimum within the group
        np.minimum(rm, 0, out=rm)
        prev_rm = np.empty_like(rm)
        prev_rm[0] = 0
        prev_rm[1:] = rm[:-1]
        prev_rm[ffirst] = 0
        f_oe = ~fb & (s < prev_rm)
        begins_before = np.cumsum(fb) - fb
        begins_before -= begins_before[ffirst][gidx]
        depth = s - rm
        level = np.where(fb, depth, depth + 1)
        valid = ~f_oe
        vi = fi[valid]
        vlev = level[valid]
        vg = gidx[valid]
        if len(vi):
            key2 = vg * (int(vlev.max()) + 2) + vlev
            o2 = np.argsort(key2, kind="stable")
            srt = key2[o2]
            o = vi[o2]
            ob_ = gb[o]
            m = ob_[:-1] & ~ob_[1:] & (srt[1:] == srt[:-1])
            pb = o[:-1][m]
            pe = o[1:][m]
            ib.append(pb)
            ie.append(pe)
            closed = np.zeros(n, dtype=bool)
            closed[pb] = True
            f_ob = vi[gb[vi] & ~closed[vi]]
            ob.append(f_ob)
            ob_edge.append(last[f_ob])
        oe_idx = fi[f_oe]
        oe.append(oe_idx)
        oe_edge.append(begins_before[f_oe] == 0)

    ib_all, ie_all = ib[0], ie[0]
    if len(ib) > 1 and len(ib[1]):  # task pairs are in group order already; merge the function pairs in
        o = np.argsort(ib[1], kind="stable")
        fb_, fe_ = ib[1][o], ie[1][o]
        at = np.searchsorted(ib_all, fb_)
        ib_all = np.insert(ib_all, at, fb_)
        ie_all = np.insert(ie_all, at, fe_)
    oe_all = np.concatenate(oe)
    oe_edge_all = np.concatenate(oe_edge)
    ob_all = np.concatenate(ob)
    ob_edge_all = np.concatenate(ob_edge)
    # Orphans in time order (there are few).
    o = np.argsort(g[oe_all], kind="stable")
    oe_all, oe_edge_all = oe_all[o], oe_edge_all[o]
    o = np.argsort(g[ob_all], kind="stable")
    ob_all, ob_edge_all = ob_all[o], ob_edge_all[o]
    return Pairing(
        name=gn[ib_all].astype(np.int32),
        b_pos=g[ib_all].astype(np.int64),
        e_pos=g[ie_all].astype(np.int64),
        orphan_end_pos=g[oe_all].astype(np.int64),
        orphan_end_edge=oe_edge_all,
        orphan_begin_pos=g[ob_all].astype(np.int64),
        orphan_begin_edge=ob_edge_all,
        double_begin_pos=np.sort(g[t_db]).astype(np.int64),
    )


def pair_reference(ids, begin, seg, is_task) -> Pairing:
    """The definition, one stamp at a time (slow; for tests and as documentation)."""
    ids = [int(x) for x in ids]
    begin = [bool(x) for x in begin]
    seg = [int(x) for x in seg]
    stacks: dict[tuple[int, int], list[int]] = {}
    seen_any: set[tuple[int, int]] = set()
    seen_begin: set[tuple[int, int]] = set()
    last_of: dict[tuple[int, int], int] = {}
    for p, (i, s) in enumerate(zip(ids, seg, strict=True)):
        last_of[(s, i)] = p
    intervals: list[tuple[int, int, int]] = []
    oe: list[tuple[int, bool]] = []
    db: list[int] = []
    for p, (i, b, s) in enumerate(zip(ids, begin, seg, strict=True)):
        k = (s, i)
        st = stacks.setdefault(k, [])
        task = bool(is_task[i])
        if b:
            if task and st:
                db.append(st.pop())
            st.append(p)
            seen_begin.add(k)
        elif st:
            intervals.append((i, st.pop(), p))
        else:
            oe.append((p, (k not in seen_any) if task else (k not in seen_begin)))
        seen_any.add(k)
    ob = sorted((p, last_of[k] == p) for k, st in stacks.items() for p in st)
    intervals.sort()
    oe.sort()
    db.sort()
    a = np.array
    return Pairing(
        name=a([x[0] for x in intervals], dtype=np.int32),
        b_pos=a([x[1] for x in intervals], dtype=np.int64),
        e_pos=a([x[2] for x in intervals], dtype=np.int64),
        orphan_end_pos=a([x[0] for x in oe], dtype=np.int64),
        orphan_end_edge=a([x[1] for x in oe], dtype=bool),
        orphan_begin_pos=a([x[0] for x in ob], dtype=np.int64),
        orphan_begin_edge=a([x[1] for x in ob], dtype=bool),
        double_begin_pos=a(db, dtype=np.int64),
    )
