"""Unmodified CAN tools on an emulated bench in a real terminal (tmux 80x24): python-can's can.viewer over
socketcand and SLCAN, cantools monitor with the exported DBC, and hilbench's own CAN dashboard."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys

import pytest

from hilbench.pytest_plugin import wait_until
from tests.conftest import REPO
from tests.dashboard.test_tmux import Terminal, hilbench, terminal  # noqa: F401 (the fixture)

pytestmark = [pytest.mark.slow,  # CAN tools in a real terminal: the slow real-client set
              pytest.mark.skipif(shutil.which("tmux") is None,
                                 reason="tmux is not installed: the real-terminal tests need it")]


def python(*args: str) -> str:
    return " ".join(shlex.quote(a) for a in (sys.executable, *args))


@pytest.fixture
def started(hilbench_emulator):
    """mecarover-can in its own process, node 2 started (TPDOs flowing)."""
    manifest = hilbench_emulator("mecarover-can")
    path = manifest["process"].args[manifest["process"].args.index("--manifest") + 1]
    out = subprocess.run([sys.executable, "-m", "hilbench.cli", "can", "nmt", path, "start", "--node", "2"],
                         capture_output=True, text=True, cwd=REPO, timeout=30)
    assert out.returncode == 0, out.stderr
    return manifest, path


def test_can_viewer_over_socketcand(terminal, started):  # noqa: F811
    manifest, _ = started
    s = manifest["endpoints"][0]["socketcand"]
    term = terminal(python("-m", "can.viewer", "-i", "socketcand", "-c", s["channel"], "--bus-kwargs",
                           f"host={s['host']}", f"port={s['port']}"))
    screen = term.wait_for("0x482")  # the 100 ms status PDO: the slowest one has arrived, all have
    for cob in ("0x182", "0x282", "0x382"):
        assert cob in screen

    def encoder_dt() -> float:  # the time between the encoder PDO's last two frames, as the viewer shows it
        return float(next(line for line in term.screen().splitlines() if "0x182" in line).split()[2])

    # its 20 ms period (one late frame on a busy machine shows a longer gap: the next ones are on time again)
    wait_until(lambda: 0.01 < encoder_dt() < 0.04, timeout=10)
    term.keys("q")
    term.wait_for("EXITED 0")


def test_can_viewer_over_slcan(terminal, started):  # noqa: F811
    manifest, _ = started
    pty = manifest["endpoints"][0]["slcan"]
    term = terminal(python("-m", "can.viewer", "-i", "slcan", "-c", pty, "-b", "500000"))
    # python-can's slcan waits 2 s after opening; each PDO shows up as its first frame arrives (no order assumed)
    for cob in ("0x182", "0x282", "0x382", "0x482"):
        term.wait_for(cob, timeout=30)
    term.keys("q")
    term.wait_for("EXITED 0")


def test_cantools_monitor_with_the_exported_dbc(terminal, started, tmp_path):  # noqa: F811
    manifest, _ = started
    dbc = tmp_path / "rover.dbc"
    out = subprocess.run([sys.executable, "-m", "hilbench.cli", "can", "dbc", "mecarover-can", "-o", str(dbc)],
                         capture_output=True, text=True, cwd=REPO, timeout=30)
    assert out.returncode == 0, out.stderr
    cantools = shutil.which("cantools", path=str(REPO / ".venv" / "bin")) or shutil.which("cantools")
    s = manifest["endpoints"][0]["socketcand"]
    cmd = [cantools, "monitor", str(dbc), "-i", "socketcand", "-c", s["channel"], "--bus-kwargs",
           f"host={s['host']}", f"port={s['port']}"] if cantools else \
        [sys.executable, "-m", "cantools", "monitor", str(dbc), "-i", "socketcand", "-c", s["channel"],
         "--bus-kwargs", f"host={s['host']}", f"port={s['port']}"]
    term = terminal(" ".join(shlex.quote(c) for c in cmd))
    term.wait_for("OdometryPose_02(")
    # each message shows up as its first frame arrives: wait for the slower ones rather than assume an order
    screen = term.wait_for("BoardStatus_02(")
    assert "Discarded: 0" in screen and "Errors: 0" in screen
    term.wait_for("battery: 24.6 V")
    term.keys("q")
    term.wait_for("EXITED 0")


def test_hilbench_dashboard_on_a_can_bench(terminal, started):  # noqa: F811
    _, path = started
    term = terminal(hilbench("monitor", path, "--dbc", "mecarover-can"))
    term.wait_for("OdometryPose_02")
    screen = term.wait_for("WheelEncoders_02")  # the first screen may show the first identifier only
    assert "Identifiers" in screen
    term.keys("2")
    term.wait_for("CANopen nodes")
    term.wait_for("OPERATIONAL")  # from the next heartbeat (1 s period)
    term.keys("4")
    term.wait_for("Event log")
    term.keys("q")
    term.wait_for("EXITED 0")
