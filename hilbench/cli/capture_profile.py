"""``hilbench profiles from-capture CAPTURE``: a bench profile from a capture of a real bus.

CAPTURE is anything the monitor reads from a file: a hilbench capture, a raw
dump (``--baud`` gives its rate), a pcap file, a python-can log or candump.
The traffic's protocol comes from the capture (or ``--protocol``, or its
first bytes); the inferrer registered for it (``hilbench.inferrers``) makes
the profile. It is written to ``-o FILE`` (replaced in one step; an existing
file only with ``--force``) or printed. ``--verify`` starts the bench it
describes, replays the capture's requests at their captured pace and reports
how many replies match.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time

from hilbench.cli.common import CliError
from hilbench.rules import LINE_BAUD, Rule

#: ``--speed``: replay speed for ``--verify`` (1: the captured pace; 0: as fast as the bench answers).
SPEED = Rule(float, 0.0, 1000.0)
#: ``--min-ratio``: the share of matching replies below which ``--verify`` fails.
RATIO = Rule(float, 0.0, 1.0)
#: Exit status when ``--verify`` finds fewer matches than ``--min-ratio``.
VERIFY_FAILED = 3


def _open(args: argparse.Namespace):
    from hilbench.cli.common import open_cli_source

    if args.capture.startswith("bench:"):
        raise CliError("from-capture reads a capture file; record a bench first (hilbench record bench:P FILE)")
    return open_cli_source(args.capture, baud=args.baud)


def cmd_from_capture(args: argparse.Namespace) -> int:
    from hilbench.bench.capture_profile import (
        InferOptions,
        check_profile_text,
        infer,
        protocol_source,
        render,
        traffic_of,
    )
    from hilbench.cli.outputs import check_outputs, source_files, write_output

    out = args.output
    check_outputs([("-o", out)], inputs=source_files(args.capture))
    if out not in (None, "-") and os.path.exists(out) and os.path.getsize(out) and not args.force:
        raise CliError(f"-o {out} exists: --force replaces it (a profile you edited would be lost)")
    if os.path.isdir(args.capture):
        raise CliError(f"{args.capture}: is a directory")
    started = time.monotonic()
    with _open(args) as source:
        if source.live:
            raise CliError(f"{args.capture}: give a capture file (record a live bus with hilbench record first)")
        told, rivals = protocol_source(source, args.protocol), []
        protocol, source = traffic_of(source, args.protocol, rivals=rivals)
        draft, facts = infer(source, protocol, baud=args.baud, baud_from="--baud" if args.baud else "",
                             protocol_from=told, rivals=rivals,
                             options=InferOptions(keep_silent=args.keep_silent))
    command = "hilbench profiles from-capture " + " ".join(shlex.quote(a) for a in _argv(args))
    text = render(draft, facts, command=command)
    name = out if out not in (None, "-") else "<generated profile>"
    profile = check_profile_text(text, name)  # what it writes loads with `hilbench emulate` unchanged
    inferred = time.monotonic() - started
    active = sum(not t.disabled for t in draft.devices)
    commented = len(draft.devices) - active
    if out not in (None, "-"):
        write_output(out, text)
        print(f"wrote {out}: {active} device entr{'y' if active == 1 else 'ies'}"
              + (f" (and {commented} commented out)" if commented else "")
              + f" from {facts.name} in {inferred:.2f} s", file=sys.stderr)
    elif not args.json:
        write_output(None, text)
    report = _verify(args, draft, profile) if args.verify else None
    if args.json:
        doc = {"capture": facts.name, "protocol": facts.protocol, "baud": facts.baud, "timestamps": facts.timestamps,
               "profile": out if out not in (None, "-") else None, "devices": active, "commented_out": commented,
               "seen": draft.seen, "guessed": draft.guessed, "contradictions": draft.contradictions,
               "unread": draft.unread, "pattern": draft.pattern, "read": {str(k): v for k, v in draft.read.items()},
               "seconds": round(inferred, 3),
               "verify": report.to_json() if report is not None else None}
        if out in (None, "-"):
            doc["text"] = text
        print(json.dumps(doc, indent=1))
    if report is not None and report.ratio < args.min_ratio:
        print(f"hilbench: verify: {100 * report.ratio:.1f} % of the replies match, less than "
              f"{100 * args.min_ratio:.0f} %", file=sys.stderr)
        return VERIFY_FAILED
    return 0


def _argv(args: argparse.Namespace) -> list[str]:
    """The command line that made the profile (for its header): what changes the profile, not --verify."""
    out = [os.path.basename(args.capture)]
    if args.output not in (None, "-"):
        out += ["-o", os.path.basename(args.output)]
    if args.baud:
        out += ["--baud", str(args.baud)]
    if args.protocol:
        out += ["--protocol", args.protocol]
    if args.keep_silent:
        out.append("--keep-silent")
    return out


def _verify(args: argparse.Namespace, draft, profile):
    """Start the bench the profile describes and replay the capture against it; the report."""
    from hilbench.bench import Bench

    if draft.replay is None:
        raise CliError("--verify: this kind of traffic cannot be replayed")
    speed = None if args.speed == 0 else args.speed
    with Bench(profile).start() as bench:
        report = draft.replay.run(bench, speed=speed)
    if not args.json:  # (the profile may be on stdout: the report goes where it does not mix with it)
        for line in report.lines():
            print(line, file=sys.stderr if args.output in (None, "-") else sys.stdout)
    return report


def add_commands(profiles: argparse.ArgumentParser) -> None:
    """``profiles``' subcommands (``hilbench profiles`` alone still lists the bundled profiles)."""
    sub = profiles.add_subparsers(dest="profiles_command", metavar="COMMAND")
    p = sub.add_parser(
        "from-capture", help="a bench profile from a capture of a real bus",
        description="Write a bench profile from a capture of a real bus: the devices that answered (models "
                    "from Ping replies or model-number reads, else guessed from the addresses the host used), "
                    "the baud rate, the first values read, the host's traffic pattern; CAN nodes with their "
                    "heartbeats, PDOs and SDO values. The header says what was seen and what was guessed.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
               "  hilbench profiles from-capture robot.hbcap -o robot.toml\n"
               "  hilbench profiles from-capture wolfgang_trace.bin --baud 2000000 --verify\n"
               "  hilbench profiles from-capture can.log -o rover-can.toml --verify")
    p.add_argument("capture", help="a hilbench capture, a raw dump, a pcap file, a python-can log or candump file")
    p.add_argument("-o", "--output", metavar="PROFILE.toml", help="write the profile here (default: print it)")
    p.add_argument("--force", action="store_true", help="replace an existing -o file")
    p.add_argument("--baud", type=LINE_BAUD, help="the bus's baud rate (a raw dump has none)")
    p.add_argument("--protocol", metavar="P", help="the traffic's protocol when the capture does not say it "
                                                   "(dynamixel, dynamixel1, feetech, can)")
    p.add_argument("--keep-silent", action="store_true",
                   help="IDs asked but never answering become absent devices (default: comments)")
    p.add_argument("--verify", action="store_true",
                   help="start the bench, replay the capture's requests and report matching replies")
    p.add_argument("--speed", type=SPEED, default=1.0,
                   help="--verify: replay speed (1: the captured pace; 0: as fast as the bench answers)")
    p.add_argument("--min-ratio", type=RATIO, default=0.0,
                   help=f"--verify: exit {VERIFY_FAILED} when fewer replies match (0..1)")
    p.add_argument("--json", action="store_true", help="print one JSON document: what was seen and guessed, the "
                                                      "profile's text (without -o) and --verify's report")
    p.set_defaults(func=cmd_from_capture)


__all__ = ["add_commands", "cmd_from_capture"]
