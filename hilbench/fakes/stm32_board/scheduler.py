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
time later, the switch-in stamp of the new one (a switch requested before the
previous one has finished waits for it, so no slice ends before it begins),
and charges run time the way the kernel's run-time statistics do (sampled at
each switch, counted in TIM13 units of ≈92.6 µs).

Fast path: when the running task is the idle task or a long computation (the
background) and every task that will be ready before the next irregular
event (an ISR, a task without a periodic model) is periodic, the kernel
generates whole runs of ticks with numpy: the release order per tick comes
from the ready and delayed lists (replayed once per relative start state until
it repeats, then tiled, and cached), execution times are drawn in bulk from
each task's own random stream, and the switch times of every tick's burst
follow from one cumulative sum; stamps, run-time counters and the
background's progress follow from those. A run ends at the first tick that
needs the exact path: a burst that would run into the next tick (overload),
the tick where the background finishes, an event (whose tick is included
when its burst is over before the event) or a task whose model does not
hold. Both paths draw from the same per-task streams in the same order, so
tests can prove they produce the same stamps and the same output bytes.
"""

from __future__ import annotations

import bisect
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
        #: No draw is longer (normal draws are clipped to max_us, fixed ones are the mean).
        self.longest = t.mean_us if t.dist == "fixed" or not t.sd_us else max(t.max_us, t.min_us)
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
        """The next ``n`` draws, without taking them."""
        if len(self._buf) - self._pos < n:
            self._fill(n)
        return self._buf[self._pos : self._pos + n]

    def consume(self, n: int) -> None:
        """Take ``n`` draws (after :meth:`peek`)."""
        if len(self._buf) - self._pos < n:
            self._fill(n)
        self._pos += n


@dataclass
class Periodic:
    """A task's fast model: each time it is selected it computes one RUN drawn from ``durations``,
    then calls ``vTaskDelayUntil(wake + period)`` (``relative=False``: blocks, or only yields when
    that tick has passed) or ``vTaskDelay(period)`` (``relative=True``). The generator must be
    suspended at that delay (or ready right after it) whenever the model is set."""

    period: int
    durations: Durations
    #: Whether the model still holds when a fast run starts (e.g. "the ring is still empty").
    valid: Callable[[], bool] | None = None
    relative: bool = False


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
        self._patterns: dict[tuple, tuple] = {}  # release patterns by relative start state
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

    def function_stamp(self, stamp_id: int, begin: bool) -> None:
        if self.sampling:
            self._st_t.append(max(self.now, self._resume_at))
            self._st_id.append(stamp_id)
            self._st_b.append(begin)

    _EMPTY = (np.zeros(0), np.zeros(0, np.int16), np.zeros(0, bool))

    def take_stamps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All stamps recorded since the last call, in time order: (t µs float, stamp id, begin)."""
        if not self._st_t and not self._chunks:
            return self._EMPTY
        self._flush_lists()
        chunks = self._chunks
        self._chunks = []
        if not chunks:
            return np.zeros(0), np.zeros(0, np.int16), np.zeros(0, bool)
        if len(chunks) == 1:
            return chunks[0]
        return (np.concatenate([c[0] for c in chunks]), np.concatenate([c[1] for c in chunks]),
                np.concatenate([c[2] for c in chunks]))

    def take_chunks(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """:meth:`take_stamps` as the pieces they were recorded in (consecutive, in time order)."""
        if self._st_t:
            self._flush_lists()
        chunks = self._chunks
        self._chunks = []
        return chunks

    def _flush_lists(self) -> None:
        if self._st_t:
            self._chunks.append((np.array(self._st_t), np.array(self._st_id, np.int16), np.array(self._st_b, bool)))
            self._st_t, self._st_id, self._st_b = [], [], []

    @property
    def has_stamps(self) -> bool:
        """Whether stamps were recorded since the last take."""
        return bool(self._st_t or self._chunks)

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

    def _delay_until(self, task: Task, tick: int) -> bool:
        """Block ``task`` until ``tick``; False (and no list change) when that tick has already come."""
        task.wake_tick = tick  # vTaskDelayUntil advances the previous wake time even when already due
        if tick <= self.tick:
            return False
        self.ready[task.priority].remove(task)
        task.state = "blocked"
        task.wake_tick = tick
        self._seq += 1
        task.seq = self._seq
        # (wake tick, sequence number) is unique, so tuple order never compares the tasks.
        bisect.insort(self.delayed, (tick, self._seq, task))
        return True

    # ------------------------------------------------------------------ switching

    def _switch(self, t: float) -> None:
        """Context switch at ``t``: charge the old task, stamp out/in, pick the next task.

        A switch requested before the previous one has finished (the task blocked without
        computing, or an ISR fired during the switch-in) happens when that one ends: the old
        task's switch-out never precedes its own switch-in stamp, so every slice has begin <= end
        and the stamps stay in time order.
        """
        old = self.current
        new = self._select()
        if new is old:
            return
        if t < self._resume_at:
            t = self._resume_at
        t_in = t + self.switch_us  # the new task's switch-in stamp; it starts computing then
        # Charge the old task's run time (TIM13 units sampled at each switch) and stamp both hooks;
        # inlined, as this is the exact path's hottest code.
        u = RUNTIME_UNIT_US
        old.runtime_us += t - old.in_at
        old.runtime_units += math.floor(t / u) - math.floor(old.in_at / u)
        if self.sampling:
            if old.hooked:
                self._st_t.append(t)
                self._st_id.append(old.stamp_id)
                self._st_b.append(False)
                self.ctx_switches += 1
            if new.hooked:
                self._st_t.append(t_in)
                self._st_id.append(new.stamp_id)
                self._st_b.append(True)
                self.ctx_switches += 1
        if old.state == "running":
            old.state = "ready"
        new.state = "running"
        new.in_at = t
        new.slices += 1
        self.current = new
        self._resume_at = t_in

    _resume_at = 0.0

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
                if not self._delay_until(cur, action[1]):
                    # Already due: vTaskDelayUntil does not block but yields (portYIELD_WITHIN_API).
                    self._switch(self.now)
                    if self.current is cur:
                        continue
                    return ()
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
            if self.fast_enabled and (cur is self.idle or cur.remaining > self.tick_us):
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
        """Run whole ticks with numpy while only periodic tasks interrupt the running task.

        The running task is the background: the idle task, or a task in the middle of a long
        computation (e.g. the profiling task formatting lines), which resumes after each tick's
        burst of periodic jobs, as time slicing and priorities make it do. Ready tasks other than
        the background must be periodic ones waiting for their turn (e.g. one release behind).
        """
        k0 = self.tick + 1  # the first tick to process
        if k0 < self._no_fast_before:
            return
        if self._resume_at > k0 * self.tick_us:
            # A switch still in progress at tick k0: the running task has not computed yet, and a switch
            # requested before it completes waits for it (see _switch); the bursts assume neither, so
            # this tick goes the exact way.
            return
        cur = self.current
        if cur is not self.idle and cur.remaining <= 0:
            return
        # Cheap early exits for what ends a run within two ticks anyway (micro-ROS: the executor wakes
        # every tick; network events come every few ticks).
        d = self.delayed
        if d and d[0][0] <= k0 + 1 and d[0][2].fast is None:
            return
        if self.events and self.events[0][0] < (k0 + 2) * self.tick_us:
            return
        tasks = []
        for p in self._prios:
            for t in self.ready[p].items:
                if t is cur or t is self.idle:
                    continue
                fast = t.fast
                if fast is None or t.remaining > 0 or (fast.valid is not None and not fast.valid()):
                    return
                tasks.append(t)
        # The run ends at the first tick that needs the exact path. The tick of the next event may
        # be processed too when its burst is over before the event (the run hands over there).
        limit = math.floor(t_end / self.tick_us)
        until = None
        if self.events:
            t_event = self.events[0][0]
            if math.floor(t_event / self.tick_us) < limit:
                limit = math.floor(t_event / self.tick_us)
                until = t_event
        for wake, _, task in self.delayed:
            if wake > limit or (wake == limit and until is None):
                break
            fast = task.fast
            if fast is None or (fast.valid is not None and not fast.valid()):
                if wake < limit:
                    limit = wake
                until = None
                break
            tasks.append(task)
        if limit - k0 < 2:
            return
        fast_run(self, k0, limit, tasks, cur, until)


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
