"""The SLCAN door: a LAWICEL adapter on a pty, driven byte by byte and by unmodified python-can in another process."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time

import pytest

from hilbench.protocols.can_frame import data_frame
from hilbench.pytest_plugin import wait_until
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.can_port import CanHostPort
from tests.conftest import REPO
from tests.transports.test_socketcand_server import Recorder


@pytest.fixture
def slcan_bus():
    made = []

    def make(bitrate=500_000):
        port = CanHostPort.open("can", CanHostPort.check_options({"socketcand": False, "slcan": True}))
        medium = CanMedium("can", bitrate)
        dev = Recorder()
        dport = medium.add_device(dev)
        medium.add_host(port)
        medium.start()
        made.append((medium, port))
        return port.slcan, dev, dport

    yield make
    for medium, port in made:
        medium.close()
        port.close()


class Tty:
    def __init__(self, path):
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        self.buf = b""

    def cmd(self, text: str) -> bytes:
        """Send one command; return the adapter's answer up to CR or BEL."""
        os.write(self.fd, text.encode() + b"\r")
        return self.line()

    def line(self, timeout=3.0) -> bytes:
        deadline = time.monotonic() + timeout
        while True:
            for i, b in enumerate(self.buf):
                if b in (0x0D, 0x07):
                    out, self.buf = self.buf[: i + 1], self.buf[i + 1 :]
                    return out
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.fd], [], [], left)[0]:
                raise TimeoutError(f"no answer; have {self.buf!r}")
            self.buf += os.read(self.fd, 1024)

    def quiet(self, seconds=0.15) -> bool:
        return not select.select([self.fd], [], [], seconds)[0] and not self.buf

    def close(self):
        os.close(self.fd)


def test_adapter_starts_closed_and_follows_lawicel(slcan_bus):
    adapter, dev, dport = slcan_bus()
    tty = Tty(adapter.path)
    dport.send(data_frame(0x100, b"\x01"))
    assert tty.quiet()  # closed: nothing reaches the host
    assert tty.cmd("t1231AA") == b"\a"  # and it may not send
    assert tty.cmd("V") == b"V1013\r" and tty.cmd("N") == b"NHB01\r"
    assert tty.cmd("S6") == b"\r" and tty.cmd("") == b"\r"
    assert tty.cmd("O") == b"\r"
    assert tty.cmd("S4") == b"\a"  # no bitrate change while open
    assert tty.cmd("t1232DEAD") == b"z\r" and tty.cmd("T1ABCDEF0101") == b"Z\r"
    wait_until(lambda: len(dev.frames) == 2)
    assert dev.frames == [data_frame(0x123, b"\xde\xad"), data_frame(0x1ABCDEF0, b"\x01", extended=True)]
    assert tty.cmd("t12") == b"\a"  # malformed
    dport.send(data_frame(0x456, b"\x11\x22\x33"))
    assert tty.line() == b"t4563112233\r"
    assert tty.cmd("F") == b"F00\r"
    assert tty.cmd("C") == b"\r" and tty.cmd("Z1") == b"\r" and tty.cmd("L") == b"\r"
    assert tty.cmd("t1230") == b"\a"  # listen-only
    dport.send(data_frame(0x7FF, b""))
    line = tty.line()
    assert line.startswith(b"t7FF0") and len(line) == 5 + 4 + 1  # a 4-digit millisecond stamp
    assert tty.cmd("X") == b"\a"
    tty.close()


def test_acceptance_filter_and_wrong_bitrate(slcan_bus):
    adapter, dev, dport = slcan_bus(bitrate=250_000)
    tty = Tty(adapter.path)
    assert tty.cmd(f"M{0x123 << 21:08X}") == b"\r" and tty.cmd("m000FFFFF") == b"\r"
    assert tty.cmd("O") == b"\r"
    dport.send(data_frame(0x124, b""))
    dport.send(data_frame(0x123, b"\x05"))
    assert tty.line() == b"t123105\r"
    assert tty.cmd("C") == b"\r" and tty.cmd("S6") == b"\r" and tty.cmd("O") == b"\r"  # 500 k on a 250 k bus
    dport.send(data_frame(0x123, b"\x06"))
    assert tty.quiet()
    assert tty.cmd("t3210") == b"z\r"
    time.sleep(0.1)
    assert all(f.can_id != 0x321 for f in dev.frames)  # nothing passes at the wrong bitrate
    assert int(tty.cmd("F")[1:3], 16) & 0x80  # bus error flag
    assert adapter.bitrate_mismatch >= 2
    tty.close()


def test_python_can_slcan_in_another_process(slcan_bus):
    adapter, dev, dport = slcan_bus()
    proc = subprocess.Popen([sys.executable, str(REPO / "tests" / "can_client.py"), "slcan", "0x123", "5", "0x18FF50E5",
                             f"channel={adapter.path}", "bitrate=500000", "sleep_after_open=0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    wait_until(lambda: adapter.open, timeout=10)
    for i in range(5):
        dport.send(data_frame(0x123, bytes([i, 2, 3])))
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    res = json.loads(out.strip().splitlines()[-1])
    assert res["version"] == [10, 13]
    assert [g["data"] for g in res["received"] if g["id"] == 0x123] == [f"{i:02x}0203" for i in range(5)]
    wait_until(lambda: sum(f.can_id == 0x18FF50E5 for f in dev.frames) == 5)
    assert all(f.extended for f in dev.frames if f.can_id == 0x18FF50E5)
    assert not adapter.open  # python-can's shutdown sends C


def test_close_discards_what_an_earlier_client_left_unread(slcan_bus):
    adapter, dev, dport = slcan_bus()
    tty = Tty(adapter.path)
    assert tty.cmd("O") == b"\r"
    for i in range(5):
        dport.send(data_frame(0x100 + i, b""))
    wait_until(lambda: adapter.received == 5)
    tty.close()  # gone without reading or closing the channel
    tty = Tty(adapter.path)
    os.write(tty.fd, b"C\r")  # the next client's first command; it reads only later (as python-can does)
    wait_until(lambda: not adapter.open)
    assert tty.line() == b"\r"  # the reply, and none of the stale frames
    assert tty.quiet()
    tty.close()
