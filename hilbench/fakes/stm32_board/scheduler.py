"""A FreeRTOS-like fixed-priority preemptive scheduler in virtual time, with a vectorised fast path.

Exact path: a discrete-event simulation of the kernel. Tasks are generators
that yield actions (compute for d µs, delay until a tick, delay n ticks, wait
for a notification, notify another task, record a scope stamp, call into the
board). Tick interrupts release delayed tasks in delayed-list order; ready
lists follow FreeRTOS's rules (a readied task goes to the end of its
priority's round; selection advances a round-robin index), a readied task of
higher priority preempts at once, one of equal priority at the next tick
(time slicing), and an ISR's notification preempts only a lower priority.
Every switch records the switch-out stamp of the old task and, one switch
time later, the switch-in stamp of the new one, and charges run time the way
the kernel's run-time statistics do (sampled at each switch, counted in TIM13
units of ≈92.6 µs).

Fast path: when the CPU is idle at a tick boundary and every blocked task
that will wake before the next irregular event (an ISR, a task without a
periodic model) is periodic, the kernel generates whole runs of ticks with
numpy: the release order per tick comes from the delayed list (computed once
per hyperperiod and tiled), execution times are drawn in bulk from each
task's own random stream, and switch stamps and run-time counters follow from
cumulative sums. A tick whose burst would run into the next tick (overload,
time slicing) ends the fast run and the exact path takes over. Both paths
draw from the same per-task streams in the same order, so a test can prove
they produce identical stamps.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Generator
from dataclasses import dataclass

import numpy as np

from hilbench.fakes.stm32_board.presets import RUNTIME_UNIT_US, Timing

# Actions a task generator yields.
RUN = 0  # (RUN, µs)
DELAY_UNTIL = 1  # (DELAY_UNTIL, tick)
DELAY = 2  # (DELAY, ticks)
WAIT = 3  # (WAIT,): ulTaskNotifyTake(pdTRUE, portMAX_DELAY); the generator receives the count taken
NOTIFY = 4  # (NOTIFY, task)
FSTAMP = 5  # (FSTAMP, stamp_id, begin)
CALL = 6  # (CALL, fn): fn(kernel) runs now; the generator receives its result
YIELD = 7  # (YIELD,)

TaskGen = Generator[tuple, object, None]


class Durations:
    """A task's execution times: normal(mean, sd) clipped to [min, max], drawn in blocks from its own stream."""

    BLOCK = 4096

    def __init__(self, timing: Timing, seed: int) -> None:
        t = timing.resolved()
        self.timing = t
        self.rng = np.random.default_rng(seed)
        self._buf = np.zeros(0)
        self._pos = 0

    def _fill(self, need: int) -> None:
        have = len(self._buf) - self._pos
        if have >= need:
            return
        n = max(self.BLOCK, need - have)
        t = self.timing
        if t.dist == "fixed" or not t.sd_us:
            new = np.full(n, t.mean_us)
        else:
            new = np.clip(self.rng.normal(t.mean_us, t.sd_us, n), t.min_us, t.max_us)
        self._buf = np.concatenate((self._buf[self._pos :], new))
        self._pos = 0

    def draw(self) -> float:
        if self._pos >= len(self._buf):
            self._fill(1)
        v = self._buf[self._pos]
        self._pos += 1
        return float(v)

    def peek(self, n: int) -> np.ndarray:
        self._fill(n)
        return self._buf[self._pos : self._pos + n]

    def consume(self, n: int) -> None:
        self._fill(n)
        self._pos += n


@dataclass
class Periodic:
    """A task's fast model while it is blocked: released every ``period`` ticks, each job one RUN
    drawn from ``durations``, then it blocks again (vTaskDelayUntil, or a relative delay that
    starts in the release tick, which is the same thing when the job ends within the tick)."""

    period: int
    durations: Durations
    #: Whether the model still holds when a fast run starts (e.g. "the ring is still empty").
    valid: Callable[[], bool] | None = None


class Task:
    """A task control block (the parts the simulation needs)."""

    __slots__ = ("name", "priority", "number", "stack_hwm", "stamp_id", "gen", "state", "wake_tick",
                 "remaining", "notified", "in_at", "runtime_us", "runtime_units", "fast", "seq", "waiting",
                 "durations", "hooked", "slices")

    def __init__(self, name: str, priority: int, number: int, stamp_id: int, stack_hwm: int = 128,
                 hooked: bool = True) -> None:
        self.name = name
        self.priority = priority
        self.number = number
        self.stamp_id = stamp_id
        self.stack_hwm = stack_hwm
        self.gen: TaskGen | None = None
        self.state = "blocked"  # running | ready | blocked (delayed) | suspended (waiting, no timeout)
        self.wake_tick = -1
        self.remaining = 0.0  # µs of the current RUN still to compute
        self.notified = 0
        self.in_at = 0.0  # time of the switch that brought it in
        self.runtime_us = 0.0
        self.runtime_units = 0
        self.fast: Periodic | None = None
        self.seq = 0
        self.waiting = False  # in WAIT
        self.durations: Durations | None = None
        self.hooked = hooked
        self.slices = 0

    def __repr__(self) -> str:
        return f"Task({self.name!r}, prio={self.priority}, {self.state})"


class ReadyList:
    """One priority's ready list with FreeRTOS's round-robin index (pxIndex).

    ``items`` is the circular order after the list end; ``idx`` is the item
    last returned (None: the end marker). Insertion puts a task just before
    ``idx``, i.e. last in the current round; :meth:`next` advances the index.
    """

    __slots__ = ("items", "idx")

    def __init__(self) -> None:
        self.items: list[Task] = []
        self.idx: Task | None = None

    def insert_end(self, t: Task) -> None:
        if self.idx is None:
            self.items.append(t)
        else:
            self.items.insert(self.items.index(self.idx), t)

    def remove(self, t: Task) -> None:
        i = self.items.index(t)
        if self.idx is t:
            self.idx = self.items[i - 1] if i > 0 else None
        self.items.pop(i)

    def next(self) -> Task:
        items = self.items
        if self.idx is None:
            i = 0
        else:
            i = items.index(self.idx) + 1
            if i == len(items):
                i = 0
        self.idx = items[i]
        return self.idx


class Kernel:
    """The scheduler. Time ``now`` is µs since scheduler start; tick k fires at ``k * tick_us``."""

    def __init__(self, tick_hz: int, *, isr_us: float = 0.6, switch_us: float = 0.4) -> None:
        self.tick_us = 1e6 / tick_hz
        self.tick_hz = tick_hz
        self.isr_us = isr_us
        self.switch_us = switch_us
        self.now = 0.0
        self.tick = 0  # ticks processed (the next tick ISR is tick + 1)
        self.tasks: list[Task] = []
        self.ready: dict[int, ReadyList] = {}
        self.delayed: list[tuple[int, int, Task]] = []  # (wake tick, insertion seq, task), kept sorted
        self.events: list[tuple[float, int, Callable[[Kernel], None]]] = []
        self._seq = 0
        self._eseq = 0
        self.current: Task | None = None
        self.idle: Task | None = None
        # Stamps recorded while sampling: exact-path lists, drained into chunks.
        self.sampling = False
        self.ctx_switches = 0
        self._st_t: list[float] = []
        self._st_id: list[int] = []
        self._st_b: list[bool] = []
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.fast_ticks = 0
        self.exact_ticks = 0
        self.fast_enabled = True
        self.on_drain: Callable[[], None] | None = None  # called before the board looks at stamps

    # ------------------------------------------------------------------ setup

    def add_task(self, task: Task, gen: TaskGen | None, *, idle: bool = False) -> Task:
        task.gen = gen
        self.tasks.append(task)
        if idle:
            self.idle = task
        return task

    def start(self) -> None:
        """Start the scheduler: every task with a generator runs its first steps in priority order."""
        for t in sorted(self.tasks, key=lambda t: t.number):
            if t.gen is not None:
                self._make_ready(t)
        self.current = self._select()
        self.current.state = "running"
        self.current.in_at = 0.0
        self._record_in(self.current, 0.0)
        self._advance_current()

    # ------------------------------------------------------------------ events

    def at(self, t: float, fn: Callable[[Kernel], None]) -> None:
        """Run ``fn(kernel)`` in ISR context at time ``t`` (µs)."""
        self._eseq += 1
        heapq.heappush(self.events, (max(t, self.now), self._eseq, fn))

    def notify_from_isr(self, task: Task) -> None:
        """vTaskNotifyGiveFromISR: wake ``task``; it preempts only a lower-priority task."""
        self._notify(task)
        cur = self.current
        if task.state == "ready" and cur is not None and task.priority > cur.priority:
            self._switch(self.now)

    def _notify(self, task: Task) -> None:
        task.notified += 1
        if task.waiting:
            task.waiting = False
            task.notified = 0
            self._make_ready(task)

    # ------------------------------------------------------------------ stamps

    def _record_in(self, task: Task, t: float) -> None:
        task.slices += 1
        if self.sampling and task.hooked:
            self._st_t.append(t)
            self._st_id.append(task.stamp_id)
            self._st_b.append(True)
            self.ctx_switches += 1

    def _record_out(self, task: Task, t: float) -> None:
        if self.sampling and task.hooked:
            self._st_t.append(t)
            self._st_id.append(task.stamp_id)
            self._st_b.append(False)
            self.ctx_switches += 1

    def function_stamp(self, stamp_id: int, begin: bool) -> None:
        if self.sampling:
            self._st_t.append(max(self.now, self._resume_at))
            self._st_id.append(stamp_id)
            self._st_b.append(begin)

    def take_stamps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All stamps recorded since the last call, in time order: (t µs float, stamp id, begin)."""
        self._flush_lists()
        chunks = self._chunks
        self._chunks = []
        if not chunks:
            return np.zeros(0), np.zeros(0, np.int16), np.zeros(0, bool)
        if len(chunks) == 1:
            return chunks[0]
        return (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
                np.concatenate([c[2] for c in chunks]))

    def _flush_lists(self) -> None:
        if self._st_t:
            self._chunks.append((np.array(self._st_t), np.array(self._st_id, np.int16), np.array(self._st_b, bool)))
            self._st_t, self._st_id, self._st_b = [], [], []

    @property
    def pending_stamps(self) -> int:
        return len(self._st_t) + sum(len(c[0]) for c in self._chunks)

    # ------------------------------------------------------------------ lists

    def _make_ready(self, task: Task) -> None:
        task.state = "ready"
        rl = self.ready.get(task.priority)
        if rl is None:
            rl = self.ready[task.priority] = ReadyList()
            self._prios = sorted(self.ready, reverse=True)
        rl.insert_end(task)

    _prios: list[int] = []

    def _select(self) -> Task:
        for p in self._prios:
            rl = self.ready[p]
            if rl.items:
                return rl.next()
        raise RuntimeError("no task ready (the idle task must always be ready)")

    def _top_ready_priority(self) -> int:
        for p in self._prios:
            if self.ready[p].items:
                return p
        return -1

    def _delay_until(self, task: Task, tick: int) -> None:
        self.ready[task.priority].remove(task)
        task.wake_tick = tick  # vTaskDelayUntil advances the previous wake time even when already due
        if tick <= self.tick:  # already due: stays ready (vTaskDelayUntil does not block)
            self._make_ready(task)
            return
        task.state = "blocked"
        task.wake_tick = tick
        self._seq += 1
        task.seq = self._seq
        entry = (tick, self._seq, task)
        d = self.delayed
        if not d or d[-1][:2] < entry[:2]:
            d.append(entry)
        else:
            lo, hi = 0, len(d)
            while lo < hi:
                mid = (lo + hi) // 2
                if d[mid][:2] < entry[:2]:
                    lo = mid + 1
                else:
                    hi = mid
            d.insert(lo, entry)

    # ------------------------------------------------------------------ switching

    def _switch(self, t: float) -> None:
        """Context switch at ``t``: charge the old task, stamp out/in, pick the next task."""
        old = self.current
        new = self._select()
        if new is old:
            return
        self._charge(old, t)
        self._record_out(old, t)
        if old.state == "running":
            old.state = "ready"
        new.state = "running"
        new.in_at = t
        self.current = new
        self._record_in(new, t + self.switch_us)
        # The new task starts computing after the switch.
        self._resume_at = t + self.switch_us

    _resume_at = 0.0

    def _charge(self, task: Task, t: float) -> None:
        task.runtime_us += t - task.in_at
        u = RUNTIME_UNIT_US
        task.runtime_units += math.floor(t / u) - math.floor(task.in_at / u)

    def _advance_current(self) -> None:
        """Let the current task run its generator until it computes or blocks (possibly switching)."""
        while True:
            cur = self.current
            if cur.remaining > 0 or cur is self.idle:
                return
            action = self._step(cur, None)
            if action is None:
                return

    def _step(self, cur: Task, value) -> tuple | None:
        """Feed the generator and apply immediate actions; returns None when the task computes/blocked."""
        gen = cur.gen
        while True:
            try:
                action = gen.send(value)
            except StopIteration:
                self.ready[cur.priority].remove(cur)
                cur.state = "suspended"
                self._switch(self.now)
                return ()
            value = None
            op = action[0]
            if op == RUN:
                cur.remaining = action[1]
                return None
            if op == FSTAMP:
                self.function_stamp(action[1], action[2])
            elif op == CALL:
                value = action[1](self)
            elif op == NOTIFY:
                target = action[1]
                self._notify(target)
                if target.state == "ready" and target.priority > cur.priority:
                    self._switch(self.now)
                    return ()
            elif op == DELAY_UNTIL:
                self._delay_until(cur, action[1])
                if cur.state != "blocked":
                    continue
                self._switch(self.now)
                return ()
            elif op == DELAY:
                self._delay_until(cur, self.tick + max(1, action[1]))
                self._switch(self.now)
                return ()
            elif op == WAIT:
                if cur.notified:
                    value = cur.notified
                    cur.notified = 0
                    continue
                self.ready[cur.priority].remove(cur)
                cur.state = "suspended"
                cur.waiting = True
                self._switch(self.now)
                return ()
            elif op == YIELD:
                self._switch(self.now)
                return ()

    def _tick_isr(self) -> None:
        self.tick += 1
        k = self.tick
        d = self.delayed
        woke = False
        while d and d[0][0] <= k:
            _, _, task = d.pop(0)
            self._make_ready(task)
            woke = True
        cur = self.current
        need = False
        if woke and self._top_ready_priority() >= cur.priority:
            need = True
        elif len(self.ready[cur.priority].items) > 1:
            need = True  # time slicing among equal priorities
        if need:
            self._switch(self.now + self.isr_us)
        elif cur.remaining > 0:
            cur.remaining += self.isr_us  # the ISR's time lands in the running task's slice

    # ------------------------------------------------------------------ running

    def run_until(self, t_end: float) -> None:
        """Simulate up to ``t_end`` µs."""
        while True:
            cur = self.current
            now = self.now
            if self.fast_enabled and cur is self.idle:
                self._try_fast(t_end)
                cur = self.current
                now = self.now
            next_tick = (self.tick + 1) * self.tick_us
            next_evt = self.events[0][0] if self.events else math.inf
            start = max(now, self._resume_at)
            done = start + cur.remaining if cur is not self.idle else math.inf
            t = min(next_tick, next_evt, done, t_end)
            if t >= t_end and t < done and t < next_tick and t < next_evt:
                if cur is not self.idle:
                    cur.remaining -= max(0.0, t_end - start)
                self.now = t_end
                return
            if cur is not self.idle and t > start:
                cur.remaining -= t - start
            self.now = t
            if done <= t and done <= next_tick and done <= next_evt:
                cur.remaining = 0.0
                self._advance_current()
            elif next_evt <= next_tick:
                _, _, fn = heapq.heappop(self.events)
                fn(self)
                if self.current.remaining <= 0:
                    self._advance_current()
            else:
                self.exact_ticks += 1
                self._tick_isr()
                if self.current.remaining <= 0:
                    self._advance_current()

    def _resume_pending(self, now: float) -> bool:
        return self._resume_at > now

    # ------------------------------------------------------------------ fast path

    _no_fast_before = 0

    def _try_fast(self, t_end: float) -> None:
        """Run whole ticks with numpy while the CPU is idle between periodic releases."""
        k0 = self.tick + 1  # the first tick to process
        if k0 < self._no_fast_before:
            return
        for t in self.ready.get(self.idle.priority, ReadyList()).items:
            if t is not self.idle:
                return
        for p in self._prios:
            if p != self.idle.priority and self.ready[p].items:
                return
        # The run ends at the first tick that needs the exact path.
        limit = math.floor(t_end / self.tick_us)
        if self.events:
            limit = min(limit, math.floor(self.events[0][0] / self.tick_us))
        tasks = []
        for wake, _, task in self.delayed:
            if wake >= limit:
                break
            fast = task.fast
            if fast is None or (fast.valid is not None and not fast.valid()):
                limit = wake
                break
            tasks.append(task)
        if limit - k0 < 2:
            return
        fast_run(self, k0, limit, [t for t in tasks if t.wake_tick < limit])


def fast_run(k: Kernel, k0: int, k_end: int, tasks: list[Task]) -> None:
    """Process ticks k0 .. k_end-1 in bulk (see the module docstring); stops early at an irregular tick."""
    tick_us = k.tick_us
    if not tasks:
        # Nothing wakes: the idle task runs on.
        k.tick = k_end - 1
        k.now = max(k.now, (k_end - 1) * tick_us + k.isr_us)
        k.fast_ticks += k_end - k0
        return
    job_tick, job_task, k_end = _release_sequence(k, tasks, k0, k_end)  # per job: tick, index into tasks
    n = len(job_tick)
    if n == 0:
        k.tick = k_end - 1
        k.now = max(k.now, (k_end - 1) * tick_us)
        k.fast_ticks += k_end - k0
        return
    # Durations in each task's own stream order.
    d = np.empty(n)
    counts = np.bincount(job_task, minlength=len(tasks))
    for i, task in enumerate(tasks):
        if counts[i]:
            d[job_task == i] = task.fast.durations.peek(int(counts[i]))
    sw = k.switch_us
    isr = k.isr_us
    # Per tick: first job starts at T + isr + sw; each job's switch-out at its end; next job + sw.
    new_tick = np.empty(n, dtype=bool)
    new_tick[0] = True
    new_tick[1:] = job_tick[1:] != job_tick[:-1]
    step = d + sw
    cs = np.cumsum(step)
    start_idx = np.flatnonzero(new_tick)
    base = np.repeat(cs[start_idx] - step[start_idx], np.diff(np.append(start_idx, n)))
    tick_t = job_tick * tick_us
    t_switch_in = tick_t + isr + (cs - step - base)  # the switch that brings the job in
    t_end_job = t_switch_in + step  # its switch-out
    last_idx = np.append(start_idx[1:] - 1, n - 1)
    burst_end = t_end_job[last_idx] + sw  # the idle task's switch-in stamp
    next_tick_t = (job_tick[last_idx] + 1) * tick_us
    bad = np.flatnonzero(burst_end >= next_tick_t)
    if len(bad):
        first_bad_tick = int(job_tick[last_idx[bad[0]]])
        cut = int(start_idx[bad[0]])  # jobs before the bad tick
        k_end = first_bad_tick
        k._no_fast_before = first_bad_tick + 1  # do not retry until the overloaded tick is past
        if cut == 0:
            if k_end - 1 >= k0:
                k.tick = k_end - 1
                k.now = max(k.now, (k_end - 1) * tick_us)
                k.fast_ticks += k_end - k0
            return
        n = cut
        job_tick, job_task, d = job_tick[:n], job_task[:n], d[:n]
        t_switch_in, t_end_job, new_tick = t_switch_in[:n], t_end_job[:n], new_tick[:n]
        start_idx = start_idx[: bad[0]]
        last_idx = last_idx[: bad[0]]
        counts = np.bincount(job_task, minlength=len(tasks))
    # Commit: consume draws, advance tasks, charge run time, record stamps.
    units = RUNTIME_UNIT_US
    idle = k.idle
    first_in = t_switch_in[start_idx]
    last_out = t_end_job[last_idx]
    for i, task in enumerate(tasks):
        c = int(counts[i])
        if not c:
            continue
        task.fast.durations.consume(c)
        sel = job_task == i
        ti, to = t_switch_in[sel], t_end_job[sel]
        task.runtime_us += float(np.sum(to - ti))
        task.runtime_units += int(np.sum(np.floor(to / units) - np.floor(ti / units)))
        task.slices += c
    # Idle: from its last switch-in to the first burst, then between bursts.
    idle_in = np.concatenate(([idle.in_at], last_out))
    idle_out = np.concatenate((first_in, [np.nan]))[:-1]
    idle.runtime_us += float(np.sum(idle_out - idle_in[:-1]))
    idle.runtime_units += int(np.sum(np.floor(idle_out / units) - np.floor(idle_in[:-1] / units)))
    idle.in_at = float(last_out[-1])
    idle.slices += len(start_idx)
    if k.sampling:
        _record_fast(k, tasks, job_task, t_switch_in, t_end_job, new_tick, start_idx, last_idx)
    # Re-insert the tasks into the delayed list with their next wake ticks, in the order the
    # exact path would have (by the tick and position of their last job).
    last_job = {}
    for j in range(n - 1, -1, -1):
        ti = int(job_task[j])
        if ti not in last_job:
            last_job[ti] = j
            if len(last_job) == len(tasks):
                break
    k.delayed = [e for e in k.delayed if e[2] not in tasks or int(counts[tasks.index(e[2])]) == 0]
    for ti, j in sorted(last_job.items(), key=lambda kv: kv[1]):
        task = tasks[ti]
        k._seq += 1
        task.seq = k._seq
        task.wake_tick = int(job_tick[j]) + task.fast.period
        k.delayed.append((task.wake_tick, task.seq, task))
    k.delayed.sort(key=lambda e: e[:2])
    k.tick = k_end - 1
    k.now = max(float(last_out[-1]) + sw, (k_end - 1) * tick_us)
    k._resume_at = k.now
    k.fast_ticks += k_end - k0


def _record_fast(k, tasks, job_task, t_in, t_out, new_tick, start_idx, last_idx) -> None:
    n = len(job_task)
    m = len(start_idx)
    sw = k.switch_us
    ids = np.array([t.stamp_id for t in tasks], dtype=np.int16)[job_task]
    hooked = np.array([t.hooked for t in tasks])[job_task]
    idle_id = k.idle.stamp_id
    # Per tick: IDLE out, (job in, job out)*, IDLE in. Build in one array of 2n + 2m entries.
    total = 2 * n + 2 * m
    t = np.empty(total)
    sid = np.empty(total, dtype=np.int16)
    b = np.empty(total, dtype=bool)
    keep = np.ones(total, dtype=bool)
    tick_of_job = np.cumsum(new_tick) - 1  # 0..m-1
    pos_in = 2 * np.arange(n) + 1 + 2 * tick_of_job  # IDLE-out slots before each tick's jobs
    t[pos_in] = t_in + sw
    sid[pos_in] = ids
    b[pos_in] = True
    t[pos_in + 1] = t_out
    sid[pos_in + 1] = ids
    b[pos_in + 1] = False
    keep[pos_in] = hooked
    keep[pos_in + 1] = hooked
    first_pos = pos_in[start_idx] - 1
    t[first_pos] = t_in[start_idx]
    sid[first_pos] = idle_id
    b[first_pos] = False
    last_pos = pos_in[last_idx] + 2
    t[last_pos] = t_out[last_idx] + sw
    sid[last_pos] = idle_id
    b[last_pos] = True
    if not keep.all():
        t, sid, b = t[keep], sid[keep], b[keep]
    k._flush_lists()
    k._chunks.append((t, sid, b))
    k.ctx_switches += len(t)


def _release_sequence(k: Kernel, tasks: list[Task], k0: int, k_end: int):
    """Jobs released in ticks [k0, k_end) in execution order: ``(ticks, task indices, k_end)``.

    Within a tick: priority first, then delayed-list order (wake tick, insertion
    sequence); a task re-inserts after its job, so the order is periodic. The
    release pattern is simulated until its relative state repeats, then tiled.
    ``k_end`` may come back smaller when no repetition was found in time.
    """
    idx = {id(t): i for i, t in enumerate(tasks)}
    periods = [t.fast.period for t in tasks]
    prio = [t.priority for t in tasks]
    state = sorted((t.wake_tick, t.seq, idx[id(t)]) for t in tasks)
    ticks: list[int] = []
    order: list[int] = []
    seq = max(t.seq for t in tasks)
    seen: dict[tuple, tuple[int, int]] = {}
    cycle = None
    steps = 0
    tick = k0
    while True:
        nxt = state[0][0]
        if nxt >= k_end:
            break
        tick = max(nxt, k0)
        released = [s for s in state if s[0] <= tick]
        state = [s for s in state if s[0] > tick]
        released.sort(key=lambda s: (-prio[s[2]], s[0], s[1]))
        for s in released:
            ticks.append(tick)
            order.append(s[2])
            seq += 1
            state.append((tick + periods[s[2]], seq, s[2]))
        state.sort()
        key = tuple((w - tick, i) for w, _, i in state)
        if key in seen:
            cycle = (*seen[key], tick, len(ticks))
            break
        seen[key] = (tick, len(ticks))
        steps += 1
        if steps > 4096:  # no short cycle: run the simulated part only
            k_end = tick + 1
            break
    ticks_a = np.array(ticks, dtype=np.int64)
    order_a = np.array(order, dtype=np.int64)
    if cycle is not None:
        t_prev, n_prev, t_now, n_now = cycle
        period = t_now - t_prev
        pat_rel = ticks_a[n_prev:n_now] - t_prev  # in (0, period]
        pat_order = order_a[n_prev:n_now]
        reps = (k_end - t_now) // period + 1
        future = (t_now + np.arange(reps, dtype=np.int64)[:, None] * period + pat_rel[None, :]).ravel()
        future_order = np.tile(pat_order, reps)
        keep = future < k_end
        ticks_a = np.concatenate((ticks_a, future[keep]))
        order_a = np.concatenate((order_a, future_order[keep]))
    return ticks_a, order_a, k_end
