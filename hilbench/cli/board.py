"""``hilbench board``: press the button, reset, or turn fault knobs of an emulated board in another process."""

from __future__ import annotations

import argparse
import json

from hilbench.cli.common import CliError
from hilbench.rules import RuleRef


def _client(args: argparse.Namespace):
    from hilbench.families.stm32_rover import BoardClient as ControlClient

    # A ControlError's exit status is the bench's judgement (2: the request, 1: the bench or board failed).
    if args.control:
        return ControlClient(args.control)
    if args.manifest:
        return ControlClient.from_manifest(args.manifest)
    raise CliError("tell me where the bench is: --manifest FILE (from hilbench emulate) or --control HOST:PORT")


def _rule(name: str) -> RuleRef:
    """The board family's rule ``name`` as an argparse type (the family is imported when it is used)."""
    return RuleRef("hilbench.families.stm32_rover", name)


def _knob(text: str) -> tuple[str, float | int]:
    key, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key, int(value, 0)  # counts (drop_next=3) stay integers for the integer rules
    except ValueError:
        pass
    try:
        return key, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number after {key}=, got {value!r}") from None


def cmd_board(args: argparse.Namespace) -> int:
    from hilbench.families.stm32_rover import FAULT_RULES, check_fault_knobs

    if args.action == "fault":
        if not args.knobs:
            raise CliError(f"fault: give KEY=VALUE knobs ({', '.join(FAULT_RULES)})")
        knobs = check_fault_knobs(dict(args.knobs))  # the bench's own rules, before anything is sent
    elif args.knobs and args.action != "micro-ros":
        raise CliError(f"{args.action}: takes no KEY=VALUE knobs (only fault and micro-ros do)")
    client = _client(args)
    if args.action == "button":
        st = client.button(args.device)
        print(f"{st['name']}: button pressed (sampling {'on' if st['sampling'] else 'off'}, window {st['window']})")
    elif args.action == "reset":
        st = client.reset(args.device)
        print(f"{st['name']}: reset (boot {st['boots']})")
    elif args.action == "fault":
        faults = client.fault(args.device, **knobs)
        print(json.dumps(faults) if args.json else ", ".join(f"{k}={v:g}" for k, v in faults.items()))
    elif args.action == "log":
        for line in client.log(args.device):
            print(line)
    elif args.action == "micro-ros":
        knobs = dict(args.knobs)
        unknown = set(knobs) - {"zeroed_next"}
        if unknown:
            raise CliError(f"micro-ros: unknown knob {sorted(unknown)[0]!r} (expected zeroed_next=N)")
        st = client.micro_ros(args.device, **{k: int(v) for k, v in knobs.items()})
        if args.json:
            print(json.dumps(st))
        else:
            c = st["counters"]
            print(f"micro-ROS link to {st['agent']}: {st['state']}, key {st['client_key']}, from {st['local']}")
            print(f"  sessions {c['sessions']}, samples out {c['samples_out']} in {c['samples_in']}, "
                  f"cmd_vel {st['cmd_vel_received']}, zeroed {c['zeroed']}, creation failures "
                  f"{c['creation_failures']}")
    elif args.action == "wait-report":
        reply = client.wait_report(args.device, timeout=args.timeout, after=args.after)
        rep = reply["report"]
        if args.json:
            print(json.dumps(rep))
        else:
            print(f"report: ctx switches {rep['ctx_switches']}, {rep['closing']} {rep['closing_us']} us")
    else:
        st = client.status(args.device)
        if args.json:
            print(json.dumps(st))
        else:
            tr = st["truth"]
            print(f"{st['name']}: {st['preset']} ({'caches' if st['caches'] else 'no caches'}), output "
                  f"{st['output']}, {st['baud']} baud, boot {st['boots']}, t={st['now_us'] / 1e6:.3f} s")
            print(f"  sampling {'on' if st['sampling'] else 'off'}, window {st['window']}, frames ok "
                  f"{tr['frames_ok']}, crc errors {tr['frames_crc_error']}, length errors "
                  f"{tr['frames_length_error']}, receive overruns {tr.get('rx_overruns', 0)} "
                  f"({tr.get('rx_overrun_bytes', 0)} bytes dropped)")
            print(f"  stamps recorded {tr['stamps_recorded']}, sent {tr['stamps_sent']}, dropped "
                  f"{tr['stamps_dropped']}, records lost {tr['records_lost']}")
            for line in st["log"][-5:]:
                print(f"  {line}")
    return 0


ORDER = 50
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "board": "control an emulated board of a running bench (button, reset, faults)",
}


def register(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("board", help=VERBS["board"],
                       description="Talk to the control channel of `hilbench emulate`: press the user button "
                                   "(starts/stops a trace window), reset the board, turn fault knobs, read status.")
    where = b.add_mutually_exclusive_group()
    where.add_argument("--manifest", metavar="FILE", help="the manifest hilbench emulate wrote")
    where.add_argument("--control", metavar="HOST:PORT", help="the control address (printed by hilbench emulate)")
    b.add_argument("--device", help="board name (default: the only board)")
    b.add_argument("--json", action="store_true", help="print JSON")
    b.add_argument("action", choices=("status", "button", "reset", "fault", "log", "wait-report", "micro-ros"),
                   help="what to do (micro-ros: the micro-ROS link of a micro-ros-* preset)")
    b.add_argument("knobs", nargs="*", type=_knob, metavar="KEY=VALUE",
                   help="fault knobs: drop_rate, corrupt_rate (per byte), drop_next, corrupt_next (bytes), stall (s); "
                        "micro-ros: zeroed_next (datagrams sent zeroed)")
    b.add_argument("--timeout", type=_rule("WAIT_TIMEOUT"), default=30.0,
                   help="wait-report: seconds to wait (default: 30)")
    b.add_argument("--after", type=_rule("REPORT_COUNT"), help="wait-report: return once more than N reports exist")
    b.set_defaults(func=cmd_board)
