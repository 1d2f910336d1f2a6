"""A bench participant (hilbench.transports.participant): blocking code on a VirtualLoop's clock, one at a
time with the loop, at exact virtual instants."""

from __future__ import annotations

import threading

from hilbench.transports.clock import VirtualClock
from hilbench.transports.participant import Participant
from hilbench.transports.virtual_loop import VirtualLoop


def test_a_participant_waits_in_virtual_time_and_never_runs_beside_the_loop() -> None:
    clock = VirtualClock(epoch=0)
    loop = VirtualLoop(clock)
    loop.start()
    p = Participant(loop.call_at, clock, "p")
    seen: list[tuple[str, float]] = []
    inside = threading.Event()  # set while either side runs its code
    overlaps = []

    def side(name: str) -> None:
        if inside.is_set():
            overlaps.append((name, clock.now()))
        inside.set()
        seen.append((name, clock.now() - 1000.0))
        inside.clear()

    def body() -> None:
        side("start")
        p.wait(0.25)  # a deadline
        side("deadline")
        p.wait(10.0)  # news comes first (at +1.0)
        side("news")
        p.wait(None, news=False)  # until stopped

    def tick(k: int) -> None:
        side(f"tick{k}")
        if k == 3:
            p.notify()  # news: its turn at this instant, after what is already due
        if k < 5:
            loop.call_at(clock.now() + 0.25, lambda: tick(k + 1))

    try:
        loop.call_at(clock.now() + 0.25, lambda: tick(1))  # (first: queued before the participant's deadline)
        p.start(body)
        loop.run_for(2.0, timeout=10)
        assert not overlaps
        # at +0.25 the tick was queued first, then the participant's deadline (in its first turn); the news of
        # tick 3 comes after it at its instant
        assert seen == [("start", 0.0), ("tick1", 0.25), ("deadline", 0.25), ("tick2", 0.5), ("tick3", 0.75),
                        ("news", 0.75), ("tick4", 1.0), ("tick5", 1.25)]
        assert p.turns == 3
    finally:
        p.stop()
        p.join(5)
        loop.close()
    assert p.thread is None
