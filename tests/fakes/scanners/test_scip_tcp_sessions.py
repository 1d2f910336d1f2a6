"""A UST-10LX over TCP, connection after connection: it holds its one client, and each new connection starts
with an empty command buffer (nothing the last client began is run for the next one)."""

from __future__ import annotations

import socket
import time

import pytest

from hilbench.bench.profile import parse_profile
from hilbench.protocols import scip
from hilbench.pytest_plugin import wait_until
from tests.fakes.scanners.conftest import need, run_client

UST = {"schema": 1, "scene": {"walls": [[[-3.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]]]},
       "endpoints": {"ust": {"type": "tcp", "protocol": "scip2", "port": 0}},
       "devices": [{"model": "ust-10lx", "endpoint": "ust", "name": "ust", "pose": {"x": 0.5, "y": 0.3}}]}


@pytest.fixture
def ust(hilbench_bench):
    return hilbench_bench(parse_profile(UST, "ust.toml"))


class Host:
    """A raw TCP client of the unit, decoding its replies."""

    def __init__(self, address) -> None:
        self.sock = socket.create_connection(address, timeout=5)
        self.dec = scip.ReplyDecoder()

    def replies(self, n: int = 1, timeout: float = 3.0) -> list[scip.Reply]:
        out: list[scip.Reply] = []
        deadline = time.monotonic() + timeout
        self.sock.settimeout(0.1)
        while len(out) < n and time.monotonic() < deadline:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            if not data:
                break
            out += [r for r in self.dec.feed(data) if isinstance(r, scip.Reply)]
        return out

    def ask(self, line: bytes) -> scip.Reply:
        self.sock.sendall(line)
        return self.replies(1)[0]

    def close(self) -> None:
        self.sock.close()


def connect(ust, address) -> Host:
    """A client the unit serves: connected once the unit let the last one go (it serves one at a time, and a
    connection queued while another is held is closed), and accepted before this returns."""
    port = ust.endpoint("ust").port
    wait_until(lambda: port.client is None, 3)
    count = port.connections
    host = Host(address)
    wait_until(lambda: port.connections > count, 3)
    return host


def test_a_new_connection_does_not_inherit_the_last_ones_unended_line(ust):
    address = ust.endpoint("ust").port.address
    first = connect(ust, address)
    first.sock.sendall(b"QTxyz")  # a command begun, never ended
    first.close()
    second = connect(ust, address)
    try:
        reply = second.ask(b"VV\n")
        assert reply.echo == "VV" and reply.status == "00"  # not "QTxyzVV" run as QT
        assert "VEND:Hokuyo Automatic Co.,Ltd." in reply.raw.decode()
    finally:
        second.close()
    assert "QT" not in ust.device("ust").requests


def test_a_reboot_armed_by_the_last_client_is_not_completed_by_the_next(ust):
    address = ust.endpoint("ust").port.address
    first = connect(ust, address)
    assert first.ask(b"RB\n").status == "01"  # armed: a second RB would reboot
    first.close()
    second = connect(ust, address)
    try:
        assert second.ask(b"RB\n").status == "01"
    finally:
        second.close()


def test_the_last_clients_continuous_scans_do_not_reach_the_next(ust):
    address = ust.endpoint("ust").port.address
    first = connect(ust, address)
    assert first.ask(b"MD0000108000000\n").status == "00"  # endless MD
    assert first.replies(1)[0].status == "99"
    first.close()
    second = connect(ust, address)
    try:
        assert second.replies(1, timeout=0.3) == []  # one scan period is 25 ms: nothing came unasked
        assert ust.device("ust").md is None
        assert second.ask(b"VV\n").echo == "VV"
    finally:
        second.close()


def test_the_unit_holds_its_one_client_and_a_second_connection_is_closed_at_once(ust):
    address = ust.endpoint("ust").port.address
    held = connect(ust, address)
    try:
        assert held.ask(b"VV\n").status == "00"
        other = socket.create_connection(address, timeout=5)
        assert other.recv(100) == b""  # accepted and closed: the unit serves one client
        other.close()
        assert held.ask(b"PP\n").status == "00"  # the held client never noticed
        assert ust.endpoint("ust").port.refused == 1
    finally:
        held.close()


def test_hokuyolx_after_a_client_left_a_command_half_sent(ust):
    need("hokuyolx")
    port = ust.endpoint("ust").port
    host, number = port.address
    stray = connect(ust, (host, number))
    stray.sock.sendall(b"MD00001080")  # half an MD: joined to hokuyolx's first %ST it would be garbage
    stray.close()
    wait_until(lambda: port.client is None, 3)
    out = run_client("hokuyolx_client.py", host, str(number), "3")
    assert out["params"]["model"] == "UST-10LX" and out["pendings"] == [2, 1, 0]


def test_requests_piled_up_unread_wait_in_a_bounded_queue_and_the_rest_are_dropped_and_counted(ust):
    from hilbench.fakes.scanners.scip import MAX_WAITING

    unit = ust.device("ust")
    address = ust.endpoint("ust").port.address
    flood = connect(ust, address)
    try:
        assert flood.ask(b"BM\n").status == "00"
        scanned = unit.scans_sent
        flood.sock.sendall(b"GD0000108000\n" * 2000)  # 2 000 scans asked at once (50 MB of them unread before)
        wait_until(lambda: unit.scans_sent - scanned + unit.counters["requests_dropped"] == 2000)
        dropped = unit.counters["requests_dropped"]
        assert dropped >= 2000 - 10 * MAX_WAITING  # (a loaded machine reads them in a few bites, replies go between)
        replies = flood.replies(2000 - dropped + 1, timeout=2.0)
        assert [r.status for r in replies] == ["00"] * (2000 - dropped)  # each kept request answered whole
        assert flood.ask(b"VV\n").status == "00"  # and the unit goes on answering
    finally:
        flood.close()
