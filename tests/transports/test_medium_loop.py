"""What every medium run by a thread of its own shares (LoopMedium): timers, the thread, start and stop."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from hilbench.pytest_plugin import wait_until
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.datagram_medium import DatagramMedium
from hilbench.transports.medium_loop import LoopMedium
from hilbench.transports.serial_medium import SerialMedium

MEDIA = {
    "serial": lambda paced: SerialMedium("line", 115_200, paced=paced, realtime=False),
    "can": lambda paced: CanMedium("can", 500_000, paced=paced),
    "udp": lambda paced: DatagramMedium("net", paced=paced),
}


@pytest.fixture(params=[(kind, paced) for kind in MEDIA for paced in (False, True)],
                ids=lambda p: f"{p[0]}-{'paced' if p[1] else 'unpaced'}")
def medium(request):
    kind, paced = request.param
    m = MEDIA[kind](paced)
    assert isinstance(m, LoopMedium)
    m.start()
    yield m
    m.close()


def test_start_returns_once_the_thread_runs_and_says_what_it_runs_under(medium):
    assert medium.scheduling == "SCHED_OTHER"  # (none of these asks for SCHED_FIFO)
    if medium.paced:
        assert medium.cpu_latency == "0 us" or medium.cpu_latency.startswith("not ")
    else:
        assert medium.cpu_latency is None
    assert not medium.in_medium_thread()
    inside = []
    medium.call_at(None, lambda: inside.append(medium.in_medium_thread()))
    assert wait_until(lambda: inside == [True])


def test_a_failing_timer_is_counted_and_the_medium_keeps_running(medium, caplog):
    ran = []
    t = time.monotonic() + 0.01

    def fail():
        raise RuntimeError("a device's bug")

    with caplog.at_level(logging.ERROR):
        medium.call_at(t, fail)
        for i in range(3):  # equal times run in the order they were queued
            medium.call_at(t, lambda i=i: ran.append(i))
        assert wait_until(lambda: len(ran) == 3)
    assert ran == [0, 1, 2]
    assert medium.stats.callback_errors == 1
    assert "a device's bug" in caplog.text
    medium.call_at(None, lambda: ran.append("later"))  # the thread is still there
    assert wait_until(lambda: ran[-1] == "later")


def test_timers_queued_in_the_medium_thread_run_too(medium):
    ran = threading.Event()
    medium.call_at(None, lambda: medium.call_at(time.monotonic() + 0.005, ran.set))
    assert ran.wait(2)


def test_stop_and_start_again():
    line = SerialMedium("line", 115_200)
    line.start()
    line.stop()
    assert line._thread is None and not line.in_medium_thread()
    ran = threading.Event()
    line.call_at(None, ran.set)  # queued while stopped: runs once the thread is back
    line.start()
    try:
        assert ran.wait(2)
    finally:
        line.close()
