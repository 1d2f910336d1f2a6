"""Statistics over paired intervals (spec sheet stm32_board.md §5.2-§5.4).

Functions here work on numpy arrays of one name's intervals or activations
(sorted by time) and return plain dicts of Python numbers, ready for JSON.
The exception is :func:`net_durations`, which needs every task slice and
every function interval at once, and is vectorised across all of them.

Definitions, briefly (the spec sheet has them in full):

- durations: count, total, mean, min, max (the *observed* maximum, with its
  time), sample standard deviation, p50/p90/p99 by nearest rank;
- net (self) time of a function interval: the owner task's running time
  inside it, minus the owner's running time inside directly nested function
  intervals; the owner is the task whose slice contains the begin. Without
  an owner: gross minus the children's gross ("preemption not removed");
- jobs: a task's slices closer than ``merge_gap`` merge; execution C = sum
  of slice lengths, response R = end - start, fragments = slice count;
- periodicity over activations (job starts, or interval begins): f =
  (N-1)/(a_N-a_1), periods, jitter peak-to-peak, absolute against T, sample
  standard deviation and p99-p1; release latency against the grid a_1 + mT;
  missed activations; deadline misses R > D; overruns C > B.
"""

from __future__ import annotations

import math

import numpy as np


def rank_index(n: int, q: float) -> int:
    """0-based index of the nearest rank ceil(q*n/100) (at least rank 1)."""
    return min(max(1, math.ceil(q * n / 100 - 1e-9)), n) - 1


def nearest_rank(sorted_values: np.ndarray, q: float):
    """The value at rank ceil(q*n/100) (at least 1) of ascending values."""
    return sorted_values[rank_index(len(sorted_values), q)]


def percentiles(values: np.ndarray, qs: tuple[float, ...]) -> list:
    """Nearest-rank percentiles without a full sort (np.partition is linear)."""
    n = len(values)
    idx = [rank_index(n, q) for q in qs]
    part = np.partition(values, sorted(set(idx)))
    return [part[i] for i in idx]


def num(x):
    """A numpy scalar as a plain int (if integral) or float."""
    if isinstance(x, np.integer | int):
        return int(x)
    f = float(x)
    return int(f) if f.is_integer() and abs(f) < 2**53 else f


def duration_stats(d: np.ndarray, b_t: np.ndarray) -> dict:
    """Basic statistics of durations ``d`` (µs) of intervals beginning at ``b_t``."""
    n = len(d)
    if n == 0:
        return {"count": 0, "total_us": 0, "mean_us": None, "min_us": None, "max_us": None, "max_at_us": None,
                "std_us": None, "p50_us": None, "p90_us": None, "p99_us": None}
    total = d.sum()
    imax = int(np.argmax(d))
    p50, p90, p99 = percentiles(d, (50, 90, 99))
    return {
        "count": n,
        "total_us": num(total),
        "mean_us": float(total) / n,
        "min_us": num(d.min()),
        "max_us": num(d[imax]),
        "max_at_us": num(b_t[imax]),
        "std_us": float(np.std(d, ddof=1)) if n > 1 else None,
        "p50_us": num(p50),
        "p90_us": num(p90),
        "p99_us": num(p99),
    }


class Jobs:
    """A task's jobs: start ``a``, end ``f``, execution ``c``, fragments, window ``seg``."""

    __slots__ = ("a", "f", "c", "fragments", "seg")

    def __init__(self, a, f, c, fragments, seg) -> None:
        self.a, self.f, self.c, self.fragments, self.seg = a, f, c, fragments, seg

    @property
    def response(self) -> np.ndarray:
        return self.f - self.a

    def __len__(self) -> int:
        return len(self.a)


def jobs_of(b_t: np.ndarray, e_t: np.ndarray, seg: np.ndarray, merge_gap: float | None) -> Jobs:
    """Merge a task's slices (sorted by begin) into jobs: a gap < ``merge_gap`` joins them."""
    n = len(b_t)
    if n == 0:
        z = np.zeros(0, np.int64)
        return Jobs(z, z, z, z, z)
    if merge_gap is None:
        return Jobs(b_t, e_t, e_t - b_t, np.ones(n, np.int64), seg)
    new = np.ones(n, dtype=bool)
    new[1:] = ((b_t[1:] - e_t[:-1]) >= merge_gap) | (seg[1:] != seg[:-1])
    starts = np.flatnonzero(new)
    c = np.add.reduceat(e_t - b_t, starts)
    f = np.maximum.reduceat(e_t, starts)
    frag = np.diff(np.append(starts, n))
    return Jobs(b_t[starts], f, c, frag, seg[starts])


def periods_of(a: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Differences of successive activations inside one window."""
    if len(a) < 2:
        return np.zeros(0, dtype=a.dtype if len(a) else np.int64)
    p = np.diff(a)
    same = seg[1:] == seg[:-1]
    return p if same.all() else p[same]


def release_latency(a: np.ndarray, seg: np.ndarray, period: float) -> np.ndarray:
    """l_k = a_k - (a_1 + m_k T), m_k = round((a_k - a_1)/T), a_1 per window (negative = early)."""
    if len(a) == 0:
        return np.zeros(0)
    first = np.ones(len(a), dtype=bool)
    first[1:] = seg[1:] != seg[:-1]
    a1 = a[np.flatnonzero(first)][np.cumsum(first) - 1]
    rel = (a - a1).astype(np.float64)
    m = np.floor(rel / period + 0.5)
    lat = rel - m * period
    return lat


def periodicity(a: np.ndarray, seg: np.ndarray, period: float | None) -> dict:
    """Frequency, period and jitter figures from activations ``a`` (sorted, µs)."""
    p = periods_of(a, seg)
    out: dict = {"activations": len(a), "freq_hz": None, "period_mean_us": None, "period_min_us": None,
                 "period_max_us": None, "jitter_us": None, "jitter_std_us": None, "jitter_p99_p1_us": None}
    if period:
        out["nominal_period_us"] = num(period)
        out["jitter_abs_us"] = None
        out["missed_activations"] = 0
    if len(p) == 0:
        return out
    total = float(p.sum())
    mean = total / len(p)
    lo, hi = p.min(), p.max()
    p1, p99 = percentiles(p, (1, 99))
    out.update({
        "freq_hz": len(p) / total * 1e6 if total > 0 else None,
        "period_mean_us": mean,
        "period_min_us": num(lo),
        "period_max_us": num(hi),
        "jitter_us": num(hi - lo),
        "jitter_std_us": float(np.std(p, ddof=1)) if len(p) > 1 else None,
        "jitter_p99_p1_us": num(p99 - p1),
    })
    if period:
        err = np.abs(p - period)
        out["jitter_abs_us"] = num(err.max())
        big = p > 1.5 * period
        out["missed_activations"] = int((np.floor(p[big] / period + 0.5) - 1).sum()) if big.any() else 0
    return out


def offenders(mask: np.ndarray, a: np.ndarray, values: np.ndarray, limit: int) -> list[dict]:
    """The first ``limit`` jobs where ``mask`` holds: job number k (1-based), start, value."""
    idx = np.flatnonzero(mask)[:limit]
    return [{"k": int(i) + 1, "at_us": num(a[i]), "value_us": num(values[i])} for i in idx]


# --------------------------------------------------------------------------- net time


def net_durations(t: np.ndarray, is_task: np.ndarray, name: np.ndarray, b_pos: np.ndarray,
                  e_pos: np.ndarray, b_t: np.ndarray | None = None,
                  e_t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Net (self) time of every function interval (§5.2).

    Arguments are the sorted stamp times and the pairing's intervals (sorted by
    name, then begin). Returns ``(net, owner, fallback)`` per interval: for task
    slices net = gross and owner = -1; ``fallback`` marks function intervals
    that had no owner (net = gross - children's gross, preemption not removed).
    """
    m = len(name)
    b_t = t[b_pos] if b_t is None else b_t
    e_t = t[e_pos] if e_t is None else e_t
    gross = e_t - b_t
    net = gross.astype(np.int64)  # a new array: task slices keep gross, function intervals get their net
    owner = np.full(m, -1, dtype=np.int64)
    fallback = np.zeros(m, dtype=bool)
    tmask = is_task[name]
    fidx = np.flatnonzero(~tmask)
    if len(fidx) == 0:
        return net, owner, fallback
    tidx = np.flatnonzero(tmask)

    # Owner: the task slice that contains the function's begin (by position, so ties are exact).
    fb = b_pos[fidx]
    if len(tidx):
        # Task slices in time order without a sort: mark each slice at its begin position.
        at = np.full(len(t), -1, dtype=np.int64)
        at[b_pos[tidx]] = tidx
        order = at[at >= 0]
        tb_sorted = b_pos[order]
        j = np.searchsorted(tb_sorted, fb, side="left") - 1
        ok = j >= 0
        jj = np.maximum(j, 0)
        ok &= e_pos[order[jj]] > fb
        own = np.where(ok, name[order[jj]], -1)
    else:
        own = np.full(len(fidx), -1, dtype=np.int64)
    owner[fidx] = own

    # Running time of task o up to time x: R_o(x), over o's slices (sorted by name then begin); only the
    # tasks that own a function interval matter.
    owners = np.unique(own[own >= 0])
    tidx = tidx[np.isin(name[tidx], owners)] if len(owners) else tidx[:0]
    if len(tidx):
        sn = name[tidx].astype(np.int64)
        sb = b_t[tidx]
        sd = gross[tidx]
        t0 = int(t[0])
        big = int(t[-1]) - t0 + 2
        keys = sn * big + (sb - t0)
        csum = np.cumsum(sd)
        first = np.ones(len(tidx), dtype=bool)
        first[1:] = sn[1:] != sn[:-1]
        before = csum - sd
        before = before - before[first][np.cumsum(first) - 1]

        def running(o: np.ndarray, x: np.ndarray) -> np.ndarray:
            o = o.astype(np.int64)  # name ids may be int32: o * big must not wrap (long traces)
            q = o * big + (x - t0)
            k = np.searchsorted(keys, q, side="right") - 1
            kk = np.maximum(k, 0)
            hit = (k >= 0) & (sn[kk] == o)
            val = before[kk] + np.clip(x - sb[kk], 0, sd[kk])
            return np.where(hit & (o >= 0), val, 0)
    else:
        def running(o: np.ndarray, x: np.ndarray) -> np.ndarray:
            return np.zeros(len(x), dtype=np.int64)

    has = own >= 0
    own_time = np.where(has, running(own, e_t[fidx]) - running(own, b_t[fidx]), gross[fidx])
    fallback[fidx] = ~has

    # Parent of each function interval: the innermost enclosing function interval (global nesting).
    n = len(t)
    delta = np.bincount(b_pos[fidx], minlength=n) - np.bincount(e_pos[fidx], minlength=n)
    depth = np.cumsum(delta)
    level = depth[b_pos[fidx]]
    keys2 = level * (n + 1) + b_pos[fidx]
    o2 = np.argsort(keys2, kind="stable")
    ks = keys2[o2]
    q = (level - 1) * (n + 1) + b_pos[fidx]
    c = np.searchsorted(ks, q, side="left") - 1
    cc = np.maximum(c, 0)
    cand = o2[cc]  # index into fidx
    par_ok = (c >= 0) & (level[cand] == level - 1) & (e_pos[fidx[cand]] >= e_pos[fidx]) & (level > 1)
    child = np.flatnonzero(par_ok)
    if len(child):
        par = cand[child]
        po = own[par]
        cb = b_t[fidx[child]]
        ce = e_t[fidx[child]]
        contrib = np.where(po >= 0, running(po, ce) - running(po, cb), ce - cb)
        own_time = own_time - np.bincount(par, weights=contrib, minlength=len(fidx)).astype(np.int64)
    net[fidx] = own_time
    return net, owner, fallback
