"""The rover verbs as a user runs them: send-vel, teleop (in a real terminal, tmux), board control."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import uuid

import pytest

from hilbench.pytest_plugin import wait_until


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("verb", [["send-vel"], ["teleop"], ["board"]])
def test_rover_verbs_have_help(verb):
    proc = hb(*verb, "--help")
    assert proc.returncode == 0 and "usage: hilbench" in proc.stdout


@pytest.fixture(scope="module")
def rover(tmp_path_factory):
    """`hilbench emulate mecarover` in its own process."""
    manifest = tmp_path_factory.mktemp("rover") / "manifest.json"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "mecarover", "--manifest",
                             str(manifest)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: manifest.exists() or proc.poll() is not None, timeout=30)
    assert proc.poll() is None, proc.stderr.read()
    data = json.loads(manifest.read_text())
    data["manifest"] = str(manifest)
    yield data
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "control: 127.0.0.1:" in out


def status(rover) -> dict:
    proc = hb("board", "--manifest", rover["manifest"], "status", "--json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_manifest_lists_the_board_and_its_control_channel(rover):
    (ep,) = [e for e in rover["endpoints"] if e["protocol"] == "vel2d"]  # (the rover's RPLIDAR is the other)
    assert (ep["protocol"], ep["baud"], ep["type"]) == ("vel2d", 115_200, "pty") and os.path.exists(ep["path"])
    (dev,) = [d for d in rover["devices"] if d["protocol"] == "vel2d"]
    assert (dev["model"], dev["preset"], dev["output"], dev["endpoint"]) == ("stm32f767-rover", "freertos-50-30",
                                                                           "v3", "rover")
    assert rover["control"].startswith("127.0.0.1:")


def test_send_vel_one_frame_and_a_stream(rover):
    path = rover["endpoints"][0]["path"]
    before = status(rover)["truth"]["frames_ok"]
    one = hb("send-vel", path, "0.1", "-0.2", "0.3", "--echo")
    assert one.returncode == 0, one.stderr
    assert "9a 99 99 99 99 99 b9 3f" in one.stdout  # the spec's frame C on the wire
    assert "[INFO]: [recv vel] [100.000000 -200.000000 0.300000]" in one.stdout
    stream = hb("send-vel", path, "0.2", "0", "0", "--rate", "100", "--count", "20")
    assert stream.returncode == 0 and "sent 20 frames" in stream.stdout
    st = status(rover)
    assert st["truth"]["frames_ok"] == before + 21 and st["truth"]["frames_crc_error"] == 0
    assert st["log"][-1].endswith("[INFO]: [recv vel] [200.000000 0.000000 0.000000]")
    assert st["robot"]["setpoint"] == [200.0, 0.0, 0.0]


def test_board_button_fault_and_reset(rover):
    ctl = ["board", "--manifest", rover["manifest"]]
    pressed = hb(*ctl, "button")
    assert pressed.returncode == 0 and "button pressed (sampling on, window 1)" in pressed.stdout
    fault = hb(*ctl, "fault", "drop_rate=0.01", "corrupt_next=3", "--json")
    assert json.loads(fault.stdout)["drop_rate"] == 0.01 and json.loads(fault.stdout)["corrupt_next"] == 3
    reset = hb(*ctl, "reset")
    assert reset.returncode == 0 and "reset (boot 2)" in reset.stdout
    st = status(rover)
    assert st["boots"] == 2 and not st["sampling"] and "boot 2" in st["log"][0]
    assert st["faults"]["drop_rate"] == 0.0  # a reset boots with the profile's knobs


def test_rover_verbs_fail_in_one_line(rover, tmp_path):
    noport = hb("send-vel", "/dev/no-such-port", "0", "0", "0")
    assert noport.returncode == 1 and len(noport.stderr.strip().splitlines()) == 1
    badurl = hb("send-vel", "udp://nowhere", "0", "0", "0")
    assert badurl.returncode == 2 and "expected udp://HOST:PORT" in badurl.stderr
    nan = hb("send-vel", "/dev/null", "nan", "0", "0")
    assert nan.returncode == 2 and "argument x: expected a number -1000..1000, got nan" in nan.stderr
    nowhere = hb("board", "status")
    assert nowhere.returncode == 2 and nowhere.stderr.count("\n") == 1 and "--manifest" in nowhere.stderr
    unknown = hb("board", "--manifest", rover["manifest"], "--device", "r2d2", "status")
    assert unknown.returncode == 2 and "no board named 'r2d2'" in unknown.stderr
    knob = hb("board", "--manifest", rover["manifest"], "fault", "warp=1")
    assert knob.returncode == 2 and "unknown fault knob 'warp'" in knob.stderr
    teleop = subprocess.run([sys.executable, "-m", "hilbench.cli", "teleop", rover["endpoints"][0]["path"]],
                            stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=30)
    assert teleop.returncode == 1 and "stdin is not a tty" in teleop.stderr


def test_send_vel_over_udp(hilbench_emulator):
    manifest = hilbench_emulator("mecarover-udp")
    url = manifest["endpoints"][0]["path"]
    assert url.startswith("udp://127.0.0.1:")
    proc = hb("send-vel", url, "-0.25", "0.25", "-0.5", "--echo")
    assert proc.returncode == 0, proc.stderr
    assert "[INFO]: [recv vel] [-250.000000 250.000000 -0.500000]" in proc.stdout


@pytest.mark.skipif(shutil.which("tmux") is None, reason="tmux is not installed")
def test_teleop_in_a_real_terminal(hilbench_bench):
    bench = hilbench_bench("mecarover")
    board = bench.family("stm32-rover").board()
    sock = f"hilbench-test-{uuid.uuid4().hex[:8]}"
    tmux = ["tmux", "-L", sock]
    cmd = f"{sys.executable} -m hilbench.cli teleop {bench.endpoint('rover').path}"
    subprocess.run([*tmux, "new-session", "-d", "-x", "100", "-y", "40", cmd], check=True)

    def frames() -> list[str]:
        return [x.message for x in board.log if x.message.startswith("[recv vel]")]

    def key(k: str, expect: str) -> None:
        subprocess.run([*tmux, "send-keys", "-t", "0", "-l", k], check=True)
        wait_until(lambda: frames() and frames()[-1] == expect, timeout=10)

    try:
        wait_until(lambda: b"CTRL-C to quit" in subprocess.run([*tmux, "capture-pane", "-p", "-t", "0"],
                                                               capture_output=True).stdout, timeout=20)
        key("i", "[recv vel] [500.000000 0.000000 0.000000]")  # forward at 0.5 m/s
        key("j", "[recv vel] [0.000000 0.000000 1.000000]")  # turn left at 1 rad/s
        key("q", "[recv vel] [0.000000 0.000000 1.100000]")  # +10 % speeds, same direction
        key("L", "[recv vel] [0.000000 -550.000000 0.000000]")  # strafe right (shift)
        key("M", "[recv vel] [-550.000000 550.000000 0.000000]")
        key("k", "[recv vel] [0.000000 0.000000 0.000000]")  # anything else stops
        n = len(frames())
        subprocess.run([*tmux, "send-keys", "-t", "0", "C-c"], check=True)
        wait_until(lambda: len(frames()) == n + 1, timeout=10)  # the stop frame on exit
        assert frames()[-1] == "[recv vel] [0.000000 0.000000 0.000000]"
        assert board.truth.frames_crc_error == 0 and board.truth.frames_length_error == 0
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True)


def test_control_channel_refuses_an_endless_line(rover):
    """A client that never sends a newline gets one refusal, and the bench keeps serving others."""
    host, port = rover["control"].split(":")
    with socket.create_connection((host, int(port)), timeout=10) as sock:
        sock.sendall(b"x" * 200_000)  # > MAX_LINE, no newline
        reply = sock.makefile("rb").readline()
    assert json.loads(reply) == {"ok": False, "error": "request too long (at most 65536 bytes)"}
    assert status(rover)["name"] == "rover"
