"""The kernel's vectorised fast path: whole runs of ticks with numpy instead of event by event.

:func:`fast_run` continues a :class:`~hilbench.fakes.stm32_board.kernel.Kernel`
(the exact path) in bulk. When the running task is the idle task or a long
computation (the background) and every task that will be ready before the
next irregular event (an ISR, a task without a periodic model) is periodic,
the kernel generates whole runs of ticks with numpy: the release order per
tick comes from the ready and delayed lists (replayed once per relative start
state until it repeats, then tiled, and cached), execution times are drawn in
bulk from each task's own random stream, and the switch times of every tick's
burst follow from one cumulative sum; stamps, run-time counters and the
background's progress follow from those. A run ends at the first tick that
needs the exact path: a burst that would run into the next tick (overload),
the tick where the background finishes, an event (whose tick is included
when its burst is over before the event) or a task whose model does not
hold. Both paths draw from the same per-task streams in the same order, so
tests can prove they produce the same stamps and the same output bytes.
"""

from __future__ import annotations

import bisect
import math
from typing import TYPE_CHECKING

import numpy as np

from hilbench.fakes.stm32_board.presets import RUNTIME_UNIT_US

if TYPE_CHECKING:  # (annotations only: the kernel imports this module)
    from hilbench.fakes.stm32_board.kernel import Kernel, Task


def fast_run(k: Kernel, k0: int, k_end: int, tasks: list[Task], bg: Task | None = None,
             until: float | None = None) -> None:
    """Process ticks k0 .. k_end-1 in bulk (see the module docstring); stops early at an irregular tick.

    ``bg`` is the running task that resumes after each burst (default: the idle task); if it is not
    the idle task, the run ends in the tick where its remaining computation would finish. With
    ``until`` (the time of the next event, in tick k_end), tick k_end is processed too if the run
    can hand over before that time.

    Times are computed per context switch: a burst of L jobs has L + 1 switch points (the first at
    the tick ISR's end, each next one a job's execution time and a switch later); every switch point
    x stamps the old task out at x and the new one in at x + switch time, as the exact path does.
    """
    tick_us = k.tick_us
    sw = k.switch_us
    isr = k.isr_us
    bg = bg or k.idle
    budget = math.inf if bg is k.idle else bg.remaining
    pre = k0 * tick_us - max(k.now, k._resume_at)  # background computing before the first tick
    if pre >= budget:
        return
    shadow = _Shadow(k, tasks, bg, k0, k_end) if tasks else None
    if budget != math.inf:
        # The background finishes long before the run's limit, typically: compute only the ticks it
        # is likely to need (the run ends at the horizon otherwise, and the next one continues).
        k_end = min(k_end, k0 + _background_ticks(k, tasks, budget - pre))
    tail = None
    if until is not None and k_end * tick_us < until:
        tail = k_end  # the event's tick, processed only if its burst is over before the event
        k_end += 1
    if shadow is not None:
        st, n, m, k_end = shadow.structure(k_end)
    else:
        st, n, m = _EMPTY_STRUCT, 0, 0
    if n:
        ji = st.ji[:n]
        counts = np.bincount(ji, minlength=len(tasks)).tolist()
        # Durations in each task's own stream order: the task's first c jobs get its next c draws.
        d = np.empty(n)
        positions = st.task_positions()
        for i, (task, c) in enumerate(zip(tasks, counts, strict=True)):
            if c:
                d[positions[i][:c]] = task.fast.durations.peek(c)
        step = d + sw  # a job's execution time and the switch that ends it
        x = _switch_points(st, n, m, step, k0 * tick_us + isr, tick_us)
        # Does a burst run into the next tick? Not even possible with the longest draws, usually.
        if isr + st.longest_burst(tuple([t.fast.durations.longest for t in tasks]), sw) >= tick_us - 1e-6:
            burst_end = x[st.bslot_last[:m]] + sw  # the background's switch-in stamp
            bad = burst_end >= st.brel_us(tick_us)[:m] + (k0 + 1) * tick_us
            if bad.any():
                k_end = k0 + int(st.brel[int(np.argmax(bad))])
                k._no_fast_before = k_end + 1  # do not retry until the overloaded tick is past
    brel = st.brel[:m]
    done = None
    if budget != math.inf:
        # Background computing per tick: from its resumption (after the burst, or the ISR) to the next tick.
        if k_end - k0 <= 0:
            return
        ticks = np.arange(k0, k_end + 1) * tick_us
        resume = ticks[:-1] + isr
        inside = int(brel.searchsorted(k_end - k0))
        if inside:
            resume[brel[:inside]] = x[st.bslot_last[:inside]] + sw
        done = pre + (ticks[1:] - resume).cumsum()  # computed by the end of each tick
        over = int(done.searchsorted(budget))
        if over < len(done):
            k_end = min(k_end, k0 + over + 1)  # hand over in the tick where it finishes
    if tail is not None and k_end == tail + 1:
        burst_at_tail = m and int(brel[m - 1]) == tail - k0
        handover = float(x[st.bslot_last[m - 1]]) + sw if burst_at_tail else tail * tick_us + isr
        if not handover < until:
            k_end = tail
    if k_end - k0 < 1:
        return
    keep = int(brel.searchsorted(k_end - k0))
    if keep < m:
        m = keep
        n2 = int(st.start[m]) if m < st.m else st.n
        if n2 < n:
            n = n2
            ji, step, counts = ji[:n], step[:n], None
        x = x[: n + m]
    if n:
        if counts is None:
            counts = np.bincount(ji, minlength=len(tasks)).tolist()
        _commit(k, tasks, bg, st, n, m, counts, ji, step, x)
    if shadow is not None:
        shadow.apply(k, k_end - 1)
    # Hand over at the background's resumption in the last processed tick.
    last = k_end - 1
    handover = float(x[st.bslot_last[m - 1]]) + sw if m and int(brel[m - 1]) == last - k0 else last * tick_us + isr
    if done is not None:
        bg.remaining = budget - (pre if last == k0 else float(done[last - k0 - 1]))
    k.tick = last
    k.now = max(k.now, handover)
    k._resume_at = k.now
    k.fast_ticks += k_end - k0


def _switch_points(st: _Struct, n: int, m: int, step: np.ndarray, t0: float, tick_us: float) -> np.ndarray:
    """The switch times of the first ``m`` bursts (``n`` jobs), burst by burst: the first at the tick's
    ISR end, then one after each job. ``t0`` is the first tick's ISR end.

    One cumulative sum over the switch slots: a job's slot adds its step, a burst's first slot adds
    the gap from the previous burst's last switch (the ticks between them less that burst's steps)."""
    a = np.empty(n + m)
    a[st.jslot_end[:n]] = step
    a[0] = t0 + float(st.brel[0]) * tick_us
    if m > 1:
        per_burst = np.add.reduceat(step, st.start[:m])
        a[st.bslot_first[1:m]] = st.brel_gap_us(tick_us)[: m - 1] - per_burst[:-1]
    return a.cumsum()


def _background_ticks(k: Kernel, tasks: list[Task], work_us: float) -> int:
    """A generous estimate of the ticks a background task needs for ``work_us`` of computation
    while ``tasks`` run their jobs in every tick's burst (mean execution times)."""
    sw = k.switch_us
    load = k.isr_us + sum((t.fast.durations.timing.mean_us + 2 * sw) / t.fast.period for t in tasks)
    avail = max(k.tick_us - load, 0.05 * k.tick_us)
    return 2 + math.ceil(1.5 * max(work_us, 0.0) / avail)


def _commit(k, tasks, bg, st: _Struct, n: int, m: int, counts: list[int], ji, step, x) -> None:
    """Consume draws, charge run time and record the stamps of the first ``m`` bursts (``n`` jobs)."""
    units = RUNTIME_UNIT_US
    nt = len(tasks)
    fx = np.floor(x / units)
    rt = np.bincount(ji, weights=step, minlength=nt).tolist()
    ut = np.bincount(ji, weights=fx[st.jslot_end[:n]] - fx[st.jslot_start[:n]], minlength=nt).tolist()
    busy_us = busy_units = 0
    for task, c, r, u in zip(tasks, counts, rt, ut, strict=True):
        if c:
            task.fast.durations.consume(c)
            task.runtime_us += r
            u = round(u)
            task.runtime_units += u
            task.slices += c
            busy_us += r
            busy_units += u
    # The background ran from its last switch-in to the end of the last burst, except in the bursts
    # (whose spans are the jobs' times, each switch point ending one job and starting the next).
    end = st.bslot_last[m - 1]
    x_end = float(x[end])
    bg.runtime_us += (x_end - bg.in_at) - busy_us
    bg.runtime_units += int(fx[end]) - math.floor(bg.in_at / units) - busy_units
    bg.in_at = x_end
    bg.slices += m
    if k.sampling:
        _record_fast(k, tasks, bg, st, n, m, x)


def _record_fast(k, tasks, bg, st: _Struct, n: int, m: int, x) -> None:
    """Stamps per switch point: the old task out, the new one in a switch later."""
    sid, b = st.stamp_labels(bg.stamp_id, tuple([t.stamp_id for t in tasks]))
    total = 2 * (n + m)
    sid, b = sid[:total], b[:total]
    t = np.empty(total)
    t[0::2] = x
    t[1::2] = x + k.switch_us
    if not (bg.hooked and all(t_.hooked for t_ in tasks)):
        keep = np.ones(total, dtype=bool)
        hooked = np.array([t_.hooked for t_ in tasks])[st.ji[:n]]
        keep[2 * st.jslot_start[:n] + 1] = hooked
        keep[2 * st.jslot_end[:n]] = hooked
        if not bg.hooked:
            keep[2 * st.bslot_first[:m]] = False
            keep[2 * st.bslot_last[:m] + 1] = False
        t, sid, b = t[keep], sid[keep], b[keep]
    if k._st_t:
        k._flush_lists()
    k._chunks.append((t, sid, b))
    k.ctx_switches += len(t)


class _ShadowList:
    """ReadyList semantics on task indices (for the order-only shadow of the fast path)."""

    __slots__ = ("items", "idx")

    def __init__(self, items: list[int], idx: int | None) -> None:
        self.items = items
        self.idx = idx

    def insert_end(self, t: int) -> None:
        if self.idx is None:
            self.items.append(t)
        else:
            self.items.insert(self.items.index(self.idx), t)

    def remove(self, t: int) -> None:
        i = self.items.index(t)
        if self.idx == t:
            self.idx = self.items[i - 1] if i > 0 else None
        self.items.pop(i)

    def next(self) -> int:
        items = self.items
        i = 0 if self.idx is None else items.index(self.idx) + 1
        if i == len(items):
            i = 0
        self.idx = items[i]
        return self.idx


class _Struct:
    """Per-job, per-burst and per-switch-point index arrays of a release pattern (ticks relative to
    the run's first). Burst b's switch points are slots ``start[b] + b`` .. ``last[b] + b + 1``, so
    the first m bursts (n jobs) are always the first n + m slots, and any prefix is a slice."""

    __slots__ = ("jt", "ji", "start", "last", "brel", "n", "m", "jslot_start", "jslot_end", "bslot_first",
                 "bslot_last", "labels", "_us", "_positions", "_longest", "jburst")

    def __init__(self, jt: np.ndarray, ji: np.ndarray) -> None:
        self.labels: dict = {}  # (background id, task ids) -> stamp ids and edges of every stamp
        self._us: dict = {}
        self._positions: list[np.ndarray] | None = None
        self._longest: dict = {}
        n = len(jt)
        self.jt, self.ji, self.n = jt, ji, n
        if n == 0:
            z = np.zeros(0, dtype=np.int64)
            self.start = self.last = self.brel = self.jslot_start = self.jslot_end = z
            self.bslot_first = self.bslot_last = self.jburst = z
            self.m = 0
            return
        new = np.empty(n, dtype=bool)
        new[0] = True
        new[1:] = jt[1:] != jt[:-1]
        self.start = np.flatnonzero(new)
        m = self.m = len(self.start)
        self.last = np.append(self.start[1:] - 1, n - 1)
        self.brel = jt[self.start]
        burst = self.jburst = np.cumsum(new) - 1  # burst index of every job
        self.jslot_start = np.arange(n) + burst
        self.jslot_end = self.jslot_start + 1
        self.bslot_first = self.start + np.arange(m)
        self.bslot_last = self.last + np.arange(m) + 1

    def task_positions(self) -> list[np.ndarray]:
        """Per task index, the positions of its jobs (ascending): a prefix's jobs of a task are the
        first of them."""
        if self._positions is None:
            ji = self.ji
            self._positions = [np.flatnonzero(ji == i) for i in range(int(ji.max()) + 1 if self.n else 0)]
        return self._positions

    def longest_burst(self, longest: tuple[float, ...], sw: float) -> float:
        """The longest any burst can take from its first switch to the background's switch-in, with
        every job at its task's longest draw (``longest`` per task index)."""
        v = self._longest.get((longest, sw))
        if v is None:
            if self.n == 0:
                v = 0.0
            else:
                per_burst = np.bincount(self.jburst, weights=np.asarray(longest)[self.ji] + sw, minlength=self.m)
                v = float(per_burst.max()) + sw
            self._longest[(longest, sw)] = v
        return v

    def brel_us(self, tick_us: float) -> np.ndarray:
        """Each burst's tick, in µs after the run's first tick."""
        v = self._us.get(("brel", tick_us))
        if v is None:
            v = self._us[("brel", tick_us)] = self.brel * tick_us
        return v

    def brel_gap_us(self, tick_us: float) -> np.ndarray:
        """µs from each burst's tick to the next one's."""
        v = self._us.get(("gap", tick_us))
        if v is None:
            v = self._us[("gap", tick_us)] = np.diff(self.brel) * tick_us
        return v

    def stamp_labels(self, bg_id: int, ids: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Stamp ids and edges of every stamp (they do not depend on the durations): switch point s
        stamps the old task out (2s) and the new one in (2s + 1)."""
        key = (bg_id, ids)
        lab = self.labels.get(key)
        if lab is None:
            total = 2 * (self.n + self.m)
            sid = np.empty(total, dtype=np.int16)
            b = np.empty(total, dtype=bool)
            job_ids = np.array(ids, dtype=np.int16)[self.ji]
            sid[2 * self.jslot_start + 1] = job_ids
            sid[2 * self.jslot_end] = job_ids
            b[2 * self.jslot_start + 1] = True
            b[2 * self.jslot_end] = False
            sid[2 * self.bslot_first] = bg_id
            b[2 * self.bslot_first] = False
            sid[2 * self.bslot_last + 1] = bg_id
            b[2 * self.bslot_last + 1] = True
            lab = self.labels[key] = (sid, b)
        return lab

    def prefix(self, horizon: int) -> tuple[int, int]:
        """(jobs, bursts) in ticks < horizon."""
        m = int(self.brel.searchsorted(horizon))
        return (int(self.start[m]) if m < self.m else self.n), m


_EMPTY_STRUCT = _Struct(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))


class _Shadow:
    """The job order of a fast run: the kernel's ready and delayed lists replayed without time.

    Every selected periodic task runs one job and then delays (vTaskDelayUntil: blocks, or
    yields when its next wake tick has already come; vTaskDelay: blocks); the background task
    resumes when the round robin reaches it. The relative state repeats after a few ticks, so
    the sequence is simulated until it does and then tiled; :meth:`state_at` rebuilds the
    lists for any tick of the run. Ticks are relative to the run's first tick ``k0``; a pattern
    found once is kept per relative start state and reused by later runs.
    """

    def __init__(self, k: Kernel, tasks: list[Task], bg: Task, k0: int, k_end: int) -> None:
        allt = [*tasks, bg] if bg is k.idle else [*tasks, bg, k.idle]
        self.allt = allt
        n = len(tasks)
        self.n = n
        self.k0 = k0
        ix = {t: i for i, t in enumerate(allt)}
        fasts = [t.fast for t in tasks]
        period = tuple([f.period for f in fasts])
        relative = tuple([f.relative for f in fasts])
        te = k0 - 1
        ready = k.ready
        # The lists relative to the tick before the run, as the simulation's snapshots describe them.
        init = (tuple([(p, tuple([ix[t] for t in ready[p].items]), None if ready[p].idx is None else ix[ready[p].idx])
                       for p in reversed(k._prios)]),
                tuple([(w - te, ix[t]) for w, _, t in k.delayed if ix.get(t, n) < n]),
                tuple([None if f.relative else t.wake_tick - te for t, f in zip(tasks, fasts, strict=True)]))
        key = (init, period, relative, tuple([t.priority for t in tasks]), bg is k.idle)
        self.unsupported_from: int | None = None
        cached = k._patterns.get(key)
        if cached is not None:
            self.entry: dict | None = cached
            self.jobs_t, self.jobs_i = cached["jobs"]
            self.events, self.snaps, self.cycle = cached["events"], cached["snaps"], cached["cycle"]
            self.horizon: int | None = None
            return
        self._simulate(k, init, period, relative, [t.priority for t in allt], k_end - k0)
        self.entry = None
        if self.cycle is not None and self.unsupported_from is None and len(k._patterns) < 256:
            self.entry = k._patterns[key] = {"jobs": (self.jobs_t, self.jobs_i), "events": self.events,
                                             "snaps": self.snaps, "cycle": self.cycle, "struct": None}

    def _simulate(self, k: Kernel, init: tuple, period: tuple, relative: tuple, prio: list[int],
                  horizon: int) -> None:
        """Replay the lists from ``init`` (relative tick -1) until the state repeats or ``horizon``."""
        n = self.n
        cur = n  # the background task
        lists = {p: _ShadowList(list(items), idx) for p, items, idx in init[0]}
        # Relative wake ticks; sequence numbers keep the kernel's order (new entries go after equal ones).
        delayed = [(w - 1, sq, i) for sq, (w, i) in enumerate(init[1])]
        seq = len(delayed)
        wake = [None if w is None else w - 1 for w in init[2]]
        prios = sorted(lists, reverse=True)

        def select() -> int:
            for p in prios:
                lst = lists[p]
                if lst.items:
                    return lst.next()
            raise RuntimeError("no task ready")

        def snapshot(te: int):
            # Relative delays do not use the wake time, so it is left out (it would never repeat).
            return (tuple((p, tuple(lst.items), lst.idx) for p, lst in sorted(lists.items())),
                    tuple((w - te, i) for w, _, i in delayed),
                    tuple(None if relative[i] else w - te for i, w in enumerate(wake)))

        jobs_t: list[int] = []
        jobs_i: list[int] = []
        events: list[int] = []
        snaps: list[tuple] = []
        seen: dict[tuple, int] = {}
        cycle = None
        last = -1
        while len(events) < 4096:
            pending = len(lists[prio[cur]].items) > 1
            nxt = delayed[0][0] if delayed else math.inf
            if pending:
                nxt = min(nxt, last + 1)
            nxt = max(nxt, 0)
            if nxt >= horizon:
                break
            tick = int(nxt)
            woke = False
            while delayed and delayed[0][0] <= tick:
                _, _, i = delayed.pop(0)
                lists[prio[i]].insert_end(i)
                woke = True
            top = next((p for p in prios if lists[p].items), -1)
            if (woke and top >= prio[cur]) or len(lists[prio[cur]].items) > 1:
                x = select()
                prev = None
                while x != cur and x < n:
                    if x == prev:  # the same task again without a switch: not modelled, hand over
                        self.unsupported_from = tick
                        break
                    jobs_t.append(tick)
                    jobs_i.append(x)
                    lst = lists[prio[x]]
                    target = tick + period[x] if relative[x] else wake[x] + period[x]
                    if not relative[x]:
                        wake[x] = target
                    if relative[x] or target > tick:
                        lst.remove(x)
                        seq += 1
                        entry = (target, seq, x)
                        pos = len(delayed)
                        while pos and delayed[pos - 1][:2] > entry[:2]:
                            pos -= 1
                        delayed.insert(pos, entry)
                    prev = x
                    x = select()
                if self.unsupported_from is not None:
                    break
            last = tick
            snap = snapshot(tick)
            events.append(tick)
            snaps.append(snap)
            if snap in seen:
                j = seen[snap]
                cycle = (events[j], tick)
                break
            seen[snap] = len(events) - 1
        self.jobs_t = np.array(jobs_t, dtype=np.int64)
        self.jobs_i = np.array(jobs_i, dtype=np.int64)
        self.events = events
        self.snaps = snaps
        self.cycle = cycle
        self.horizon = horizon if cycle is not None or not events or len(events) < 4096 else events[-1] + 1
        if self.unsupported_from is not None:
            self.horizon = min(self.horizon, self.unsupported_from)

    def structure(self, k_end: int) -> tuple[_Struct, int, int, int]:
        """The job structure of ticks < k_end (cached per pattern, relative to the first tick): the
        structure, the jobs and bursts before k_end, and k_end (earlier if the pattern is unknown
        beyond)."""
        horizon = k_end - self.k0
        if self.horizon is not None:
            horizon = min(horizon, self.horizon)
        entry = self.entry
        if entry is not None and entry["struct"] is not None and entry["struct"][0] >= horizon:
            st = entry["struct"][1]
        else:
            span = horizon
            if entry is not None:  # cached structures grow by doubling: most runs are short
                span = max(horizon, 256, 2 * entry["struct"][0] if entry["struct"] is not None else 0)
            st = _Struct(*self.jobs(span))
            if entry is not None:
                entry["struct"] = (span, st)
        return (st, *st.prefix(horizon), self.k0 + horizon)

    def jobs(self, horizon: int) -> tuple[np.ndarray, np.ndarray]:
        """Relative job ticks and task indices for ticks < horizon (tiled past the simulated part if a
        cycle was found; otherwise only what was simulated)."""
        ticks, order = self.jobs_t, self.jobs_i
        if self.cycle is not None:
            t_prev, t_now = self.cycle
            period = t_now - t_prev
            in_cycle = (ticks > t_prev) & (ticks <= t_now)
            pat_rel = ticks[in_cycle] - t_prev
            pat_order = order[in_cycle]
            head = ticks <= t_now
            ticks, order = ticks[head], order[head]
            reps = max(0, (horizon - t_now) // period + 1)
            if reps and len(pat_rel):
                future = (t_now + np.arange(reps, dtype=np.int64)[:, None] * period + pat_rel[None, :]).ravel()
                ticks = np.concatenate((ticks, future))
                order = np.concatenate((order, np.tile(pat_order, reps)))
        keep = ticks < horizon
        return ticks[keep], order[keep]

    def state_at(self, rel: int):
        """(relative event tick, snapshot) of the lists after processing relative tick ``rel``; None if
        nothing changed."""
        events = self.events
        if not events or rel < events[0]:
            return None
        if self.cycle is None or rel <= self.cycle[1]:
            j = bisect.bisect_right(events, rel) - 1
            return events[j], self.snaps[j]
        t_prev, t_now = self.cycle
        period = t_now - t_prev
        reps = (rel - t_prev - 1) // period
        base = rel - reps * period  # in (t_prev, t_now]
        j = bisect.bisect_right(events, base) - 1  # events includes t_prev (same relative state as t_now)
        return events[j] + reps * period, self.snaps[j]

    def apply(self, k: Kernel, tick: int) -> None:
        """Write the lists after ``tick`` back into the kernel."""
        st = self.state_at(tick - self.k0)
        if st is None:
            return
        te, (lists, delayed, wake) = st
        te += self.k0
        allt = self.allt
        n = self.n
        ready = k.ready
        for p, items, idx in lists:
            rl = ready[p]
            rl.items = [allt[i] for i in items]
            rl.idx = allt[idx] if idx is not None else None
            for i in items:
                if i < n:
                    allt[i].state = "ready"
        mine = set(allt[:n])
        keep = [e for e in k.delayed if e[2] not in mine]
        seq = k._seq
        for rel, i in delayed:
            task = allt[i]
            seq += 1
            task.seq = seq
            task.state = "blocked"
            keep.append((rel + te, seq, task))
        k._seq = seq
        keep.sort()  # (wake tick, sequence number) is unique
        k.delayed = keep
        for i in range(n):
            if wake[i] is not None:
                allt[i].wake_tick = wake[i] + te
        for rel, i in delayed:
            allt[i].wake_tick = rel + te  # what _delay_until records for every delay
