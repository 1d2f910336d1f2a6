"""The UDP relay (``hilbench tap udp``) and UDP host ports keep their bounds: clients, what the watching side
holds, and they say so; a relay listening beyond loopback is warned about like the other servers."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading

import pytest

from hilbench.pytest_plugin import wait_until
from hilbench.transports import udp_relay
from hilbench.transports.udp import MAX_PEERS, UdpPort
from hilbench.transports.udp_relay import UdpRelay


@pytest.fixture
def echo():
    """A UDP echo on 127.0.0.1 (the relay's target)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            try:
                data, addr = sock.recvfrom(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            sock.sendto(data, addr)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    yield sock.getsockname()
    stop.set()
    t.join(2)
    sock.close()


def client() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(2)
    return s


def test_clients_beyond_the_limit_are_dropped_oldest_first_and_counted(echo) -> None:
    relay = UdpRelay(("127.0.0.1", 0), echo, max_clients=2).start()
    clients = [client() for _ in range(3)]
    try:
        for i, c in enumerate(clients):
            c.sendto(b"ping %d" % i, relay.listen)
            assert c.recv(100) == b"ping %d" % i  # each one relayed both ways
        wait_until(lambda: relay.counters()["datagrams_down"] == 3, 5)  # (counted just after it is sent)
        c = relay.counters()
        assert c["clients"] == 2 and c["clients_dropped"] == 1 and c["datagrams_up"] == 3
        assert [a[1] for a in relay.clients] == [s.getsockname()[1] for s in clients[1:]]
    finally:
        relay.close()
        for s in clients:
            s.close()


def test_what_the_watching_side_cannot_hold_is_relayed_and_counted(echo, monkeypatch) -> None:
    monkeypatch.setattr(udp_relay, "WATCH_BYTES", 4096)
    relay = UdpRelay(("127.0.0.1", 0), echo).start()  # nobody reads relay.source
    c = client()
    try:
        for _ in range(20):
            c.sendto(bytes(1000), relay.listen)
            assert len(c.recv(2000)) == 1000  # relayed whatever the watcher holds
        wait_until(lambda: relay.counters()["datagrams_down"] == 20, 5)
        counters = relay.counters()
        assert counters["unwatched_bytes"] == 40 * 1000 - 4000  # up and down, 4 kB held
        # Once the watcher catches up, the monitor hears of the loss before the next datagram.
        stream = relay.source.chunks(idle=0)
        held = list(iter(lambda: next(stream), None))
        assert len(held) == 4 and not any(ch.lost for ch in held)
        c.sendto(b"again", relay.listen)
        wait_until(lambda: relay.counters()["datagrams_up"] == 21, 5)
        after = list(iter(lambda: next(stream), None))
        assert sum(ch.lost for ch in after) == counters["unwatched_bytes"] and after[-1].data == b"again"
    finally:
        relay.close()
        c.close()


RELAY_ON_LOOPBACK = """
import sys
from hilbench.transports import udp_relay

class Relay(udp_relay.UdpRelay):  # tests bind 127.0.0.1 only: the verb sees the address it was given
    def __init__(self, listen, target, **kw):
        super().__init__(("127.0.0.1", listen[1]), target, **kw)
        self.listen = listen

udp_relay.UdpRelay = Relay
from hilbench.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_tap_udp_on_every_interface_is_warned_about() -> None:
    run = [sys.executable, "-c", RELAY_ON_LOOPBACK, "tap", "udp"]
    wide = subprocess.run([*run, "0.0.0.0:0", "127.0.0.1:9", "--seconds", "0.2"], capture_output=True, text=True,
                          timeout=60)
    assert wide.returncode == 0, wide.stderr
    assert ("hilbench: warning: the relay (LISTEN 0.0.0.0:0) listens on 0.0.0.0, beyond this machine "
            "(anyone who reaches this machine can send through it to the upstream") in wide.stderr
    here = subprocess.run([*run, "0", "127.0.0.1:9", "--seconds", "0.2"], capture_output=True, text=True,
                          timeout=60)
    assert here.returncode == 0 and "warning" not in here.stderr, here.stderr
    assert "0 clients dropped (beyond 64), 0 bytes relayed unwatched" in here.stderr


def test_a_udp_host_port_shows_its_traffic_and_losses() -> None:
    ep = UdpPort("u")
    peers = [client() for _ in range(MAX_PEERS + 2)]
    try:
        for p in peers:
            p.sendto(b"hi", ep.address)
        wait_until(lambda: ep.read() is not None and ep.datagrams_in == len(peers), 5)
        c = ep.describe()["counters"]
        assert c["datagrams_in"] == len(peers) and c["peers"] == MAX_PEERS == c["max_peers"]
    finally:
        ep.close()
        for p in peers:
            p.close()
