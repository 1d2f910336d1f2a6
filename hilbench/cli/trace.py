"""``hilbench trace SOURCE``: per-task timing, periodicity, jitter, histograms, Gantt and Perfetto export.

SOURCE is anything :func:`hilbench.transports.sources.open_source` opens: a
file (text or binary stamps, or a hilbench capture), ``-`` (stdin), a serial
port or pty (``/dev/ttyACM0``, ``serial:///dev/ttyACM0?baud=N``), a UDP port
(``udp://127.0.0.1:PORT``, ``?peer=HOST:PORT`` to register with a board), a
bench's tap (``tcp://...`` or ``manifest.json#endpoint``), or ``bench:PROFILE``.
Files are read to their end; live sources until ``--duration``, ``--reports``
or Ctrl-C, then the results are printed (and written) as for a file.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import re
import sys
import time

from hilbench.cli.common import CliError, add_set_option, open_cli_source, terminate_on_sigterm
from hilbench.rules import LINE_BAUD, POSITIVE_COUNT, SECONDS, Rule

#: ``--bins``: linear histogram bins (each is an array slot: bounded).
BINS = Rule(int, 1, 10_000)
#: ``--tick``: histogram tick in µs.
TICK_US = Rule(float, 0, 1e9, above=True)

_UNITS_US = {"": 1.0, "us": 1.0, "µs": 1.0, "ms": 1e3, "s": 1e6}
_TIME = re.compile(r"\s*([0-9]*\.?[0-9]+(?:e[+-]?\d+)?)\s*(us|µs|ms|s|hz|khz)?\s*", re.I)


def time_us(text: str, *, allow_hz: bool = False, positive: bool = False) -> float:
    """``"250"`` (µs), ``"1.5ms"``, ``"2s"``, and with ``allow_hz`` ``"1kHz"`` (a period of 1000 µs); never
    negative, and with ``positive`` above 0 (a period, deadline, budget or span of 0 has no meaning)."""
    m = _TIME.fullmatch(text)
    if m is None:
        rate = " or a rate such as 100Hz" if allow_hz else ""
        raise argparse.ArgumentTypeError(f"expected a time such as 250, 1.5ms or 2s{rate}, got {text!r}")
    value, unit = float(m[1]), (m[2] or "").lower()
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite time, got {text!r}")
    if unit in ("hz", "khz"):
        if not allow_hz:
            raise argparse.ArgumentTypeError(f"expected a time, got a frequency {text!r}")
        hz = value * (1000 if unit == "khz" else 1)
        if hz <= 0:
            raise argparse.ArgumentTypeError(f"frequency must be positive, got {text!r}")
        return 1e6 / hz
    if positive and value == 0:
        raise argparse.ArgumentTypeError(f"expected a time above 0, got {text!r}")
    return value * _UNITS_US[unit]


def positive_time_us(text: str) -> float:
    """A time above 0 (:func:`time_us`)."""
    return time_us(text, positive=True)


def window_arg(text: str) -> tuple[float, float]:
    """``A:B`` in µs or with units (``1s:2s``); either side may be empty."""
    a, sep, b = text.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected A:B (e.g. 1s:1.02s or 3000:4000), got {text!r}")
    lo = time_us(a) if a.strip() else float("-inf")
    hi = time_us(b) if b.strip() else float("inf")
    if hi < lo:
        raise argparse.ArgumentTypeError(f"window end before its start: {text!r}")
    return lo, hi


def name_value(text: str, *, allow_hz: bool = False, positive: bool = False) -> tuple[str, float]:
    name, sep, value = text.rpartition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (e.g. wheel_ctrl=1ms), got {text!r}")
    return name, time_us(value, allow_hz=allow_hz, positive=positive)


def name_period(text: str) -> tuple[str, float]:
    """``NAME=T`` with T a time or a rate above 0 (``--period``)."""
    return name_value(text, allow_hz=True, positive=True)


def name_positive(text: str) -> tuple[str, float]:
    """``NAME=T`` with T a time above 0 (``--deadline``, ``--budget``)."""
    return name_value(text, positive=True)


def denominator_arg(text: str) -> str | float:
    """``--denominator``: ``span``, ``profiled`` or a time above 0 (µs)."""
    if text in ("span", "profiled"):
        return text
    try:
        return time_us(text, positive=True)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected span, profiled or a time above 0 such as 10s, got {text!r}") \
            from None


HIST_KINDS = ("duration", "latency", "response", "period_error", "duration:linear", "latency:linear",
              "response:linear")


def hist_kinds(text: str) -> tuple[str, ...]:
    """``--hist`` kinds, checked."""
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    for k in kinds:
        if k not in HIST_KINDS:
            raise argparse.ArgumentTypeError(f"unknown histogram {k!r} (expected: {', '.join(HIST_KINDS)})")
    return kinds


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def settings_from(args: argparse.Namespace):
    from hilbench.profiler.settings import ProfilerSettings

    denominator: str | float = "span" if args.denominator is None else args.denominator
    return ProfilerSettings(
        tasks=frozenset(_names(args.tasks)) if args.tasks is not None else None,
        periods=dict(args.period or []),
        merge_gaps=dict(args.merge_gap or []),
        deadlines=dict(args.deadline or []),
        budgets=dict(args.budget or []),
        window=args.window,
        denominator=denominator,
        reorder_us=args.reorder,
        hist_tick_us=args.tick,
        linear_bins=args.bins,
    )


def board_sources(source, pattern: str | None):
    """Which chunk sources carry the board's output: ``--from`` globs, or by default on a board line the
    board's side (the trace instrument's :attr:`~hilbench.profiler.instrument.TraceInstrument.device_sources`:
    a bench names the host's side after the endpoint, the board's after the board), elsewhere everything."""
    from hilbench.profiler.instrument import trace_instrument

    if pattern:
        globs = _names(pattern)
        return lambda name: any(fnmatch.fnmatchcase(name, g) for g in globs)
    inst = trace_instrument(source.protocol)
    if inst is not None and inst.device_sources:
        glob = inst.device_sources
        return lambda name: fnmatch.fnmatchcase(name, glob)
    return lambda name: True


def _device_name(protocol: str | None) -> str:
    """The process name of an exported trace: the source's trace instrument's device, else the first's."""
    from hilbench.profiler.instrument import trace_instrument, trace_instruments

    inst = trace_instrument(protocol) or next(iter(trace_instruments()), None)
    return inst.device_name if inst is not None else "board"


def _default_baud() -> int:
    from hilbench.profiler.instrument import default_baud

    return default_baud()


def _read(args, profiler, source, console) -> int:
    """Feed ``source`` to ``profiler`` until it ends, --duration, --reports or Ctrl-C; returns bytes lost."""
    from hilbench.profiler.live import LiveView

    deadline = time.monotonic() + args.duration if args.duration else None
    wanted = board_sources(source, args.from_)
    verdict: dict[str, bool] = {}
    lost = 0

    def done() -> bool:
        if deadline is not None and time.monotonic() >= deadline:
            return True
        return bool(args.reports and len(profiler.reports) >= args.reports)

    view = LiveView(profiler, console, source=source.name, stats_us=args.live_window,
                    gantt_us=args.live_gantt) if args.live else None
    cut = False  # the reading stopped before the source ended: what it cut in two is no damage
    try:
        if view is not None:
            view.__enter__()
        for chunk in source.chunks(0.05 if source.live else None):
            if chunk is not None:
                ok = verdict.get(chunk.source)
                if ok is None:
                    ok = verdict[chunk.source] = wanted(chunk.source)
                if ok:
                    if chunk.lost:
                        lost += chunk.lost
                    else:
                        profiler.feed(chunk.data)
            if view is not None:
                view.tick()
            if done():
                cut = True
                break
        if view is not None:
            view.tick(force=True)
    except KeyboardInterrupt:
        cut = True  # Ctrl-C ends a live capture; the results still come
    finally:
        if view is not None:
            view.__exit__(None, None, None)
    profiler.finish(cut=cut)
    return lost


def _check_protocol(source) -> None:
    """A source that says it carries something else (a servo bus) is refused in one line."""
    from hilbench.monitor.detect import choose

    if source.protocol:
        choose(source.protocol, verb="trace", name=source.name)


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse outputs that would write over an input or each other, before anything is read."""
    from hilbench.cli.outputs import check_outputs, source_files

    if args.gantt and not args.gantt.lower().endswith((".png", ".svg")):
        raise CliError(f"--gantt {args.gantt}: the Gantt chart is drawn as .png or .svg")
    check_outputs([("--json-out", args.json_out), ("--export", args.export), ("--gantt", args.gantt)],
                  inputs=[*source_files(args.source), *source_files(args.compare)])


def _is_json(path: str) -> bool:
    """Whether ``--compare`` names a JSON document (by its name, or its first byte), not a capture."""
    if path.endswith(".json"):
        return True
    try:
        with open(path, "rb") as f:
            return f.read(64).lstrip()[:1] in (b"{", b"[")
    except OSError:
        return False  # not a plain file: the capture sources say what it is


def _check_baseline_capture(args: argparse.Namespace) -> None:
    """``--compare`` names a capture: it must be a file that carries a board's trace output (one line if not)."""
    from hilbench.errors import UsageError
    from hilbench.profiler.instrument import trace_instruments
    from hilbench.transports.sources import peek

    name = args.compare
    try:
        with open_cli_source(name, baud=args.baud, default_baud=_default_baud()) as source:
            if source.live:
                raise CliError(f"--compare {name}: give a file or a saved --json document")
            _check_protocol(source)  # a capture that says it carries something else (a servo bus)
            data, _ = peek(source, min_bytes=8192)
            if source.protocol is None and not any(inst.sniff(data) for inst in trace_instruments()):
                raise CliError(f"--compare {name}: neither a `hilbench trace --json` document nor a board's "
                               f"trace (no stamps, logs or reports in its first {len(data)} bytes)")
    except CliError as exc:
        raise CliError(str(exc) if str(exc).startswith("--compare") else f"--compare {exc}") from None
    except UsageError as exc:
        raise CliError(f"--compare {exc}") from None


def cmd_profile(args: argparse.Namespace) -> int:
    from hilbench.console import Console
    from hilbench.profiler.compare import compare, load_summary
    from hilbench.profiler.ingest import Profiler
    from hilbench.profiler.report import compare_table, full_report

    _check_outputs(args)
    settings = settings_from(args)
    base = None
    if args.compare:
        # The other run: a saved --json document, or another capture analysed with the same settings.
        try:
            base = load_summary(args.compare) if _is_json(args.compare) else None
        except (OSError, ValueError) as exc:
            raise CliError(f"--compare {exc}") from None
        if base is None:  # checked before a live capture is taken, read after it
            _check_baseline_capture(args)
    terminate_on_sigterm()
    with open_cli_source(args.source, baud=args.baud, default_baud=_default_baud(), overrides=args.overrides) as source:
        _check_protocol(source)
        endless = source.live and not (args.source == "-" and not sys.stdin.isatty())  # a pipe ends by itself
        if endless and not args.live and not args.duration and not args.reports:
            print(f"reading {source.name} until Ctrl-C (or give --duration / --reports)", file=sys.stderr)
        to_stderr = args.json or args.json_out == "-"
        tty = (sys.stderr if to_stderr else sys.stdout).isatty()
        # Tables are wide; a pipe or file gets 132 columns rather than rich's default 80.
        console = Console(stderr=to_stderr, width=None if tty else 132)
        profiler = Profiler(settings.with_(joined_mid_stream=source.live))
        lost = _read(args, profiler, source, console)
        source_name, source_protocol = source.name, source.protocol
        damage = source.quality()
    a = profiler.analyse()
    q = a.quality
    if lost:  # bytes the transport lost (a slow tap client): the board's own counters cannot know
        q["source_bytes_lost"] = lost
        q["untrustworthy"] = True
        q["reasons"].append(f"{lost} bytes lost between the board and the profiler")
    if damage["findings"]:  # the capture file itself is damaged (cut short, corrupted, times out of order)
        q["capture"] = damage
        q["untrustworthy"] = True
        q["reasons"].extend(f"capture {line}" for line in damage["findings"])
    if args.compare and base is None:
        other = Profiler(settings)
        with open_cli_source(args.compare, baud=args.baud, default_baud=_default_baud()) as s2:
            if s2.live:
                raise CliError(f"--compare {args.compare}: give a file or a saved --json document")
            _read(argparse.Namespace(**{**vars(args), "live": False, "duration": None, "reports": None}),
                  other, s2, console)
        base = other.analyse()

    doc = a.to_json()
    doc["source"] = source_name
    cmp = None
    if base is not None:
        cmp = compare(base, a)
        doc["compare"] = {"base": args.compare, **cmp}
    if args.export:
        from hilbench.profiler.export_perfetto import write_trace

        n = write_trace(a, args.export, board=args.board_name or _device_name(source_protocol))
        print(f"wrote {n} trace events to {args.export} (open it in ui.perfetto.dev)", file=sys.stderr)
    if args.gantt:
        from hilbench.profiler.gantt import render_gantt

        try:
            rows = render_gantt(a, args.gantt, window=args.gantt_window, names=_names(args.only) if args.only
                                else None)
        except ValueError as exc:  # a suffix other than .png/.svg (MissingExtra passes: its own one line)
            raise CliError(str(exc)) from None
        print(f"wrote Gantt chart of {len(rows)} rows to {args.gantt}", file=sys.stderr)
    if args.json_out and args.json_out != "-":
        from hilbench.cli.outputs import output_file

        with output_file(args.json_out) as f:
            json.dump(doc, f, indent=1)
    if args.json or args.json_out == "-":
        json.dump(doc, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        only = _names(args.only) if args.only else None
        hist = args.hist or ()
        console.print(full_report(a, only=only, histograms=hist, title=f"Trace profile of {source_name}",
                                  thesis=args.thesis))
        if cmp is not None:
            console.print(compare_table(cmp, args.compare, source_name))
    if args.strict and a.quality["untrustworthy"]:
        print("hilbench: untrustworthy statistics: " + "; ".join(a.quality["reasons"]), file=sys.stderr)
        return 3
    return 0


ORDER = 60
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "trace": "trace profiler: per-task timing, periods, jitter, Gantt, Perfetto export",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "trace", help=VERBS["trace"],
        description="Analyse a board's trace stamps (text in either dialect, or hilbench's binary words, mixed "
                    "with logs and run-time statistics reports): per task and function count, total, mean, min, "
                    "observed max, share of the window, gross and net time, frequency, period, jitter, "
                    "deadline misses, histograms, data quality. Definitions: spec sheet stm32_board.md §5.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
               "  hilbench trace trace.txt --period wheel_ctrl=10ms --gantt trace.png\n"
               "  hilbench trace /dev/ttyACM0 --baud 1152000 --live\n"
               "  hilbench trace udp://127.0.0.1:9000 --reports 1 --json > run.json\n"
               "  hilbench trace caches_on.txt --compare caches_off.txt")
    p.add_argument("source", help="file or capture, - (stdin), serial port or pty, serial://PATH?baud=N, "
                                  "udp://HOST:PORT[?peer=HOST:PORT], tcp://HOST:PORT (a bench tap), a bench "
                                  "manifest.json[#endpoint], or bench:PROFILE")
    p.add_argument("--baud", type=LINE_BAUD, help="serial baud rate (default 115200)")
    add_set_option(p, "bench:PROFILE: ")
    p.add_argument("--from", dest="from_", metavar="GLOB,...",
                   help="read only these chunk sources of a capture or tap (default: on a board line, the "
                        "board's side, '*-board'; elsewhere everything)")
    p.add_argument("--tasks", metavar="A,B,...", help="the task (hook-stamp) names; default: from the run-time "
                                                     "report, plus IDLE and Tmr Svc, else inferred")
    p.add_argument("--period", action="append", type=name_period, metavar="NAME=T",
                   help="nominal period of a task or function (µs, or 10ms, or 100Hz); repeatable")
    p.add_argument("--deadline", action="append", type=name_positive, metavar="NAME=D",
                   help="relative deadline for response times (default: the period)")
    p.add_argument("--budget", action="append", type=name_positive, metavar="NAME=B",
                   help="execution budget for overruns (default: the period)")
    p.add_argument("--merge-gap", action="append", type=name_value, metavar="NAME=G",
                   help="slices closer than G form one job (default: half the period)")
    p.add_argument("--window", type=window_arg, metavar="A:B", help="analyse only stamps in [A, B] (µs or 1s:2s)")
    p.add_argument("--denominator", type=denominator_arg, metavar="span|profiled|T",
                   help="share denominator: stamps' span (default), the report's 'profiled for', or a time")
    p.add_argument("--reorder", type=time_us, default=500_000, metavar="T",
                   help="reorder window for late stamps (default 500ms)")
    p.add_argument("--tick", type=TICK_US, default=1.0, metavar="US", help="histogram tick in µs (default 1)")
    p.add_argument("--bins", type=BINS, default=20, help="linear histogram bins (default 20, at most 10000)")
    p.add_argument("--hist", metavar="KINDS", type=hist_kinds,
                   help="print histograms: duration, latency, response, period_error in PX4 buckets; "
                        "duration:linear, latency:linear, response:linear in linear bins (--bins)")
    p.add_argument("--only", metavar="A,B,...", help="show only these names")
    p.add_argument("--thesis", action="store_true", help="show the thesis's %% column (total over the sum of "
                                                        "all totals) instead of the share of the window")
    p.add_argument("--json", action="store_true", help="print the JSON document instead of tables")
    p.add_argument("--json-out", metavar="FILE", help="also write the JSON document to FILE")
    p.add_argument("--export", metavar="TRACE.json", help="write Chrome/Perfetto trace-event JSON")
    p.add_argument("--board-name", help="process name in the exported trace (default: the board's model)")
    p.add_argument("--gantt", metavar="OUT.png|OUT.svg", help="write a Gantt chart (needs hilbench[plot])")
    p.add_argument("--gantt-window", type=window_arg, metavar="A:B", help="time window of the Gantt chart")
    p.add_argument("--compare", metavar="OTHER", help="compare with another run: a capture file or a --json "
                                                     "document (change in %% of OTHER, as the thesis reports it)")
    p.add_argument("--live", action="store_true", help="live view while the stream runs (refresh <= 10/s)")
    p.add_argument("--live-window", type=positive_time_us, default=1_000_000, metavar="T",
                   help="live view: statistics over the last T (default 1s)")
    p.add_argument("--live-gantt", type=positive_time_us, default=20_000, metavar="T",
                   help="live view: text Gantt of the last T (default 20ms)")
    p.add_argument("--duration", type=SECONDS, metavar="S", help="live sources: stop after S seconds")
    p.add_argument("--reports", type=POSITIVE_COUNT, metavar="N", help="stop after N run-time statistics reports")
    p.add_argument("--strict", action="store_true", help="exit 3 when the data quality makes the figures "
                                                        "untrustworthy")
    p.set_defaults(func=cmd_profile)
