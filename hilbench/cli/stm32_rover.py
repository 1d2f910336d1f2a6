"""The rover board family's verbs: ``hilbench send-vel`` and ``teleop`` drive a rover board (real or emulated)
without ROS, ``hilbench board`` presses the button, resets or turns fault knobs of an emulated board in another
process.

The family's own module (registered by its entry points ``send-vel``, ``teleop`` and ``board``), so it may
import the family (:mod:`hilbench.families.stm32_rover`), inside its functions.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

from hilbench.cli.common import CliError
from hilbench.errors import UnavailableError
from hilbench.rules import POSITIVE_COUNT, RATE_HZ, SECONDS, Rule, RuleRef

#: ``teleop --repeat-rate``: 0 (only on key presses) or a rate in Hz.
REPEAT_HZ = Rule(float, 0, 1000)
#: ``send-vel X Y Z``, ``teleop --speed`` / ``--turn``: m/s and rad/s (a Vel2d frame carries doubles; keep them
#: sane).
SPEED_LIMIT = Rule(float, -1000, 1000)


#: ``--baud``: the board family's UART rule (the family is imported only when the option is used).
_board_baud = RuleRef("hilbench.families.stm32_rover", "BOARD_BAUD")


def _print_logs(decoder, data: bytes) -> int:
    n = 0
    for item in decoder.feed(data):
        if type(item).__name__ == "LogMessage":
            print(f"board: {item.clock} [{item.level}]: {item.message}", flush=True)
            n += 1
    return n


def cmd_send_vel(args: argparse.Namespace) -> int:
    from hilbench.protocols import vel2d
    from hilbench.protocols.tracestamp_stream import StreamDecoder
    from hilbench.transports.host_connection import HostConnection

    try:
        link = HostConnection.open(args.port, args.baud)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:  # not there, busy, refused: exit status 1
        raise UnavailableError(f"cannot open {args.port}: {exc}") from None
    from hilbench.clients.rover_speed import beyond_top_speed

    warning = beyond_top_speed(args.x, args.y, args.z)
    if warning:  # sent as given, as the ROS bridge would: the board saturates its wheels
        print(f"hilbench send-vel: warning: {warning}", file=sys.stderr)
    frame = vel2d.build(args.x, args.y, args.z)
    decoder = StreamDecoder()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    sent = 0
    try:
        if args.echo:
            link.register()
            link.read()  # forget what was waiting: only replies to our frames matter
        if args.rate is None:
            link.send(frame)
            sent = 1
            print(f"sent x={args.x:g} y={args.y:g} z={args.z:g}: {frame.hex(' ')}", flush=True)
        else:
            period = 1.0 / args.rate
            t0 = time.monotonic()
            next_t = t0
            print(f"sending x={args.x:g} y={args.y:g} z={args.z:g} at {args.rate:g} Hz; Ctrl-C stops", flush=True)
            while not stop:
                if args.count is not None and sent >= args.count:
                    break
                if args.duration is not None and time.monotonic() - t0 >= args.duration:
                    break
                link.send(frame)
                sent += 1
                next_t += period
                while True:
                    wait = next_t - time.monotonic()
                    if args.echo:
                        _print_logs(decoder, link.read(max(0.0, wait)))
                    elif wait > 0:
                        time.sleep(wait)
                    if time.monotonic() >= next_t:
                        break
            print(f"sent {sent} frames in {time.monotonic() - t0:.2f} s", flush=True)
        if args.echo:
            deadline = time.monotonic() + args.echo_time
            while time.monotonic() < deadline:
                _print_logs(decoder, link.read(0.02))
    except KeyboardInterrupt:
        print(f"sent {sent} frames", flush=True)
    except OSError as exc:  # a UDP target that refuses (nothing listens), a serial adapter unplugged: exit 1
        raise UnavailableError(f"{args.port}: {exc.strerror or exc} (after {sent} frames)") from None
    finally:
        link.close()
    return 0


def cmd_teleop(args: argparse.Namespace) -> int:
    from hilbench.clients import teleop

    try:
        teleop.run(args.port, args.baud, args.speed, args.turn, args.repeat_rate)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return 0


# --------------------------------------------------------------------------- board


def _client(args: argparse.Namespace):
    from hilbench.clients.stm32_rover import BoardClient as ControlClient

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
            rb = st["robot"]
            (ox, oy, oth), (mx, my, mth) = rb["pose"], rb["measured"]
            print(f"  odometry x {ox:.1f} mm, y {oy:.1f} mm, theta {oth:.4f} rad (the firmware's); wheels "
                  f"measured x {mx:.1f} mm, y {my:.1f} mm, theta {mth:.4f} rad (every encoder delta)")
            for line in st["log"][-5:]:
                print(f"  {line}")
    return 0


#: Where ``hilbench --help`` lists each verb (beside the other verbs' ``ORDER``).
ORDER = {"send-vel": 40, "teleop": 40, "board": 50}
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "send-vel": "send Vel2d velocity frames to a rover board (serial port or UDP)",
    "teleop": "drive a rover board from the keyboard (teleop_twist_keyboard keys)",
    "board": "control an emulated board of a running bench (button, reset, faults)",
}


def register(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("send-vel", help=VERBS["send-vel"],
                       description="Send one 28-byte Vel2d frame (x, y in m/s, z in rad/s, CRC-32/MPEG-2) with one "
                                   "write, as the ROS bridge vel2d_bridge does, or stream it with --rate. A velocity "
                                   "the rover cannot follow (a wheel beyond 105 rpm: |x| + |y| + 0.3125 m x |z| "
                                   "above 0.55 m/s) is sent as given, with a warning: the board saturates its wheels.")
    s.add_argument("port", help="serial port (/dev/ttyACM0, an emulated pty) or udp://127.0.0.1:PORT")
    s.add_argument("x", type=SPEED_LIMIT, help="linear.x in m/s")
    s.add_argument("y", type=SPEED_LIMIT, help="linear.y in m/s")
    s.add_argument("z", type=SPEED_LIMIT, help="angular.z in rad/s")
    s.add_argument("--baud", type=_board_baud, default=115_200, help="serial baud rate (default: 115200)")
    s.add_argument("--rate", type=RATE_HZ, metavar="HZ", help="stream the frame at HZ until Ctrl-C (or --count)")
    s.add_argument("--count", type=POSITIVE_COUNT, help="with --rate: stop after N frames")
    s.add_argument("--duration", type=SECONDS, metavar="S", help="with --rate: stop after S seconds")
    s.add_argument("--echo", action="store_true", help="print the log lines the board sends back")
    s.add_argument("--echo-time", type=SECONDS, default=0.5, metavar="S",
                   help="with --echo: how long to listen after the last frame (default: 0.5)")
    s.set_defaults(func=cmd_send_vel)

    t = sub.add_parser("teleop", help=VERBS["teleop"],
                       description="Keyboard teleoperation with teleop_twist_keyboard's keys (u i o / j k l / "
                                   "m , . and shift for strafing; q/z w/x e/c change speeds; anything else stops). "
                                   "Every key sends one Vel2d frame; Ctrl-C sends a stop frame and quits.")
    t.add_argument("port", help="serial port or udp://127.0.0.1:PORT")
    t.add_argument("--baud", type=_board_baud, default=115_200, help="serial baud rate (default: 115200)")
    t.add_argument("--speed", type=SPEED_LIMIT, default=0.5, help="initial linear speed in m/s (default: 0.5)")
    t.add_argument("--turn", type=SPEED_LIMIT, default=1.0, help="initial angular speed in rad/s (default: 1.0)")
    t.add_argument("--repeat-rate", type=REPEAT_HZ, default=0.0, metavar="HZ",
                   help="also resend the current command at HZ (default: 0, only on key presses)")
    t.set_defaults(func=cmd_teleop)

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
