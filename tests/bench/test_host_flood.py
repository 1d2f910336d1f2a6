"""A client that writes faster than the wire into a bench's pty is held back as a USB adapter holds it (its
writes wait, EAGAIN when non-blocking): the bench's memory stays at its level, and the devices hear well-formed
traffic right after. Before, the bench read everything at once and queued it at wire pace (20 MB into the
paced Wolfgang bus: +22 MB, for the 100 s of wire time it needed; a Vel2d flood into the rover board's door:
+67 MB in 3 s)."""

from __future__ import annotations

import os
import random
import termios
import time
import tty

import dynamixel_sdk as sdk

from hilbench.bench.control import ControlClient
from hilbench.clients.stm32_rover import BoardClient
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import vel2d
from hilbench.pytest_plugin import wait_until

OFFERED = 20_000_000  # bytes the client tries to write


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


def open_client(path: str, baud: int) -> int:
    """A raw, non-blocking client at ``baud`` (its bytes go out at its own rate)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = getattr(termios, f"B{baud}")
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return fd


def flood(fd: int, chunk: bytes, pid: int, seconds: float) -> dict:
    """Offer OFFERED bytes of ``chunk`` repeated for at most ``seconds``: bytes accepted, EAGAINs, time, and the
    bench's RSS (MB) before and at its peak."""
    before = peak = rss_mb(pid)
    accepted = refused = 0
    t0 = last = time.monotonic()
    while accepted < OFFERED and time.monotonic() - t0 < seconds:
        try:
            accepted += os.write(fd, chunk[accepted % len(chunk):])  # (a write may take part of it)
        except BlockingIOError:
            refused += 1
            time.sleep(0.0005)
        if time.monotonic() - last > 0.05:
            peak, last = max(peak, rss_mb(pid)), time.monotonic()
    return {"accepted": accepted, "refused": refused, "seconds": time.monotonic() - t0, "before": before,
            "peak": max(peak, rss_mb(pid))}


def no_traceback(bench: dict) -> None:
    proc = bench["process"]
    proc.terminate()
    _, err = proc.communicate(timeout=10)
    assert "Traceback" not in err, err


def test_a_flood_into_a_paced_bus_is_held_back_and_the_sdk_pings_right_after(hilbench_emulator):
    bench = hilbench_emulator("wolfgang", "--paced")
    ep = bench["endpoints"][0]
    pid, baud = bench["process"].pid, ep["baud"]
    control = ControlClient.from_manifest(bench["manifest_path"])
    taken = lambda: control.media()[ep["name"]]["stats"]["by_source"].get(ep["name"], 0)  # noqa: E731
    fd = open_client(ep["path"], baud)
    try:
        # The servos' decoder makes its numpy tables (numpy: ~19 MB) with the first large buffer, and a bench
        # starts without numpy: a first burst, taken in full, brings them in before the level is read.
        warm = random.Random(8).randbytes(2 * dxl.VECTOR_MIN)
        sent = 0
        deadline = time.monotonic() + 10
        while sent < len(warm) and time.monotonic() < deadline:
            try:
                sent += os.write(fd, warm[sent:])
            except BlockingIOError:
                time.sleep(0.001)
        wait_until(lambda: taken() == sent == len(warm), 10)
        got = flood(fd, random.Random(7).randbytes(4096), pid, 1.0)  # (the same bytes every run)
    finally:
        os.close(fd)
    # Taken at the wire's pace (2 Mbaud: 200 kB/s) plus what the pty itself buffers, not the 20 MB offered.
    assert got["refused"] > 0
    assert got["accepted"] < baud / 10 * got["seconds"] + 256 * 1024, got
    stats = control.media()[ep["name"]]["stats"]
    assert stats["held_back"] > 0
    # Everything taken goes out; then the bench is back at its level, and a servo answers the official SDK.
    wait_until(lambda: taken() == len(warm) + got["accepted"], 10)
    after = rss_mb(pid)
    assert got["peak"] - got["before"] < 8, got
    assert after - got["before"] < 8, (got, after)
    port = sdk.PortHandler(ep["path"])
    assert port.openPort() and port.setBaudRate(baud)
    try:
        # The flood may end inside what looks like a packet's header and length: the servos take the next
        # bytes as its rest, as real ones would, so the first ping may go unanswered; the second is heard.
        for _ in range(2):
            model, result, error = sdk.PacketHandler(2.0).ping(port, 1)
            if result == sdk.COMM_SUCCESS:
                break
    finally:
        port.closePort()
    assert (result, error) == (sdk.COMM_SUCCESS, 0) and model > 0
    no_traceback(bench)


def test_a_vel2d_flood_into_the_rover_boards_pty_door_is_held_back(hilbench_emulator):
    """The board's UART takes the frames at 115200 baud; its writer waits meanwhile, as over the ST-LINK's USB
    link. Nothing is dropped on the way in (no receive overrun on a pty door), so every frame the client got
    in is counted by the board exactly as before: received whole (frames_ok), or lost while recv_vel was busy."""
    bench = hilbench_emulator("mecarover")
    ep = next(e for e in bench["endpoints"] if e["name"] == "rover")
    pid, baud = bench["process"].pid, ep["baud"]
    board = BoardClient.from_manifest(bench["manifest_path"])
    frame = vel2d.build(0.1, 0.0, 0.0)
    fd = open_client(ep["path"], baud)
    try:
        got = flood(fd, frame * 146, pid, 1.5)  # 4088 bytes a write
        rest = frame[got["accepted"] % len(frame):] if got["accepted"] % len(frame) else b""
        while rest:  # the last frame whole (a write may have taken part of it)
            try:
                rest = rest[os.write(fd, rest):]
            except BlockingIOError:
                time.sleep(0.001)
    finally:
        os.close(fd)
    frames = -(-got["accepted"] // len(frame))
    assert got["refused"] > 0
    assert got["accepted"] < baud / 10 * got["seconds"] + 256 * 1024, got  # the UART's 11.5 kB/s, not MB

    def truth() -> dict:
        return board.status()["truth"]

    def counted() -> int:
        t = truth()
        return t["frames_ok"] + t["frames_lost"] + t["frames_crc_error"] + t["frames_length_error"]

    wait_until(lambda: counted() >= frames, timeout=30)
    t = truth()
    assert counted() == frames and t["frames_crc_error"] == t["frames_length_error"] == 0, t
    assert t["frames_ok"] > 0 and t["rx_overruns"] == 0
    after = rss_mb(pid)
    assert got["peak"] - got["before"] < 8, got
    assert after - got["before"] < 8, (got, after)
    # The board takes the next frame at once.
    fd = open_client(ep["path"], baud)
    try:
        os.write(fd, vel2d.build(0.25, 0.0, 0.0))
    finally:
        os.close(fd)
    wait_until(lambda: any("[recv vel] [250.000000 " in line for line in board.log()), 5)
    no_traceback(bench)
