"""A host that writes faster than a paced line's wire is held back as a USB adapter holds it: the line reads it
only while its bytes ahead of the wire are under HOST_FIFO, so the kernel's buffer fills and the writer waits
(EAGAIN for a non-blocking one); nothing it wrote is lost, and the wire stays busy meanwhile."""

from __future__ import annotations

import os
import socket
import termios
import threading
import time
import tty

import pytest

from hilbench.pytest_plugin import wait_until
from hilbench.transports.pty import PtyPort
from hilbench.transports.serial_medium import HOST_FIFO, SerialMedium
from hilbench.transports.tcp import TcpPort

STREAM = bytes(i * 7 % 251 for i in range(1 << 16)) * 64  # 4 MiB, no period of 4 KiB: order shows


class Sink:
    """A device that keeps what it hears."""

    def __init__(self, name: str = "sink") -> None:
        self.name = name
        self.chunks: list[bytes] = []
        self.lock = threading.Lock()

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        with self.lock:
            self.chunks.append(bytes(data))

    def received(self) -> bytes:
        with self.lock:
            return b"".join(self.chunks)


def pty_client(path: str, baud: int) -> int:
    """A non-blocking raw client of ``path`` at ``baud`` (a flood's bytes go out at the client's rate)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    attrs[4] = attrs[5] = getattr(termios, f"B{baud}")
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
    return fd


def pty_buffer() -> int:
    """What this kernel's pty takes from a writer while nobody reads the other side."""
    master, slave = os.openpty()
    try:
        tty.setraw(slave)
        os.set_blocking(slave, False)
        n = 0
        try:
            while True:
                n += os.write(slave, b"x" * 1024)
        except BlockingIOError:
            pass
        return n
    finally:
        os.close(master)
        os.close(slave)


def flood(send, medium: SerialMedium, host: str, seconds: float) -> tuple[int, int, float, float]:
    """Offer STREAM through ``send`` (non-blocking: returns bytes taken, raises BlockingIOError) for ``seconds``;
    returns (bytes accepted, EAGAINs, the most the line had of the host ahead of the wire (s), elapsed)."""
    accepted = refused = 0
    most = 0.0
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds and accepted < len(STREAM):
        try:
            accepted += send(STREAM[accepted:accepted + 4096])
        except BlockingIOError:
            refused += 1
            time.sleep(0.0005)
        most = max(most, medium.backlog(host))
    return accepted, refused, most, time.monotonic() - t0


@pytest.fixture
def paced_line():
    made = []

    def make(port, baud: int = 1_000_000, paced: bool = True) -> tuple[SerialMedium, Sink]:
        medium = SerialMedium("line", baud, paced=paced)
        sink = Sink()
        medium.add_device(sink)
        medium.add_host(port)
        medium.start()
        made.append((medium, port))
        return medium, sink

    yield make
    for medium, port in made:
        medium.close()
        port.close()


def test_a_paced_line_holds_a_flooding_pty_client_back(paced_line):
    baud = 1_000_000
    ep = PtyPort("host")
    medium, sink = paced_line(ep, baud)
    fd = pty_client(ep.path, baud)
    try:
        accepted, refused, most, elapsed = flood(lambda b: os.write(fd, b), medium, "host", 0.6)
        wire = baud / 10 * elapsed
        # Taken at the wire's pace (before: the whole 4 MiB at once, queued for 42 s of wire time).
        assert refused > 0
        assert accepted <= wire + pty_buffer() + HOST_FIFO + 4096, (accepted, wire)
        assert most <= (HOST_FIFO + 64) * 10 / baud, most  # never more than HOST_FIFO ahead of the wire
        assert medium.stats.held_back > 0
        # Nothing is lost and the order is kept; the wire was kept busy (2 KiB reads, resumed in time).
        wait_until(lambda: len(sink.received()) >= accepted, timeout=5)
        assert sink.received() == STREAM[:accepted]
        assert accepted >= 0.5 * wire, (accepted, wire)
        # Once the flood has drained, the client is read at once again.
        os.write(fd, b"tail")
        wait_until(lambda: sink.received().endswith(b"tail"), timeout=2)
    finally:
        os.close(fd)


def test_a_paced_line_holds_a_flooding_tcp_client_back(paced_line):
    baud = 4_000_000
    ep = TcpPort("host")
    medium, sink = paced_line(ep, baud)
    client = socket.create_connection(ep.address)
    client.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 16384)
    client.setblocking(False)
    try:
        accepted, refused, most, _ = flood(client.send, medium, "host", 0.4)
        assert refused > 0  # TCP's window closed: the client was held back
        assert most <= (HOST_FIFO + 64) * 10 / baud, most
        assert medium.stats.held_back > 0
        wait_until(lambda: len(sink.received()) >= accepted, timeout=10)
        assert sink.received() == STREAM[:accepted]
    finally:
        client.close()


def test_an_unpaced_line_takes_a_flood_at_once(paced_line):
    """No wire to wait for: what the client writes is delivered as it is read, and nobody is held back."""
    ep = PtyPort("host")
    medium, sink = paced_line(ep, 1_000_000, paced=False)
    fd = pty_client(ep.path, 1_000_000)
    try:
        accepted, _, most, elapsed = flood(lambda b: os.write(fd, b), medium, "host", 0.3)
        wait_until(lambda: len(sink.received()) >= accepted, timeout=5)
        assert sink.received() == STREAM[:accepted]
        assert medium.stats.held_back == 0 and most == 0.0
    finally:
        os.close(fd)


class SlowReceiver(Sink):
    """A device pacing its own receiver on an unpaced line (as the rover board's UART does)."""

    def __init__(self, baud: int) -> None:
        super().__init__("uart")
        self.byte_time = 10 / baud
        self.free_at = 0.0

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        super().on_bytes(data, t, baud)
        self.free_at = max(self.free_at, t) + len(data) * self.byte_time

    def input_backlog(self, now: float) -> float:
        return self.free_at - now


def test_a_device_pacing_its_receiver_holds_the_host_back_on_an_unpaced_line():
    baud = 500_000
    medium = SerialMedium("line", baud)
    uart = SlowReceiver(baud)
    medium.add_device(uart)
    ep = PtyPort("host")
    medium.add_host(ep)
    medium.start()
    fd = pty_client(ep.path, baud)
    try:
        accepted, refused, most, elapsed = flood(lambda b: os.write(fd, b), medium, "host", 0.5)
        assert refused > 0 and medium.stats.held_back > 0
        assert most <= (HOST_FIFO + 64) * 10 / baud, most
        assert accepted <= baud / 10 * elapsed + pty_buffer() + HOST_FIFO + 4096
        wait_until(lambda: len(uart.received()) >= accepted, timeout=5)
        assert uart.received() == STREAM[:accepted]
    finally:
        os.close(fd)
        medium.close()
        ep.close()


def test_a_held_back_host_is_not_quiet_and_a_drain_takes_everything(paced_line):
    """The delivery ledger's quiet watch says nothing while bytes wait unread; drain_host (``hilbench run``'s
    tcdrain) takes them all, however far ahead of the wire."""
    baud = 1_000_000
    ep = PtyPort("host")
    medium, sink = paced_line(ep, baud)
    quiet: list[int] = []
    medium.watch_quiet(ep, quiet.append)
    wait_until(lambda: quiet, timeout=2)  # (nothing written yet: quiet at once)
    fd = pty_client(ep.path, baud)
    try:
        accepted, _, _, _ = flood(lambda b: os.write(fd, b), medium, "host", 0.2)
        stamp = time.monotonic_ns()
        box: dict = {}
        done = threading.Event()

        def drain() -> None:
            box["checked"] = medium.check_quiet(ep)
            box["taken"], box["end"] = medium.drain_host(ep)
            done.set()

        medium.call_at(None, drain)
        assert done.wait(5)
        assert box["checked"] is False
        assert box["end"] - time.monotonic() > HOST_FIFO * 10 / baud  # the rest is on its way: long
        wait_until(lambda: len(sink.received()) >= accepted, timeout=10)
        assert sink.received() == STREAM[:accepted]
        wait_until(lambda: quiet[-1] > stamp, timeout=2)  # told once all of it was delivered
    finally:
        os.close(fd)
