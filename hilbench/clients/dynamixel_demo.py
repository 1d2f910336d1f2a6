"""``hilbench demo``: a bench driven by its servos' own SDK, watched by the bus monitor.

The demo starts the profile's devices behind a pseudo-terminal and runs a
control loop against the pty of its first servo bus with the SDK that bus's
robots use, unmodified, the way a robot's own control software would: the
official ``dynamixel-sdk`` on a Protocol 2.0 bus (as the Wolfgang capture of
the spec sheet shows it: Sync Read of Present Position, Sync Write of Goal
Position, now and then voltage, temperature, Hardware Error Status and the
foot sensor that never answers), the same SDK's Protocol 1.0 handler on a
Protocol 1.0 bus (a Read per servo: it has no Sync Read), Feetech's
``scservo_sdk`` on a Feetech bus (Sync Read 0x82, as LeRobot does); see
:mod:`hilbench.clients.servo_connections`.

Meanwhile the monitor taps the bench's line and the dashboard shows what it
sees. Two things go wrong on purpose, so a newcomer sees every state: one
servo drops off the bus for a while and comes back, and another overheats
(Alert bit and Hardware Error Status on Protocol 2.0; the overheating bit of
every status on Protocol 1.0 and Feetech).

A profile without a servo bus is refused before anything starts
(:func:`check_profile`).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

from hilbench.bench import Bench
from hilbench.bench.profile import DEFAULT_PROFILE, Profile, load_profile
from hilbench.clients.servo_connections import Layout, ServoConnection, connection_for, feetech_sdk, layout
from hilbench.console import Console
from hilbench.dashboard import Dashboard
from hilbench.errors import UsageError
from hilbench.monitor import Monitor
from hilbench.transports.sources import MediumSource

#: Hardware Error Status bit of an overheating Protocol 2.0 servo.
OVERHEATING = 0x04
#: Every this many cycles: voltage/temperature, hardware error status, and the foot sensor.
SLOW_EVERY = 25
#: The endpoint protocols the demo drives (with the SDK :func:`~hilbench.clients.servo_connections.connection_for` picks).
SERVO_PROTOCOLS = ("dynamixel", "feetech")


class DemoUsageError(UsageError):
    """A profile the demo cannot drive (exit status 2, one line)."""


def check_profile(prof: Profile) -> None:
    """Refuse a profile without a servo bus, or whose bus needs an SDK that is not installed (one line)."""
    eps = [ep for ep in prof.endpoints.values() if ep.protocol in SERVO_PROTOCOLS]
    if not eps:
        kinds = ", ".join(f"{ep.name}: {ep.protocol}" for ep in prof.endpoints.values())
        raise DemoUsageError(f"demo drives a servo bus (Dynamixel or Feetech) and profile {prof.name!r} has none "
                             f"({kinds}); start it with `hilbench emulate {prof.name}` and drive it with your "
                             f"own program")
    if eps[0].protocol == "feetech":
        feetech_sdk()


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
    #: IDs that answered the start-up Ping.
    pings: list[int] = field(default_factory=list)
    scenario: Scenario | None = None
    summary: dict = field(default_factory=dict)
    sdk_packets: dict[str, int] = field(default_factory=dict)
    #: The driven bus's traffic: ``dynamixel``, ``dynamixel1`` or ``feetech``.
    protocol: str = "dynamixel"

    @property
    def rate(self) -> float:
        return self.cycles / self.seconds if self.seconds else 0.0


#: Every servo sweeps around the middle of its angle limits by this share of their span.
SWEEP = 0.1
#: Degrees C above its Temperature Limit an overheating servo of a table without Hardware Error Status reaches.
OVERHEAT_MARGIN = 10


def servo_endpoint(bench: Bench):
    """The bench's first servo bus (a Dynamixel or Feetech endpoint with servos)."""
    for name in bench.endpoints:
        ep = bench.endpoint(name)
        bus = ep.bus
        if bus is not None and any(getattr(s, "is_servo", False) for s in getattr(bus, "servos", ())):
            return ep
    raise DemoUsageError(f"profile {bench.profile.name!r} has no servo bus")


class Controller:
    """The robot's control software: the bus's own SDK in a loop, in its own thread.

    Each cycle reads Present Position of every servo (one Sync Read per register layout, or a Read per
    servo on Protocol 1.0) and writes Goal Position along a sine wave around the middle of each servo's
    angle limits (one Sync Write per layout); now and then it reads voltage and temperature, Hardware
    Error Status where the table has it, and the Wolfgang foot sensor's 16 bytes.
    """

    def __init__(self, bench: Bench, seconds: float, period: float = 2.0) -> None:
        self.bench = bench
        self.ep = servo_endpoint(bench)
        self.seconds = seconds
        self.period = period
        servos = sorted((s for s in self.ep.bus.servos if s.is_servo), key=lambda s: s.id)
        self.ids = [s.id for s in servos]
        others = sorted((s for s in self.ep.bus.servos if not s.is_servo), key=lambda s: s.id)
        self.others = [s.id for s in others]
        self.feet = [s.id for s in others if s.model.name == "Wolfgang Foot"]
        self.layouts: dict[int, Layout] = {}
        groups: dict[Layout, list[int]] = {}
        for s in servos:
            lay = layout(s.model)
            if lay is not None:
                self.layouts[s.id] = lay
                groups.setdefault(lay, []).append(s.id)
        self.groups = list(groups.items())
        opts = self.ep.spec.options
        self.connection = connection_for(self.ep.spec.protocol, opts.get("protocol_version", 2), self.ep.path,
                             self.ep.spec.baud, [s.model for s in servos])
        self.result = DemoResult(scenario=Scenario.for_run(self.ids, seconds), protocol=self.connection.protocol)
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

    def _overheat(self, dev_id: int, now: float) -> None:
        """The staged fault: Hardware Error Status where the table has it, else a servo hotter than its limit
        (which Protocol 1.0 and Feetech servos report in every status's error byte)."""
        servo = self.bench.device(dev_id, self.ep.name)
        lay = self.layouts.get(dev_id)
        if lay is None or lay.hardware_error is not None or lay.temperature_limit is None:
            servo.raise_hardware_error(OVERHEATING, now)
            return
        servo.ambient_temperature = servo.get(lay.temperature_limit.key) + OVERHEAT_MARGIN

    def _read(self, address: int, size: int, ids: list[int], what: str) -> dict[int, bytes]:
        got, failed = self.connection.group_read(address, size, ids)
        self.result.failed_reads += failed if self.connection.group_reads else len(ids) - len(got)
        self._count(what, 1 if self.connection.group_reads else len(ids))
        return got

    def _sweeps(self, connection: ServoConnection) -> dict[int, tuple[float, float]]:
        """(middle, amplitude) of each servo that tells its angle limits (a servo in wheel mode sweeps not)."""
        out = {}
        for i, lay in self.layouts.items():
            if lay.min_position is None or lay.max_position is None:
                continue
            lo, hi = connection.read_field(i, lay.min_position), connection.read_field(i, lay.max_position)
            self._count("read", 2)
            if lo is None or hi is None or hi <= lo:
                continue
            out[i] = ((lo + hi) / 2, (hi - lo) * SWEEP)
        return out

    def _loop(self) -> None:
        res, sc, ep = self.result, self.result.scenario, self.ep
        kind = "sync_read" if self.connection.group_reads else "read"
        with self.connection as connection:
            for dev_id in self.ids + self.others:  # start-up: who is there (the foot sensor 101 is not)
                if connection.ping(dev_id):
                    res.pings.append(dev_id)
                self._count("ping")
            sweeps = self._sweeps(connection)
            for lay, ids in self.groups:
                connection.sync_write(lay.torque, dict.fromkeys(ids, 1))
                self._count("sync_write")
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
                    self._overheat(sc.error_id, now)
                    errored = True
                for k, (lay, ids) in enumerate(self.groups):
                    self._read(lay.present.address, lay.present.size, ids, kind)
                    goals = {}
                    for j, i in enumerate(ids):
                        if i in sweeps:
                            mid, amp = sweeps[i]
                            phase = 2 * math.pi * elapsed / self.period + (k + j) * 0.3
                            goals[i] = int(mid + amp * math.sin(phase))
                    if goals:
                        connection.sync_write(lay.goal, goals)
                        self._count("sync_write")
                res.cycles += 1
                if res.cycles % SLOW_EVERY == 1:
                    for lay, ids in self.groups:
                        if lay.voltage is not None:
                            self._read(lay.voltage.address, lay.condition_size, ids, kind)
                        if lay.hardware_error is not None:
                            self._read(lay.hardware_error.address, lay.hardware_error.size, ids, kind)
                    for foot in self.feet:  # the foot sensor of the Wolfgang capture: 101 never answers
                        connection.read(foot, 36, 16)
                        self._count("read")
            res.seconds = time.monotonic() - start
            for lay, ids in self.groups:
                connection.sync_write(lay.torque, dict.fromkeys(ids, 0))
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
    check_profile(prof)
    with Bench(prof, paced=paced) as bench:
        ctl = Controller(bench, seconds)
        ep = ctl.ep
        source = MediumSource(ep.medium, name=f"demo {prof.name} on {ep.path}")
        monitor = Monitor(source, silence=0.5).start()
        ctl.start()
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
