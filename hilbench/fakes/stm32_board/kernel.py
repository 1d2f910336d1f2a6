"""A FreeRTOS-like fixed-priority preemptive kernel in virtual time: the exact path.

A discrete-event simulation of the kernel. Tasks are generators
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

Whenever only periodic tasks interrupt the running task, :meth:`Kernel.run_until`
hands whole runs of ticks to the vectorised fast path
(:func:`hilbench.fakes.stm32_board.fast_path.fast_run`, which names this
module's types in annotations only).
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections.abc import Callable, Generator
from dataclasses import dataclass

import numpy as np

from hilbench.fakes.stm32_board.fast_path import fast_run
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
