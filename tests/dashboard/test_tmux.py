"""The dashboard in a real terminal: tmux at 80x24, keys sent as a person types them, the screen read back."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys

import pytest

from hilbench.pytest_plugin import wait_until
from tests.conftest import REPO, WOLFGANG_TRACE

pytestmark = pytest.mark.skipif(shutil.which("tmux") is None,
                                reason="tmux is not installed: the real-terminal dashboard test needs it")


class Terminal:
    """A detached tmux session of 80x24 on a private server, running one command."""

    def __init__(self, command: str) -> None:
        self.server = f"hilbench-test-{os.getpid()}-{id(self)}"
        env = {**os.environ, "LANG": "C.UTF-8"}
        script = f"cd {shlex.quote(str(REPO))} && {command}; echo EXITED $?; sleep 60"
        subprocess.run(["tmux", "-L", self.server, "-f", "/dev/null", "new-session", "-d", "-s", "t", "-x", "80",
                        "-y", "24", script], check=True, env=env)

    def screen(self, escapes: bool = False) -> str:
        args = ["tmux", "-L", self.server, "capture-pane", "-p", "-t", "t"] + (["-e"] if escapes else [])
        return subprocess.run(args, capture_output=True, text=True, check=True).stdout

    def keys(self, *keys: str) -> None:
        subprocess.run(["tmux", "-L", self.server, "send-keys", "-t", "t", *keys], check=True)

    def wait_for(self, text: str, timeout: float = 20.0) -> str:
        try:
            wait_until(lambda: text in self.screen(), timeout=timeout, interval=0.05)
        except AssertionError:
            raise AssertionError(f"{text!r} never appeared; the screen shows:\n{self.screen()}") from None
        return self.screen()

    def close(self) -> None:
        subprocess.run(["tmux", "-L", self.server, "kill-server"], capture_output=True)


@pytest.fixture
def terminal():
    opened: list[Terminal] = []

    def start(command: str) -> Terminal:
        term = Terminal(command)
        opened.append(term)
        return term

    yield start
    for term in opened:
        term.close()


def hilbench(*args: str) -> str:
    return " ".join(shlex.quote(a) for a in (sys.executable, "-m", "hilbench.cli", *args))


def test_replayed_capture_in_a_real_terminal(terminal):
    term = terminal(hilbench("monitor", str(WOLFGANG_TRACE), "--baud", "2000000"))
    screen = term.wait_for("[ended - q quits]")
    lines = screen.splitlines()
    assert lines[2] == "Device overview" and len(lines) <= 24
    assert "20 connected  1 disconnected" in lines[0]
    assert "101 DISC" in screen and "<unknown>" in screen
    assert "\x1b[" in term.screen(escapes=True).splitlines()[0]  # the top bar is coloured (red: a device is down)
    term.keys("3")
    term.wait_for("Device details: ID 1  MX-64(2.0)")
    term.keys("Right")
    screen = term.wait_for("Device details: ID 2  MX-64(2.0)")
    assert "Present Position" in screen and "requests 1485" in screen
    term.keys("4")
    screen = term.wait_for("Error log: ")
    assert "[+00:02." in screen and "error: " in screen
    term.keys("2")
    term.wait_for("Model overview: MX-106(2.0)")
    term.keys("q")
    term.wait_for("EXITED 0")


@pytest.mark.slow  # the whole demo in a real terminal: the slow set
def test_demo_in_a_real_terminal(terminal):
    term = terminal(hilbench("demo", "--seconds", "4"))
    screen = term.wait_for("Device overview")
    assert "hilbench monitor  demo wolfgang on /dev/" in screen
    term.keys("3")
    term.wait_for("Device details: ID 1  MX-64(2.0)")  # keys work while the SDK drives the bench
    screen = term.wait_for("EXITED 0", timeout=30)
    assert "monitor: ID 7 dropped out 1 time(s)" in screen and "came back" in screen
    assert "monitor: ID 12 alert on, hardware error: overheating" in screen
    assert all(len(line) <= 80 for line in screen.splitlines())
