"""Byte sources: a receive-only serial sniffer on a real pty, a bench's TCP tap, push sources, FIFOs and
stdin pipes, UDP on 127.0.0.1 with peer registration, source strings and their one-line errors."""

from __future__ import annotations

import json
import os
import select
import socket
import subprocess
import sys
import threading
import time
import tty

import dynamixel_sdk as sdk
import pytest

from hilbench.bench import Bench
from hilbench.protocols import dynamixel as dxl
from hilbench.pytest_plugin import wait_until
from hilbench.transports import tap_server
from hilbench.transports.capture_parser import CaptureParser
from hilbench.transports.chunk import Chunk
from hilbench.transports.sources import (
    FileSource,
    PushSource,
    SerialSource,
    SourceError,
    StreamSource,
    TcpSource,
    UdpSource,
    open_source,
)
from hilbench.transports.tap_server import TapServer


class Collector:
    """Iterates a source in a thread and keeps what it yields."""

    def __init__(self, source, idle: float | None = None) -> None:
        self.source = source
        self.chunks: list[Chunk] = []
        self.idles = 0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.idle = idle
        self.thread.start()

    def _run(self) -> None:
        for c in self.source.chunks(self.idle):
            if c is None:
                self.idles += 1
            else:
                self.chunks.append(c)

    def data(self, source: str | None = None) -> bytes:
        return b"".join(c.data for c in list(self.chunks) if source is None or c.source == source)


def test_serial_source_sniffs_a_real_pty_and_never_writes():
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        src = open_source(os.ttyname(slave), baud=2_000_000)
        assert isinstance(src, SerialSource) and src.baud == 2_000_000
        col = Collector(src, idle=0.02)
        packet = dxl.status_packet(1, 0, b"\x32\x08\x00\x00")
        os.write(master, packet[:5])
        os.write(master, packet[5:])
        wait_until(lambda: col.data() == packet)
        wait_until(lambda: col.idles > 0)  # a quiet line still wakes the consumer
        assert all(c.source == "bus" for c in col.chunks)
        assert not select.select([master], [], [], 0.05)[0]  # receive-only: nothing came back
        src.close()
        col.thread.join(timeout=2)
        assert not col.thread.is_alive()
    finally:
        os.close(master)
        os.close(slave)


def test_a_manifest_named_freely_is_found_by_its_content(tmp_path):
    """``emulate --manifest bench.manifest`` takes any name, and prints ``hilbench monitor bench.manifest#arm``."""
    with Bench("arm", tap=True) as bench:
        path = tmp_path / "arm.manifest"
        bench.write_manifest(path)
        src = open_source(f"{path}#arm")
        try:
            assert isinstance(src, TcpSource) and src.protocol == "dynamixel"
        finally:
            src.close()
    (tmp_path / "notes.manifest").write_text('{"hilbench": "no manifest"}')  # JSON, but not a manifest
    assert isinstance(open_source(str(tmp_path / "notes.manifest")), FileSource)


def test_a_bench_tap_streams_both_directions_to_every_client():
    with Bench("arm", tap=True) as bench:
        ep = bench.endpoint()
        assert bench.manifest()["endpoints"][0]["tap"] == ep.tap.url
        assert ep.tap.url.startswith("tcp://127.0.0.1:")
        first, second = (open_source(ep.tap.url) for _ in range(2))
        assert isinstance(first, TcpSource) and first.baud == 1_000_000 and first.protocol == "dynamixel"
        cols = [Collector(first), Collector(second)]
        wait_until(lambda: ep.tap.clients == 2)
        port = sdk.PortHandler(ep.path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        # the traffic the taps must show (a ping the SDK timed out on, under load, is sent again: both are seen)
        pings = 1
        while sdk.PacketHandler(2.0).ping(port, 3)[1] != sdk.COMM_SUCCESS and pings < 3:
            pings += 1
        port.closePort()
        ping = dxl.instruction_packet(3, dxl.Instruction.PING)
        for col in cols:
            wait_until(lambda col=col: col.data("arm") == ping * pings and len(col.data("arm-devices")) == 14 * pings)
            assert col.chunks[0].t <= col.chunks[1].t  # the request before its reply
        for src in (first, second):
            src.close()


def test_a_slow_tap_client_gets_a_gap_record_not_unbounded_memory():
    server = TapServer(max_buffer=64 << 10)
    try:
        client = socket.socket()
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        client.connect((server.host, server.port))
        wait_until(lambda: server.clients == 1)
        block = bytes(1024)
        total = 0
        for _ in range(4096):  # 4 MiB while the client reads nothing
            server.feed(time.monotonic(), "bus", block)
            total += len(block)
        parser = CaptureParser()
        got: list[Chunk] = []
        client.setblocking(False)
        deadline = time.monotonic() + 20
        while not any(c.data == b"end" for c in got):
            assert time.monotonic() < deadline
            server.feed(time.monotonic(), "bus", b"end")
            total += 3
            while select.select([client], [], [], 0.01)[0]:
                data = client.recv(1 << 16)
                if not data:
                    break
                got += parser.feed(data)
        lost = sum(c.lost for c in got)
        assert lost > 0
        assert sum(len(c.data) for c in got) + lost <= total
        assert sum(len(c.data) for c in got) > 64 << 10
        client.close()
    finally:
        server.close()


def test_push_source_bounds_memory_and_reports_losses():
    src = PushSource("test", max_bytes=10)
    src.push(1.0, "a", b"12345678")
    src.push(2.0, "a", b"too much")  # would exceed 10 bytes waiting: dropped, counted
    it = src.chunks()
    assert next(it) == Chunk(1.0, "a", b"12345678")
    src.push(3.0, "b", b"ok")
    src.end()
    assert list(it) == [Chunk(3.0, "a", b"", 8), Chunk(3.0, "b", b"ok")]


def test_source_strings(tmp_path):
    capture = tmp_path / "trace.bin"
    capture.write_bytes(b"\x00" * 10)
    assert isinstance(open_source(str(capture)), FileSource)
    with pytest.raises(SourceError, match="no such file, port or source"):
        open_source(str(tmp_path / "missing"))
    with pytest.raises(SourceError, match="expected tcp://HOST:PORT"):
        open_source("tcp://nowhere")
    with pytest.raises(SourceError, match="cannot connect"):
        open_source("tcp://127.0.0.1:1")
    manifest = tmp_path / "bench.json"
    manifest.write_text(json.dumps({"endpoints": [{"name": "dxl", "tap": None}]}))
    with pytest.raises(SourceError, match="offers no tap"):
        open_source(str(manifest))
    with pytest.raises(SourceError, match="no endpoint named 'arm'"):
        open_source(f"{manifest}#arm")
    with pytest.raises(SourceError, match="no times"):
        FileSource(capture, speed=1.0)
    with pytest.raises(SourceError, match="cannot open"):
        open_source("serial:///dev/no-such-port?baud=57600")


@pytest.mark.parametrize(("spec", "message"), [
    ("udp://127.0.0.1:70000", "expected HOST:PORT"),
    ("udp://127.0.0.1:1?peer=nowhere", "peer: expected HOST:PORT"),
    ("ftp://127.0.0.1:5", "unknown source scheme 'ftp'"),
    ("serial:///dev/ttyS0?baud=fast", "baud must be an integer"),
])
def test_bad_source_strings_are_one_line_errors(spec, message):
    with pytest.raises(SourceError, match=message):
        open_source(spec)


def test_a_raw_file_is_read_to_its_end_without_times(tmp_path):
    path = tmp_path / "trace.txt"
    path.write_bytes(b"wheel_ctrl 96 in\n" * 20_000)
    with open_source(str(path)) as src:
        assert isinstance(src, FileSource) and not src.live and src.timestamps == "none"
        chunks = list(src)
    assert b"".join(c.data for c in chunks) == path.read_bytes()
    assert {c.t for c in chunks} == {0.0}


def test_a_fifo_is_live_and_ends_when_the_writer_closes(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    src = open_source(str(fifo))
    assert isinstance(src, StreamSource) and src.live
    col = Collector(src, idle=0.01)
    wfd = os.open(fifo, os.O_WRONLY)
    try:
        wait_until(lambda: col.idles > 0)  # quiet: idle ticks, not the end
        assert col.thread.is_alive()
        t0 = time.monotonic()
        os.write(wfd, b"IDLE 1 0\n")
        wait_until(lambda: col.data() == b"IDLE 1 0\n")
        assert t0 <= col.chunks[0].t <= time.monotonic()  # raw live bytes carry their arrival time
    finally:
        os.close(wfd)
    col.thread.join(timeout=5)
    assert not col.thread.is_alive()  # the writer closed: the source ended
    src.close()


def test_stdin_pipe_is_live_and_a_redirected_file_is_replayed(tmp_path):
    code = ("import sys; from hilbench.transports.sources import open_source\n"
            "s = open_source('-'); print(type(s).__name__, s.live, sum(len(c.data) for c in s))")
    piped = subprocess.run([sys.executable, "-c", code], input=b"x" * 5000, capture_output=True, timeout=30)
    assert piped.stdout.split() == [b"StreamSource", b"True", b"5000"], piped.stderr
    path = tmp_path / "in.bin"
    path.write_bytes(b"y" * 7000)
    with open(path, "rb") as f:
        redirected = subprocess.run([sys.executable, "-c", code], stdin=f, capture_output=True, timeout=30)
    assert redirected.stdout.split() == [b"FileSource", b"False", b"7000"], redirected.stderr


def test_udp_binds_loopback_and_registers_with_a_peer():
    board = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    board.bind(("127.0.0.1", 0))
    board.settimeout(5)
    try:
        bport = board.getsockname()[1]
        src = open_source(f"udp://:0?peer=127.0.0.1:{bport}")
        assert isinstance(src, UdpSource) and src.address[0] == "127.0.0.1" and src.live
        data, addr = board.recvfrom(100)  # the announcement: an empty datagram from the source's socket
        assert data == b"" and addr == src.address
        col = Collector(src, idle=0.01)
        for k in range(5):
            board.sendto(b"word%d" % k, addr)
        wait_until(lambda: col.data() == b"word0word1word2word3word4")
        assert src.datagrams == 5
        assert {c.source for c in col.chunks} == {f"udp:127.0.0.1:{bport}"}
        src.close()
        col.thread.join(timeout=5)
    finally:
        board.close()


def test_replay_at_recorded_speed_takes_the_recorded_time(tmp_path):
    capture = tmp_path / "trace.bin"
    capture.write_bytes(bytes(2000))  # 2000 bytes at 100 kbaud: 0.2 s of byte time
    t0 = time.monotonic()
    chunks = list(FileSource(capture, baud=100_000, speed=1.0))
    elapsed = time.monotonic() - t0
    assert sum(len(c.data) for c in chunks) == 2000
    assert 0.18 <= elapsed < 1.0
    fast = time.monotonic()
    list(FileSource(capture, baud=100_000))
    assert time.monotonic() - fast < 0.15


def _recording(kind: str, tmp_path) -> str:
    """Two records 0.3 s apart, as a hilbench capture, a pcap or a candump log."""
    if kind == "capture":
        from hilbench.transports.capture_file import CaptureWriter

        path = tmp_path / "two.hbcap"
        with CaptureWriter(path) as w:
            w.write(10.0, "host", b"a")
            w.write(10.3, "host", b"b")
    elif kind == "pcap":
        from hilbench.transports.pcap import PcapWriter

        path = tmp_path / "two.pcap"
        with PcapWriter(path) as w:
            w.write(1436564565.0, b"a", ("127.0.0.1", 1, "127.0.0.1", 2))
            w.write(1436564565.3, b"b", ("127.0.0.1", 1, "127.0.0.1", 2))
    else:
        path = tmp_path / "two.log"
        path.write_text("(1436564565.000000) can0 123#01\n(1436564565.300000) can0 123#02\n")
    return str(path)


@pytest.mark.parametrize("kind", ["capture", "pcap", "candump"])
def test_every_replay_source_keeps_the_recorded_pace_and_ticks_while_it_waits(kind, tmp_path):
    path = _recording(kind, tmp_path)
    src = open_source(path, speed=1.0)
    t0 = time.monotonic()
    items = list(src.chunks(0.05))
    elapsed = time.monotonic() - t0
    src.close()
    assert len([c for c in items if c is not None]) == 2
    assert 0.28 <= elapsed < 2.0
    assert items.count(None) >= 3  # idle ticks while the second record was not due
    fast = open_source(path)
    assert len(list(fast)) == 2 and fast.clock() is None
    fast.close()
    with pytest.raises(SourceError, match="replay speed must be positive"):
        open_source(path, speed=0)


@pytest.mark.parametrize("kind", ["capture", "pcap", "candump"])
def test_closing_a_replay_source_ends_its_wait(kind, tmp_path):
    src = open_source(_recording(kind, tmp_path), speed=0.01)  # the second record is 30 s away
    col = Collector(src)
    wait_until(lambda: len(col.chunks) == 1)
    t0 = time.monotonic()
    src.close()
    col.thread.join(timeout=5)
    assert not col.thread.is_alive() and time.monotonic() - t0 < 2.0
    assert len(col.chunks) == 1


def test_a_udp_burst_is_taken_in_bounded_bites_and_in_order():
    src = UdpSource()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        n = 3 * UdpSource.MAX_DATAGRAMS + 7
        for k in range(n):  # queued in the socket before anyone reads
            sender.sendto(b"%05d" % k, src.address)
        bites = []
        wait_until(lambda: bites.append(src._drain()) or sum(len(c.data) for b in bites for c in b) >= 5 * n)
        assert all(len(c.data) <= 5 * UdpSource.MAX_DATAGRAMS for b in bites for c in b)
        assert b"".join(c.data for b in bites for c in b) == b"".join(b"%05d" % k for k in range(n))
    finally:
        sender.close()
        src.close()


def test_a_tap_refuses_clients_beyond_its_limit_and_the_reader_says_why():
    server = TapServer(max_clients=2)
    try:
        first, second = TcpSource(server.host, server.port), TcpSource(server.host, server.port)
        wait_until(lambda: server.clients == 2)
        with pytest.raises(SourceError, match=r"refused: 2 clients at most$"):
            TcpSource(server.host, server.port)
        assert server.status()["refused"] == 1
        server.feed(time.monotonic(), "bus", b"still here")  # the others are served as before
        for src in (first, second):
            assert next(c for c in src.chunks(idle=1.0) if c is not None).data == b"still here"
            src.close()
    finally:
        server.close()


def test_a_tap_newcomer_takes_the_place_of_a_client_that_never_reads_and_readers_keep_theirs(monkeypatch):
    monkeypatch.setattr(tap_server, "READ_GRACE", 0.2)
    server = TapServer(max_clients=2)
    sources = []
    try:
        sources.append(TcpSource(server.host, server.port))  # the oldest: it would go first if reading did not count
        deaf = socket.create_connection((server.host, server.port), timeout=5)  # never reads, not even the header
        t_deaf = time.monotonic()
        wait_until(lambda: server.clients == 2)
        wait_until(lambda: time.monotonic() - t_deaf > 0.2)  # deaf has left its header unread long enough
        sources.append(TcpSource(server.host, server.port))  # served: it took deaf's place
        data = deaf.recv(65536)
        while chunk := deaf.recv(65536):  # its stream just ends (after the header it never read)
            data += chunk
        assert data.startswith(b"\x89HBC") and server.status()["evicted"] == 1
        with pytest.raises(SourceError, match=r"refused: 2 clients at most$"):  # both kept clients read
            TcpSource(server.host, server.port)
        server.feed(time.monotonic(), "bus", b"still here")
        for src in sources:
            assert next(c for c in src.chunks(idle=1.0) if c is not None).data == b"still here"
        deaf.close()
    finally:
        for src in sources:
            src.close()
        server.close()


def test_a_tap_client_that_takes_nothing_is_disconnected(monkeypatch):
    monkeypatch.setattr(tap_server, "STALL_TIMEOUT", 0.3)
    server = TapServer(max_buffer=16 << 10)
    sleeper = socket.socket()
    sleeper.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    try:
        sleeper.connect((server.host, server.port))
        wait_until(lambda: server.clients == 1)
        deadline = time.monotonic() + 20
        while not server.stalled:  # the kernel holds a few hundred kB first, then its 16 KiB fill up
            assert time.monotonic() < deadline
            server.feed(time.monotonic(), "bus", bytes(1024))
            assert server.status()["buffered_bytes"] <= (16 << 10) + 2048
            time.sleep(0.0005)
        wait_until(lambda: server.clients == 0)
        assert server.bytes_dropped > 0
    finally:
        sleeper.close()
        server.close()
