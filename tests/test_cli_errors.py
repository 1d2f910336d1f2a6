"""Every error is one line with the documented exit status (2: what you asked, 1: what the system refused);
a closed pipe is no error; the command line checks ranges with the rules the profile loader uses."""

from __future__ import annotations

import subprocess
import sys

import dynamixel_sdk.port_handler as port_handler
import pytest

from hilbench.bench.checks import Checker, ProfileError
from hilbench.families.dynamixel import BUS_BAUD, DYNAMIXEL_BAUDS
from hilbench.families.stm32_rover import FAULT_RULES, check_fault_knobs
from hilbench.protocols.dynamixel_models import SDK_BAUDS
from hilbench.rules import LINE_BAUD, Rule, RuleError
from tests.conftest import WOLFGANG_TRACE

HB = [sys.executable, "-m", "hilbench.cli"]


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([*HB, *args], capture_output=True, text=True, timeout=timeout)


def one_line(proc: subprocess.CompletedProcess, code: int, *needles: str) -> None:
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "error:" in lines[0] and "Traceback" not in proc.stderr, proc.stderr
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.mark.parametrize(("args", "needle"), [
    (["dxl", "ping", "/dev/null", "1", "--baud", "12345"], "--baud: expected a baud rate the Dynamixel SDK can open"),
    (["dxl", "ping", "/dev/null", "1", "--baud", "-1"], "got -1"),
    (["dxl", "ping", "/dev/null", "1", "--baud", "0"], "got 0"),
    (["dxl", "scan", "/dev/null", "--baud", "250000"], "got 250000"),
    (["dxl", "read", "/dev/null", "1", "132", "0"], "expected an integer 1..1024, got 0"),
    (["demo", "--seconds", "-1"], "--seconds: expected a number 0..1000000000, got -1"),
    (["monitor", "x", "--seconds", "-5"], "--seconds: expected a number"),
    (["monitor", "x", "--baud", "-9600"], "--baud: expected an integer 1..100000000, got -9600"),
    (["monitor", "x", "--speed", "0"], "--speed: expected a number > 0"),
    (["monitor", "x", "--miss-limit", "-1"], "--miss-limit"),
    (["monitor", "x", "--max-length", "2"], "--max-length: expected an integer 3..65535"),
    (["record", "x", "y", "--seconds", "nan"], "--seconds"),
    (["trace", "x", "--duration", "-1"], "--duration: expected a number"),
    (["trace", "x", "--bins", "-3"], "--bins: expected an integer 1..10000, got -3"),
    (["trace", "x", "--bins", "1000000000"], "--bins"),
    (["trace", "x", "--tick", "0"], "--tick: expected a number > 0"),
    (["trace", "x", "--reports", "0"], "--reports"),
    (["trace", "x", "--reorder", "1e999"], "expected a finite time"),
    (["send-vel", "x", "0", "0", "0", "--count", "-5"], "--count: expected an integer 1.."),
    (["send-vel", "x", "0", "0", "0", "--rate", "-1"], "--rate: expected a number > 0"),
    (["send-vel", "x", "0", "0", "0", "--baud", "0"], "--baud: expected an integer 1200..12500000"),
    (["teleop", "x", "--repeat-rate", "-2"], "--repeat-rate"),
    (["board", "--timeout", "-1", "wait-report"], "--timeout: expected a number 0..3600"),
])
def test_out_of_range_options_are_usage_errors(args, needle):
    one_line(hb(*args), 2, needle)


@pytest.mark.parametrize(("knob", "needle"), [
    ("nosuch=1", "unknown fault knob 'nosuch' (expected one of: drop_rate, corrupt_rate, drop_next, corrupt_next"),
    ("drop_rate=2", "fault knob drop_rate: expected a number 0..1, got 2"),
    ("stall=-1", "fault knob stall: expected a number 0..3600, got -1"),
    ("drop_next=1.5", "fault knob drop_next: expected an integer 0..2147483648, got 1.5"),
])
def test_board_fault_knobs_are_checked_before_anything_is_sent(knob, needle):
    # port 1 has no bench: a refusal proves the knob was judged before connecting
    one_line(hb("board", "--control", "127.0.0.1:1", "fault", knob), 2, needle)


def test_a_bench_that_is_not_there_is_a_system_error():
    one_line(hb("board", "--control", "127.0.0.1:1", "status"), 1, "no bench control channel at 127.0.0.1:1")


def test_fault_rules_are_the_profiles_and_the_benchs():
    assert check_fault_knobs({"drop_rate": 0.5, "drop_next": 3}) == {"drop_rate": 0.5, "drop_next": 3}
    for key, value in (("drop_rate", 2), ("stall", -1), ("corrupt_next", -1)):
        with pytest.raises(RuleError):
            check_fault_knobs({key: value})
    c = Checker("rover.toml")
    with pytest.raises(ProfileError, match="rover.toml: devices\\[0\\].faults.drop_rate: expected a number 0..1, got 2"):
        c.rule(2, "devices[0].faults.drop_rate", FAULT_RULES["drop_rate"])


def test_one_rule_gives_one_message_everywhere():
    rule = Rule(int, 1, 10)
    with pytest.raises(RuleError, match="^expected an integer 1..10, got 11$"):
        rule.check(11)
    with pytest.raises(ProfileError, match="^p.toml: k: expected an integer 1..10, got 11$"):
        Checker("p.toml").rule(11, "k", rule)
    with pytest.raises(Exception, match="^expected an integer 1..10, got 11$"):
        rule("11")
    assert rule("0x0a") == 10 and Rule(float, 0, 1)("1") == 1.0
    for bad in (True, float("nan"), float("inf"), "3", None):
        assert not Rule(float, 0, 10).ok(bad)
    assert LINE_BAUD.ok(2_000_000) and not LINE_BAUD.ok(-9600)


def test_sdk_bauds_are_the_sdks_own():
    handler = port_handler.PortHandler("/dev/null")
    candidates = range(1_200, 4_600_001, 100)
    assert tuple(b for b in candidates if handler.getCFlagBaud(b) != -1) == SDK_BAUDS
    # every Protocol 2.0 baud code but 4.5 Mbaud, which pyserial opens with a lifted PortHandler list
    assert set(DYNAMIXEL_BAUDS) - set(SDK_BAUDS) == {4_500_000}
    assert BUS_BAUD.ok(2_000_000) and BUS_BAUD.ok(4_500_000) and not BUS_BAUD.ok(123_456)


def test_a_profile_that_is_not_utf8_is_one_line_everywhere(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'schema = 1\ndescription = "\xff\xfe"\n')
    for args in (["emulate", str(bad)], ["monitor", f"bench:{bad}", "--summary"], ["trace", f"bench:{bad}"],
                 ["demo", "--profile", str(bad), "--seconds", "1"]):
        one_line(hb(*args), 2, f"{bad}: not a UTF-8 text file")


@pytest.mark.parametrize("flag", ["--summary", "--json"])
def test_a_closed_pipe_is_no_error(flag):
    proc = subprocess.Popen([*HB, "monitor", str(WOLFGANG_TRACE), flag, "--baud", "2000000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader leaves before the summary is written, as `| head -1` does
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait(timeout=60) == 0 and err == b""
    shell = subprocess.run(["bash", "-c", "set -o pipefail; \"$@\" | head -1", "bash", *HB, "monitor",
                            str(WOLFGANG_TRACE), flag], capture_output=True, text=True, timeout=60)
    assert shell.returncode == 0 and shell.stderr == "" and len(shell.stdout.splitlines()) == 1


def test_demo_reports_only_what_happened(monkeypatch, capsys):
    from hilbench.cli import demo, main
    from hilbench.clients import dynamixel_demo
    from hilbench.clients.dynamixel_demo import DemoResult, Scenario

    sc = Scenario(vanish_id=7, vanish_at=2.5, vanish_for=3.0, error_id=12, error_at=5.0)
    quiet = DemoResult(cycles=0, scenario=sc, summary={"devices": {
        "7": {"state": "connected", "disconnects": 0, "misses": 0},
        "12": {"alert": False, "hardware_error_bits": []}}})
    assert demo.demo_report(quiet)[0] == "monitor: ID 7 did not drop out (missed 0 replies)"
    monkeypatch.setattr(dynamixel_demo, "run_demo", lambda *a, **k: quiet)
    assert main(["demo", "--seconds", "1"]) == 1
    out, err = capsys.readouterr()
    assert "came back" not in out
    assert err.splitlines() == ["hilbench: error: the control loop completed no cycle (give it more time: --seconds)"]


def test_ctrl_c_while_the_verbs_load_ends_quietly(monkeypatch, capsys):
    """Ctrl-C in the first half second (the verbs' modules loading) is status 130 and no traceback."""
    import hilbench.cli as cli

    def interrupted(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["--help"]) == 130
    assert capsys.readouterr().err == ""
