"""The FreeRTOS-like kernel: preemption, time slicing, delayed-list order, run-time counters, fast path."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from hilbench.fakes.stm32_board.kernel import DELAY_UNTIL, RUN, WAIT, Durations, Kernel, Periodic, Task
from hilbench.fakes.stm32_board.presets import Timing


def make(tick_hz=1000):
    k = Kernel(tick_hz, isr_us=0.0, switch_us=0.0)
    idle = Task("IDLE", 0, 99, 0)
    k.add_task(idle, None, idle=True)
    k._make_ready(idle)
    return k


def periodic(task, period, first, dur):
    yield (DELAY_UNTIL, first)
    while True:
        yield (RUN, dur)
        yield (DELAY_UNTIL, task.wake_tick + period)


def trace(k):
    t, sid, b = k.take_stamps()
    names = {task.stamp_id: task.name for task in k.tasks}
    return [(round(float(x), 3), names[int(i)], bool(e)) for x, i, e in zip(t, sid, b, strict=True)]


def test_equal_priority_waits_for_the_next_tick_higher_priority_preempts_at_once():
    k = make()
    long = Task("long", 24, 1, 1)
    short = Task("short", 24, 2, 2)
    high = Task("high", 32, 3, 3)
    k.add_task(long, periodic(long, 100, 1, 2500.0))  # released at tick 1, computes 2.5 ticks
    k.add_task(short, periodic(short, 100, 2, 10.0))  # released at tick 2 while long runs

    def waiter(task):
        while True:
            yield (WAIT,)
            yield (RUN, 5.0)

    k.add_task(high, waiter(high))
    k.start()
    k.sampling = True
    k.at(1200.0, lambda kk: kk.notify_from_isr(high))  # an ISR wakes the high-priority task mid-slice
    k.run_until(5000)
    got = trace(k)
    assert got[:10] == [
        (1000.0, "IDLE", False), (1000.0, "long", True),
        (1200.0, "long", False), (1200.0, "high", True), (1205.0, "high", False), (1205.0, "long", True),
        (2000.0, "long", False), (2000.0, "short", True),  # time slicing at the tick: short gets its turn
        (2010.0, "short", False), (2010.0, "long", True),
    ]
    assert got[10:12] == [(3515.0, "long", False), (3515.0, "IDLE", True)]  # 2500 µs of its work + 15 of others
    assert long.runtime_us == pytest.approx(2500.0)


def test_tasks_released_together_run_in_delayed_list_order():
    k = make(10_000)
    tasks = {}
    for num, (name, period) in enumerate((("hal_fetch", 2), ("pose_control", 5), ("wheel_ctrl", 2),
                                           ("odometry", 5)), start=1):
        t = Task(name, 24, num, num)
        k.add_task(t, periodic(t, period, period, 5.0))
        tasks[name] = t
    k.start()
    k.run_until(9_000)  # let the insertion order settle
    k.sampling = True
    k.run_until(10_050)
    order = [n for t, n, b in trace(k) if b and n != "IDLE" and t >= 10_000]
    # At a tick shared by both rates the pose tasks (which went to sleep earlier) come first (listing 38).
    assert set(order[:2]) == {"pose_control", "odometry"} and order[2:] == ["hal_fetch", "wheel_ctrl"]


def test_run_time_counters_use_tim13_units():
    k = make()
    t = Task("busy", 24, 1, 1)
    k.add_task(t, periodic(t, 1, 1, 500.0))
    k.start()
    k.run_until(1_000_000.0)
    assert t.runtime_us == pytest.approx(999 * 500.0, rel=1e-6)
    # Counted per slice in ≈92.6 µs units: the sum is close to the time over the unit.
    assert abs(t.runtime_units - t.runtime_us / (10001 / 108)) < 999 * 0.5 + 2


def test_fast_path_matches_the_exact_path_and_is_used():
    (fast_st, fast_k), (exact_st, exact_k) = run_fast_and_exact(
        lambda: control_kernel((("hal", 1, 6.6), ("wheel", 1, 10.7), ("pose", 2, 9.9), ("odo", 2, 6.8),
                                ("poll", 10, 3.0)), prio={"poll": 32}), 300_000)
    assert fast_k.fast_ticks > 2900 and exact_k.fast_ticks == 0
    assert_same_stamps(fast_st, exact_st)
    assert units(fast_k) == units(exact_k)
    assert runtimes(fast_k) == pytest.approx(runtimes(exact_k), abs=1e-6)


def test_fast_path_with_a_long_computation_in_the_background():
    """A prio-24 task formatting for milliseconds interleaves with the control ticks (time slicing)."""

    def build():
        k = control_kernel((("hal", 1, 6.6), ("wheel", 1, 10.7), ("pose", 2, 9.9)))
        add_background(k, Timing(1500.0, sd_us=300.0), every=50)  # e.g. formatting a batch of lines
        return k

    (fast_st, fast_k), (exact_st, exact_k) = run_fast_and_exact(build, 200_000)
    assert fast_k.fast_ticks > 1000, (fast_k.fast_ticks, fast_k.exact_ticks)  # background phases ran fast too
    assert_same_stamps(fast_st, exact_st)
    assert units(fast_k) == units(exact_k)


def add_background(k: Kernel, timing: Timing, every: int) -> Task:
    """The prio-24 ``profile`` task (id 7): a drawn computation, then a delay of ``every`` ticks, forever."""
    worker = Task("profile", 24, 7, 7)
    worker.durations = Durations(timing, seed=7)

    def work(task=worker):
        while True:
            yield (RUN, task.durations.draw())
            yield (DELAY_UNTIL, task.wake_tick + every)

    k.add_task(worker, work())
    return worker


def add_waiter(k: Kernel, task: Task, run_us: float | None = None) -> Task:
    """``task`` waits for a notification, then computes ``run_us`` (None: a draw of its durations), forever."""

    def waiter():
        while True:
            yield (WAIT,)
            yield (RUN, task.durations.draw() if run_us is None else run_us)

    k.add_task(task, waiter())
    return task


def run_fast_and_exact(build, until: int) -> list[tuple[tuple, Kernel]]:
    """Run a kernel ``build()`` makes to tick time ``until`` on the fast path, then one on the exact path
    only; ``[(stamps, kernel) fast, (stamps, kernel) exact]``."""
    runs = []
    for fast in (True, False):
        k = build()
        k.fast_enabled = fast
        k.start()
        k.sampling = True
        k.run_until(until)
        runs.append((k.take_stamps(), k))
    return runs


def assert_same_stamps(stamps, exact) -> None:
    """Times agree to float rounding (cumulative sums against step-by-step sums); ids and edges exactly."""
    assert len(stamps[0]) == len(exact[0])
    assert np.allclose(stamps[0], exact[0], rtol=0, atol=1e-6)
    assert np.array_equal(stamps[1], exact[1]) and np.array_equal(stamps[2], exact[2])


def units(k: Kernel) -> list[int]:
    """Each task's run time in TIM13 units."""
    return [t.runtime_units for t in k.tasks]


def runtimes(k: Kernel) -> list[float]:
    """Each task's run time in µs."""
    return [t.runtime_us for t in k.tasks]


def periodic_drawn(task, period):
    yield (DELAY_UNTIL, period)
    while True:
        yield (RUN, task.durations.draw())
        yield (DELAY_UNTIL, task.wake_tick + period)



def control_kernel(tasks, *, isr_us: float = 0.6, prio: dict[str, int] | None = None) -> Kernel:
    """A 10 kHz kernel with IDLE and periodic tasks ``(name, period in ticks, Timing or mean µs)``, numbered
    from 1, for comparing the fast path with the exact simulation."""
    k = Kernel(10_000, isr_us=isr_us, switch_us=0.4)
    idle = Task("IDLE", 0, 9, 0)
    k.add_task(idle, None, idle=True)
    k._make_ready(idle)
    for num, (name, period, timing) in enumerate(tasks, start=1):
        t = Task(name, (prio or {}).get(name, 24), num, num)
        t.durations = Durations(timing if isinstance(timing, Timing) else Timing(timing), seed=num)
        t.fast = Periodic(period, t.durations)
        k.add_task(t, periodic_drawn(t, period))
    return k


def assert_slices_in_order(stamps) -> None:
    """Stamps are in time order, and each task's begins and ends alternate with no end before its begin."""
    t, sid, b = stamps
    assert len(t) > 0
    assert np.all(np.diff(t) >= 0), f"stamps out of time order at {np.flatnonzero(np.diff(t) < 0)[:5]}"
    for i in np.unique(sid):
        edges, times = b[sid == i], t[sid == i]
        assert not np.any(edges[1:] == edges[:-1]), f"stamp id {i}: two begins or two ends in a row"
        first_begin = 0 if edges[0] else 1
        begins, ends = times[first_begin::2], times[first_begin + 1 :: 2]
        assert np.all(ends >= begins[: len(ends)]), f"stamp id {i}: a slice ends before it begins"


def test_a_slice_shorter_than_a_switch_never_ends_before_it_begins():
    """A task that blocks again at once (V1's profile task at the button press) or is preempted by an ISR
    during its own switch-in: its switch-out comes after its switch-in stamp, and the stamps stay in order."""
    k = Kernel(1000, isr_us=0.6, switch_us=0.4)
    idle = Task("IDLE", 0, 9, 0)
    k.add_task(idle, None, idle=True)
    k._make_ready(idle)
    flusher = Task("profile", 24, 1, 1)
    high = Task("high", 32, 2, 2)
    work = Task("work", 24, 3, 3)

    def flush(task):
        while True:
            yield (WAIT,)
            yield (DELAY_UNTIL, k.tick + 1)  # no computation before blocking (nor after): zero-length slices

    def waiter(task):
        while True:
            yield (WAIT,)
            yield (RUN, 5.0)

    k.add_task(flusher, flush(flusher))
    k.add_task(high, waiter(high))
    k.add_task(work, periodic(work, 2, 4, 20.0))
    k.fast_enabled = False
    k.start()
    k.sampling = True
    k.at(1500.0, lambda kk: kk.notify_from_isr(flusher))  # IDLE -> profile, which blocks at once
    # work is switched in at 4000.6 (tick ISR); an ISR 0.1 µs later, inside the switch, wakes high.
    k.at(4000.7, lambda kk: kk.notify_from_isr(high))
    k.run_until(10_000)
    stamps = k.take_stamps()
    assert_slices_in_order(stamps)
    t, sid, b = stamps
    prof = t[sid == flusher.stamp_id]
    # Woken at 1500 (switch-in 1500.4) and at tick 2 (switch at 2000.6, in at 2001.0): out as soon as in.
    assert prof.tolist() == pytest.approx([1500.4, 1500.4, 2001.0, 2001.0])
    w = t[sid == work.stamp_id]
    assert w[0] == pytest.approx(4001.0) and w[1] == pytest.approx(4001.0)  # switched out as its switch-in ends


@pytest.mark.parametrize("isr_us", [0.6, 0.0])
def test_fast_path_equals_exact_with_short_jobs_and_a_switch_that_ends_after_the_tick(isr_us):
    """Jobs shorter than a context switch (down to 0 µs), and ISR-woken tasks that leave the idle task's
    switch-in unfinished when the next tick comes (possible when the tick ISR is shorter than a switch):
    the fast path gives the exact path's stamps and run times, and both keep slices in order."""

    def build():
        k = control_kernel((("zero", 1, Timing(0.0, dist="fixed")), ("short", 2, Timing(0.2, dist="fixed")),
                            ("wheel", 1, Timing(10.7))), isr_us=isr_us)
        high = add_waiter(k, Task("isr_task", 32, 4, 4), 0.0)
        for ms in range(1, 50):  # woken 0.5 µs before a tick: idle's switch-in ends 0.3 µs after it
            k.at(ms * 1000 - 0.5, lambda kk, high=high: kk.notify_from_isr(high))
        return k

    (st, k), (exact_st, exact_k) = run_fast_and_exact(build, 50_000)
    assert_slices_in_order(exact_st)
    assert_slices_in_order(st)
    assert k.fast_ticks > 400
    assert_same_stamps(st, exact_st)
    assert units(k) == units(exact_k)
    assert runtimes(k) == pytest.approx(runtimes(exact_k), abs=1e-6)


def test_fast_path_equals_exact_when_the_background_resumes_after_a_tick():
    """An overloaded tick's burst (exact path) ends 0.3 µs before the next tick, so the background task's
    switch-in completes after it; the fast run that starts there must not credit the background with
    negative computing time before its first burst."""

    def build():
        # Every 10th tick: a (90 µs) and b (8.3 µs) end at T + 99.7, the background is back in at T + 100.1.
        k = control_kernel((("a", 10, Timing(90.0, dist="fixed")), ("b", 1, Timing(8.3, dist="fixed"))))
        add_background(k, Timing(3000.0, sd_us=300.0), every=100)
        return k

    (st, k), (exact_st, exact_k) = run_fast_and_exact(build, 100_000)
    assert k.fast_ticks > 200, k.fast_ticks
    assert_slices_in_order(st)
    assert_same_stamps(st, exact_st)
    assert runtimes(k) == pytest.approx(runtimes(exact_k), abs=1e-6)


def test_fast_path_equals_exact_with_events_between_and_inside_bursts():
    """ISR events at random times (like DMA completions waking tsink) while a long computation runs
    in the background: a run takes the event's tick when its burst is over before the event."""
    rng = np.random.default_rng(5)
    times = np.sort(rng.uniform(1_000, 199_000, 300))

    def build():
        k = control_kernel((("hal", 1, 6.6), ("wheel", 1, 10.7), ("pose", 2, 9.9)))
        sink = Task("tsink", 32, 4, 4)
        sink.durations = Durations(Timing(3.0), seed=4)
        add_waiter(k, sink)
        add_background(k, Timing(700.0, sd_us=200.0), every=30)
        for t_ev in times:
            k.at(float(t_ev), lambda kk, sink=sink: kk.notify_from_isr(sink))
        return k

    (st, k), (exact_st, exact_k) = run_fast_and_exact(build, 200_000)
    assert k.fast_ticks > 1000, k.fast_ticks
    assert_slices_in_order(st)
    assert_same_stamps(st, exact_st)
    assert units(k) == units(exact_k)
    assert runtimes(k) == pytest.approx(runtimes(exact_k), abs=1e-6)


@pytest.mark.parametrize("first", ["kernel", "fast_path"])
def test_the_kernel_and_its_fast_path_import_in_either_order(first):
    """The kernel imports its fast path; the fast path names the kernel's types in annotations only (no import
    circle: whichever is imported first, both load)."""
    code = (f"import hilbench.fakes.stm32_board.{first}; "
            "from hilbench.fakes.stm32_board.kernel import fast_run, Kernel; "
            "from hilbench.fakes.stm32_board import fast_path; assert fast_run is fast_path.fast_run")
    subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", code], check=True)

