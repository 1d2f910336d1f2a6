"""``hilbench monitor``, ``record`` and ``tap``: watching, recording and tapping a bus.

SOURCE is anything :func:`hilbench.transports.sources.open_source` opens (a
capture file, ``-``, a serial port, ``tcp://127.0.0.1:PORT``, a bench
manifest) or ``bench:PROFILE``, which starts that profile's bench in this
process and watches its line (its pty is shown in the header).

What is decoded comes from the instrument registered for the source's
protocol (:mod:`hilbench.monitor.instrument`): ``--protocol`` names it, a
bench or capture says it, or the monitor tells it from the first bytes. Each
instrument adds its own options, summary and dashboard views.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable

from hilbench.cli.common import (
    CliError,
    add_set_option,
    open_cli_source,
    terminate_on_sigterm,
    warn_beyond_machine,
)
from hilbench.errors import UnavailableError
from hilbench.rules import LINE_BAUD, SECONDS, SPEED, Rule

#: ``--device``: a device's address on its bus (a servo ID 0..253, a CANopen node id 1..127).
DEVICE_ADDRESS = Rule(int, 0, 255, what="a device ID")


def _monitor_instruments() -> list:
    """Instruments ``hilbench monitor`` runs (others belong to other verbs)."""
    from hilbench import registry

    return [i for i in registry.instruments.values() if i.verb == "monitor"]


def _instrument(args: argparse.Namespace, source):
    """The instrument ``--protocol`` or the source names (None: the monitor tells it from the bytes)."""
    from hilbench.monitor.detect import choose

    declared = choose(source.protocol, name=source.name) if source.protocol else None
    if args.protocol:
        asked = choose(args.protocol, name=source.name)
        if declared is not None and declared is not asked:
            raise CliError(f"{source.name} carries {source.protocol}, not {args.protocol}")
        return asked
    return declared or choose(None, name=source.name)


def _options(args: argparse.Namespace):
    """Each instrument's tracker options, checked up front: a function of the instrument chosen."""
    by_protocol = {inst.protocol: inst.tracker_options(args) for inst in _monitor_instruments()}
    return lambda inst: by_protocol.get(inst.protocol, {})


def _view(text: str) -> str:
    """A dashboard view some monitoring instrument has."""
    names = sorted({v for inst in _monitor_instruments() if inst.views() for v in inst.views().views})
    if text not in names:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(names)}, got {text!r}")
    return text


def _writer(path: str | None, source, description: str | None = None, *, force: bool = False):
    """The recording of ``--record`` / ``record``'s FILE: streamed into FILE's ``.partial`` file, renamed into
    place when it ends (:func:`hilbench.cli.outputs.start_recording`)."""
    if not path:
        return None
    from hilbench import registry
    from hilbench.cli.outputs import start_recording
    from hilbench.transports.capture_file import CaptureWriter

    def open_writer(write_path: str):
        if path != "-":  # a recording format of a plug-in (python-can logs for CAN), else the hilbench capture
            for fmt in registry.recorders.values():
                if fmt.accepts(path, source.protocol):  # (the .partial name keeps the suffix it decides by)
                    return fmt.open(write_path, source=source, description=description or source.name)
        info = getattr(getattr(source, "reader", getattr(source, "parser", None)), "info", None)
        if info is not None and info.measured and info.t0_monotonic:
            # A capture's stream (a file, a bench's tap): its description, and its clock's mapping to Unix
            # time (the copy's t0 is its first record, not the original's t0). A tap's address names a port
            # that changes from run to run: two runs of a virtual-time bench then make the same file but for
            # the date.
            return CaptureWriter(write_path, baud=source.baud, protocol=source.protocol or "",
                                 description=description or info.description or source.name,
                                 timestamps=source.timestamps, wall_offset=info.t0_wall - info.t0_monotonic)
        return CaptureWriter(write_path, baud=source.baud, protocol=source.protocol or "",
                             description=description or source.name, timestamps=source.timestamps,
                             wall_offset=getattr(source, "wall_offset", None))

    return start_recording(path, open_writer, force=force)


def _check_record(args: argparse.Namespace, label: str, path: str | None, inputs: list[str]) -> None:
    """Refuse a recording onto an input (the source's, or a file an instrument's options read: ``--dbc``) or
    an existing recording, before anything is opened."""
    from hilbench.cli.outputs import check_outputs

    options = [f for inst in _monitor_instruments() for f in inst.input_files(args)]
    check_outputs([(label, path)], inputs=[*inputs, *options], recordings=(label,), force=args.force)


#: Exit status of ``--strict`` when the input is damaged (as ``hilbench trace --strict``).
STRICT_EXIT = 3


def bench_line(entry: dict, most: int | None = None) -> str:
    """A bench endpoint's overflow in a line: its non-zero counters (``most`` at most), or ``none``."""
    from hilbench.bench.overflow import counted

    counts = counted(entry)
    shown = [f"{k} {v}" for k, v in counts.items() if v]
    if not shown:
        servers = ", ".join(k for k, v in entry.items() if isinstance(v, dict))
        return f"bench {entry.get('endpoint')} overflow: none ({servers or 'nothing bounded'}: 0 refused, evicted, " \
               "dropped, stalled or timed out)"
    more = f" (+{len(shown) - most} more)" if most is not None and len(shown) > most else ""
    return f"bench {entry.get('endpoint')} overflow: {', '.join(shown[:most])}{more}"


class _BenchStatus:
    """The watched bench endpoint's overflow for the dashboard's status: asked in the background (a bench over
    the control channel may be slow to answer) at most every :attr:`PERIOD` s; shown only once non-zero."""

    PERIOD = 2.0

    def __init__(self, ask: Callable[[], dict | None]) -> None:
        self.ask = ask
        self.text = ""
        self._next = 0.0
        self._busy = threading.Lock()

    def __call__(self) -> str:
        now = time.monotonic()
        if now >= self._next and self._busy.acquire(blocking=False):
            self._next = now + self.PERIOD
            threading.Thread(target=self._refresh, name="hilbench-bench-status", daemon=True).start()
        return self.text

    def _refresh(self) -> None:
        from hilbench.bench.overflow import counted

        try:
            entry = self.ask()
            self.text = bench_line(entry, most=3) if entry and any(counted(entry).values()) else ""
        except Exception:  # noqa: BLE001 (the dashboard's status must never break the dashboard)
            self.text = ""
        finally:
            self._busy.release()


def _watch(monitor, args: argparse.Namespace, label: str, status: Callable[[], str],
           stop: Callable[[], bool] | None = None, bench: Callable[[], dict | None] | None = None) -> int:
    """Show the dashboard (or, with --summary/--json, just wait), then print the summary; the exit status.

    ``bench`` (a bench endpoint's source: :attr:`~hilbench.transports.sources.Source.bench_overflow`) adds that
    endpoint's overflow counters, asked when the summary is printed, as ``bench`` (a closed bench: nothing)."""
    from hilbench.console import Console
    from hilbench.transports.atomic_file import WriteError

    deadline = time.monotonic() + args.seconds if args.seconds else None

    def done() -> bool:
        return (deadline is not None and time.monotonic() >= deadline) or (stop is not None and stop())

    quiet = args.summary or args.json
    # A summary into a pipe or file gets 132 columns rather than rich's 80, so its lines do not wrap.
    console = Console(width=None if not quiet or sys.stdout.isatty() else 132)
    try:
        if quiet:
            while not monitor.ended.is_set() and not done():
                # Not ended.wait(0.05): Ctrl-C (or the SIGINT that stops a tap) raised inside Event.wait can
                # land while its condition's lock is released, and CPython 3.11 then turns the
                # KeyboardInterrupt into "RuntimeError: release unlocked lock" with a traceback (seen on CI).
                time.sleep(0.05)
        else:
            from hilbench.dashboard import Dashboard

            dash = Dashboard(monitor, source=label, view=args.view, device=args.device,
                             clock=lambda: monitor.source.clock(), status=status)
            interactive = console.is_terminal and sys.stdin.isatty() and not args.once
            dash.run(console=console, stop=lambda: done() or (not interactive and monitor.ended.is_set()))
    except KeyboardInterrupt:
        pass
    monitor.stop()
    if isinstance(monitor.error, WriteError):
        raise monitor.error  # the recording's file could not be written (it names the file; exit status 1)
    if monitor.error is not None:
        message = str(monitor.error)  # detection's errors name the source already
        raise CliError(message if message.startswith(label) else f"{label}: {message}")
    report = monitor.summary()
    overflow = bench() if bench is not None else None
    if overflow is not None:
        report["bench"] = overflow
    findings = report["data_quality"]["findings"]
    if quiet:
        if args.json:
            print(json.dumps(report, indent=None if args.compact else 2))
        elif monitor.instrument is None or monitor.tracker is None:
            console.print(f"[bold]{report['source']}[/]: {report['note']}", highlight=False)
        else:
            monitor.instrument.print_summary(report, console)
        if not args.json:
            for line in findings:
                console.print(f"data quality: {line}", markup=False, highlight=False)
            if overflow is not None:
                console.print(bench_line(overflow), markup=False, highlight=False)
    elif findings:  # the dashboard is gone: say what was wrong with the input
        for line in findings:
            print(f"hilbench: data quality: {line}", file=sys.stderr)
    if args.strict and findings:
        print(f"hilbench: error: {label}: the input is damaged ({len(findings)} data-quality finding(s)); "
              "--strict", file=sys.stderr)
        return STRICT_EXIT
    return 0


# --------------------------------------------------------------------------- verbs


def cmd_monitor(args: argparse.Namespace) -> int:
    from hilbench.cli.outputs import source_files
    from hilbench.monitor import Monitor

    terminate_on_sigterm()
    speed = args.speed if args.speed is not None else (1.0 if args.realtime else None)
    _check_record(args, "--record", args.record, source_files(args.source))
    options = _options(args)
    with open_cli_source(args.source, baud=args.baud, speed=speed, overrides=args.overrides) as source:
        instrument = _instrument(args, source)
        if args.baud and source.baud != args.baud:
            source.baud = args.baud  # the user knows the line rate better than the source
        mon = Monitor(source, instrument=instrument, record=_writer(args.record, source, force=args.force),
                      options=options)
        mon.start()

        overflow = source.bench_overflow
        bench = _BenchStatus(overflow) if overflow is not None and not (args.summary or args.json) else None

        def status() -> str:
            if mon.ended.is_set():
                word = "ended - q quits" if sys.stdin.isatty() else "ended"
            elif source.live:
                word = "live"
            else:
                word = f"replay {speed:g}x" if speed else "replay"
            extra = bench() if bench is not None else ""
            return f"{word}; {extra}" if extra else word

        return _watch(mon, args, source.name, status, bench=overflow)


def cmd_record(args: argparse.Namespace) -> int:
    from hilbench.cli.outputs import source_files
    from hilbench.transports.chunk import CaptureError

    terminate_on_sigterm()
    speed = args.speed if args.speed is not None else None
    deadline = time.monotonic() + args.seconds if args.seconds else None
    _check_record(args, "FILE", args.file, source_files(args.source))
    with open_cli_source(args.source, baud=args.baud, speed=speed, overrides=args.overrides) as source:
        writer = _writer(args.file, source, force=args.force)
        stop = threading.Event()
        try:
            for chunk in source.chunks(0.1 if source.live else None):
                if chunk is None:
                    writer.tick()  # flushed at least every half second: a kill loses at most that
                else:
                    try:
                        writer.chunk(chunk)
                    except CaptureError as exc:
                        raise CliError(str(exc)) from None
                if deadline is not None and time.monotonic() >= deadline:
                    break
                if stop.is_set():
                    break
        except KeyboardInterrupt:
            pass
        finally:
            writer.close()
        findings = source.quality()["findings"]
    out = sys.stderr if args.file == "-" else sys.stdout
    print(f"recorded {writer.bytes} bytes in {writer.records} records from {source.name} to {args.file}", file=out)
    for line in findings:  # what a damaged input lost on the way (the copy holds what could be read)
        print(f"hilbench record: data quality: {line}", file=sys.stderr)
    return 0


def cmd_tap_udp(args: argparse.Namespace) -> int:
    """``hilbench tap udp LISTEN UPSTREAM``: a UDP relay between clients and an upstream, decoding both ways."""
    from hilbench.monitor import Monitor
    from hilbench.transports.udp import parse_address
    from hilbench.transports.udp_relay import UdpRelay

    if len(args.more) != 2:
        raise CliError("usage: hilbench tap udp LISTEN UPSTREAM (LISTEN: PORT or HOST:PORT, UPSTREAM: HOST:PORT)")
    listen_text, upstream_text = args.more
    try:
        host, _, port_text = listen_text.rpartition(":")
        if not port_text.isdigit() or int(port_text) > 65535:
            raise ValueError(f"LISTEN: expected PORT or HOST:PORT, got {listen_text!r}")
        listen = (host.strip("[]") or "127.0.0.1", int(port_text))
        upstream = parse_address(upstream_text)
    except ValueError as exc:
        raise CliError(f"tap udp: {exc}") from None
    terminate_on_sigterm()
    _check_record(args, "--record", args.record, [])
    options = _options(args)
    try:
        relay = UdpRelay(listen, upstream)
    except OSError as exc:  # taken (or not an address of this machine): exit status 1
        raise UnavailableError(f"tap udp: cannot listen on udp://{listen[0]}:{listen[1]}: {exc.strerror or exc} "
                               "(give another LISTEN port, or 0 for any free one)") from None
    warn_beyond_machine(relay.listen[0], f"the relay (LISTEN {listen_text})",
                        "anyone who reaches this machine can send through it to the upstream; 127.0.0.1:PORT or "
                        "PORT alone keeps it here")
    try:
        label = f"udp relay {relay.listen[0]}:{relay.listen[1]} -> {upstream[0]}:{upstream[1]}"
        instrument = _instrument(args, relay.source)
        mon = Monitor(relay.source, instrument=instrument,
                      record=_writer(args.record, relay.source, label, force=args.force), options=options)
        mon.start()
        relay.start()
        # A banner, not a result: stderr, so stdout holds only the summary (one JSON document with --json).
        print(f"hilbench tap: clients send to udp://{relay.listen[0]}:{relay.listen[1]}, relayed to "
              f"{upstream[0]}:{upstream[1]}", file=sys.stderr, flush=True)
        code = _watch(mon, args, label, lambda: "relaying" if relay.error is None else "failed",
                      stop=lambda: relay.error is not None)
    finally:
        relay.close()
    if relay.error is not None:
        raise CliError(f"tap udp: {relay.error}")
    c = relay.counters()
    print(f"hilbench tap: relayed {c['datagrams_up']} datagrams to the upstream, {c['datagrams_down']} back; "
          f"{c['send_errors']} not sent, {c['clients_dropped']} clients dropped (beyond {relay.max_clients}), "
          f"{c['unwatched_bytes']} bytes relayed unwatched", file=sys.stderr)
    return code


def cmd_tap(args: argparse.Namespace) -> int:
    if args.port == "udp" and args.more:
        return cmd_tap_udp(args)
    if args.more:
        raise CliError(f"unexpected arguments after the port: {' '.join(args.more)} (the UDP relay is "
                       "`hilbench tap udp LISTEN UPSTREAM`)")
    from hilbench.monitor import Monitor
    from hilbench.transports.serial_tap import SerialTap

    terminate_on_sigterm()
    _check_record(args, "--record", args.record, [args.port])
    options = _options(args)
    # The forwarding thread must get the interpreter as soon as its read returns, not when the
    # decoding thread's time slice ends (5 ms by default): a tap must not make the SDK time out.
    sys.setswitchinterval(1e-4)
    tap = SerialTap(args.port, baud=args.baud, link=args.link)  # SourceError: one line, its own exit status
    try:
        label = f"tap {args.port} <-> app {tap.app_path}"
        instrument = _instrument(args, tap.source)
        mon = Monitor(tap.source, instrument=instrument, record=_writer(args.record, tap.source, label,
                                                                        force=args.force), options=options)
        mon.start()
        tap.start()
        print(f"hilbench tap: application port {tap.app_path} <-> {args.port}", file=sys.stderr, flush=True)
        code = _watch(mon, args, label, lambda: "tapping" if not mon.ended.is_set() else "device gone",
                      stop=lambda: tap.error is not None)
    finally:
        tap.close()
    if tap.error is not None:
        raise CliError(f"{args.port}: {tap.error}")
    print(f"hilbench tap: forwarded {tap.bytes_to_device} bytes to the device, {tap.bytes_to_app} to the application",
          file=sys.stderr)
    return code


# --------------------------------------------------------------------------- parsers


def _kinds() -> str:
    from hilbench.transports.sources import source_kinds

    return "; ".join(k.usage for k in source_kinds() if k.usage)



def _formats() -> str:
    """The recording formats plug-ins add, for help texts (``; for can sources also .log .asc ...``)."""
    from hilbench import registry

    extra = [f"for {fmt.name} sources also {' '.join(fmt.suffixes)}" for fmt in registry.recorders.values()]
    return "; " + "; ".join(extra) if extra else ""


FORCE_HELP = ("record even over an existing non-empty file (replaced when the recording ends) or the "
              ".partial file of a recording that did not end")


def _watch_args(p: argparse.ArgumentParser) -> None:
    protocols = [i.protocol for i in _monitor_instruments()]
    p.add_argument("--protocol", choices=protocols,
                   help=f"what the source carries ({', '.join(protocols)}; default: what a bench or capture says, "
                        "else told from the first bytes)")
    p.add_argument("--summary", action="store_true",
                   help="no dashboard: print a summary when the source ends (or on Ctrl-C / --seconds)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON document (implies --summary)")
    p.add_argument("--compact", action="store_true", help="JSON on one line")
    p.add_argument("--strict", action="store_true",
                   help=f"exit {STRICT_EXIT} when the input is damaged (a capture cut short or corrupted, times out "
                        "of order: the data-quality findings)")
    p.add_argument("--seconds", type=SECONDS, help="stop after this many seconds (0: no limit)")
    p.add_argument("--view", type=_view, help="dashboard view to start with (the instrument's, e.g. devices, models, details, "
                                  "log; keys 1-9)")
    p.add_argument("--device", type=DEVICE_ADDRESS, help="device ID the details view shows first (keys: left/right)")
    p.add_argument("--once", action="store_true",
                   help="leave the dashboard when the source ends, even in a terminal")
    p.add_argument("--record", metavar="FILE", help="also record everything to FILE (hilbench capture format"
                                                    f"{_formats()}; see --force)")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    for inst in _monitor_instruments():
        inst.add_arguments(p)


ORDER = 20
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "monitor": "watch a bus: live dashboard, or a summary (--summary --json)",
    "record": "record a bus to a capture file",
    "tap": "sit between an application and a serial port (or UDP clients and an upstream), forwarding and "
           "decoding both ways",
}


def register(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser(
        "monitor", help=VERBS["monitor"],
        description="Decode and track traffic from SOURCE with the instrument of its protocol: a capture file "
                    "(hilbench format or raw dump), '-' (stdin), a serial port (receive-only), "
                    "tcp://127.0.0.1:PORT or a manifest.json of `hilbench emulate` (its traffic tap), or "
                    "bench:PROFILE (start that bench here); every kind: " + _kinds() + ".")
    m.add_argument("source", help="what to watch (see above)")
    m.add_argument("--baud", type=LINE_BAUD,
                   help="line rate in bit/s (for the bus load; a serial port's rate; the byte time of a raw dump)")
    speed = m.add_mutually_exclusive_group()
    speed.add_argument("--realtime", action="store_true", help="replay a capture at its recorded speed")
    speed.add_argument("--speed", type=SPEED, help="replay a capture at this multiple of its recorded speed")
    add_set_option(m, "bench:PROFILE: ")
    _watch_args(m)
    m.set_defaults(func=cmd_monitor)

    r = sub.add_parser(
        "record", help=VERBS["record"],
        description="Store every byte from SOURCE (as for `hilbench monitor`) with its time and direction in FILE "
                    "(hilbench capture format, see docs/formats/capture-format.md; '-' for stdout" + _formats() + "). Stops "
                    "when the source ends, on Ctrl-C / SIGTERM, or after --seconds. Converts raw dumps too.")
    r.add_argument("source", help="what to record")
    r.add_argument("file", help="capture file to write ('-': stdout)")
    r.add_argument("--baud", type=LINE_BAUD, help="line rate in bit/s (a serial port's rate; a raw dump's byte time)")
    r.add_argument("--seconds", type=SECONDS, help="stop after this many seconds (0: no limit)")
    r.add_argument("--speed", type=SPEED, help="read a capture at this multiple of its recorded speed")
    r.add_argument("--force", action="store_true", help=FORCE_HELP)
    add_set_option(r, "bench:PROFILE: ")
    r.set_defaults(func=cmd_record)

    t = sub.add_parser(
        "tap", help=VERBS["tap"],
        usage="%(prog)s [options] PORT | %(prog)s [options] udp LISTEN UPSTREAM",
        description="Create a pty for the application, forward every byte between it and PORT as soon as it is "
                    "read, and decode both directions: dashboard (in a terminal), --summary/--json at the end "
                    "(Ctrl-C, SIGTERM or --seconds), --record FILE. `hilbench tap udp LISTEN UPSTREAM` is a UDP "
                    "relay instead: clients send to LISTEN (PORT or HOST:PORT, 127.0.0.1 by default), each is "
                    "relayed to UPSTREAM (e.g. a micro-ROS agent at 127.0.0.1:8888) from a socket of its own, "
                    "and both directions are decoded with their addresses.")
    t.add_argument("port", help="the real port (e.g. /dev/ttyUSB0, or an emulated bench's pty), or udp")
    t.add_argument("more", nargs="*", metavar="LISTEN UPSTREAM", help="after udp: where clients send, and the upstream")
    t.add_argument("--baud", type=LINE_BAUD,
                   help="fixed baud rate for PORT (default: follow the rate the application sets)")
    t.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the application's pty")
    _watch_args(t)
    t.set_defaults(func=cmd_tap)
