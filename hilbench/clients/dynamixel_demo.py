"""``hilbench demo``: a bench driven by its servos' own SDK, watched by the bus monitor.

The demo starts the profile's devices behind a pseudo-terminal and runs a
control loop against the pty of its first servo bus with the SDK that bus's
robots use, unmodified, the way a robot's own control software would: the
official ``dynamixel-sdk`` on a Protocol 2.0 bus (as the Wolfgang capture of
the spec sheet shows it: Sync Read of Present Position, Sync Write of Goal
Position, now and then voltage, temperature, Hardware Error Status and the
foot sensor that never answers), the same SDK's Protocol 1.0 handler on a
Protocol 1.0 bus (a Read per servo: it has no Sync Read), Feetech's
``scservo_sdk`` on a Feetech bus (Sync Read 0x82, as LeRobot does). Each
servo family brings its SDK as a servo client (:mod:`hilbench.clients.servo_connections`:
:class:`~hilbench.clients.servo_connections.ServoClient`); the demo finds them in the
registry and names no family.

Meanwhile the monitor taps the bench's line and the dashboard shows what it
sees. Two things go wrong on purpose, so a newcomer sees every state: one
servo drops off the bus for a while and comes back, and another overheats
(Alert bit and Hardware Error Status on Protocol 2.0; the overheating bit of
every status on Protocol 1.0 and Feetech).

A profile without a servo bus is refused before anything starts
(:func:`check_profile`).

With ``hilbench demo --virtual-time`` (:func:`hilbench.cli.demo.run_virtual_demo`)
the bench runs on a virtual clock and the control loop runs as a child process
in lockstep with it, as ``hilbench run`` would start it (``python -m
hilbench.clients.dynamixel_demo --client FILE``: the bus it drives, written by
the bench's process; it prints its counts as JSON). The faults are the
bench's timers at virtual instants, the monitor and the dashboard stay in the
bench's process, and two runs print the same figures.
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilbench.bench import Bench
from hilbench.bench.profile import DEFAULT_PROFILE, Profile, load_profile
from hilbench.clients.servo_connections import Layout, ServoConnection, layout, servo_clients
from hilbench.console import Console
from hilbench.dashboard import Dashboard
from hilbench.errors import DeviceError, UsageError
from hilbench.monitor import Monitor
from hilbench.protocols.control_table import Model
from hilbench.transports.sources import MediumSource

#: Hardware Error Status bit of an overheating Protocol 2.0 servo.
OVERHEATING = 0x04
#: Every this many cycles: voltage/temperature, hardware error status, and the foot sensor.
SLOW_EVERY = 25


class DemoUsageError(UsageError):
    """A profile the demo cannot drive (exit status 2, one line)."""


class DemoClientError(DeviceError):
    """The control loop's process of ``demo --virtual-time`` failed (exit status 1, one line)."""


def check_profile(prof: Profile) -> None:
    """Refuse a profile without a servo bus, or whose bus needs an SDK that is not installed (one line)."""
    clients = servo_clients()
    eps = [ep for ep in prof.endpoints.values() if ep.protocol in clients]
    if not eps:
        kinds = ", ".join(f"{ep.name}: {ep.protocol}" for ep in prof.endpoints.values())
        buses = " or ".join(c.bus_title or c.protocol for c in clients.values())
        raise DemoUsageError(f"demo drives a servo bus ({buses}) and profile {prof.name!r} has none "
                             f"({kinds}); start it with `hilbench emulate {prof.name}` and drive it with your "
                             f"own program")
    clients[eps[0].protocol].check()


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
    #: The driven bus's traffic (its connection's :attr:`~hilbench.clients.servo_connections.ServoConnection.protocol`).
    protocol: str = ""
    #: Whether its servos report their condition in every status's error byte (Protocol 1.0, Feetech), not in
    #: a Hardware Error Status register.
    status_errors: bool = False
    #: When the control loop started (after its Pings and set-up), on its clock (monotonic seconds).
    started: float = 0.0
    #: Virtual time only: the lockstep's counters of what makes runs differ (``stalls``: a thread of the control
    #: loop ran a stall's length without waiting, then time followed the wall clock; ``settle_timeouts``:
    #: delivered bytes the lockstep gave up waiting for).
    lockstep: dict[str, int] = field(default_factory=dict)

    @property
    def rate(self) -> float:
        return self.cycles / self.seconds if self.seconds else 0.0


#: Every servo sweeps around the middle of its angle limits by this share of their span.
SWEEP = 0.1
#: Degrees C above its Temperature Limit an overheating servo of a table without Hardware Error Status reaches.
OVERHEAT_MARGIN = 10


def servo_endpoint(bench: Bench):
    """The bench's first servo bus (an endpoint with servos, of a protocol a servo client drives)."""
    clients = servo_clients()
    for name in bench.endpoints:
        ep = bench.endpoint(name)
        if ep.spec.protocol not in clients:
            continue
        bus = ep.bus
        if bus is not None and any(getattr(s, "is_servo", False) for s in getattr(bus, "servos", ())):
            return ep
    raise DemoUsageError(f"profile {bench.profile.name!r} has no servo bus")


@dataclass
class ServoBus:
    """The servo bus the control loop drives, as a program on the host sees it: no bench, only the port to
    open and what is on the bus (what a child process of ``demo --virtual-time`` gets from the bench's)."""

    #: The bench's endpoint.
    name: str
    protocol: str
    #: The endpoint's options (e.g. the Dynamixel ``protocol_version``).
    options: dict[str, Any]
    #: The pty the program opens.
    path: str
    baud: int
    #: (ID, model) of the servos, by ID.
    servos: list[tuple[int, Model]]
    #: (ID, model) of the bus's devices that are not servos (the Wolfgang foot sensor), by ID.
    others: list[tuple[int, Model]]

    @classmethod
    def of(cls, bench: Bench) -> ServoBus:
        """The bench's first servo bus (:func:`servo_endpoint`)."""
        ep = servo_endpoint(bench)
        devices = sorted(ep.bus.servos, key=lambda s: s.id)
        return cls(ep.name, ep.spec.protocol, dict(ep.spec.options), ep.path, ep.spec.baud,
                   [(s.id, s.model) for s in devices if s.is_servo],
                   [(s.id, s.model) for s in devices if not s.is_servo])

    @property
    def ids(self) -> list[int]:
        return [i for i, _ in self.servos]

    def layouts(self) -> dict[int, Layout]:
        """The register layout of each servo that has one."""
        return {i: lay for i, model in self.servos if (lay := layout(model)) is not None}


def stage_vanish(bench: Bench, bus: ServoBus, scenario: Scenario, now: float) -> None:
    """The staged drop-out: the scenario's servo falls silent for ``vanish_for`` seconds from ``now``."""
    bench.device(scenario.vanish_id, bus.name).vanish(now, scenario.vanish_for)


def stage_overheat(bench: Bench, bus: ServoBus, dev_id: int, now: float) -> None:
    """The staged fault: Hardware Error Status where the table has it, else a servo hotter than its limit
    (which Protocol 1.0 and Feetech servos report in every status's error byte)."""
    servo = bench.device(dev_id, bus.name)
    lay = bus.layouts().get(dev_id)
    if lay is None or lay.hardware_error is not None or lay.temperature_limit is None:
        servo.raise_hardware_error(OVERHEATING, now)
        return
    servo.ambient_temperature = servo.get(lay.temperature_limit.key) + OVERHEAT_MARGIN


def schedule_faults(bench: Bench, bus: ServoBus, scenario: Scenario, t0: float) -> None:
    """The scenario as timers of a virtual-time bench's loop, at ``t0`` plus its offsets (virtual seconds)."""
    loop = bench.loop
    if loop is None:
        raise ValueError("schedule_faults needs a virtual-time bench (its loop runs the timers)")
    loop.call_at(t0 + scenario.vanish_at, lambda: stage_vanish(bench, bus, scenario, bench.now()))
    loop.call_at(t0 + scenario.error_at, lambda: stage_overheat(bench, bus, scenario.error_id, bench.now()))


class Controller:
    """The robot's control software: the bus's own SDK in a loop, in its own thread.

    Each cycle reads Present Position of every servo (one Sync Read per register layout, or a Read per
    servo on Protocol 1.0) and writes Goal Position along a sine wave around the middle of each servo's
    angle limits (one Sync Write per layout); now and then it reads voltage and temperature, Hardware
    Error Status where the table has it, and the Wolfgang foot sensor's 16 bytes.
    """

    def __init__(self, bench: Bench | None, seconds: float, period: float = 2.0, *,
                 bus: ServoBus | None = None) -> None:
        """``bench``: the controller stages the scenario's faults on it (None: a client process, which drives
        ``bus`` and leaves the faults to the bench's timers)."""
        if bus is None:
            if bench is None:
                raise ValueError("a Controller needs a bench or a bus")
            bus = ServoBus.of(bench)
        self.bench = bench
        self.bus = bus
        self.ep = bench.endpoint(bus.name) if bench is not None else None
        self.seconds = seconds
        self.period = period
        self.ids = bus.ids
        self.others = [i for i, _ in bus.others]
        client = servo_clients()[bus.protocol]
        # devices the robot reads now and then that are not servos (the Wolfgang foot sensor, which never answers)
        self.sensor_reads = client.sensor_reads(bus.others)
        self.layouts: dict[int, Layout] = bus.layouts()
        groups: dict[Layout, list[int]] = {}
        for i, lay in self.layouts.items():
            groups.setdefault(lay, []).append(i)
        self.groups = list(groups.items())
        self.connection = client.connection(bus.options, bus.path, bus.baud, [m for _, m in bus.servos])
        self.result = DemoResult(scenario=Scenario.for_run(self.ids, seconds), protocol=self.connection.protocol,
                                 status_errors=self.connection.status_errors)
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
        assert self.bench is not None
        stage_overheat(self.bench, self.bus, dev_id, now)

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
        res, sc, bench = self.result, self.result.scenario, self.bench
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
            start = res.started = time.monotonic()
            # a client process (no bench) leaves the faults to the bench's timers
            vanished = errored = bench is None
            while not self.stop.is_set():
                elapsed = time.monotonic() - start
                if self.seconds and elapsed >= self.seconds:
                    break
                if not vanished and elapsed >= sc.vanish_at:
                    stage_vanish(bench, self.bus, sc, bench.now())
                    vanished = True
                if not errored and elapsed >= sc.error_at:
                    self._overheat(sc.error_id, bench.now())
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
                    for dev_id, address, size in self.sensor_reads:  # the foot sensor of the Wolfgang capture
                        connection.read(dev_id, address, size)
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
    """Run the demo for ``seconds`` (0 = until Ctrl-C or ``q``); returns what happened. (In virtual time:
    :func:`hilbench.cli.demo.run_virtual_demo`.)"""
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
            drain(monitor, ep.medium)
            monitor.stop()
        result = ctl.result
        result.summary = monitor.summary()
    return result


def drain(monitor: Monitor, medium: Any, timeout: float = 1.0) -> None:
    """Let the monitor see the last transmissions before it stops."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with monitor.lock:
            seen = monitor.tracker.bytes if monitor.tracker is not None else 0
        if seen >= medium.stats.bytes:
            break
        time.sleep(0.01)


def client_main(argv: list[str] | None = None) -> int:
    """The control loop of ``demo --virtual-time`` as a process of its own (under the bench's clock): drives the
    bus of ``--client FILE`` for ``--seconds`` and prints its counts as one JSON line. SIGINT ends the loop
    after its cycle, and the counts are printed all the same."""
    ap = argparse.ArgumentParser(prog=f"python -m {__name__}", description=client_main.__doc__)
    ap.add_argument("--client", required=True, metavar="FILE", help="the bus to drive (written by the demo)")
    ap.add_argument("--seconds", type=float, default=10.0, help="how long (0: until SIGINT)")
    args = ap.parse_args(argv)
    bus = pickle.loads(Path(args.client).read_bytes())  # (a file the demo's own process just wrote)
    ctl = Controller(None, args.seconds, bus=bus)
    signal.signal(signal.SIGINT, lambda *_: ctl.stop.set())
    ctl._run()
    if ctl.error is not None:
        raise ctl.error
    res = ctl.result
    print(json.dumps({"cycles": res.cycles, "seconds": res.seconds, "failed_reads": res.failed_reads,
                      "pings": res.pings, "sdk_packets": res.sdk_packets, "protocol": res.protocol,
                      "status_errors": res.status_errors, "started": res.started}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(client_main())
