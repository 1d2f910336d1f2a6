"""``hilbench demo``: the main job (a servo bench driven by its own SDK, watched live)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from hilbench.cli.common import CliError, add_set_option
from hilbench.errors import DeviceError
from hilbench.rules import SECONDS

if TYPE_CHECKING:
    from hilbench.bench.profile import Profile
    from hilbench.clients.dynamixel_demo import DemoResult
    from hilbench.console import Console


class DemoError(DeviceError):
    """The demo's control loop did nothing (exit status 1, one line)."""


def demo_report(result) -> list[str]:
    """What the monitor saw of the demo's staged faults, in a few lines."""
    lines = []
    sc = result.scenario
    devices = result.summary.get("devices", {})
    gone = devices.get(str(sc.vanish_id), {}) if sc else {}
    hot = devices.get(str(sc.error_id), {}) if sc else {}
    if gone:
        drops = gone.get("disconnects", 0)
        if drops:
            back = "came back" if gone.get("state") == "connected" else f"is {gone.get('state')}"
            lines.append(f"monitor: ID {sc.vanish_id} dropped out {drops} time(s), "
                         f"missed {gone.get('misses', 0)} replies, {back}")
        else:  # a run too short to reach the staged drop-out
            lines.append(f"monitor: ID {sc.vanish_id} did not drop out (missed {gone.get('misses', 0)} replies)")
    if hot and not getattr(result, "status_errors", False):  # Protocol 2.0: Hardware Error Status and the Alert bit
        bits = ", ".join(hot.get("hardware_error_bits") or []) or "none read"
        lines.append(f"monitor: ID {sc.error_id} alert {'on' if hot.get('alert') else 'off'}, hardware error: {bits}")
    elif hot:  # Protocol 1.0 and Feetech: the servo's condition is in every status's error byte
        from hilbench.registry import instrument_for

        errors = hot.get("error_statuses", 0)
        last = instrument_for(result.protocol).dialect.describe_error(hot.get("last_error") or 0)
        lines.append(f"monitor: ID {sc.error_id} sent {errors} status(es) with an error, the last: {last}")
    never = [k for k, d in devices.items() if d.get("never_answered")]
    if never:
        lines.append(f"monitor: never answered: ID {', '.join(never)}")
    return lines


def cmd_demo(args: argparse.Namespace) -> int:
    from hilbench.bench.profile import load_profile
    from hilbench.clients.dynamixel_demo import run_demo

    if args.virtual_time and args.unpaced:
        raise CliError("virtual time is paced: --unpaced and --virtual-time do not go together")
    prof = load_profile(args.profile, args.overrides)
    if args.virtual_time:
        result = run_virtual_demo(prof, args.seconds, view=args.view)
    else:
        result = run_demo(prof, args.seconds, paced=not args.unpaced, view=args.view)
    print()
    for line in demo_report(result):
        print(line)
    unit = "virtual s" if args.virtual_time else "s"
    if args.virtual_time:
        print(f"demo: the control loop started {result.started:.6f} virtual s after the bench")
    print(f"demo: {result.cycles} control cycles in {result.seconds:.1f} {unit} ({result.rate:.0f}/s), "
          f"{result.failed_reads} failed reads")
    if any(result.lockstep.values()):  # (see DemoResult.lockstep)
        counts = ", ".join(f"{k} {v}" for k, v in result.lockstep.items() if v)
        print(f"hilbench: note: the lockstep counted {counts}: these figures may differ from run to run",
              file=sys.stderr)
    if not result.cycles:
        raise DemoError("the control loop completed no cycle (give it more time: --seconds)")
    return 0


#: How long a control loop told to stop (Ctrl-C, ``q``) has to finish its cycle and say what it did.
CLIENT_GRACE = 10.0


def run_virtual_demo(prof: Profile, seconds: float, console: Console | None = None,
                     view: str = "devices") -> DemoResult:
    """The demo on a virtual-time bench: the bench's timers stage the faults at virtual instants from its
    start, the control loop runs under the bench's clock in a child process
    (:func:`hilbench.clients.dynamixel_demo.client_main`)."""
    import json
    import pickle
    import signal
    import subprocess
    import tempfile
    import threading
    from pathlib import Path

    from hilbench.bench import Bench
    from hilbench.bench.port_state_server import serve_port_state
    from hilbench.clients.dynamixel_demo import (
        DemoClientError,
        DemoResult,
        Scenario,
        ServoBus,
        check_profile,
        drain,
        schedule_faults,
    )
    from hilbench.console import Console
    from hilbench.dashboard import Dashboard
    from hilbench.monitor import Monitor
    from hilbench.run.environment import read_bench, run_environment
    from hilbench.transports.sources import MediumSource

    console = console or Console()
    check_profile(prof)

    with Bench(prof, virtual_time=True) as bench, tempfile.TemporaryDirectory(prefix="hilbench-demo-") as tmp:
        serve_port_state(bench)  # (the SDK's open sets DTR and RTS; its drains ask the line)
        bus = ServoBus.of(bench)
        scenario = Scenario.for_run(bus.ids, seconds)
        # the clock holds until the client's threads take part: its start-up takes no virtual time
        schedule_faults(bench, bus, scenario, bench.now())
        ep = bench.endpoint(bus.name)
        source = MediumSource(ep.medium, name=f"demo {prof.name} on {ep.path}")
        monitor = Monitor(source, silence=0.5).start()
        spec = Path(tmp) / "bus.pickle"
        spec.write_bytes(pickle.dumps(bus))
        env, _notes = run_environment([read_bench(bench.manifest())], "c")
        proc = subprocess.Popen([sys.executable, "-m", "hilbench.clients.dynamixel_demo", "--client", str(spec), "--seconds", repr(seconds)],
                                stdout=subprocess.PIPE, env=env, text=True)
        out: list[str] = []
        reader = threading.Thread(target=lambda: out.append(proc.stdout.read() if proc.stdout else ""),
                                  name="demo-client-out", daemon=True)
        reader.start()

        def status() -> str:
            t = bench.now() - bench.started_at if bench.started_at is not None else 0.0
            return f"SDK: {'done' if proc.poll() is not None else 'running'}, virtual {t:.1f} s"

        dash = Dashboard(monitor.tracker, lock=monitor.lock, source=source.name, view=view, status=status)
        try:
            dash.run(console=console, stop=lambda: proc.poll() is not None, screen_mode=False)
        except KeyboardInterrupt:
            pass
        finally:
            if proc.poll() is None:  # q, or Ctrl-C in a terminal (which the child got too): finish the cycle
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=CLIENT_GRACE)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            reader.join(timeout=5)
            drain(monitor, ep.medium)
            monitor.stop()
        result = DemoResult(scenario=scenario)
        text = "".join(out).strip().splitlines()
        try:
            got = json.loads(text[-1]) if text else None
        except ValueError:
            got = None
        if proc.returncode != 0 or not isinstance(got, dict):
            raise DemoClientError(f"the demo's control loop (pid {proc.pid}) ended with status {proc.returncode} "
                                  "and no figures (its error is above)")
        for key in ("cycles", "seconds", "failed_reads", "pings", "sdk_packets", "protocol", "status_errors", "started"):
            if key in got:
                setattr(result, key, got[key])
        result.started -= bench.started_at or 0.0  # (from the bench's start, where the scenario counts from)
        result.summary = monitor.summary()
        stats = bench.services["clock"].stats()
        result.lockstep = {k: stats[k] for k in ("stalls", "settle_timeouts")}
    return result


ORDER = 70
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "demo": "run a servo bench, drive it with its own SDK, watch it live",
}


def views() -> tuple[str, ...]:
    """The dashboard views ``--view`` takes: those of the instruments of the buses a servo client drives."""
    from hilbench import registry
    from hilbench.clients.servo_connections import servo_clients

    found: dict[str, None] = {}
    for protocol in servo_clients():
        inst = registry.instruments.get(protocol) if protocol in registry.instruments else None
        view_set = inst.views() if inst is not None else None
        found.update(dict.fromkeys(getattr(view_set, "views", ())))
    return tuple(found)


def register(sub: argparse._SubParsersAction) -> None:
    from hilbench.profiles import DEFAULT_PROFILE

    choices = views()

    dm = sub.add_parser("demo", help=VERBS["demo"],
                        description="Start a bench, run a control loop against its servo bus with that bus's own "
                                    "SDK (dynamixel-sdk for Dynamixel Protocol 2.0 and 1.0, Feetech's scservo_sdk "
                                    "for Feetech), and show the bus monitor's dashboard while one servo drops out "
                                    "and comes back and another reports overheating.")
    dm.add_argument("--profile", default=DEFAULT_PROFILE, help=f"profile (default: {DEFAULT_PROFILE})")
    add_set_option(dm)
    dm.add_argument("--seconds", type=SECONDS, default=10.0, help="how long to run (0: until Ctrl-C; default 10)")
    dm.add_argument("--unpaced", action="store_true", help="deliver bytes at once instead of at wire speed")
    dm.add_argument("--virtual-time", action="store_true",
                    help="run the bench on a virtual clock and the control loop in lockstep with it, in a "
                         "process of its own: --seconds are virtual, and two runs print the same figures")
    dm.add_argument("--view", choices=choices, default=choices[0] if choices else None,
                    help="dashboard view to start with (keys: 1-4)")
    dm.set_defaults(func=cmd_demo)
