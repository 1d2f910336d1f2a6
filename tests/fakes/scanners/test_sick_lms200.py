"""The emulated SICK LMS 200 on its pty: ACK/NAK, link speeds, modes, variants, units, scans at the baud rate."""

from __future__ import annotations

import time

import numpy as np
import pytest
import serial

from hilbench.protocols import sick_lms200 as lms
from hilbench.pytest_plugin import wait_until
from tests.fakes.scanners.conftest import fraction_within

H = bytes.fromhex


class Host:
    """A minimal LMS host (as sicktoolbox does it): telegrams out, ACK + reply telegrams in."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 9600, timeout=0.05)
        self.dec = lms.Decoder()

    def read_items(self, n: int = 1, timeout: float = 3.0) -> list:
        items: list = []
        deadline = time.monotonic() + timeout
        while sum(isinstance(i, lms.Frame) for i in items) < n and time.monotonic() < deadline:
            items += self.dec.feed(self.port.read(4096))
        return items

    def ask(self, telegram: bytes, n: int = 1, timeout: float = 3.0) -> list:
        self.port.write(telegram)
        return self.read_items(n, timeout)


@pytest.fixture
def host(scanners):
    h = Host(scanners.endpoint("lms").path)
    yield h
    h.port.close()


def test_status_and_type(host):
    items = host.ask(lms.request(lms.Cmd.TYPE))
    assert items[0] == lms.Handshake(True)
    assert items[1].cmd == 0xBA and items[1].data == b"LMS200;30106" and items[1].status == 0x10
    status = host.ask(lms.request(lms.Cmd.STATUS))[1]
    assert status.cmd == 0xB1 and status.data[:7] == b"V02.10 "


def test_baud_change_reply_at_old_speed(scanners, host):
    dev = scanners.device("lms")
    t0 = time.monotonic()
    host.port.write(lms.mode_request(lms.Mode.BAUD_38400))
    raw = b""
    while len(raw) < 11 and time.monotonic() - t0 < 2:
        raw += host.port.read(11 - len(raw))
    took = time.monotonic() - t0
    assert raw == b"\x06" + H("02 80 03 00 A0 00 10 16 0A")  # still at 9600 baud
    assert took >= 11 * 10 / 9600 * 0.9  # 11 bytes at 9600 baud
    wait_until(lambda: dev.baud == 38400)
    host.port.write(lms.request(lms.Cmd.TYPE))  # still at 9600: the LMS hears garbage
    wait_until(lambda: dev.baud_mismatch > 0)
    host.port.baudrate = 38400
    assert host.ask(lms.request(lms.Cmd.TYPE))[-1].data == b"LMS200;30106"


def test_polled_scan_matches_the_room(scanners, host):
    items = host.ask(lms.request(lms.Cmd.SCAN, b"\x01"))
    scan = [i for i in items if isinstance(i, lms.Frame)][0]
    f = scan.fields()
    assert scan.cmd == 0xB0 and f["count"] == 361 and f["units"] == 1 and f["complete"]
    angles = np.arange(361) * 0.5  # 0° on the right, 90° straight ahead
    r = np.asarray(f["values"]) / 1000.0
    assert fraction_within(np.radians(angles - 90.0), r, sigma0=0.005, sigma_k=0.0) > 0.97
    assert fraction_within(np.radians(90.0 - angles), r, sigma0=0.005, sigma_k=0.0) < 0.5  # mirrored
    truth = scanners.device("lms").truth[-1]  # hilbench's decoder gives exactly what the emulator measured
    assert np.array_equal(np.round(truth.measured * 1000), f["values"])


def test_invalid_request_gets_the_invalid_reply(host):
    items = host.ask(lms.request(0x55))
    assert items[0] == lms.Handshake(True) and items[1].cmd == lms.REPLY_INVALID


def test_continuous_output_no_faster_than_the_baud(scanners, host):
    host.port.write(lms.mode_request(lms.Mode.CONTINUOUS))
    start = time.monotonic()
    got = 0
    frames = []
    while len(frames) < 3 and time.monotonic() - start < 5:
        data = host.port.read(4096)
        got += len(data)
        frames += [i for i in host.dec.feed(data) if isinstance(i, lms.Frame) and i.cmd == 0xB0]
    elapsed = time.monotonic() - start
    assert len(frames) == 3
    assert got / elapsed <= 960 * 1.02  # 9600 baud = 960 bytes/s at most
    host.port.write(lms.mode_request(lms.Mode.POLLED))
    wait_until(lambda: not scanners.device("lms").streaming)


def test_variant_units_and_refusals(scanners, host):
    r = host.ask(lms.variant_request(100, 100))[-1]
    assert r.cmd == 0xBB and r.fields() == {"accepted": True, "angle": 100, "resolution": 100}
    bad = host.ask(lms.variant_request(90, 100))[-1]
    assert bad.fields() == {"accepted": False, "angle": 100, "resolution": 100}
    refused = host.ask(lms.mode_request(lms.Mode.INSTALLATION, b"WRONGPWD"))[-1]
    assert refused.cmd == 0xA0 and refused.data == b"\x01"
    ok = host.ask(lms.mode_request(lms.Mode.INSTALLATION))[-1]
    assert ok.data == b"\x00"
    block = bytes(lms.CONFIG_SIZE)  # units byte 0: cm
    assert host.ask(lms.request(lms.Cmd.WRITE_CONFIG, block))[-1].data[0] == 1
    host.ask(lms.mode_request(lms.Mode.POLLED))
    scan = [i for i in host.ask(lms.request(lms.Cmd.SCAN, b"\x01")) if isinstance(i, lms.Frame)][-1].fields()
    assert scan["count"] == 101 and scan["units"] == 0
    r_cm = np.asarray(scan["values"]) / 100.0
    angles = 40.0 + np.arange(101)
    assert fraction_within(np.radians(angles - 90.0), r_cm, sigma0=0.005, sigma_k=0.0, slack=0.006) > 0.97


def test_nak_on_bad_crc_and_reset(scanners, host):
    bad = bytearray(lms.request(lms.Cmd.STATUS))
    bad[-1] ^= 1
    host.port.write(bytes(bad))
    host.port.timeout = 2.0
    assert host.port.read(1) == b"\x15"  # NAK, and no reply
    host.port.timeout = 0.05
    items = host.ask(lms.request(lms.Cmd.RESET), n=2, timeout=3)
    frames = [i for i in items if isinstance(i, lms.Frame)]
    assert [f.cmd for f in frames] == [lms.REPLY_RESET, lms.REPLY_POWER_ON]
    assert scanners.device("lms").baud == 9600
