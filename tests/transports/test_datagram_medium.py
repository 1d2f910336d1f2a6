"""The datagram net: addressed delivery to devices, replies from the port the host wrote to, owned sockets,
taps (with and without addresses) seeing each datagram once, timers; ADDRESS records in captures and taps."""

from __future__ import annotations

import socket
import time

from hilbench.protocols import capture as cap
from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.capture_parser import CaptureParser
from hilbench.transports.datagram_medium import DatagramMedium
from hilbench.transports.sources.stream import TcpSource
from hilbench.transports.tap_server import TapServer
from hilbench.transports.udp import UdpPort


class Echo:
    """Answers every datagram with it reversed, from wherever it arrived."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.heard: list[tuple[bytes, tuple, tuple]] = []
        self.port = None

    def on_datagram(self, data, src, dst, t) -> None:
        self.heard.append((data, src, dst))
        self.port.send(data[::-1], src)


def test_devices_hear_and_answer_with_addresses() -> None:
    net = DatagramMedium("net")
    host = UdpPort("ep")
    echo = Echo("echo")
    echo.port = net.add_device(echo)
    net.add_host(host)
    four, three = [], []
    net.add_tap(lambda t, source, data, addr: four.append((source, data, addr)))
    net.add_tap(lambda t, source, data: three.append((source, data)))
    net.start()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.bind(("127.0.0.1", 0))
    client.settimeout(2)
    try:
        client.sendto(b"abc", host.address)
        data, sender = client.recvfrom(100)
        assert data == b"cba" and sender == host.address  # the reply leaves from the port the host wrote to
        c = client.getsockname()
        assert echo.heard == [(b"abc", c, host.address)]
        wait_until(lambda: len(four) == 2)
        assert four == [(f"udp:127.0.0.1:{c[1]}", b"abc", (*c, *host.address)),
                        ("echo", b"cba", (*host.address, *c))]
        assert three == [(s, d) for s, d, _ in four]
    finally:
        client.close()
        net.close()
        host.close()


def test_owned_sockets_and_in_net_traffic_is_tapped_once() -> None:
    net = DatagramMedium("net")
    a, b = Echo("a"), Echo("b")
    a.port, b.port = net.add_device(a), net.add_device(b)
    sa, sb = a.port.open_socket(), b.port.open_socket()
    seen = []
    net.add_tap(lambda t, s, d, addr: seen.append((s, d)))
    net.start()
    try:
        a.port.send(b"ping", sb.address)
        wait_until(lambda: len(seen) >= 6)  # ping, gnip, ping ... bounces until stopped
        net.stop()
        assert not a.heard[0][0].startswith(b"ping") or a.heard[0][0] == b"gnip"
        assert b.heard[0] == (b"ping", sa.address, sb.address)  # only b heard what came to its socket
        assert all(h[2] == sa.address for h in a.heard)
        sources = [s for s, _ in seen]
        assert sources[:4] == ["a", "b", "a", "b"]  # each datagram once, named by its sender
    finally:
        net.close()


def test_timers_run_in_order_in_the_nets_thread() -> None:
    net = DatagramMedium("net")
    host = UdpPort("ep")
    net.add_host(host)
    net.start()
    order = []
    try:
        now = time.monotonic()
        net.call_at(now + 0.05, lambda: order.append(2))
        net.call_at(now + 0.01, lambda: order.append(1))
        wait_until(lambda: order == [1, 2], 2)
    finally:
        net.close()
        host.close()


def test_address_records_round_trip_and_old_readers_still_get_the_data(tmp_path) -> None:
    path = tmp_path / "d.hbcap"
    addr = ("127.0.0.1", 40000, "10.1.2.3", 8888)
    with CaptureWriter(path, protocol="udp") as w:
        w.write(1.0, "udp:127.0.0.1:40000", b"xyz", addr)
        w.write(2.0, "bus", b"serial")
        w.write(3.0, "v6", b"six", ("::1", 1, "::1", 2))
    chunks = list(CaptureReader(path))
    assert [(c.data, c.addr) for c in chunks] == [(b"xyz", addr), (b"serial", None), (b"six", ("::1", 1, "::1", 2))]
    raw = path.read_bytes()
    assert cap.build_address(addr) in raw
    # A reader that knows only DATA/SOURCE/GAP (and skips other kinds by their length, as the format
    # says) still gets every datagram's bytes: the addresses ride in records of their own.
    pos = cap.HEADER_PREFIX_SIZE + cap.header_body_size(raw)
    data = []
    while pos < len(raw):
        kind, _, length, _ = cap.unpack_record_header(raw, pos)
        payload = raw[pos + cap.RECORD_HEADER_SIZE:pos + cap.RECORD_HEADER_SIZE + length]
        pos += cap.RECORD_HEADER_SIZE + length
        if kind == cap.RecordKind.DATA:
            data.append(payload)
    assert data == [b"xyz", b"serial", b"six"]
    assert [c.addr for c in CaptureParser().feed(raw)][0] == addr


def test_tap_server_streams_addresses() -> None:
    srv = TapServer(protocol="udp")
    try:
        src = TcpSource("127.0.0.1", srv.port)
        wait_until(lambda: srv.clients == 1)
        srv.feed(time.monotonic(), "agent", b"data", ("127.0.0.1", 8888, "127.0.0.1", 5000))
        it = src.chunks()
        chunk = next(it)
        assert chunk.data == b"data" and chunk.addr == ("127.0.0.1", 8888, "127.0.0.1", 5000)
        src.close()
    finally:
        srv.close()


def test_addresses_survive_runs_of_plain_data(tmp_path) -> None:
    """A datagram among runs of address-less data (a serial source in the same capture): the reader's fast
    path for plain DATA runs must leave each datagram its address, whatever the split of the input."""
    path = tmp_path / "mixed.hbcap"
    t = 1.0
    with CaptureWriter(path, protocol="udp") as w:
        w.write(t, "bus", b"x")
        for k in range(50):
            t += 0.001
            w.write(t, "udp", b"D%d" % k, ("127.0.0.1", 1000 + k, "127.0.0.1", 8888))
            for _ in range(3):
                t += 0.001
                w.write(t, "bus", b"serial")
    want = [1000 + k for k in range(50)]
    assert [c.addr[1] for c in CaptureReader(path) if c.source == "udp"] == want
    raw = path.read_bytes()
    for step in (1, 7, 64, 4096):
        parser = CaptureParser()
        got = [c for i in range(0, len(raw), step) for c in parser.feed(raw[i:i + step])] + parser.finish()
        assert [c.addr[1] for c in got if c.source == "udp"] == want, step
        assert all(c.addr is None for c in got if c.source == "bus"), step
