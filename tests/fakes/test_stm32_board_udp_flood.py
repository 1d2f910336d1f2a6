"""The rover board's UDP door under a Vel2d flood: a bounded receive FIFO drops what the UART cannot carry and
counts it (and recv_vel keeps a bounded number of frames), so the bench's memory stays at its level and the
board is quiet, and answers, at once when the flood ends."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

from hilbench.clients.stm32_rover import BoardClient
from hilbench.fakes.stm32_board.firmware import RX_FIFO
from hilbench.protocols import vel2d
from hilbench.pytest_plugin import wait_until


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


def board(manifest: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", "board", "--manifest", manifest, *args],
                          capture_output=True, text=True, timeout=30)


def test_a_vel2d_flood_is_bounded_counted_and_forgotten(hilbench_emulator) -> None:
    bench = hilbench_emulator("mecarover-udp")
    manifest, pid = bench["manifest_path"], bench["process"].pid
    client = BoardClient.from_manifest(manifest)

    def truth() -> dict:
        return client.status()["truth"]

    ep = bench["endpoints"][0]
    assert bench["devices"][0]["rx_fifo"] == {"bytes": RX_FIFO, "overruns": 0, "overrun_bytes": 0}
    target = (ep["host"], ep["port"])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    frame = vel2d.build(0.1, 0.0, 0.0)
    try:
        sock.sendto(frame, target)
        wait_until(lambda: truth()["frames_ok"] == 1, 10)
        before = peak = rss_mb(pid)
        end = time.monotonic() + 1.5  # 28-byte datagrams as fast as this process sends: ~20x the UART's pace
        sent = 0
        while time.monotonic() < end:
            for _ in range(200):
                try:
                    sock.sendto(frame, target)
                    sent += 1
                except OSError:  # (the kernel's buffers are full)
                    pass
            peak = max(peak, rss_mb(pid))
        # What was taken is on the wire within a FIFO's time: the board is quiet again at once.
        wait_until(lambda: (a := truth()["frames_ok"]) > 1 and time.sleep(0.05) is None and truth()["frames_ok"] == a,
                   5)
        settled = truth()
        time.sleep(0.5)  # (measuring that nothing more arrives)
        assert truth()["frames_ok"] == settled["frames_ok"]
        after = rss_mb(pid)
        assert settled["rx_overruns"] > 0 and settled["rx_overrun_bytes"] == 28 * settled["rx_overruns"]
        assert settled["frames_ok"] + settled["frames_lost"] + settled["rx_overruns"] <= sent + 1
        assert peak - before < 10, (before, peak, after)  # it grew by 19 MB in 3 s, 61 MB in 10 s, never freed
        assert after - before < 10, (before, peak, after)
        # The board still takes a frame at once, and says what it dropped.
        sock.sendto(vel2d.build(0.25, 0.0, 0.0), target)
        wait_until(lambda: any("[recv vel] [250.000000 " in line for line in client.log()), 5)
        text = board(manifest, "status").stdout
        assert f"receive overruns {settled['rx_overruns']} ({settled['rx_overrun_bytes']} bytes dropped)" in text
    finally:
        sock.close()
    proc = bench["process"]
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    assert "Traceback" not in err, err
