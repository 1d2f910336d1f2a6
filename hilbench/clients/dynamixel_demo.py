"""``hilbench demo``: a bench driven by the official SDK, watched by the bus monitor.

The demo starts the profile's devices behind a pseudo-terminal and runs a
control loop against that pty with the unmodified ``dynamixel-sdk``, the way a
robot's own control software would (and the way the Wolfgang capture of the
spec sheet shows it): a Ping of every device, torque on, then every cycle a
Sync Read of Present Position and a Sync Write of Goal Position along a sine
wave, and now and then a Sync Read of voltage and temperature, a Sync Read of
Hardware Error Status and a Read of the foot sensor that never answers.

Meanwhile the monitor taps the bench's line and the dashboard shows what it
sees. Two things go wrong on purpose, so a newcomer sees every state: one
servo drops off the bus for a while and comes back, and another reports an
overheating error (Alert bit, Hardware Error Status).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

import dynamixel_sdk as sdk

from hilbench.bench import Bench
from hilbench.bench.profile import DEFAULT_PROFILE, load_profile
from hilbench.clients.dynamixel import open_port
from hilbench.console import Console
from hilbench.dashboard import Dashboard
from hilbench.monitor import Monitor
from hilbench.transports.sources import MediumSource

POSITION = 132
GOAL = 116
VOLT_TEMP = 144  # Present Input Voltage (2) + Present Temperature (1)
HW_ERROR = 70
TORQUE = 64
OVERHEATING = 0x04
#: Every this many cycles: voltage/temperature, hardware error status, and the foot sensor.
SLOW_EVERY = 25


@dataclass
class Scenario:
    """Who fails when (seconds from the start of the control loop)."""

    vanish_id: int
    vanish_at: float
    vanish_for: float
    error_id: int
    error_at: float

    @classmethod
    def for_run(cls, ids: list[int], seconds: float) -> Scenario:
        """Scaled to the run (a 10 s demo: a servo is gone from 2.5 s to 5.5 s, another overheats at 5 s)."""
        span = seconds if seconds else 10.0
        vanish = 7 if 7 in ids else ids[len(ids) // 3]
        error = 12 if 12 in ids else ids[-1]
        return cls(vanish, 0.25 * span, 0.3 * span, error, 0.5 * span)


@dataclass
class DemoResult:
    """What the control loop did and what the monitor saw; ``hilbench demo`` prints it at the end."""

    cycles: int = 0
    seconds: float = 0.0
    failed_reads: int = 0
    pings: dict[int, int] = field(default_factory=dict)
    scenario: Scenario | None = None
    summary: dict = field(default_factory=dict)
    sdk_packets: dict[str, int] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        return self.cycles / self.seconds if self.seconds else 0.0


class Controller:
    """The robot's control software: the official SDK in a loop, in its own thread."""

    def __init__(self, bench: Bench, seconds: float, amplitude: int = 400, period: float = 2.0) -> None:
        self.bench = bench
        self.ep = bench.endpoint(next(iter(bench.endpoints)))
        self.seconds = seconds
        self.amplitude = amplitude
        self.period = period
        servos = sorted((s for s in self.ep.bus.servos if s.is_servo), key=lambda s: s.id)
        self.ids = [s.id for s in servos]
        self.others = sorted(s.id for s in self.ep.bus.servos if not s.is_servo)
        self.result = DemoResult(scenario=Scenario.for_run(self.ids, seconds))
        self.stop = threading.Event()
        self.done = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="demo-controller", daemon=True)

    def start(self) -> Controller:
        self._thread.start()
        return self

    def join(self) -> None:
        self.stop.set()
        self._thread.join(timeout=10)
        if self.error is not None:
            raise self.error

    def _count(self, name: str, n: int = 1) -> None:
        self.result.sdk_packets[name] = self.result.sdk_packets.get(name, 0) + n

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # reported by join()
            self.error = exc
        finally:
            self.done.set()

    def _loop(self) -> None:
        res, ids, sc, ep = self.result, self.ids, self.result.scenario, self.ep
        ph = sdk.PacketHandler(2.0)
        with open_port(ep.path, ep.spec.baud) as port:
            for dev_id in ids + self.others:  # start-up: who is there (the foot sensor 101 is not)
                model, result, _ = ph.ping(port, dev_id)
                self._count("ping")
                if result == sdk.COMM_SUCCESS:
                    res.pings[dev_id] = model
            torque = sdk.GroupSyncWrite(port, ph, TORQUE, 1)
            for i in ids:
                torque.addParam(i, [1])
            torque.txPacket()
            self._count("sync_write")
            reader = sdk.GroupSyncRead(port, ph, POSITION, 4)
            volt_temp = sdk.GroupSyncRead(port, ph, VOLT_TEMP, 3)
            hw_error = sdk.GroupSyncRead(port, ph, HW_ERROR, 1)
            for i in ids:
                reader.addParam(i)
                volt_temp.addParam(i)
                hw_error.addParam(i)
            writer = sdk.GroupSyncWrite(port, ph, GOAL, 4)
            start = time.monotonic()
            vanished = errored = False
            while not self.stop.is_set():
                elapsed = time.monotonic() - start
                if self.seconds and elapsed >= self.seconds:
                    break
                now = self.bench.now()
                if not vanished and elapsed >= sc.vanish_at:
                    self.bench.device(sc.vanish_id, ep.name).vanish(now, sc.vanish_for)
                    vanished = True
                if not errored and elapsed >= sc.error_at:
                    self.bench.device(sc.error_id, ep.name).raise_hardware_error(OVERHEATING, now)
                    errored = True
                if reader.txRxPacket() != sdk.COMM_SUCCESS:
                    res.failed_reads += 1
                self._count("sync_read")
                writer.clearParam()
                for k, i in enumerate(ids):
                    goal = int(2048 + self.amplitude * math.sin(2 * math.pi * elapsed / self.period + k * 0.3))
                    writer.addParam(i, list(goal.to_bytes(4, "little")))
                writer.txPacket()
                self._count("sync_write")
                res.cycles += 1
                if res.cycles % SLOW_EVERY == 1:
                    for group in (volt_temp, hw_error):
                        if group.txRxPacket() != sdk.COMM_SUCCESS:
                            res.failed_reads += 1
                        self._count("sync_read")
                    ph.readTxRx(port, 101, 36, 16)  # the foot sensor of the Wolfgang capture: never answers
                    self._count("read")
            res.seconds = time.monotonic() - start
            torque.clearParam()
            for i in ids:
                torque.addParam(i, [0])
            torque.txPacket()
            self._count("sync_write")


def run_demo(
    profile: str = DEFAULT_PROFILE,
    seconds: float = 10.0,
    *,
    console: Console | None = None,
    paced: bool = True,
    view: str = "devices",
) -> DemoResult:
    """Run the demo for ``seconds`` (0 = until Ctrl-C or ``q``); returns what happened."""
    console = console or Console()
    prof = load_profile(profile)
    with Bench(prof, paced=paced) as bench:
        ep = bench.endpoint(next(iter(bench.endpoints)))
        source = MediumSource(ep.medium, name=f"demo {prof.name} on {ep.path}")
        monitor = Monitor(source, silence=0.5).start()
        ctl = Controller(bench, seconds).start()
        timing = "paced" if ep.medium.paced else "unpaced"

        def status() -> str:
            state = "done" if ctl.done.is_set() else timing
            return f"SDK: {ctl.result.cycles} cycles, {state}"

        dash = Dashboard(monitor.tracker, lock=monitor.lock, source=source.name, view=view, status=status)
        try:
            dash.run(console=console, stop=ctl.done.is_set, screen_mode=False)
        except KeyboardInterrupt:
            pass
        finally:
            ctl.join()
            # let the monitor see the last transmissions before it stops
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                with monitor.lock:
                    seen = monitor.tracker.bytes
                if seen >= ep.medium.stats.bytes:
                    break
                time.sleep(0.01)
            monitor.stop()
        result = ctl.result
        result.summary = monitor.summary()
    return result
