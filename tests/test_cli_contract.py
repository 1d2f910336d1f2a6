"""What every verb promises, walked over every registered verb (a new verb must add its cases here):

- every numeric option is a shared rule (:mod:`hilbench.rules`), its range shows in ``--help`` and a value out
  of it is refused in one line naming the option, the value and the range (exit 2);
- the exit-code rule of :mod:`hilbench.errors`: a missing manifest, a refused connection, a taken address and
  a timeout exit 1, a bad value 2, in every verb that can meet them;
- stdout of every ``--json`` is exactly one JSON document (banners go to stderr).
"""

from __future__ import annotations

import argparse
import json
import os
import pty
import socket
import subprocess
import sys
import threading
import tty
from concurrent.futures import ThreadPoolExecutor

import pytest

from hilbench import registry
from hilbench.cli import build_parser, main
from hilbench.cli import trace as trace_cli
from tests.helpers.domains import free_domain

HB = [sys.executable, "-m", "hilbench.cli"]


def verbs() -> set[str]:
    """Every verb the installed modules register (their ``VERBS``)."""
    return {verb for module in registry.verbs.values() for verb in getattr(module, "VERBS", {})}


def parsers():
    """``(command path, parser)`` of every verb and sub-command."""
    def walk(p: argparse.ArgumentParser, path: tuple[str, ...]):
        yield path, p
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk(sub, (*path, name))

    for verb in sorted(verbs()):
        top = build_parser([verb])
        (sub,) = [a for a in top._actions if isinstance(a, argparse._SubParsersAction)]
        yield from walk(sub.choices[verb], (verb,))


# --------------------------------------------------------------------------- numeric options

#: Typed arguments that are not one number of a range, and why.
NOT_A_RANGE = {
    ("board", "knobs"): "KEY=VALUE; the family's fault rules check each value before anything is sent",
    ("dxl", "ping", "id"): "dxl_id: a device ID 0..252, said in its message and help",
    ("dxl", "read", "id"): "dxl_id",
    ("dxl", "write", "id"): "dxl_id",
    ("dxl", "write", "value"): "the written item's own range (the client checks it against the model's table)",
    ("emulate", "bind"): "an address",
    ("emulate", "virtual_epoch"): "a time: ISO 8601 or Unix seconds",
    ("emulate", "lockstep_stall"): "seconds above 0, or never",
    ("monitor", "view"): "a view name",
    ("tap", "view"): "a view name",
}
#: trace's times with units (``1.5ms``, ``100Hz``): finite and not negative (trace.time_us), above 0 where 0
#: has no meaning (a period, deadline, budget, denominator, live window).
TIME_PARSERS = {trace_cli.time_us, trace_cli.positive_time_us, trace_cli.window_arg, trace_cli.name_value,
                trace_cli.name_period, trace_cli.name_positive, trace_cli.denominator_arg, trace_cli.hist_kinds}


def test_every_numeric_option_is_a_rule_and_its_help_shows_the_range(monkeypatch):
    monkeypatch.setenv("COLUMNS", "3000")  # help lines unwrapped, so a range is one string
    seen = 0
    for path, parser in parsers():
        text = parser.format_help()
        for action in parser._actions:
            kind = action.type
            if kind is None or action.choices is not None:
                continue
            where = (*path, action.dest)
            assert kind not in (int, float), f"{' '.join(where)}: bare {kind.__name__}: use a hilbench.rules Rule"
            if hasattr(kind, "expected"):
                seen += 1
                assert f"[{kind.expected}]" in text, f"{' '.join(where)}: --help does not show its range"
            else:
                assert where in NOT_A_RANGE or kind in TIME_PARSERS, f"{' '.join(where)}: {kind!r} is no Rule"
    assert seen > 60


@pytest.mark.parametrize(("argv", "line"), [
    (["can", "drive", "m.json", "--vx", "nan"],
     "hilbench can drive: error: argument --vx: expected a number -32.768..32.767, got nan"),
    (["can", "drive", "m.json", "--vx", "inf"], "argument --vx: expected a number -32.768..32.767, got inf"),
    (["can", "drive", "m.json", "--vx", "99"], "argument --vx: expected a number -32.768..32.767, got 99"),
    (["can", "drive", "m.json", "--seconds", "-1"], "argument --seconds: expected a number > 0"),
    (["can", "drive", "m.json", "--period", "0"], "argument --period: expected a number 0.001..60, got 0"),
    (["can", "dump", "x.log", "-n", "0"], "argument -n/--count: expected an integer 1.."),
    (["can", "sdo", "m.json", "read", "1018", "--node", "128"],
     "argument --node: expected a CANopen node id: an integer 1..127, got 128"),
    (["can", "emcy", "--manifest", "m.json", "0x1zz"], "argument code: expected an EMCY error code"),
    (["lidar", "/dev/null", "--scans", "0"], "argument --scans: expected an integer 1.."),
    (["lidar", "/dev/null", "--timeout", "0"], "argument --timeout: expected a number > 0"),
    (["monitor", "x", "--miss-factor", "1"], "argument --miss-factor: expected a number > 1"),
    (["monitor", "x", "--agent-port", "70000"], "argument --agent-port: expected a port number: an integer 1..65535"),
    (["monitor", "x", "--device", "-1"], "argument --device: expected a device ID: an integer 0..255, got -1"),
    (["send-vel", "x", "nan", "0", "0"], "argument x: expected a number -1000..1000, got nan"),
    (["board", "--after", "-1", "wait-report"], "argument --after: expected an integer 0.."),
    (["trace", "x", "--period", "wheel_ctrl=0"], "argument --period: expected a time above 0, got '0'"),
    (["trace", "x", "--period", "wheel_ctrl=0Hz"], "argument --period: frequency must be positive, got '0Hz'"),
    (["trace", "x", "--deadline", "wheel_ctrl=0ms"], "argument --deadline: expected a time above 0, got '0ms'"),
    (["trace", "x", "--budget", "wheel_ctrl=nan"], "argument --budget: expected a time such as 250"),
    (["trace", "x", "--denominator", "-5"], "argument --denominator: expected span, profiled or a time above 0"),
    (["trace", "x", "--denominator", "0"], "argument --denominator: expected span, profiled or a time above 0"),
    (["trace", "x", "--live-window", "0"], "argument --live-window: expected a time above 0, got '0'"),
    (["trace", "x", "--live-gantt", "0s"], "argument --live-gantt: expected a time above 0, got '0s'"),
    (["trace", "x", "--duration", "inf"], "argument --duration: expected a number 0..1000000000, got inf"),
    (["world", "m.json", "--duration", "nan"], "argument --duration: expected a number 0..1000000000, got nan"),
    (["demo", "--seconds", "inf"], "argument --seconds: expected a number 0..1000000000, got inf"),
    (["lidar", "/dev/null", "--scans", "nan"], "argument --scans: expected an integer 1..2147483648, got 'nan'"),
    (["teleop", "x", "--speed", "nan"], "argument --speed: expected a number"),
])
def test_an_out_of_range_value_is_one_line_naming_option_value_and_range(argv, line, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and line in err, err


def test_can_drive_ranges_are_the_setpoint_pdo_and_the_rover_wheels():
    from hilbench.cli.canopen_board import SETPOINT_VALUE
    from hilbench.clients import can_rover, rover_speed
    from hilbench.fakes import mecanum_robot as robot
    from hilbench.protocols import board_can

    for signal in board_can.SETPOINT.signals:
        if signal.name in ("vx", "vy", "omega"):
            lo, hi = signal.raw_range
            assert (lo * signal.scale, hi * signal.scale) == pytest.approx((SETPOINT_VALUE.lo, SETPOINT_VALUE.hi))
    assert pytest.approx(robot.WHEEL_MAX) == rover_speed.WHEEL_MAX
    assert rover_speed.WHEEL_RADIUS * 1000 == robot.WHEEL_RADIUS and rover_speed.LEVER_ARM * 1000 == robot.L_W_HALF
    assert rover_speed.beyond_top_speed(0.5, 0, 0) is None and rover_speed.beyond_top_speed(0, 0, 1.7) is None
    assert rover_speed.beyond_top_speed(0.3, 0.3, 0).endswith("needs a wheel at 12.00 rad/s; the rover's wheels turn "
                                                              "at most 11.00 rad/s (105 rpm: |x| + |y| + 0.3125 m x "
                                                              "|z| <= 0.55 m/s): the board saturates them")
    with pytest.raises(ValueError, match="vx: expected a number -32.768..32.767"):
        can_rover.RoverCanClient.drive(object.__new__(can_rover.RoverCanClient), float("nan"))


# --------------------------------------------------------------------------- exit codes


class NA:
    """A case that cannot happen to a verb, and why."""

    def __init__(self, why: str) -> None:
        self.why = why


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """What the cases meet: a manifest that is not there, a refused port, a silent TCP server (accepts, never
    answers), a silent pty, a taken UDP and TCP port, a file that is no manifest."""
    d = tmp_path_factory.mktemp("world")
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    refused = s.getsockname()[1]
    s.close()
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(64)
    held: list[socket.socket] = []

    def accept():
        while True:
            try:
                held.append(silent.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    tcp = socket.socket()
    tcp.bind(("127.0.0.1", 0))
    tcp.listen(1)
    master, slave = pty.openpty()
    tty.setraw(slave)
    (d / "bad.json").write_text("[1, 2]")
    yield {"missing": str(d / "gone.json"), "refused": refused, "silent": silent.getsockname()[1],
           "pty": os.ttyname(slave), "udp": udp.getsockname()[1], "tcp": tcp.getsockname()[1],
           "bad": str(d / "bad.json"), "dir": d}
    for sock in (silent, udp, tcp, *held):
        sock.close()
    os.close(master)
    os.close(slave)


def cases(w: dict) -> dict[str, dict[str, list[str] | NA]]:
    """For every verb: the argv of each case (expected exit: missing, refused, taken, timeout 1; bad 2)."""
    m, r, s, out = w["missing"], w["refused"], w["silent"], str(w["dir"] / "out.hbcap")
    tcp = f"tcp://127.0.0.1:{r}"
    none = NA("connects nowhere")
    return {
        "emulate": {"missing": NA("writes its manifest"), "refused": none,
                    "taken": ["emulate", "mecarover-udp", "--set", f"rover.port={w['udp']}"],
                    "timeout": none, "bad": ["emulate", "arm", "--set", "arm.baud=12345"]},
        "run": {"missing": ["run", "--manifest", m, "--", "true"], "refused": NA("the program's status"),
                "taken": NA("listens nowhere"), "timeout": NA("the program's status"),
                "bad": ["run", "--shim", "nope", "--", "true"]},
        "monitor": {"missing": ["monitor", m, "--summary"], "refused": ["monitor", tcp, "--summary"],
                    "taken": ["monitor", "bench:mecarover-can", "--set", f"can.socketcand.port={w['tcp']}",
                              "--summary"],
                    "timeout": ["monitor", f"tcp://127.0.0.1:{s}", "--summary"],
                    "bad": ["monitor", "x.hbcap", "--seconds", "-1"]},
        "record": {"missing": ["record", m, out], "refused": ["record", tcp, out],
                   "taken": ["record", "bench:mecarover-udp", out, "--set", f"rover.port={w['udp']}"],
                   "timeout": ["record", f"tcp://127.0.0.1:{s}", out], "bad": ["record", "x", out, "--baud", "0"]},
        "tap": {"missing": ["tap", "/dev/no-such-port"], "refused": ["tap", f"rfc2217://127.0.0.1:{r}"],
                "taken": ["tap", "udp", str(w["udp"]), "127.0.0.1:9"],
                "timeout": ["tap", f"rfc2217://127.0.0.1:{s}"], "bad": ["tap", "/dev/null", "--baud", "-1"]},
        "dxl": {"missing": ["dxl", "ping", "/dev/no-such-port", "1"],
                "refused": ["dxl", "ping", f"rfc2217://127.0.0.1:{r}", "1"], "taken": NA("listens nowhere"),
                "timeout": ["dxl", "ping", w["pty"], "1"], "bad": ["dxl", "ping", w["pty"], "1", "--baud", "12345"]},
        "send-vel": {"missing": ["send-vel", "/dev/no-such-port", "0", "0", "0"],
                     "refused": ["send-vel", f"udp://127.0.0.1:{r}", "0", "0", "0", "--rate", "100", "--count", "5"],
                     "taken": NA("listens nowhere"), "timeout": NA("waits for no answer (--echo shows what comes)"),
                     "bad": ["send-vel", "x", "nan", "0", "0"]},
        "teleop": {c: NA("needs a terminal (tests/test_cli_rover.py drives it in tmux)")
                   for c in ("missing", "refused", "taken", "timeout")} | {"bad": ["teleop", "x", "--speed", "1e9"]},
        "lidar": {"missing": ["lidar", m], "refused": ["lidar", tcp],
                  "taken": ["lidar", "bench:scanners#ust", "--set", f"ust.port={w['tcp']}"],
                  "timeout": ["lidar", w["pty"], "--timeout", "0.5"], "bad": ["lidar", w["pty"], "--scans", "0"]},
        "can": {"missing": ["can", "send", m, "123#00"],
                "refused": ["can", "send", f"socketcand://127.0.0.1:{r}/can0", "123#00"],
                "taken": ["can", "dump", "bench:mecarover-can", "--set", f"can.socketcand.port={w['tcp']}"],
                "timeout": ["can", "sdo", f"socketcand://127.0.0.1:{s}/can0", "read", "1018", "--node", "2"],
                "bad": ["can", "drive", m, "--vx", "nan"]},
        "board": {"missing": ["board", "--manifest", m, "status"],
                  "refused": ["board", "--control", f"127.0.0.1:{r}", "status"], "taken": NA("listens nowhere"),
                  "timeout": ["board", "--control", f"127.0.0.1:{s}", "status"],
                  "bad": ["board", "--manifest", m, "fault", "drop_rate=2"]},
        "world": {"missing": ["world", m, "--json"], "refused": ["world", "--control", f"127.0.0.1:{r}", "--json"],
                  "taken": NA("listens nowhere"), "timeout": ["world", "--control", f"127.0.0.1:{s}", "--json"],
                  "bad": ["world", m, "--duration", "-1"]},
        "trace": {"missing": ["trace", m], "refused": ["trace", tcp],
                    "taken": ["trace", "bench:mecarover-udp", "--set", f"rover.port={w['udp']}"],
                    "timeout": ["trace", f"tcp://127.0.0.1:{s}"], "bad": ["trace", "x", "--bins", "0"]},
        "demo": {"missing": NA("starts its own bench"), "refused": NA("starts its own bench"),
                 "taken": NA("Dynamixel buses are ptys"), "timeout": NA("starts its own bench"),
                 "bad": ["demo", "--seconds", "-1"]},
        "profiles": {c: NA("lists the bundled profiles") for c in ("missing", "refused", "taken", "timeout")}
        | {"bad": ["profiles", "--no-such-option"]},
        "plugins": {c: NA("lists this installation's plug-ins") for c in ("missing", "refused", "taken", "timeout")}
        | {"bad": ["plugins", "--no-such-option"]},
        "labgrid": {"missing": ["labgrid", "env", m], "refused": NA("reads a manifest only"),
                    "taken": NA("reads a manifest only"), "timeout": NA("reads a manifest only"),
                    "bad": ["labgrid", "env", w["bad"]]},
    }


EXIT = {"missing": 1, "refused": 1, "taken": 1, "timeout": 1, "bad": 2}
#: Verbs whose timeout case ends within about two seconds (dxl's status timeout, lidar --timeout, socketcand's
#: greeting): in the normal set. The others wait 4 to 10 s (a tap's header 5 s, the control channel 10 s): the
#: slow set walks every verb's timeout.
QUICK_TIMEOUTS = {"dxl", "lidar", "can"}


def _complaints(verb: str, case: str, argv: list[str], code: int, err: str) -> list[str]:
    lines = err.strip().splitlines()
    if code == EXIT[case] and len(lines) == 1 and "error:" in lines[0] and "Traceback" not in err:
        return []
    return [f"{verb} {case}: exit {code} (want {EXIT[case]}): {' '.join(argv)}\n    {err.strip()[-400:]}"]


@pytest.fixture
def in_process(capsys, monkeypatch):
    """``run(argv) -> (exit status, stderr)`` of ``hilbench.cli.main`` in this process (no interpreter start:
    fast), undoing what verbs change process-wide (SIGTERM handler, switch interval)."""
    import signal

    sigterm = signal.getsignal(signal.SIGTERM)

    def run(argv: list[str]) -> tuple[int, str]:
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse
            code = exc.code
        return code, capsys.readouterr().err

    with open(os.devnull) as null:
        monkeypatch.setattr(sys, "stdin", null)  # (no terminal: no dashboard)
        yield run
    signal.signal(signal.SIGTERM, sigterm)
    sys.setswitchinterval(0.005)


def test_every_verb_follows_the_exit_code_rule(world, in_process):
    table = cases(world)
    assert set(table) == verbs(), "a verb without exit-code cases (add them above)"
    assert all(set(row) == set(EXIT) for row in table.values())
    wrong = []
    for verb, row in sorted(table.items()):
        for case, argv in row.items():
            if isinstance(argv, NA) or (case == "timeout" and verb not in QUICK_TIMEOUTS):
                continue
            wrong += _complaints(verb, case, argv, *in_process(argv))
    assert not wrong, "\n".join(wrong)
    # a refused or failed recording creates nothing (no out.hbcap, no out.partial.hbcap)
    assert not [p.name for p in world["dir"].iterdir() if p.name.startswith("out")]


def subcommand_cases(w: dict) -> dict[tuple[str, str], dict[str, list[str] | NA]]:
    """The same cases for every sub-command (``can dump``, ``dxl read``, ``profiles from-capture``...): a verb's
    row above tries one of them; each meets the rule on its own path."""
    m, r, s, d = w["missing"], w["refused"], w["silent"], w["dir"]
    refused_m, silent_m = str(d / "refused.json"), str(d / "silent.json")  # manifests of a bench at r, at s
    for path, port in ((refused_m, r), (silent_m, s)):
        with open(path, "w") as f:
            json.dump({"hilbench_manifest": 1, "endpoints": [], "control": f"127.0.0.1:{port}"}, f)
    can_r, can_s = f"socketcand://127.0.0.1:{r}/can0", f"socketcand://127.0.0.1:{s}/can0"
    rfc_r = f"rfc2217://127.0.0.1:{r}"
    gone = str(d / "gone.hbcap")
    no_taken = NA("listens nowhere")

    def control(cmd: list[str], bad: list[str] | NA) -> dict[str, list[str] | NA]:
        return {"missing": ["can", cmd[0], "--manifest", m, *cmd[1:]],
                "refused": ["can", cmd[0], "--manifest", refused_m, *cmd[1:]], "taken": no_taken,
                "timeout": ["can", cmd[0], "--manifest", silent_m, *cmd[1:]], "bad": bad}

    def can_bus(cmd: list[str], bad: list[str]) -> dict[str, list[str] | NA]:
        return {"missing": ["can", cmd[0], m, *cmd[1:]], "refused": ["can", cmd[0], can_r, *cmd[1:]],
                "taken": no_taken, "timeout": ["can", cmd[0], can_s, *cmd[1:]], "bad": bad}

    def dxl(cmd: str, *rest: str) -> dict[str, list[str] | NA]:
        return {"missing": ["dxl", cmd, "/dev/no-such-port", *rest], "refused": ["dxl", cmd, rfc_r, *rest],
                "taken": no_taken, "timeout": ["dxl", cmd, w["pty"], *rest, "--baud", "1000000"],
                "bad": ["dxl", cmd, w["pty"], *rest, "--baud", "12345"]}

    def export(cmd: str) -> dict[str, list[str] | NA]:
        return {"missing": NA("reads a profile: a profile that is not there is unknown (2, below)"),
                "refused": NA("connects nowhere"), "taken": no_taken, "timeout": NA("connects nowhere"),
                "bad": ["can", cmd, str(d / "gone.toml")]}

    def labgrid(cmd: str) -> dict[str, list[str] | NA]:
        return {"missing": ["labgrid", cmd, m], "refused": NA("reads a manifest only"), "taken": no_taken,
                "timeout": NA("reads a manifest only"), "bad": ["labgrid", cmd, w["bad"]]}

    return {
        ("can", "dump"): can_bus(["dump"], ["can", "dump", can_r, "--dbc", str(d / "gone.dbc")]),
        ("can", "send"): can_bus(["send", "123#00"], ["can", "send", m, "800#00"]),
        ("can", "nmt"): can_bus(["nmt", "start"], ["can", "nmt", m, "start", "--node", "200"]),
        ("can", "sdo"): can_bus(["sdo", "read", "1018", "--node", "2"],
                                ["can", "sdo", m, "read", "10000", "--node", "2"]),
        ("can", "drive"): can_bus(["drive", "--vx", "0.1"], ["can", "drive", m, "--seconds", "-1"]),
        ("can", "bus"): control(["bus"], NA("KEY=VALUE: the bench checks its knobs")),
        ("can", "status"): control(["status"], ["can", "status", "--manifest", m, "--no-such-option"]),
        ("can", "fault"): control(["fault", "error_rate=0"], NA("KEY=VALUE: the bench checks its knobs")),
        ("can", "emcy"): control(["emcy", "0x1000"], ["can", "emcy", "--manifest", m, "0x1zz"]),
        ("can", "reset"): control(["reset"], ["can", "reset", "--manifest", m, "--no-such-option"]),
        ("can", "state"): control(["state", "stopped"], ["can", "state", "--manifest", m, "bogus"]),
        ("can", "dbc"): export("dbc"),
        ("can", "eds"): export("eds"),
        ("dxl", "scan"): dxl("scan"),
        ("dxl", "ping"): dxl("ping", "1"),
        ("dxl", "read"): dxl("read", "1", "present_position"),
        ("dxl", "write"): dxl("write", "1", "goal_position", "5"),
        ("labgrid", "env"): labgrid("env"),
        ("labgrid", "exporter-config"): labgrid("exporter-config"),
        ("profiles", "from-capture"): {"missing": ["profiles", "from-capture", gone],
                                       "refused": NA("reads a capture file"), "taken": no_taken,
                                       "timeout": NA("reads a capture file"),
                                       "bad": ["profiles", "from-capture", w["bad"]]},
    }


#: Sub-commands whose timeout waits for the control channel (10 s): walked by the slow set.
SLOW_SUBCOMMAND_TIMEOUTS = {("can", c) for c in ("bus", "status", "fault", "emcy", "reset", "state")}


def test_every_sub_command_follows_the_exit_code_rule(world, in_process):
    table = subcommand_cases(world)
    assert set(table) == {path for path, _ in parsers() if len(path) == 2}, "a sub-command without cases"
    assert all(set(row) == set(EXIT) for row in table.values())
    wrong = []
    for path, row in sorted(table.items()):
        for case, argv in row.items():
            if isinstance(argv, NA) or (case == "timeout" and path in SLOW_SUBCOMMAND_TIMEOUTS):
                continue
            wrong += _complaints(" ".join(path), case, argv, *in_process(argv))
    assert not wrong, "\n".join(wrong)


def test_a_stale_manifest_is_a_bench_not_running(world, in_process):
    """A manifest a killed bench left (its pid gone) is a missing manifest: status 1, one line, in every verb
    that reads one."""
    stale = world["dir"] / "stale.json"
    stale.write_text(json.dumps({"hilbench_manifest": 1, "endpoints": [], "pid": 2**22 + 1, "control": "127.0.0.1:9"}))
    wrong = []
    for argv in (["monitor", str(stale), "--summary"], ["record", str(stale), str(world["dir"] / "x.hbcap")],
                 ["board", "--manifest", str(stale), "status"], ["world", str(stale), "--json"],
                 ["can", "status", "--manifest", str(stale)], ["can", "send", str(stale), "123#00"],
                 ["lidar", str(stale)], ["trace", str(stale)], ["labgrid", "env", str(stale)],
                 ["run", "--manifest", str(stale), "--", "true"]):
        code, err = in_process(argv)
        wrong += _complaints(argv[0], "missing", argv, code, err)
        if "stale manifest" not in err:
            wrong.append(f"{' '.join(argv)}: {err.strip()}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.slow  # real waits of 4 to 10 s, side by side
def test_every_verb_that_waits_times_out_with_status_1_in_one_line(world):
    runs = [(verb, argv) for verb, row in sorted(cases(world).items())
            if not isinstance(argv := row["timeout"], NA)]
    runs += [(" ".join(path), row["timeout"]) for path, row in sorted(subcommand_cases(world).items())
             if path in SLOW_SUBCOMMAND_TIMEOUTS]

    def run(argv: list[str]) -> subprocess.CompletedProcess:
        return subprocess.run([*HB, *argv], capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)

    with ThreadPoolExecutor(len(runs)) as pool:
        done = list(pool.map(run, [argv for _, argv in runs]))
    wrong = [c for (verb, argv), p in zip(runs, done, strict=True)
             for c in _complaints(verb, "timeout", argv, p.returncode, p.stderr)]
    assert not wrong, "\n".join(wrong)


def test_a_taken_port_names_the_endpoint_the_address_and_the_key(world, in_process):
    proc = subprocess.run([*HB, "emulate", "mecarover-udp", "--set", f"rover.port={world['udp']}"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1 and proc.stderr.strip().endswith(
        f"mecarover-udp.toml: endpoint 'rover': cannot listen on UDP port 127.0.0.1:{world['udp']}: Address "
        "already in use (another bench or program has it); change endpoints.rover.port in the profile, or --set "
        "rover.port=0 (any free port)"), proc.stderr
    code, err = in_process(["monitor", "bench:scanners", "--set", f"ust.port={world['tcp']}", "--json"])
    assert code == 1 and err.count("\n") == 1 and (
        f"endpoint 'ust': cannot listen on TCP port 127.0.0.1:{world['tcp']}: Address already in use" in err
        and "change endpoints.ust.port in the profile, or --set ust.port=0 (any free port)" in err), err



@pytest.mark.parametrize(("bind", "reason"), [("10.9.9.9", "Cannot assign requested address"),
                                              ("no-such-host.invalid", "Name or service not known")])
def test_a_bind_address_this_machine_lacks_names_it_and_the_option(bind, reason, in_process):
    code, err = in_process(["emulate", "arm", "--bind", bind])
    assert code == 1 and err.count("\n") == 1 and err.endswith(
        f"endpoint 'arm': cannot listen on traffic tap (TCP port) {bind}:0: {reason}; {bind} is the bench's bind "
        "address (--bind): give one of this machine's addresses\n"), err

# --------------------------------------------------------------------------- one JSON document

BOTH = """\
schema = 1
[endpoints.arm]
type = "pty"
protocol = "dynamixel"
baud = 1_000_000

[endpoints.rover]
type = "pty"
protocol = "vel2d"
baud = 115_200

[endpoints.lidar]
type = "pty"
protocol = "rplidar"
baud = 115_200

[[devices]]
model = "XM430-W350"
ids = [1]
endpoint = "arm"

[[devices]]
model = "stm32f767-rover"
name = "rover"
endpoint = "rover"

[[devices]]
model = "rplidar-a1"
name = "lidar"
endpoint = "lidar"
motor = "always"
"""


def _small_capture(tmp_path):
    """A raw dump of one servo's Ping and a read of its position, with their replies."""
    from hilbench.protocols import dynamixel as dxl

    path = tmp_path / "bus.bin"
    path.write_bytes(dxl.instruction_packet(1, dxl.Instruction.PING) + dxl.status_packet(1, 0, bytes([0xFC, 3, 52]))
                     + dxl.instruction_packet(1, dxl.Instruction.READ, bytes([132, 0, 4, 0]))
                     + dxl.status_packet(1, 0, (2048).to_bytes(4, "little")))
    return path


def test_every_json_option_prints_one_json_document(tmp_path, hilbench_emulator):
    prof = tmp_path / "both.toml"
    prof.write_text(BOTH)
    bench = hilbench_emulator(str(prof), "--unpaced")
    mfile = bench["manifest_path"]
    path = {ep["name"]: ep["path"] for ep in bench["endpoints"]}
    commands = {
        ("plugins",): ["plugins", "--json"],
        ("monitor",): ["monitor", f"{mfile}#arm", "--json", "--seconds", "0.5"],
        ("tap",): ["tap", path["arm"], "--json", "--seconds", "0.5"],
        ("dxl", "scan"): ["dxl", "scan", path["arm"], "--baud", "1000000", "--json"],
        ("dxl", "ping"): ["dxl", "ping", path["arm"], "1", "--baud", "1000000", "--json"],
        ("dxl", "read"): ["dxl", "read", path["arm"], "1", "present_position", "--baud", "1000000", "--json"],
        ("lidar",): ["lidar", f"{mfile}#lidar", "--scans", "2", "--json"],
        ("board",): ["board", "--manifest", mfile, "--json", "status"],
        ("world",): ["world", mfile, "--json"],
        ("trace",): ["trace", f"{mfile}#rover", "--duration", "1", "--json"],
        ("profiles", "from-capture"): ["profiles", "from-capture", str(_small_capture(tmp_path)), "--baud", "1000000",
                                       "--verify", "--speed", "0", "--json"],
    }
    with_json = {path for path, parser in parsers() if any("--json" in a.option_strings for a in parser._actions)}
    assert with_json == set(commands), "a verb with --json and no case here"
    commands[("tap", "udp")] = ["tap", "udp", "0", "127.0.0.1:9", "--summary", "--json", "--seconds", "0.5"]

    def run(keys: list[tuple[str, ...]]) -> list[tuple[tuple[str, ...], subprocess.CompletedProcess]]:
        return [(k, subprocess.run([*HB, *commands[k]], capture_output=True, text=True, timeout=60)) for k in keys]

    arm = [k for k in commands if k[0] in ("dxl", "tap") and k != ("tap", "udp")]  # one line: one at a time
    with ThreadPoolExecutor(4) as pool:
        groups = pool.map(run, [arm, *([k] for k in commands if k not in arm)])
    for key, proc in (item for group in groups for item in group):
        assert proc.returncode == 0, (key, proc.stderr)
        try:
            json.loads(proc.stdout)  # exactly one document: a banner before or after it fails here
        except ValueError as exc:
            raise AssertionError(f"{' '.join(key)}: stdout is not one JSON document ({exc}): {proc.stdout[:300]!r}") \
                from None
    assert bench["process"].poll() is None


def test_set_moves_a_bench_and_is_checked_as_the_profile(hilbench_emulator, hilbench_bench, in_process):
    free = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    free.bind(("127.0.0.1", 0))
    port = free.getsockname()[1]
    free.close()
    m = hilbench_emulator("mecarover-udp", set={"rover.port": port, "rover.baud": 230_400})
    (ep,) = m["endpoints"]
    assert (ep["port"], ep["baud"]) == (port, 230_400)
    assert m["set"] == {"rover.port": port, "rover.baud": 230_400}  # (readers of the profile file apply them)
    domain = free_domain(8)
    b = hilbench_bench("freertps", set={"nodes.domain_id": domain, "devices.echo.participant_index": 7})
    assert b.endpoint("nodes").spec.options["domain_id"] == domain and b.profile.devices[2].participant_index == 7
    proc = subprocess.run([*HB, "emulate", "wolfgang", "--set", "dxl.baud=12345"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and proc.stderr.strip().endswith(
        "wolfgang.toml: endpoints.dxl.baud: expected a Dynamixel baud rate (one of 9600, 19200, 57600, 115200, "
        "200000, 250000, 400000, 500000, 1000000, 2000000, 2250000, 2500000, 3000000, 4000000, 4500000), got "
        "12345 (set: dxl.baud=12345)"), proc.stderr
    for argv, needle in ((["emulate", "arm", "--set", "nope.x=1"], "override 'nope.x': no endpoint or table 'nope' "
                                                                   "(endpoints: arm; tables: defaults, description"),
                         (["emulate", "arm", "--set", "arm.baud"], "override 'arm.baud': expected KEY=VALUE"),
                         (["monitor", "x.hbcap", "--set", "arm.baud=1"], "--set changes the profile of a bench this "
                                                                         "command starts: give bench:PROFILE")):
        code, err = in_process(argv)
        assert code == 2 and err.count("\n") == 1 and needle in err, err


@pytest.mark.hilbench_profile("mecarover-udp", set={"rover.port": 0, "rover.baud": 230_400})
def test_the_profile_marker_takes_set_as_emulate_does(bench):
    assert bench.endpoint("rover").spec.baud == 230_400
    assert bench.manifest()["set"] == {"rover.port": 0, "rover.baud": 230_400}


def test_set_in_the_pytest_fixtures_is_checked_as_the_profile(hilbench_bench, hilbench_emulator):
    from hilbench.bench.checks import ProfileError

    with pytest.raises(ProfileError, match=r"arm\.toml: endpoints\.arm\.baud: expected a Dynamixel baud rate .* got "
                                           r"12345 \(set: arm\.baud=12345\)$"):
        hilbench_bench("arm", set={"arm.baud": 12345})
    with pytest.raises(ProfileError, match="override 'nope.x': no endpoint or table 'nope'"):
        hilbench_bench("arm", set={"nope.x": 1})
    with pytest.raises(RuntimeError, match=r"exited with 2: .*\(set: arm\.baud=12345\)$"):
        hilbench_emulator("arm", set={"arm.baud": 12345})
