"""The VirtualLoop: media, host ports and timers of a bench in virtual time, run in rounds by one thread."""

from __future__ import annotations

import os
import threading
import time

import pytest
import serial

from hilbench.pytest_plugin import wait_until
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.clock import VirtualClock
from hilbench.transports.datagram_medium import DatagramMedium
from hilbench.transports.pty import PtyPort
from hilbench.transports.serial_medium import SerialMedium
from hilbench.transports.virtual_loop import VirtualLoop

T0 = VirtualClock.ORIGIN


class Echo:
    """An in-process device that records what it hears (with the time) and may answer after ``gap``."""

    def __init__(self, name: str, answer: bytes = b"", gap: float = 0.0) -> None:
        self.name = name
        self.answer = answer
        self.gap = gap
        self.got: list[tuple[bytes, float]] = []
        self.port = None

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        self.got.append((data, t))
        if self.answer:
            self.port.transmit(self.answer, t=t, gap=self.gap)


@pytest.fixture
def loop():
    clock = VirtualClock(epoch=1_700_000_000.0)
    lp = VirtualLoop(clock, name="test")
    yield lp
    lp.close()
    for medium in lp.media:
        medium.close()


def test_time_stands_still_when_held_and_moves_only_with_run_for(loop):
    line = SerialMedium("line", 115200, paced=True, clock=loop.clock)
    loop.add(line)
    ran: list[float] = []
    line.call_at(T0 + 1.0, lambda: ran.append(loop.clock.now()))
    loop.start()
    assert loop.run_until(T0, timeout=5) == T0  # the loop has settled this instant: nothing ran
    assert ran == [] and loop.clock.now() == T0
    assert loop.run_for(0.5, timeout=5) == T0 + 0.5
    assert ran == []
    assert loop.run_for(0.5, timeout=5) == T0 + 1.0
    assert ran == [T0 + 1.0]  # at its exact time, and run by the time run_for returns
    assert loop.run_for(58.0, timeout=5) == T0 + 59.0  # nothing due: straight to the target
    assert loop.stats.advances <= 4  # (0.5, 1.0, 59: jumps, not steps)


def test_events_at_one_instant_run_in_the_order_queued_across_media(loop):
    line = SerialMedium("line", 115200, paced=True, clock=loop.clock)
    bus = CanMedium("bus", paced=True, clock=loop.clock)
    net = DatagramMedium("net", clock=loop.clock)
    for medium in (line, bus, net):
        loop.add(medium)
    order: list[str] = []
    t = T0 + 2.0
    bus.call_at(t, lambda: order.append("bus 1"))
    line.call_at(t, lambda: order.append("line 1"))
    loop.call_at(t, lambda: order.append("loop"))
    net.call_at(t, lambda: order.append("net"))
    line.call_at(t - 1.0, lambda: order.append("line earlier"))
    bus.call_at(t, lambda: order.append("bus 2"))
    loop.start()
    loop.run_for(3.0, timeout=5)
    assert order == ["line earlier", "bus 1", "line 1", "loop", "net", "bus 2"]


def test_zero_delay_work_runs_in_more_rounds_at_the_same_instant(loop):
    line = SerialMedium("line", 115200, paced=True, clock=loop.clock)
    loop.add(line)
    seen: list[tuple[str, float]] = []

    def first() -> None:
        seen.append(("first", loop.clock.now()))
        line.call_at(None, lambda: seen.append(("then", loop.clock.now())))  # "now": the same instant

    line.call_at(T0 + 1.0, first)
    loop.start()
    loop.run_for(2.0, timeout=5)
    assert seen == [("first", T0 + 1.0), ("then", T0 + 1.0)]


def test_deliveries_and_replies_come_at_exact_wire_times(loop):
    baud = 115200
    line = SerialMedium("line", baud, paced=True, clock=loop.clock)
    asker, answerer = Echo("asker"), Echo("answerer", answer=b"0123456789", gap=250e-6)
    asker.port = line.add_device(asker)
    answerer.port = line.add_device(answerer)
    loop.add(line)
    loop.start()
    asker.port.call_at(T0 + 1.0, lambda: asker.port.transmit(b"ping!"))
    loop.run_for(2.0, timeout=5)
    byte = 10 / baud
    end = T0 + 1.0 + 5 * byte
    assert answerer.got == [(b"ping!", end)]
    assert asker.got == [(b"0123456789", end + 250e-6 + 10 * byte)]  # no granule, no lateness: the model


def test_a_free_clock_jumps_from_event_to_event_on_its_own(loop):
    line = SerialMedium("line", 115200, paced=True, clock=loop.clock)
    loop.add(line)
    ticks: list[float] = []

    def tick() -> None:
        ticks.append(loop.clock.now())
        if len(ticks) < 100:
            line.call_at(loop.clock.now() + 10.0, tick)  # 1000 virtual seconds in all

    line.call_at(T0 + 10.0, tick)
    loop.free()
    start = time.monotonic()
    loop.start()
    wait_until(lambda: len(ticks) == 100, timeout=10)
    assert time.monotonic() - start < 5  # (well under the 1000 s it models)
    assert ticks == [T0 + 10.0 * (i + 1) for i in range(100)]
    wait_until(lambda: loop.run_until(ticks[-1], timeout=5) >= ticks[-1])
    assert loop.clock.now() == ticks[-1]  # nothing after the last event: time stays there
    loop.hold()


def test_bench_side_threads_sleep_and_wait_in_virtual_time(loop):
    line = SerialMedium("line", 115200, paced=True, clock=loop.clock)
    loop.add(line)
    loop.start()
    woke: list[float] = []
    event = threading.Event()

    def sleeper() -> None:
        loop.clock.sleep(30.0)
        woke.append(loop.clock.now())
        woke.append(loop.clock.wait(event, 5.0))  # nobody sets it: a virtual timeout

    th = threading.Thread(target=sleeper)
    th.start()
    wait_until(lambda: loop._events, timeout=5)  # (the sleeper's wake-up is queued)
    loop.run_for(29.0, timeout=5)
    assert not woke
    loop.run_for(1.0, timeout=5)
    wait_until(lambda: len(woke) == 1, timeout=5)
    assert woke == [T0 + 30.0]
    wait_until(lambda: len(loop._events) == 1, timeout=5)
    loop.run_for(5.0, timeout=5)
    th.join(5)
    assert woke == [T0 + 30.0, False]


def test_a_hosts_writes_at_one_instant_are_one_transmission_at_that_instant(loop):
    baud = 1_000_000
    line = SerialMedium("line", baud, paced=True, clock=loop.clock)
    host = PtyPort("host")
    dev = Echo("dev")
    dev.port = line.add_device(dev)
    line.add_host(host)
    tapped: list[tuple[float, str, bytes]] = []
    line.add_tap(lambda t, src, data: tapped.append((t, src, data)))
    loop.add(line)
    loop.start()
    try:
        loop.run_for(1.0, timeout=5)
        with serial.Serial(host.client_path, baud) as ser:
            with loop.paused():  # the program's three writes come before the loop looks again
                ser.write(b"ab")
                ser.write(b"cd")
                os.write(ser.fileno(), b"ef")
                ser.flush()
                wait_until(lambda: _readable(host), timeout=5)
            loop.run_for(0.5, timeout=5)  # (the round at 1.0 reads all six bytes, then time moves)
        assert [(src, data) for _, src, data in tapped] == [("host", b"abcdef")]
        assert dev.got == [(b"abcdef", T0 + 1.0 + 6 * 10 / baud)]
        assert tapped[0][0] == dev.got[0][1]
    finally:
        loop.stop()  # (as a bench does: the loop ends before its ports close)
        host.close()


def _readable(host: PtyPort) -> bool:
    import select

    return bool(select.select([host.master_fd], [], [], 0)[0])


def test_a_medium_on_another_clock_is_refused(loop):
    with pytest.raises(ValueError, match="not on this loop's clock"):
        loop.add(SerialMedium("line", 115200))
    with pytest.raises(ValueError, match="hold, free"):
        VirtualLoop(VirtualClock(), mode="fast")
