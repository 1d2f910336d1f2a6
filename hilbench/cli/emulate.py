"""``hilbench emulate``: run the devices of a profile until interrupted."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path

from hilbench import registry
from hilbench.cli.common import add_set_option, warn_beyond_machine
from hilbench.rules import Rule
from hilbench.transports.host_port import DEFAULT_BIND, bind_address


def cmd_emulate(args: argparse.Namespace) -> int:
    from hilbench.bench import Bench, load_profile
    from hilbench.bench.control import BENCH_COMMANDS
    from hilbench.bench.port_state_server import serve_port_state

    profile = load_profile(args.profile, args.overrides)
    paced = True if args.paced else (False if args.unpaced else None)
    serve = _server_names(args.serve)
    virtual = _virtual_options(args)
    bench = Bench(profile, paced=paced, link_dir=args.link_dir, tap=not args.no_tap, serve=serve, bind=args.bind,
                  **virtual)
    manifest = Path(args.manifest) if args.manifest else None
    if manifest:
        bench.check_manifest_path(manifest)  # refuse a user's file or a live bench's manifest before starting
    # Ctrl-C and SIGTERM wake the main thread through a pipe the interpreter writes to at C level (whichever
    # thread the signal hit); the Python handlers do nothing. Not an Event set by a handler: a handler runs
    # between two bytecodes of the main thread, possibly while that thread holds the very lock Event.set()
    # takes (inside Event.wait()), and then waits for itself forever (seen once on CI: a bench never ended).
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: None)
    signal.set_wakeup_fd(wake_w)
    bench.start()
    try:
        bench.serve_control()  # family commands, and what every bench answers (its media's timing, taps, ...)
        lines = serve_port_state(bench)  # modem lines, BREAK and flushes for clients under `hilbench run`
        if manifest:
            claim = bench.write_manifest(manifest)
            if claim.took_over is not None:
                print(f"hilbench: {manifest}: took over a stale manifest (pid {claim.took_over} gone)",
                      file=sys.stderr)
        print(f"hilbench: bench {profile.name!r} running ({len(bench.devices)} devices); Ctrl-C stops it")
        for ep in bench.endpoints.values():
            address = getattr(ep.port, "address", None)
            if address is not None:
                warn_beyond_machine(address[0], f"endpoint {ep.name!r}",
                                    "the profile's bind; the default is 127.0.0.1")
        warn_beyond_machine(args.bind, f"--bind {args.bind}: every server, traffic tap and the control channel",
                            "without authentication; labgrid's SSH proxying reaches a bench bound to 127.0.0.1")
        for ep in bench.endpoints.values():
            print(f"  {ep.name}: {_where(ep)}  ({ep.bus_kind.summary(ep)})")
            for name, service in ep.services.items():
                print(f"    {name}: {service.describe().get(registry.servers.get(name).manifest_key, service)}")
            if ep.tap is not None:
                where = f"{manifest}#{ep.name}" if manifest else ep.tap.url
                print(f"    traffic tap: {ep.tap.url}  (hilbench {ep.bus_kind.tap_reader} {where})")
        if bench.control is not None:
            takers = "; ".join([f"{name}: {', '.join(bench.family_of(name).control_commands)}"
                                for ep in bench.endpoints.values() for name in ep.devices
                                if bench.family_of(name).control_commands]
                               + [f"endpoint {ep.name}: {', '.join(ep.bus_kind.control_commands)}"
                                  for ep in bench.endpoints.values() if ep.bus_kind.control_commands])
            print(f"  control: {bench.control.address_text}  ({takers or ', '.join(BENCH_COMMANDS)})")
            if bench.world.bodies:
                where = manifest or f"--control {bench.control.address_text}"
                print(f"  world: bodies {', '.join(bench.world.bodies)}  (hilbench world {where}: live view, "
                      f"--json, --png, --record)")
        if lines is not None and manifest:
            print(f"  modem lines: hilbench run --manifest {manifest} -- COMMAND")
        if bench.loop is not None:
            stall = "never" if bench.lockstep_stall is None else f"{bench.lockstep_stall:g} s"
            print(f"  clock: virtual ({bench.loop.mode}; lockstep stall after {stall}; seed {bench.seed})"
                  + (f"; clients join with: hilbench run --manifest {manifest} -- COMMAND" if manifest else ""))
        if manifest:
            print(f"  manifest: {manifest}")
        sys.stdout.flush()
        os.read(wake_r, 1)  # a signal's byte (the read is retried after each signal's handler: PEP 475)
    finally:
        bench.stop()
        bench.remove_manifest()  # only our own, and only while it is still ours
        signal.set_wakeup_fd(-1)
        os.close(wake_r)
        os.close(wake_w)
    return 0


def _virtual_options(args: argparse.Namespace) -> dict:
    """Bench keywords from --virtual-time, --virtual-epoch, --lockstep-stall and --seed (one-line errors)."""
    from hilbench.errors import UsageError

    if not args.virtual_time:
        given = [opt for opt, value in (("--virtual-epoch", args.virtual_epoch), ("--lockstep-stall", args.lockstep_stall),
                                        ("--seed", args.seed)) if value is not None]
        if given:
            raise UsageError(f"{' and '.join(given)} need --virtual-time")
        return {}
    if args.unpaced:
        raise UsageError("virtual time is paced: --unpaced and --virtual-time do not go together")
    out: dict = {"virtual_time": args.virtual_time, "seed": args.seed or 0}
    if args.virtual_epoch is not None:
        out["virtual_epoch"] = args.virtual_epoch
    if args.lockstep_stall is not None:
        out["lockstep_stall"] = args.lockstep_stall
    return out


def _epoch_arg(text: str) -> float:
    """--virtual-epoch: an ISO 8601 date and time (UTC unless it says otherwise) or Unix seconds."""
    import datetime as dt

    try:
        return float(text)
    except ValueError:
        pass
    try:
        when = dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither an ISO 8601 time (2026-01-01T00:00:00Z) nor "
                                         "Unix seconds") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=dt.UTC)
    return when.timestamp()


def _stall_arg(text: str) -> float | None:
    """--lockstep-stall: wall seconds (> 0) or ``never``."""
    if text.strip().lower() == "never":
        return None
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}: expected seconds above 0, or never")
    return value


def _where(ep) -> str:
    """What a program opens: the pty, or the stable link and the pty it points to, or a socket's URL."""
    d = ep.port.describe()
    if d.get("link") and d.get("pty") and d["pty"] != ep.path:
        return f"{ep.path} -> {d['pty']}"
    return ep.path


def _server_names(values: list[str] | None) -> tuple[str, ...]:
    """``--serve a --serve b,c`` -> ("a", "b", "c"), each a registered server (one-line error otherwise)."""
    names: list[str] = []
    for value in values or ():
        for name in filter(None, (n.strip() for n in value.split(","))):
            registry.servers.get(name)  # raises UsageError naming the known ones
            if name not in names:
                names.append(name)
    return tuple(names)


def _serve_help() -> str:
    servers = registry.servers.items()
    known = "; ".join(f"{name}: {getattr(s, 'help', '')}" for name, s in servers) or "none installed"
    return (f"serve the endpoints over the network as NAME (repeatable or comma-separated; "
            f"listed in the manifest). Installed: {known}")


ORDER = 10
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "emulate": "run a bench from a profile until interrupted",
}


def register(sub: argparse._SubParsersAction) -> None:
    from hilbench.profiles import DEFAULT_PROFILE

    e = sub.add_parser("emulate", help=VERBS["emulate"],
                       description="Start the devices of a profile behind pseudo-terminals and run until Ctrl-C. "
                                   "Once every endpoint is ready, the manifest (JSON) is written.")
    e.add_argument("profile", nargs="?", default=DEFAULT_PROFILE,
                   help=f"profile file or bundled profile name (default: {DEFAULT_PROFILE})")
    e.add_argument("--manifest", metavar="FILE", help="write where every endpoint and device is to FILE (JSON)")
    add_set_option(e)
    timing = e.add_mutually_exclusive_group()
    timing.add_argument("--paced", action="store_true", help="model wire time and Return Delay Time on every line")
    timing.add_argument("--unpaced", action="store_true", help="deliver bytes at once on every line")
    e.add_argument("--link-dir", metavar="DIR", help="also make a stable symlink DIR/<endpoint> to each pty")
    e.add_argument("--no-tap", action="store_true",
                   help="do not serve each line's traffic on 127.0.0.1 for `hilbench monitor` / `record`")
    e.add_argument("--serve", metavar="NAME", action="append", help=_serve_help())
    e.add_argument("--bind", metavar="ADDR", default=DEFAULT_BIND, type=_bind_arg,
                   help="address the servers, traffic taps and control channel listen on (default: 127.0.0.1; "
                        "anything else is reachable from other machines and warned about)")
    vt = e.add_argument_group("virtual time", "run the bench on a virtual clock that clients under `hilbench run` "
                                              "share: time jumps from event to event when everyone waits")
    vt.add_argument("--virtual-time", nargs="?", const="hold", choices=("hold", "free"), metavar="MODE",
                    help="run in virtual time (paced); MODE hold (default): time moves only while clients under "
                         "`hilbench run` take part; free: an idle bench runs ahead on its own")
    vt.add_argument("--virtual-epoch", metavar="TIME", type=_epoch_arg,
                    help="the Unix time the virtual clock starts at: ISO 8601 (2026-01-01T00:00:00Z) or seconds "
                         "(default: now); pins the Unix time stamps in payloads")
    vt.add_argument("--lockstep-stall", metavar="SECONDS|never", type=_stall_arg,
                    help="wall seconds a client thread that never waits holds the clock before time follows the "
                         "wall clock (counted and warned; default 1)")
    vt.add_argument("--seed", type=Rule(int, 0), metavar="N",
                    help="seed what a profile leaves random (a bus's fault draws), per medium (default 0)")
    e.set_defaults(func=cmd_emulate)


def _bind_arg(text: str) -> str:
    try:
        return bind_address(text, "--bind")
    except Exception as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
