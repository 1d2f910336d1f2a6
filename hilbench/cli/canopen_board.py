"""The CANopen board family's sub-commands of ``hilbench can`` (entry point ``can.canopen``, an extension).

::

    hilbench can dbc PROFILE [-o FILE]                 the DBC of the profile's CANopen boards
    hilbench can eds PROFILE [--device NAME] [-o FILE] a board's EDS
    hilbench can drive BUS [--node N] --vx V [--vy V] [--omega W] [--seconds S]
    hilbench can status|fault|emcy|reset|state --manifest FILE ...   a running bench's boards

``hilbench can`` (:mod:`hilbench.cli.can`) is the generic CAN verb; this
module adds the board's commands to it (:func:`extend`), the way a lab's own
family adds its sub-commands to a verb.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from hilbench.cli.can import BUS_HELP, NODE_ID, add_control_options, knobs, open_bus
from hilbench.cli.common import CliError, add_set_option, terminate_on_sigterm
from hilbench.errors import DeviceError
from hilbench.rules import Rule

#: ``--vx``/``--vy`` (m/s) and ``--omega`` (rad/s): what the setpoint PDO carries (int16, 0.001 per count;
#: :data:`hilbench.protocols.board_can.SETPOINT`, held equal by a test).
SETPOINT_VALUE = Rule(float, -32.768, 32.767)
#: ``drive --seconds``: how long to drive.
DRIVE_SECONDS = Rule(float, 0, 1e9, above=True)
#: ``drive --period``: the setpoint repeat (the board's setpoint timeout is 150 ms by default: longer periods
#: rehearse timeouts).
SETPOINT_PERIOD = Rule(float, 0.001, 60)
#: ``emcy``: the error code and error register (CiA 301's EMCY frame: u16, u8).
EMCY_CODE = Rule(int, 0, 0xFFFF, what="an EMCY error code")
ERROR_REGISTER = Rule(int, 0, 0xFF, what="an error register")

#: The lines this extension adds to ``hilbench can --help``'s list of commands (see :mod:`hilbench.cli`).
SYNOPSIS = """\
  hilbench can dbc PROFILE [-o FILE]                  the DBC of the profile's CANopen boards
  hilbench can eds PROFILE [--device NAME] [-o FILE]  a board's EDS
  hilbench can drive BUS [--node N] --vx V [--vy V] [--omega W] [--seconds S]
  hilbench can status|fault|emcy|reset|state --manifest FILE ...   the boards' control channel"""


# --------------------------------------------------------------------------- artefacts

def _profile(args: argparse.Namespace):
    """The profile read, refusing ``-o`` onto it (or into no directory) first, and one without boards."""
    from hilbench.bench.profile import load_profile
    from hilbench.cli.outputs import check_outputs
    from hilbench.families.canopen_board import profile_boards

    check_outputs([("-o", args.output)], inputs=[args.profile])
    profile = load_profile(args.profile, args.overrides)
    boards = [name for name, _ in profile_boards(profile)]
    if not boards:
        raise CliError(f"{args.profile}: the profile has no CANopen boards")
    return profile, boards


def _write(text: str, out: str | None) -> None:
    """To stdout, or replacing ``out`` in one step (a full disk leaves an old file whole)."""
    from hilbench.cli.outputs import write_output

    write_output(out, text)
    if out not in (None, "-"):
        print(f"wrote {out}", file=sys.stderr)


def cmd_dbc(args: argparse.Namespace) -> int:
    from hilbench.families.canopen_board import FAMILY

    profile, _ = _profile(args)
    _write(FAMILY.artefact("dbc", profile) or "", args.output)
    return 0


def cmd_eds(args: argparse.Namespace) -> int:
    from hilbench.families.canopen_board import FAMILY

    profile, boards = _profile(args)
    if args.device:
        if args.device not in boards:
            raise CliError(f"{args.profile}: no CANopen board named {args.device!r}")
        boards = [args.device]
    if len(boards) > 1:
        raise CliError(f"{args.profile} has several boards ({', '.join(boards)}): name one with --device")
    _write(FAMILY.artefact("eds", profile, boards[0]) or "", args.output)
    return 0


# --------------------------------------------------------------------------- drive

def cmd_drive(args: argparse.Namespace) -> int:
    from hilbench.clients.can_rover import RoverCanClient
    from hilbench.clients.rover_speed import beyond_top_speed

    terminate_on_sigterm()
    warning = beyond_top_speed(args.vx, args.vy, args.omega)
    if warning:  # sent as given, as a ROS driver would: the board saturates its wheels (the real one and ours)
        print(f"hilbench can drive: warning: {warning}", file=sys.stderr)
    bus = open_bus(args.bus)
    with RoverCanClient(bus, args.node, period=args.period, own_bus=True) as rover:
        if not args.no_start:
            rover.start()
        start = time.monotonic()
        rover.drive(args.vx, args.vy, args.omega)
        try:
            while time.monotonic() - start < args.seconds:
                time.sleep(min(0.5, args.seconds))
                pose = rover.pose()
                if pose is not None and args.verbose:
                    print(f"t={time.monotonic() - start:5.2f} s  x={pose[0]:+.3f} m  y={pose[1]:+.3f} m  "
                          f"theta={pose[2]:+.4f} rad", flush=True)
        except KeyboardInterrupt:
            pass
        rover.drive(0.0, 0.0, 0.0)
        time.sleep(0.3)
        rover.halt()
        try:
            odo = rover.wait_for("odometry", timeout=1.0)
        except TimeoutError:
            raise DeviceError(f"node {args.node} sent no odometry (is it OPERATIONAL? sent {rover.sent} setpoints)") \
                from None
        print(json.dumps({"node": args.node, "setpoints_sent": rover.sent,
                          "pose": {"x": odo["x"], "y": odo["y"], "theta": odo["theta"]},
                          "nmt_state": rover.nmt_state, "emcy": [f"0x{c:04X}" for c, _ in rover.emcy]}))
    return 0


# --------------------------------------------------------------------------- control channel

def cmd_control(args: argparse.Namespace) -> int:
    from hilbench.clients.canopen_board import CanClient

    client = CanClient.from_manifest(args.manifest)
    if args.cmd == "status":
        reply = client.status(args.device)
        out = {"status": reply["status"], "bus": reply["bus"]}
    elif args.cmd == "fault":
        out = {"faults": client.fault(args.device, **knobs(args.knobs))}
    elif args.cmd == "emcy":
        out = {"status": client.emcy(args.code, args.register, args.data, args.device)}
    elif args.cmd == "reset":
        out = {"status": client.reset(args.device)}
    else:
        out = {"status": client.nmt(args.state, args.device)}
    print(json.dumps(out, indent=None if args.compact else 2))
    return 0


# --------------------------------------------------------------------------- parser

def extend(cs: argparse._SubParsersAction) -> None:
    """Add the board's sub-commands to ``hilbench can``'s."""
    d = cs.add_parser("dbc", help="export the DBC of a profile's CANopen boards (cantools reads it)")
    d.add_argument("profile", help="profile file or bundled profile name (e.g. mecarover-can)")
    d.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of stdout")
    add_set_option(d)
    d.set_defaults(func=cmd_dbc)

    e = cs.add_parser("eds", help="export a board's EDS (the canopen package and CANopen tools import it)")
    e.add_argument("profile", help="profile file or bundled profile name")
    e.add_argument("--device", help="the board (when the profile has several)")
    e.add_argument("-o", "--output", metavar="FILE", help="write to FILE instead of stdout")
    add_set_option(e)
    e.set_defaults(func=cmd_eds)

    v = cs.add_parser("drive", help="drive the rover board: NMT start, setpoints every 50 ms, the odometry after",
                      description="NMT start, then the velocity setpoint every --period until --seconds pass, then "
                                  "a stop setpoint and the odometry as JSON. A setpoint the PDO cannot carry is "
                                  "refused; one the rover cannot follow (a wheel beyond 105 rpm: |vx| + |vy| + "
                                  "0.3125 m x |omega| above 0.55 m/s) is sent as given, with a warning: the board "
                                  "saturates its wheels as the real one does.")
    v.add_argument("bus", metavar="BUS", help=BUS_HELP)
    v.add_argument("--node", type=NODE_ID, default=2, help="node id (default 2)")
    v.add_argument("--vx", type=SETPOINT_VALUE, default=0.0, help="forward velocity in m/s")
    v.add_argument("--vy", type=SETPOINT_VALUE, default=0.0, help="sideways velocity in m/s (left positive)")
    v.add_argument("--omega", type=SETPOINT_VALUE, default=0.0, help="yaw rate in rad/s")
    v.add_argument("--seconds", type=DRIVE_SECONDS, default=1.0, help="how long (default 1)")
    v.add_argument("--period", type=SETPOINT_PERIOD, default=0.05, help="setpoint repeat in seconds (default 0.05)")
    v.add_argument("--no-start", action="store_true", help="do not send NMT start first")
    v.add_argument("-v", "--verbose", action="store_true", help="print the pose twice a second")
    v.set_defaults(func=cmd_drive)

    for name, help_text in (("status", "a node's state and the bus's figures"),
                            ("fault", "turn a node's fault knobs (KEY=VALUE ...)"),
                            ("emcy", "make a node send an EMCY"),
                            ("reset", "reboot a node"),
                            ("state", "put a node into an NMT state from inside")):
        c = cs.add_parser(name, help=f"control channel: {help_text}")
        add_control_options(c)
        if name == "fault":
            c.add_argument("knobs", nargs="*", metavar="KEY=VALUE")
        if name == "emcy":
            c.add_argument("code", type=EMCY_CODE, help="error code, e.g. 0x2310")
            c.add_argument("--register", type=ERROR_REGISTER, default=0x80, help="error register bits (default 0x80)")
            c.add_argument("--data", default="", help="up to 5 vendor bytes in hex")
        if name == "state":
            c.add_argument("state", choices=("operational", "stopped", "pre-operational", "reset",
                                             "reset-communication"))
        c.set_defaults(func=cmd_control, cmd=name if name != "state" else "nmt")


__all__ = ["SYNOPSIS", "cmd_control", "cmd_dbc", "cmd_drive", "cmd_eds", "extend"]
