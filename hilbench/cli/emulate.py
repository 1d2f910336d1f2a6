"""``hilbench emulate``: run the devices of a profile until interrupted."""

from __future__ import annotations

import argparse
import ipaddress
import signal
import sys
import threading
from pathlib import Path

from hilbench.bench.profile import DEFAULT_PROFILE, load_profile


def cmd_emulate(args: argparse.Namespace) -> int:
    from hilbench.bench import Bench

    profile = load_profile(args.profile)
    paced = True if args.paced else (False if args.unpaced else None)
    bench = Bench(profile, paced=paced, link_dir=args.link_dir, tap=not args.no_tap)
    manifest = Path(args.manifest) if args.manifest else None
    if manifest:
        bench.check_manifest_path(manifest)  # refuse a user's file or a live bench's manifest before starting
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    bench.start()
    try:
        if bench.has_control_commands:
            bench.serve_control()
        if manifest:
            claim = bench.write_manifest(manifest)
            if claim.took_over is not None:
                print(f"hilbench: {manifest}: took over a stale manifest (pid {claim.took_over} gone)",
                      file=sys.stderr)
        print(f"hilbench: bench {profile.name!r} running ({len(bench.devices)} devices); Ctrl-C stops it")
        for ep in bench.endpoints.values():
            address = getattr(ep.port, "address", None)
            if address is not None and not _is_loopback(address[0]):
                print(f"hilbench: warning: endpoint {ep.name!r} listens on {address[0]}, beyond this machine "
                      "(the profile's bind; the default is 127.0.0.1)", file=sys.stderr)
        for ep in bench.endpoints.values():
            print(f"  {ep.name}: {_where(ep)}  ({ep.family.summary(ep)})")
            if ep.tap is not None:
                where = f"{manifest}#{ep.name}" if manifest else ep.tap.url
                print(f"    traffic tap: {ep.tap.url}  (hilbench {ep.family.tap_reader} {where})")
        if bench.control is not None:
            takers = "; ".join(f"{name}: {', '.join(ep.family.control_commands)}"
                               for ep in bench.endpoints.values() if ep.family.control_commands
                               for name in ep.devices)
            print(f"  control: {bench.control.address_text}  ({takers})")
        if manifest:
            print(f"  manifest: {manifest}")
        sys.stdout.flush()
        stop.wait()
    finally:
        bench.stop()
        bench.remove_manifest()  # only our own, and only while it is still ours
    return 0


def _where(ep) -> str:
    """What a program opens: the pty, or the stable link and the pty it points to, or a socket's URL."""
    d = ep.port.describe()
    if d.get("link") and d.get("pty") and d["pty"] != ep.path:
        return f"{ep.path} -> {d['pty']}"
    return ep.path


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


ORDER = 10


def register(sub: argparse._SubParsersAction) -> None:
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
    e.add_argument("--no-tap", action="store_true",
                   help="do not serve each line's traffic on 127.0.0.1 for `hilbench monitor` / `record`")
    e.set_defaults(func=cmd_emulate)
