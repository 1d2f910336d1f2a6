"""The emulated board live on a bench: real ptys (pyserial), UDP on 127.0.0.1, taps, baud mismatch."""

from __future__ import annotations

import itertools
import struct

import pytest
import serial

from hilbench.protocols import vel2d
from hilbench.protocols.tracestamp import LogMessage, RuntimeReport
from hilbench.protocols.tracestamp_stream import StreamDecoder, stamps_of
from hilbench.pytest_plugin import wait_until
from hilbench.transports.host_connection import HostConnection
from tests.stm32_vectors import crc32_mpeg2_bitwise


class Reader:
    """Collects what a port receives and decodes it."""

    def __init__(self, read) -> None:
        self.read = read
        self.dec = StreamDecoder()
        self.items: list = []

    def poll(self) -> list:
        data = self.read()
        if data:
            self.items += self.dec.feed(data)
        return self.items

    def logs(self) -> list[str]:
        self.poll()
        return [i.message for i in self.items if isinstance(i, LogMessage)]

    def report(self):
        self.poll()
        reps = [i for i in self.items if isinstance(i, RuntimeReport)]
        return reps[-1] if reps else None


@pytest.mark.hilbench_profile("mecarover-thesis")
def test_pty_frames_logs_button_window_and_taps(bench):
    ep = bench.endpoint("rover")
    board = bench.family("stm32-rover").board()
    seen: dict[str, int] = {}
    ep.medium.add_tap(lambda t, source, data: seen.__setitem__(source, seen.get(source, 0) + len(data)))
    port = serial.Serial(ep.path, 1_152_000, timeout=0)
    rd = Reader(lambda: port.read(65536))
    try:
        port.write(vel2d.build(0.1, -0.2, 0.3))
        port.flush()
        payload = struct.pack("<3d", 0.0, 0.0, 1.0)  # a frame from an independent CRC
        port.write(payload + struct.pack("<I", crc32_mpeg2_bitwise(payload)))
        port.flush()
        wait_until(lambda: sum("[recv vel]" in m for m in rd.logs()) == 2, timeout=5)
        assert "[recv vel] [0.000000 0.000000 1.000000]" in rd.logs()
        board.press_button()
        wait_until(lambda: len(stamps_of(rd.poll())) > 500, timeout=5)
        board.press_button()
        rep = wait_until(rd.report, timeout=10)
        stamps = stamps_of(rd.items)
        assert rep.complete and rep.closing == "profiled for" and rep.ctx_switches == len(stamps)
        assert {"hal_fetch", "wheel_ctrl", "odometry", "pose_control", "tsink", "profile", "IDLE"} <= {
            s.name for s in stamps}
        assert rd.dec.text.parse_errors == 0
        # Taps see both directions, by sender, and everything the host read went through them.
        assert seen["rover"] == 56 and seen["rover-board"] >= rd.dec.bytes_in > 5_000
    finally:
        port.close()


@pytest.mark.hilbench_profile("mecarover")
def test_a_host_at_the_wrong_baud_rate_gets_crc_errors(bench):
    ep = bench.endpoint("rover")
    port = serial.Serial(ep.path, 9600, timeout=0)  # the board runs at 115200
    try:
        port.write(vel2d.build(0.5, 0.0, 0.0))
        port.flush()
        board = bench.family("stm32-rover").board()
        wait_until(lambda: board.truth.frames_crc_error == 1, timeout=5)
        assert board.log[-1].message == "crc mismatch!" and board.rx_baud_mismatch == 28
    finally:
        port.close()


def test_udp_round_trip_frames_logs_and_binary_stamps(hilbench_bench):
    bench = hilbench_bench("mecarover-udp")
    ep = bench.endpoint("rover")
    assert ep.path.startswith("udp://127.0.0.1:") and ep.port.kind == "udp" and ep.port.address[0] == "127.0.0.1"
    board = bench.family("stm32-rover").board()
    link = HostConnection.open(ep.path)
    rd = Reader(link.read)
    try:
        link.send(vel2d.build(0.1, -0.2, 0.3))  # one datagram, one frame; it also registers us
        wait_until(lambda: "[recv vel] [100.000000 -200.000000 0.300000]" in rd.logs(), timeout=5)
        board.press_button()
        wait_until(lambda: len(stamps_of(rd.poll())) > 2000, timeout=5)
        board.press_button()
        rep = wait_until(rd.report, timeout=10)
        w = rd.dec.words
        stamps = stamps_of(rd.items)
        assert w.windows_started == w.windows_stopped == 1 and w.checks_failed == 0 and w.broken_words == 0
        assert len(stamps) + w.drops == rep.ctx_switches == board.truth.stamps_recorded
        assert w.drops == board.truth.stamps_dropped
        begins = [s.t_us for s in stamps if s.name == "hal_fetch" and s.begin]
        # A task switched in twice in one period (preempted by a higher-priority task woken mid-run, as
        # FreeRTOS does) is one activation: count releases, not switch-ins.
        releases = [t for i, t in enumerate(begins) if i == 0 or t - begins[i - 1] > 500]
        assert len(releases) > 100
        odd = [(a, b) for a, b in itertools.pairwise(begins) if not 950 <= b - a <= 1050]  # shown on failure
        assert (releases[-1] - releases[0]) / (len(releases) - 1) == pytest.approx(1000, abs=2), odd
    finally:
        link.close()


def test_udp_rejects_short_frames_like_the_uart(hilbench_bench):
    bench = hilbench_bench("mecarover-udp")
    link = HostConnection.open(bench.endpoint().path)
    try:
        link.send(vel2d.build(0.0, 0.0, 0.0)[:20])
        board = bench.family("stm32-rover").board()
        wait_until(lambda: board.truth.frames_length_error == 1, timeout=5)
        assert board.log[-1].message == "parsing velocity failed: insufficient bytes received"
    finally:
        link.close()
