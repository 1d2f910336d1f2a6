"""A client under ``hilbench run`` that writes faster than the wire into a virtual-time bench's pty is held back
as on the wall clock (a USB adapter's FIFO, then its write() waits): writing N bytes takes the wire's time for
them, less what the kernel and that FIFO hold, the bench's memory stays where it was and time never stalls.
Before, the bench read everything at once: the writes took no virtual time, the wire queued the whole flood
in memory (a 64 MiB flood: bench RSS 45 -> 117 MB) and the lockstep counted a stall on the bytes it left."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.port_state_server import serve_port_state
from hilbench.transports.serial_medium import HOST_FIFO

pytestmark = pytest.mark.usefixtures("library")  # (tests/run/conftest.py: skipped without the shim)

#: What a client's write() may have handed over without the wire sending it yet: the pty's kernel buffers
#: (16 KiB on this project's Linux 6 VMs, up to 64 KiB of tty buffers on others) and the adapter's FIFO.
SLACK = 64 * 1024 + HOST_FIFO

FLOOD = """
import json, os, sys, termios, time, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
attrs = termios.tcgetattr(fd)
attrs[4] = attrs[5] = getattr(termios, "B" + sys.argv[3])
termios.tcsetattr(fd, termios.TCSANOW, attrs)
n, total, chunk = 0, int(sys.argv[2]), bytes(4096)
t0 = time.monotonic_ns()
while n < total:
    n += os.write(fd, chunk[:total - n])
print(json.dumps({"written": n, "ns": time.monotonic_ns() - t0}))
"""


def flood(tmp_path: Path, profile: str, endpoint: str, baud: int, total: int) -> tuple[dict, dict, object]:
    """``total`` bytes written as fast as a client can into ``endpoint``'s pty; (client's report, lockstep
    stats, the line's stats)."""
    script = tmp_path / "flood.py"
    script.write_text(FLOOD)
    with Bench(profile, virtual_time=True) as bench:
        serve_port_state(bench)
        manifest = tmp_path / "bench.json"
        bench.write_manifest(manifest)
        ep = bench.endpoint(endpoint)
        env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
        proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "run", "--manifest", str(manifest), "--",
                               sys.executable, str(script), ep.port.client_path, str(total), str(baud)],
                              capture_output=True, text=True, timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout), bench.services["clock"].stats(), ep.medium.stats


def check(report: dict, stats: dict, line, baud: int, total: int, source: str) -> None:
    byte_ns = 10 * 10**9 // baud  # 8N1
    assert report["written"] == total
    # It took the wire's time for what the bench took, and the bench took no more than the slack ahead.
    assert (total - SLACK) * byte_ns <= report["ns"] <= total * byte_ns, report
    assert stats["stalls"] == 0, stats
    assert line.held_back > 0
    assert total - SLACK <= line.by_source[source] <= total


def test_a_flood_into_a_paced_bus_takes_the_wire_time_and_no_memory(tmp_path):
    total, baud = 256 * 1024, 1_000_000  # 2.6 virtual s on the arm's bus
    report, stats, line = flood(tmp_path, "arm", "arm", baud, total)
    check(report, stats, line, baud, total, "arm")


@pytest.mark.slow
def test_a_flood_into_the_rover_boards_uart_takes_its_time(tmp_path):
    """The rover's line delivers at once; the board's UART paces what it takes in (``input_backlog``)."""
    total, baud = 160 * 1024, 115_200  # 14 virtual s of the board's UART
    report, stats, line = flood(tmp_path, "mecarover", "rover", baud, total)
    check(report, stats, line, baud, total, "rover")
