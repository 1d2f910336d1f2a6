"""Precise waits (the Waiter that learns this machine's wake-up lateness) and the idle-CPU latency request."""

from __future__ import annotations

import os
import resource
import struct
import threading
import time

import pytest

from hilbench.transports.clock import CPU_DMA_LATENCY, CpuLatency, Waiter, wait
from hilbench.transports.readiness import Readiness, readable


@pytest.fixture
def pipe():
    r, w = os.pipe()
    yield r, w
    os.close(r)
    os.close(w)


def test_waiter_never_returns_before_its_deadline_and_learns_to_ask_early(pipe):
    r, _ = pipe
    waiter = Waiter()
    late = []
    for _ in range(50):
        deadline = time.monotonic() + 300e-6
        assert waiter([r], deadline) == []
        late.append(time.monotonic() - deadline)
    assert min(late) >= 0  # at the deadline or after, never before
    # A timed wait is always somewhat late: the waiter has measured that and now asks early by it
    assert 0 < waiter.early <= Waiter.MAX_EARLY


def test_waiter_returns_at_once_on_input(pipe):
    r, w = pipe
    waiter = Waiter()
    threading.Timer(0.02, os.write, (w, b"x")).start()
    t0 = time.monotonic()
    assert waiter([r], t0 + 5) == [r]
    assert time.monotonic() - t0 < 1
    assert waiter([r], None) == [r]  # no deadline: waits for input only (it is still there)


def _system_latency() -> int | None:
    """The kernel's current PM QoS CPU latency (readable by root only)."""
    try:
        fd = os.open(CPU_DMA_LATENCY, os.O_RDONLY)
    except OSError:
        return None
    try:
        return struct.unpack("=i", os.read(fd, 4))[0]
    finally:
        os.close(fd)


def test_cpu_latency_is_held_while_a_holder_wants_it(monkeypatch):
    monkeypatch.setenv("HILBENCH_CPU_LATENCY_US", "0")
    others = CpuLatency._users  # paced lines still running in this process (none, normally)
    first = CpuLatency.hold()
    try:
        if not os.access(CPU_DMA_LATENCY, os.W_OK):  # not root: nothing changes, and the answer says why
            assert first.startswith("not granted (/dev/cpu_dma_latency")
            return
        assert first == "0 us"
        assert CpuLatency.hold() == "0 us"  # a second line shares the one request
        CpuLatency.release()
        assert _system_latency() == 0  # still held by the first
    finally:
        CpuLatency.release()
    if not others:
        assert CpuLatency._fd is None  # the last release ends the request: idle CPUs may sleep again


def test_cpu_latency_can_be_turned_off(monkeypatch):
    monkeypatch.setenv("HILBENCH_CPU_LATENCY_US", "off")
    if CpuLatency._users:
        pytest.skip("a paced line of an earlier test still holds the request")
    try:
        assert CpuLatency.hold() == "not requested (HILBENCH_CPU_LATENCY_US=off)"
        assert CpuLatency._fd is None
    finally:
        CpuLatency.release()
    monkeypatch.setenv("HILBENCH_CPU_LATENCY_US", "25")
    assert CpuLatency.setting() == (25, "")
    monkeypatch.setenv("HILBENCH_CPU_LATENCY_US", "fast")  # a typo asks for nothing, and says why
    try:
        assert CpuLatency.hold() == ("not requested (HILBENCH_CPU_LATENCY_US='fast' is neither a number of "
                                     "microseconds nor off)")
        assert CpuLatency._fd is None
    finally:
        CpuLatency.release()


def test_waiter_does_not_spin_towards_a_far_deadline(pipe):
    r, _ = pipe
    waiter = Waiter()
    t0 = time.monotonic()
    cpu0 = time.thread_time()
    assert waiter([r], t0 + 10, idle=0.2) == []  # back after idle, long before the deadline
    assert time.monotonic() - t0 < 1
    assert time.thread_time() - cpu0 < 0.1  # slept, did not poll the clock


def test_a_waiter_leaving_the_cpu_sleeps_to_a_near_deadline_instead_of_polling(pipe):
    r, _ = pipe
    waiter = Waiter()
    for _ in range(40):  # learn this machine's lateness first, so that waits ask early and poll the rest
        waiter([r], time.monotonic() + 300e-6)
    polls = waiter.polls
    for _ in range(20):
        deadline = time.monotonic() + waiter.early + Waiter.MIN_SLEEP / 2  # too near for an early sleep
        assert waiter([r], deadline, leave_cpu=True) == []
        assert time.monotonic() >= deadline  # still never early
    assert waiter.polls == polls  # every one of them slept (left the CPU to whoever needed it)
    # A far deadline is waited for as usual (an early sleep leaves the CPU anyway), and input still ends it
    deadline = time.monotonic() + 0.002
    assert waiter([r], deadline, leave_cpu=True) == []
    assert time.monotonic() >= deadline


def test_a_deadline_already_passed_still_looks_at_the_descriptors(pipe):
    # A loop whose timed work is always behind (a cyclic job it cannot keep up with) calls every wait with a
    # deadline in the past: it must still hear its clients (it went deaf once: no greeting for a minute).
    r, w = pipe
    os.write(w, b"x")
    past = time.monotonic() - 1.0
    waiter = Waiter()
    assert waiter([r], past) == [r]
    assert wait([r], past) == [r]
    os.read(r, 1)
    assert waiter([r], past) == []  # and returns at once when nothing is there
    assert wait([r], past) == []


@pytest.fixture
def high_pipe():
    """A pipe whose read end is numbered above select()'s FD_SETSIZE (1024)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1400:
        pytest.skip(f"the descriptor limit ({hard}) is below 1400")
    if soft < 1400:
        resource.setrlimit(resource.RLIMIT_NOFILE, (1400, hard))
    r, w = os.pipe()
    high = os.dup2(r, 1300)
    os.close(r)
    try:
        yield high, w
    finally:
        os.close(high)
        os.close(w)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def test_waits_work_for_descriptors_beyond_1023(high_pipe):
    r, w = high_pipe
    waiter = Waiter()
    assert waiter([r], time.monotonic() + 300e-6) == []
    assert wait([r], time.monotonic() + 300e-6) == []
    assert waiter([r], None, idle=0.01) == []
    os.write(w, b"x")
    assert waiter([r], time.monotonic() + 5) == [r]
    assert waiter([r], time.monotonic() + 0.001, leave_cpu=True) == [r]
    assert wait([r], None) == [r]
    assert readable([r], 0) == [r]


def test_readiness_rebuilt_for_a_new_list_and_reports_each_descriptor_once(pipe):
    r, w = pipe
    r2, w2 = os.pipe()
    try:
        waiter = Waiter()
        assert waiter([r], time.monotonic() + 0.001) == []
        os.write(w2, b"x")
        assert waiter([r, r2, r2], time.monotonic() + 1) == [r2]  # the new list counts (once per descriptor)
        assert Readiness([r, r2]).wait(0.5) == [r2]
    finally:
        os.close(r2)
        os.close(w2)
