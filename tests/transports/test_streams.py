"""Byte streams for instruments: files, FIFOs, a real pty through pyserial, UDP on 127.0.0.1 with peer
registration, and one-line errors."""

from __future__ import annotations

import os
import socket

import pytest

from hilbench.pytest_plugin import wait_until
from hilbench.transports.pty import PtyEndpoint
from hilbench.transports.streams import FileStream, SerialStream, StreamError, UdpReceiver, open_stream


def read_all(stream, until: int, timeout: float = 5.0) -> bytes:
    got = bytearray()

    def more() -> bool:
        data = stream.read(0.05)
        if data:
            got.extend(data)
        return len(got) >= until or data is None

    wait_until(more, timeout=timeout)
    return bytes(got)


def test_file_to_its_end(tmp_path):
    path = tmp_path / "trace.txt"
    path.write_bytes(b"x" * 3_000_000)
    with open_stream(str(path)) as s:
        assert isinstance(s, FileStream) and not s.live
        chunks = []
        while (d := s.read()) is not None:
            chunks.append(d)
    assert b"".join(chunks) == b"x" * 3_000_000 and len(chunks) == 3


def test_fifo_is_live_and_ends_when_the_writer_closes(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    wfd = None
    rfd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # so the writer's open does not block
    try:
        wfd = os.open(fifo, os.O_WRONLY)
        s = FileStream(str(fifo))
        assert s.live and s.read(0.01) == b""  # nothing yet: no data, not the end
        os.write(wfd, b"IDLE 1 0\n")
        assert read_all(s, 9) == b"IDLE 1 0\n"
        os.close(wfd)
        wfd = None
        assert s.read(0.5) is None
        s.close()
    finally:
        os.close(rfd)
        if wfd is not None:
            os.close(wfd)


def test_serial_port_over_a_real_pty():
    ep = PtyEndpoint()
    try:
        s = open_stream(ep.path, baud=1_152_000)
        assert isinstance(s, SerialStream) and s.live
        assert ep.client_baud() == 1_152_000  # opened raw at the requested rate, as the bridge would
        os.write(ep.master_fd, b"wheel_ctrl 96 in\n" * 100)
        assert read_all(s, 1700) == b"wheel_ctrl 96 in\n" * 100
        s.close()
        s2 = open_stream(f"serial://{ep.path}?baud=115200")
        assert ep.client_baud() == 115_200
        s2.close()
    finally:
        ep.close()


def test_udp_binds_loopback_and_registers_with_a_peer():
    board = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    board.bind(("127.0.0.1", 0))
    board.settimeout(5)
    try:
        bport = board.getsockname()[1]
        s = open_stream(f"udp://:0?peer=127.0.0.1:{bport}")
        assert isinstance(s, UdpReceiver) and s.address[0] == "127.0.0.1"
        data, addr = board.recvfrom(100)  # the announcement: an empty datagram from the receiver's socket
        assert data == b"" and addr == s.address
        for k in range(5):
            board.sendto(b"word%d" % k, addr)
        assert read_all(s, 25) == b"word0word1word2word3word4" and s.datagrams == 5
        s.close()
    finally:
        board.close()


@pytest.mark.parametrize(("spec", "message"), [
    ("/no/such/port", "no such file, port or source"),
    ("udp://127.0.0.1:70000", "expected HOST:PORT"),
    ("udp://127.0.0.1:1?peer=nowhere", "peer: expected HOST:PORT"),
    ("tcp://127.0.0.1:5", "unknown source scheme"),
    ("serial:///dev/ttyS0?baud=fast", "baud must be an integer"),
])
def test_bad_sources_are_one_line_errors(spec, message):
    with pytest.raises(StreamError, match=message):
        open_stream(spec)
