"""``hilbench lidar``: live scans of a laser scanner (real or emulated) in the terminal, or one as a picture.

SOURCE is a serial port (``/dev/ttyUSB0``, a bench's pty), ``tcp://HOST:PORT``
(a scanner on Ethernet), a bench manifest (``/tmp/bench.json#lidar``: the
endpoint's path, protocol, and the scene for ``--png``) or
``bench:PROFILE#ENDPOINT`` (start that bench here). hilbench acts as the host:
the scanner's client driver (``hilbench.clients`` entry points of role
``scanner``, :class:`~hilbench.clients.scanners.ScannerClient`) starts the
scans its protocol's way, with options of its own, and the tracker the monitor
uses decodes them. This module names no scanner: ``--protocol``'s choices, the
port's speed, the options and the guess for a bare port come from the clients.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import time
from typing import Any

from hilbench import registry
from hilbench.cli.common import CliError, add_set_option, terminate_on_sigterm
from hilbench.errors import DeviceError, UnavailableError, require
from hilbench.rules import POSITIVE_COUNT, SECONDS, Rule

#: ``--timeout``: how long to wait for the first scan (s).
FIRST_SCAN_TIMEOUT = Rule(float, 0, 3600, above=True)
#: The role of the client drivers this verb runs (:attr:`~hilbench.clients.base.ClientDriver.role`).
ROLE = "scanner"


def scanner_clients() -> dict[str, Any]:
    """Protocol -> its :class:`~hilbench.clients.scanners.ScannerClient`, for every registered scanner client."""
    return {c.protocol: c for c in registry.clients.values() if c.role == ROLE}


def protocol_names(clients: dict[str, Any]) -> dict[str, str]:
    """Every name ``--protocol`` takes (protocols and aliases) -> its protocol."""
    return {name: protocol for protocol, c in clients.items() for name in c.names}


def _default_protocols(clients: dict[str, Any]) -> dict[str, str]:
    """Link kind (``serial``, ``tcp``) -> the protocol taken when nothing says which (the first client's)."""
    found: dict[str, str] = {}
    for protocol, c in clients.items():
        for kind in c.default_on:
            found.setdefault(kind, protocol)
    return found


class ScannerAddress:
    """What to open: a device path or HOST:PORT (its location), its protocol, and (for benches) the scene and the scanner's pose.

    ``set_dtr(level)`` drives the port's DTR where pyserial cannot (a bench's pty seen without the port-state
    shim): through the bench's port-state server or its control channel."""

    def __init__(self, location: str, protocol: str | None, *, scene=None, pose: dict | None = None,
                 set_dtr=None, bench=None, label: str = "", world_pose=None) -> None:
        self.location = location
        self.protocol = protocol
        self.scene = scene
        self.pose = pose
        #: For a scanner mounted on a body: a callable giving its pose in the world now (x, y, heading in
        #: degrees), since ``pose`` is then its mount on the body, which moves.
        self.world_pose = world_pose
        self.set_dtr = set_dtr
        self.bench = bench
        self.label = label or location


def _endpoint_of(manifest: dict, fragment: str, where: str) -> dict:
    """The manifest's scanner endpoint: ``#NAME``, else its only one (:func:`~hilbench.bench.manifest.endpoint_of`)."""
    from hilbench.bench.manifest import endpoint_of

    clients = scanner_clients()
    return endpoint_of(manifest, fragment, where, lambda e: e.get("protocol") in clients, "scanner endpoints")


def _control_dtr(address: str | None, device: str | None):
    """DTR of ``device``'s port through the bench's control channel (``dtr`` command), else None."""
    if not address or not device:
        return None

    def set_dtr(level: bool) -> None:
        from hilbench.bench.control import ControlClient

        with contextlib.suppress(Exception):
            ControlClient(address).call("dtr", device=device, dtr=level)

    return set_dtr


def _carry_port_state(manifest: dict) -> None:
    """pyserial's DTR on the bench's ptys goes to its port-state server, as under ``hilbench run``."""
    lines = manifest.get("port_state") or {}
    if not isinstance(lines, dict) or not isinstance(lines.get("socket"), str):
        return  # an older bench: the control channel's dtr command is the way (see _control_motor)
    from hilbench.run import pyserial_shim

    for port in (lines.get("ports") or {}).values():
        with contextlib.suppress(KeyError, TypeError, ValueError):
            pyserial_shim.register(int(port["rdev"]), lines["socket"])
    pyserial_shim.install()


def resolve(source: str, overrides: list[str] | None = None) -> ScannerAddress:
    """A :class:`ScannerAddress` from the command line's SOURCE (``overrides``: ``--set`` of a ``bench:`` source)."""
    if overrides and not source.startswith("bench:"):
        raise CliError(f"--set changes the profile of a bench this command starts: give bench:PROFILE, not {source}")
    if source.startswith("bench:"):
        from hilbench.bench import Bench
        from hilbench.bench.manifest import devices_on
        from hilbench.bench.profile import load_profile

        spec, _, frag = source[len("bench:"):].partition("#")
        bench = Bench(load_profile(spec or "scanners", overrides)).start()
        manifest = bench.manifest()
        try:
            ep = _endpoint_of(manifest, frag, source)
        except Exception:
            bench.stop()  # a bench without the endpoint asked for: stopped before the one-line error
            raise
        dev = next(iter(devices_on(manifest, ep)), {})
        port = bench.endpoint(ep["name"]).port
        lines = getattr(port, "port_state", None)
        set_dtr = (lambda level: lines.host_sets(dtr=level)) if lines is not None else None
        world_pose = None
        if dev.get("body"):
            name = dev.get("name")

            def world_pose():
                return _heading_pose(bench.world.devices()[name]["pose"])
        return ScannerAddress(ep["path"] if ep["type"] != "tcp" else f"{ep['host']}:{ep['port']}", ep["protocol"],
                      scene=bench.profile.tables.get("scene"), pose=dev.get("pose"), set_dtr=set_dtr, bench=bench,
                      label=f"bench {bench.profile.name}#{ep['name']}", world_pose=world_pose)
    path, _, frag = source.partition("#")
    if path.endswith(".json"):
        from hilbench.bench.manifest import devices_on, read_manifest

        # not a manifest: exit status 2; a bench that is not running (no manifest, a stale one): 1
        manifest = read_manifest(path)
        ep = _endpoint_of(manifest, frag, path)
        dev = next(iter(devices_on(manifest, ep)), {})
        scene = None
        if manifest.get("profile"):
            with contextlib.suppress(Exception):
                from hilbench.bench.profile import load_profile

                overrides = manifest.get("set") if isinstance(manifest.get("set"), dict) else None
                scene = load_profile(manifest["profile"], overrides).tables.get("scene")
        location = f"{ep['host']}:{ep['port']}" if ep.get("type") == "tcp" else ep["path"]
        _carry_port_state(manifest)
        world_pose = None
        if dev.get("body") and manifest.get("control"):
            address, name = manifest["control"], dev.get("name")

            def world_pose():
                from hilbench.bench.control import ControlClient

                return _heading_pose(ControlClient(address).world()["devices"][name]["pose"])
        return ScannerAddress(location, ep.get("protocol"), scene=scene, pose=dev.get("pose"),
                      set_dtr=_control_dtr(manifest.get("control"), dev.get("name")), label=f"{path}#{ep['name']}",
                      world_pose=world_pose)
    if os.path.isfile(source):  # a capture or any other file: lidar drives a scanner, it does not replay one
        raise CliError(f"{source}: a file, not a scanner's port: lidar drives a live scanner (a serial port, "
                       "tcp://HOST:PORT, a manifest's FILE.json#ENDPOINT); `hilbench monitor` reads a recording "
                       "of one")
    return ScannerAddress(source, None)


def _driver(address: ScannerAddress, args: argparse.Namespace):
    from hilbench.clients.scanners import ScannerConnection

    clients = scanner_clients()
    protocol = address.protocol
    if args.protocol:
        asked = protocol_names(clients)[args.protocol]
        if protocol and protocol != asked:
            raise CliError(f"{address.label} speaks {protocol}, not {asked}")
        protocol = asked
    if protocol is None:
        kind = ScannerConnection.kind_of(address.location)
        protocol = _default_protocols(clients).get(kind)
        if protocol is None:
            raise CliError(f"{address.label}: which scanner is it? give --protocol")
    client = clients.get(protocol)
    if client is None:
        raise CliError(f"{address.label}: {protocol} is not a scanner protocol")
    try:
        connection = ScannerConnection.open(address.location, client.default_baud)
    except OSError as exc:  # not there, refused, busy: exit status 1
        raise UnavailableError(f"{address.location}: {getattr(exc, 'strerror', None) or exc}") from None
    except ValueError as exc:
        raise CliError(f"{address.location}: {exc}") from None
    return client.open(connection, args, set_dtr=address.set_dtr)


def _stats(tr) -> str:
    rate = tr.scan_rate
    pps = tr.points_per_scan
    return (f"{tr.protocol}: {tr.scans} scans, {f'{rate:.2f} Hz' if rate else '- Hz'}, "
            f"{f'{pps:.0f}' if pps is not None else '-'} points/scan, health {tr.health}, "
            f"checksum failures {tr.checksum_failures}, errors {tr.error_count}")


def _heading_pose(pose: dict) -> dict:
    """A world pose (x, y, theta in rad) as the scanner poses here are given (x, y, heading in degrees)."""
    return {"x": pose["x"], "y": pose["y"], "heading": math.degrees(pose["theta"])}


def save_png(path: str, scan, address: ScannerAddress) -> None:
    """One scan as a picture: over the scene in world coordinates when the pose is known, else sensor frame."""
    matplotlib = require("matplotlib", "plot", "--png")
    matplotlib.use("Agg")
    plt = require("matplotlib.pyplot", "plot", "--png")
    import numpy as np

    ok = scan.ranges > 0
    a, r = scan.angles[ok], scan.ranges[ok]
    fig, ax = plt.subplots(figsize=(7, 6), dpi=100)
    pose = address.pose
    if address.world_pose is not None:  # on a body: where the body has taken it (at the end of the scan)
        try:
            pose = address.world_pose()
        except Exception:  # noqa: BLE001 - no world answer: the sensor frame, which is still right
            pose = None
    if pose is not None:
        x0, y0 = pose["x"], pose["y"]
        h = math.radians(pose["heading"])
        xs, ys = x0 + r * np.cos(h + a), y0 + r * np.sin(h + a)
        if address.scene is not None:
            for seg in address.scene.segments:
                ax.plot([seg[0], seg[2]], [seg[1], seg[3]], color="0.3", lw=2)
            for cx, cy, rad in address.scene.circles:
                ax.add_patch(plt.Circle((cx, cy), rad, color="0.3", fill=False, lw=2))
        ax.plot([x0], [y0], "r^", ms=10, label="scanner")
        ax.arrow(x0, y0, 0.4 * math.cos(h), 0.4 * math.sin(h), color="r", width=0.01)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    else:
        xs, ys = r * np.cos(a), r * np.sin(a)
        ax.plot([0], [0], "r^", ms=10, label="scanner")
        ax.set_xlabel("forward (m)")
        ax.set_ylabel("left (m)")
    ax.scatter(xs, ys, s=4, color="tab:blue", label=f"{len(r)} points")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right")
    ax.set_title(f"{address.label}: one scan")
    fig.tight_layout()
    from hilbench.cli.outputs import output_file

    try:
        with output_file(path, "wb") as f:  # a full disk or a kill leaves an old picture whole
            fig.savefig(f, format=_picture_format(path))
    finally:
        plt.close(fig)


def _picture_format(path: str) -> str:
    from hilbench.cli.outputs import picture_format

    return picture_format("--png", path, "the scan")


def cmd_lidar(args: argparse.Namespace) -> int:
    from hilbench.cli.outputs import check_outputs, source_files

    check_outputs([("--png", args.png)], inputs=source_files(args.source))
    if args.png:
        _picture_format(args.png)
    terminate_on_sigterm()
    address = resolve(args.source, args.overrides)
    try:
        drv = _driver(address, args)
        try:
            drv.start()
            return _run(drv, address, args)
        finally:
            drv.stop()
            drv.connection.close()
    finally:
        if address.bench is not None:
            address.bench.stop()


def _run(drv, address: ScannerAddress, args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live
    from rich.text import Text

    from hilbench.dashboard.scanner_views import polar_lines

    tr = drv.tracker
    deadline = time.monotonic() + args.seconds if args.seconds else None
    want = 1 if args.png else args.scans
    quiet = args.json or args.summary or args.png or not sys.stdout.isatty()
    first_scan_timeout = time.monotonic() + args.timeout

    def done() -> bool:
        if deadline is not None and time.monotonic() >= deadline:
            return True
        return want is not None and tr.scans >= want + (1 if args.png else 0)

    def frame() -> Text:
        size = Console().size
        lines = [f" hilbench lidar  {address.label}", " " + _stats(tr)]
        s = tr.last_scan
        h = max(6, size.height - 3)
        lines += polar_lines(s.angles, s.ranges, size.width - 2, h) if s is not None else [" waiting for scans"]
        return Text("\n".join(lines))

    try:
        if quiet:
            while not done():
                drv.pump(0.05)
                if tr.scans == 0 and time.monotonic() > first_scan_timeout:
                    raise DeviceError(f"{address.label}: no scan within {args.timeout:g} s ({_stats(tr)})")
        else:
            with Live(frame(), auto_refresh=False, screen=True) as live:
                last = 0.0
                while not done():
                    drv.pump(0.05)
                    if time.monotonic() - last >= 0.1:
                        live.update(frame(), refresh=True)
                        last = time.monotonic()
    except KeyboardInterrupt:
        pass
    except ConnectionError as exc:  # the scanner closed the connection
        raise DeviceError(str(exc)) from None
    if args.png:
        if tr.last_scan is None:
            raise CliError(f"{address.label}: no scan to draw ({_stats(tr)})")
        save_png(args.png, tr.last_scan, address)
        print(f"hilbench lidar: one scan ({tr.last_scan.points} points) drawn to {args.png}")
        return 0
    report: dict[str, Any] = tr.summary(source=address.label, timestamps="measured")
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(_stats(tr))
    return 0


ORDER = 45
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "lidar": "live scans of a laser scanner (RPLIDAR, SICK LMS 200, SCIP 2.0) in the terminal",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "lidar", help=VERBS["lidar"],
        description="Drive a laser scanner as its host and show its scans live: a polar plot (straight ahead up), "
                    "scan rate, points per scan, health. SOURCE: a serial port (/dev/ttyUSB0 or a bench pty), "
                    "tcp://HOST:PORT (SCIP 2.0 on Ethernet), a manifest of `hilbench emulate` (FILE.json#ENDPOINT) "
                    "or bench:PROFILE#ENDPOINT (start that bench here). --png draws one scan over the bench's "
                    "scene (a manifest or bench source) or in the sensor frame.")
    p.add_argument("source", help="what to read (see above)")
    clients = scanner_clients()
    defaults = _default_protocols(clients)
    guesses = "".join(f"; {'a serial port' if kind == 'serial' else f'{kind}://'}: {protocol}"
                      for kind, protocol in sorted(defaults.items()))
    p.add_argument("--protocol", choices=sorted(protocol_names(clients)),
                   help=f"the scanner's protocol (default: what a bench says{guesses})")
    add_set_option(p, "bench:PROFILE: ")
    for client in clients.values():  # each scanner's own options (--express, --lms-baud, ...)
        client.add_arguments(p)
    p.add_argument("--scans", type=POSITIVE_COUNT, help="stop after N scans")
    p.add_argument("--seconds", type=SECONDS, help="stop after S seconds (0: no limit)")
    p.add_argument("--timeout", type=FIRST_SCAN_TIMEOUT, default=10.0, help="give up when no scan arrives within S seconds "
                   "(without a terminal; default 10)")
    p.add_argument("--json", action="store_true", help="no live view: print the JSON summary at the end")
    p.add_argument("--summary", action="store_true", help="no live view: print one summary line at the end")
    p.add_argument("--png", metavar="FILE", help="draw one complete scan to FILE (PNG) and exit")
    p.set_defaults(func=cmd_lidar)
