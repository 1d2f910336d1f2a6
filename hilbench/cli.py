"""The ``hilbench`` command line: thin verbs over the library.

Every error is one line on stderr and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path

from hilbench import __version__
from hilbench.profile import DEFAULT_PROFILE, ProfileError, bundled_profiles, load_profile


class CliError(Exception):
    """An error to report on one line with exit status 1."""


def _int(text: str) -> int:
    """Integers in decimal or 0x hex."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


# ---------------------------------------------------------------------- emulate


def cmd_emulate(args: argparse.Namespace) -> int:
    from hilbench.bench import Bench

    profile = load_profile(args.profile)
    paced = True if args.paced else (False if args.unpaced else None)
    bench = Bench(profile, paced=paced, link_dir=args.link_dir)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    bench.start()
    manifest = Path(args.manifest) if args.manifest else None
    try:
        if manifest:
            bench.write_manifest(manifest)
        print(f"hilbench: bench {profile.name!r} running ({len(bench.devices)} devices); Ctrl-C stops it")
        for ep in bench.endpoints.values():
            timing = "paced" if ep.medium.paced else "unpaced"
            n = len(ep.bus.servos)
            print(f"  {ep.name}: {ep.path}  ({ep.spec.protocol}, {ep.spec.baud} baud, {timing}, {n} devices)")
        if manifest:
            print(f"  manifest: {manifest}")
        sys.stdout.flush()
        stop.wait()
    finally:
        bench.stop()
        if manifest:
            manifest.unlink(missing_ok=True)
    return 0


# ---------------------------------------------------------------------- dxl


def cmd_dxl_scan(args: argparse.Namespace) -> int:
    from hilbench import dxl_client

    bauds = tuple(args.baud) if args.baud else dxl_client.SCAN_BAUDS
    found = dxl_client.scan(args.port, bauds, protocol=float(args.protocol))
    if args.json:
        print(json.dumps([{"id": f.id, "model": f.model_number, "model_name": f.model_name,
                           "firmware": f.firmware, "baud": f.baud} for f in found]))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"Dynamixel devices on {args.port}")
    for col in ("ID", "model", "number", "firmware", "baud"):
        table.add_column(col, justify="right")
    for f in found:
        table.add_row(str(f.id), f.model_name, str(f.model_number), str(f.firmware), str(f.baud))
    Console().print(table)
    if not found:
        print(f"no device answered at {', '.join(map(str, bauds))} baud", file=sys.stderr)
        return 1
    return 0


def cmd_dxl_ping(args: argparse.Namespace) -> int:
    from hilbench import dxl_client

    f = dxl_client.ping(args.port, args.id, args.baud, protocol=float(args.protocol))
    if args.json:
        print(json.dumps({"id": f.id, "model": f.model_number, "model_name": f.model_name, "firmware": f.firmware}))
    else:
        print(f"ID {f.id}: {f.model_name} (model {f.model_number}), firmware {f.firmware}")
    return 0


def cmd_dxl_read(args: argparse.Namespace) -> int:
    from hilbench import dxl_client

    address, raw, f = dxl_client.read(args.port, args.id, args.item, args.baud, args.length)
    if args.json:
        value = f.decode(raw[: f.size]) if f and len(raw) >= f.size else int.from_bytes(raw, "little")
        print(json.dumps({"id": args.id, "address": address, "item": f.key if f else None, "value": value,
                          "unit": f.unit if f else "", "raw": raw.hex()}))
    else:
        name = f.name if f else f"address {address}"
        print(f"ID {args.id} {name}: {dxl_client.format_value(raw, f)}")
    return 0


def cmd_dxl_write(args: argparse.Namespace) -> int:
    from hilbench import dxl_client

    address, f = dxl_client.write(args.port, args.id, args.item, args.value, args.baud, args.length)
    print(f"ID {args.id} {f.name if f else f'address {address}'} <- {args.value}")
    return 0


# ---------------------------------------------------------------------- demo and profiles


def cmd_demo(args: argparse.Namespace) -> int:
    from hilbench.demo import run_demo

    result = run_demo(args.profile, args.seconds, paced=not args.unpaced)
    print(f"\ndemo: {result.cycles} control cycles in {result.seconds:.1f} s ({result.rate:.0f}/s), "
          f"{result.failed_reads} failed reads")
    return 0 if result.cycles else 1


def cmd_profiles(args: argparse.Namespace) -> int:
    for name, path in sorted(bundled_profiles().items()):
        prof = load_profile(path)
        marker = " (default)" if name == DEFAULT_PROFILE else ""
        print(f"{name}{marker}: {prof.description}  [{path}]")
    return 0


# ---------------------------------------------------------------------- parser


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="hilbench",
        description="Hardware-in-the-loop benches for robots: emulated devices on real ptys, and tools to talk to them.",
    )
    p.add_argument("--version", action="version", version=f"hilbench {__version__}")
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")

    e = sub.add_parser("emulate", help="run a bench from a profile until interrupted",
                       description="Start the devices of a profile behind pseudo-terminals and run until Ctrl-C. "
                                   "Once every endpoint is ready, the manifest (JSON) is written.")
    e.add_argument("profile", nargs="?", default=DEFAULT_PROFILE,
                   help=f"profile file or bundled profile name (default: {DEFAULT_PROFILE})")
    e.add_argument("--manifest", metavar="FILE", help="write where every endpoint and device is to FILE (JSON)")
    timing = e.add_mutually_exclusive_group()
    timing.add_argument("--paced", action="store_true", help="model wire time and Return Delay Time on every line")
    timing.add_argument("--unpaced", action="store_true", help="deliver bytes at once on every line")
    e.add_argument("--link-dir", metavar="DIR", help="also make a stable symlink DIR/<endpoint> to each pty")
    e.set_defaults(func=cmd_emulate)

    d = sub.add_parser("dxl", help="Dynamixel tools for any port, real or emulated (official SDK)",
                       description="Talk to Dynamixel devices on a serial port through the official dynamixel-sdk.")
    dsub = d.add_subparsers(dest="dxl_verb", required=True, metavar="TOOL")

    def port_args(q: argparse.ArgumentParser, baud: bool = True) -> None:
        q.add_argument("port", help="serial port, e.g. /dev/ttyUSB0 or an emulated pty")
        if baud:
            q.add_argument("--baud", type=_int, default=57_600, help="baud rate (default: 57600)")

    s = dsub.add_parser("scan", help="find IDs and models across baud rates",
                        description="Broadcast-ping at each baud rate and list every device that answers.")
    port_args(s, baud=False)
    s.add_argument("--baud", type=_int, action="append", help="baud rate to try (repeatable; default: all)")
    s.add_argument("--protocol", choices=("1", "2"), default="2", help="protocol version (default: 2)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=cmd_dxl_scan)

    pg = dsub.add_parser("ping", help="ping one ID", description="Ping one ID and print its model and firmware.")
    port_args(pg)
    pg.add_argument("id", type=_int, help="device ID (0-252)")
    pg.add_argument("--protocol", choices=("1", "2"), default="2", help="protocol version (default: 2)")
    pg.add_argument("--json", action="store_true", help="print JSON")
    pg.set_defaults(func=cmd_dxl_ping)

    r = dsub.add_parser("read", help="read a control-table item",
                        description="Read an item by name (present_position) or address (132 [LENGTH]).")
    port_args(r)
    r.add_argument("id", type=_int, help="device ID")
    r.add_argument("item", help="item name (e.g. present_position) or address")
    r.add_argument("length", type=_int, nargs="?", help="bytes to read (default: the item's size)")
    r.add_argument("--json", action="store_true", help="print JSON")
    r.set_defaults(func=cmd_dxl_read)

    w = dsub.add_parser("write", help="write a control-table item",
                        description="Write an item by name (goal_position) or address.")
    port_args(w)
    w.add_argument("id", type=_int, help="device ID")
    w.add_argument("item", help="item name (e.g. goal_position) or address")
    w.add_argument("value", type=_int, help="value to write (decimal or 0x hex; negative for signed items)")
    w.add_argument("--length", type=_int, help="bytes to write (default: the item's size)")
    w.set_defaults(func=cmd_dxl_write)

    dm = sub.add_parser("demo", help="run the default bench and drive it with the official SDK, live",
                        description="Start a bench and run a Sync Read / Sync Write control loop against it "
                                    "with the official dynamixel-sdk, showing what it reads.")
    dm.add_argument("--profile", default=DEFAULT_PROFILE, help=f"profile (default: {DEFAULT_PROFILE})")
    dm.add_argument("--seconds", type=float, default=10.0, help="how long to run (0: until Ctrl-C; default 10)")
    dm.add_argument("--unpaced", action="store_true", help="deliver bytes at once instead of at wire speed")
    dm.set_defaults(func=cmd_demo)

    pr = sub.add_parser("profiles", help="list the bundled profiles", description="List the bundled profiles.")
    pr.set_defaults(func=cmd_profiles)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hilbench`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (ProfileError, CliError) as exc:
        print(f"hilbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:
        from hilbench.dxl_client import DxlError

        if isinstance(exc, DxlError | OSError):
            print(f"hilbench: error: {exc}", file=sys.stderr)
            return 1
        raise


if __name__ == "__main__":
    sys.exit(main())
