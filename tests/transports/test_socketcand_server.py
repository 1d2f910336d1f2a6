"""The socketcand door: the daemon's handshake and modes on a raw socket, and unmodified python-can in other
processes exchanging frames with the bus both ways."""

from __future__ import annotations

import json
import logging
import socket
import subprocess
import sys
import threading
import time

import pytest

from hilbench.protocols import can_frame as cf
from hilbench.protocols import socketcand as sc
from hilbench.protocols.can_frame import data_frame
from hilbench.pytest_plugin import wait_until
from hilbench.transports import socketcand_server
from tests.conftest import REPO


@pytest.fixture
def can_bus(door_bus):
    """A CAN medium with only a socketcand door, a device on it, and the server's address."""

    def make(paced=False, **socketcand):
        medium, port, dev, dport = door_bus({"socketcand": socketcand, "slcan": False}, paced=paced)
        return medium, port, dev, dport, port.socketcand.address

    return make


class Raw:
    """A bare TCP client: sends messages, reads whole messages as the server sends them."""

    def __init__(self, address):
        self.sock = socket.create_connection(address, timeout=5)
        self.splitter = sc.MessageSplitter()
        self.pending: list[str] = []

    def send(self, text: str) -> None:
        self.sock.sendall(text.encode())

    def read(self, timeout: float = 5.0) -> str:
        deadline = time.monotonic() + timeout
        while not self.pending:
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            data = self.sock.recv(4096)
            if not data:
                raise ConnectionError("closed")
            self.pending += self.splitter.feed(data)
        return self.pending.pop(0)

    def segment(self) -> bytes:
        """One recv's worth, as python-can's handshake reads it."""
        return self.sock.recv(256)

    def close(self):
        self.sock.close()


def test_handshake_replies_come_alone_and_frames_wait_for_the_delay(can_bus):
    _m, port, _dev, dport, address = can_bus(rawmode_delay_ms=100)
    server = port.socketcand
    raw = Raw(address)
    assert raw.segment() == b"< hi >"
    raw.send("< open can0 >")
    assert raw.segment() == b"< ok >"
    t0 = time.monotonic()  # before the switch: a late test thread cannot make the hold look short
    raw.send("< rawmode >")
    # On the bus right after the switch (and before the test reads its "< ok >"); a frame sent before the
    # server has read "< rawmode >" is not for this client yet, so wait for the server's own state.
    wait_until(lambda: any(c.mode == "raw" for c in server.clients))
    dport.send(data_frame(0x123, b"\x01"))
    assert raw.segment() == b"< ok >"  # alone: python-can compares the whole read with "< ok >"
    msg = sc.parse_server_message(raw.read())
    assert msg.frame == data_frame(0x123, b"\x01")  # held, not lost
    assert time.monotonic() - t0 >= 0.1  # the 100 ms the server waits after the switch
    assert abs(msg.t_wall - time.time()) < 5  # Unix time, not the monotonic clock
    raw.close()


def test_unknown_bus_is_refused_and_closed(can_bus):
    *_, address = can_bus()
    raw = Raw(address)
    raw.read()
    raw.send("< open vcan9 >")
    assert raw.read() == sc.ERROR_OPEN
    with pytest.raises(ConnectionError):
        raw.read()


def test_raw_mode_commands(can_bus):
    _m, _p, dev, dport, address = can_bus(rawmode_delay_ms=0)
    raw = Raw(address)
    raw.read()
    raw.send("< open can0 >< rawmode >")  # two commands in one segment
    assert raw.read() == sc.OK and raw.read() == sc.OK
    raw.send("< echo >")
    assert raw.read() == sc.ECHO
    raw.send("< frobnicate >")
    assert raw.read() == sc.ERROR_UNKNOWN
    raw.send("< rawmode >")  # no change: the daemon answers an error
    assert raw.read() == sc.ERROR_UNKNOWN
    raw.send("< send 123 2 de >")  # malformed: dropped silently
    raw.send("< send 12345678 2 de ad >< send 7ff 0 >")
    wait_until(lambda: len(dev.frames) == 2)
    assert dev.frames == [data_frame(0x12345678, b"\xde\xad", extended=True), data_frame(0x7FF, b"")]
    dport.send(data_frame(0x7FF, b""))
    report = raw.read()
    assert report.startswith("< frame 7FF ") and report.endswith("  >")  # DLC 0: two spaces before ">"
    raw.close()


def test_bcm_mode_subscriptions_filters_and_cyclic_jobs(can_bus):
    _m, _p, dev, dport, address = can_bus()
    raw = Raw(address)
    raw.read()
    raw.send("< open can0 >")
    assert raw.read() == sc.OK
    raw.send("< subscribe 0 0 123 >< filter 0 0 456 1 F0 >")
    time.sleep(0.05)  # commands without replies: let them arrive before the frames (no reply to wait on)
    for frame in (data_frame(0x100, b"\x00"), data_frame(0x123, b"\x01\x02"), data_frame(0x456, b"\x11"),
                  data_frame(0x456, b"\x1f"), data_frame(0x456, b"\x21")):
        dport.send(frame)
    assert raw.read().endswith(" 01 02  >")  # BCM's spaced bytes
    assert raw.read().split()[2] == "456" and raw.read().endswith(" 21  >")  # 0x1F: masked bits unchanged
    raw.send("< add 0 20000 321 1 aa >")
    wait_until(lambda: sum(f.can_id == 0x321 for f in dev.frames) >= 3)
    raw.send("< delete 321 >")
    time.sleep(0.1)
    n = sum(f.can_id == 0x321 for f in dev.frames)
    time.sleep(0.1)
    assert sum(f.can_id == 0x321 for f in dev.frames) == n  # the job is gone
    raw.send("< controlmode >")
    assert raw.read() == sc.OK
    raw.send("< statistics 50 >")
    stat = raw.read().split()
    assert stat[1] == "stat" and len(stat) == 7
    raw.close()


def test_beacon_reaches_python_can_detection(can_bus):
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("127.0.0.1", sc.BEACON_PORT))
    except OSError:
        probe.close()
        pytest.skip("UDP port 42000 is taken on this machine (another beacon listener)")
    probe.close()
    from can.interfaces.socketcand.socketcand import detect_beacon

    result: list = []
    t = threading.Thread(target=lambda: result.extend(detect_beacon(4000)))
    t.start()
    time.sleep(0.2)
    *_, address = can_bus(beacon=True)
    t.join()
    assert {"interface": "socketcand", "host": "127.0.0.1", "port": address[1], "channel": "can0"} in result


def _client(args: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, str(REPO / "tests" / "can_client.py"), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO)
    line = proc.stdout.readline()
    if line.strip() != "ready":
        proc.kill()
        raise AssertionError(f"client did not start: {line} {proc.stderr.read()}")
    return proc


def _result(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("paced", [False, True])
def test_python_can_clients_in_other_processes_both_ways(can_bus, paced):
    _m, _p, dev, dport, (host, port) = can_bus(paced=paced)
    kwargs = [f"host={host}", f"port={port}", "channel=can0"]
    clients = [_client(["socketcand", "0x123", "5", str(0x300 + i), *kwargs]) for i in range(2)]
    # The server holds frames for 100 ms after rawmode; wait until both clients are past it.
    wait_until(lambda: all(c.raw_at is None and c.mode == "raw" for c in _p.socketcand.clients)
               and len(_p.socketcand.clients) == 2, timeout=10)
    for i in range(5):
        dport.send(data_frame(0x123, bytes([i])))
    results = [_result(c) for c in clients]
    for res in results:
        frames = [g for g in res["received"] if g["id"] == 0x123]
        assert [g["data"] for g in frames] == [f"{i:02x}" for i in range(5)]
        assert all(abs(g["t"] - time.time()) < 30 for g in frames)
    wait_until(lambda: sum(f.can_id in (0x300, 0x301) for f in dev.frames) == 10)
    assert sorted(f.data for f in dev.frames if f.can_id == 0x300) == [bytes([i, 0xAA]) for i in range(5)]
    # A client never hears its own frames back.
    assert 0x300 not in {g["id"] for g in results[0]["received"]}
    assert 0x301 not in {g["id"] for g in results[1]["received"]}


# ---------------------------------------------------------------------- hostile clients: limits and bounds


def test_clients_beyond_the_limit_get_the_daemons_error_and_python_can_still_works(can_bus, monkeypatch):
    import can

    monkeypatch.setattr(socketcand_server, "MAX_CLIENTS", 3)
    _m, port, dev, _dport, (host, tcp) = can_bus()
    server = port.socketcand
    held = [Raw((host, tcp)) for _ in range(3)]
    for raw in held:
        assert raw.read() == sc.HI
    extra = Raw((host, tcp))
    assert extra.read() == "< error too many clients >"  # instead of "< hi >", then the end
    with pytest.raises(ConnectionError):
        extra.read()
    with pytest.raises(can.CanError, match="too many clients"):  # what python-can says: one clear line
        can.Bus(interface="socketcand", host=host, port=tcp, channel="can0")
    assert server.listener.refused == 2 and len(server.clients) == 3
    held[0].send("< open can0 >")
    assert held[0].read() == sc.OK  # the others are served as before
    held.pop().close()
    wait_until(lambda: len(server.clients) == 2)
    bus = can.Bus(interface="socketcand", host=host, port=tcp, channel="can0")
    try:
        bus.send(can.Message(arbitration_id=0x321, data=[7], is_extended_id=False))
        wait_until(lambda: data_frame(0x321, b"\x07") in dev.frames)
    finally:
        bus.shutdown()
    for raw in held:
        raw.close()


def test_a_newcomer_takes_the_place_of_a_client_of_no_use_and_python_can_is_served(can_bus, monkeypatch):
    """Beyond the limit, a newcomer evicts first a client that never opened a bus, then one that leaves what it
    is sent unread; python-can clients that read (the bus is quiet: they have read everything) keep their place,
    and a newcomer finding only those is refused."""
    import can

    monkeypatch.setattr(socketcand_server, "MAX_CLIENTS", 4)
    monkeypatch.setattr(socketcand_server, "OPEN_GRACE", 60.0)
    monkeypatch.setattr(socketcand_server, "READ_GRACE", 0.2)
    _m, port, dev, _dport, (host, tcp) = can_bus()
    server = port.socketcand

    def python_can():
        return can.Bus(interface="socketcand", host=host, port=tcp, channel="can0")

    reader = python_can()  # the oldest client: it would go first if reading did not keep its place
    deaf = Raw((host, tcp))
    deaf.send("< open can0 >< rawmode >")  # opened, and never reads a reply
    t_deaf = time.monotonic()
    mute = Raw((host, tcp))  # reads its greeting, never opens a bus
    assert mute.read() == sc.HI
    buses = [reader]
    try:
        buses.append(python_can())
        wait_until(lambda: len(server.clients) == 4)
        with pytest.raises(can.CanError, match="too many clients"):  # nobody is useless yet: refused
            python_can()
        monkeypatch.setattr(socketcand_server, "OPEN_GRACE", 0.0)  # mute has had its time to open a bus
        buses.append(python_can())  # takes mute's place
        assert mute.read() == socketcand_server.ERROR_EVICTED
        with pytest.raises(ConnectionError):
            mute.read()
        wait_until(lambda: time.monotonic() - t_deaf > 0.2)  # deaf has left its replies unread long enough
        buses.append(python_can())  # takes deaf's place, not the older reader's
        data = deaf.sock.recv(65536)
        while chunk := deaf.sock.recv(65536):
            data += chunk
        assert data.endswith(socketcand_server.ERROR_EVICTED.encode())  # after the replies it never read
        assert len(server.clients) == 4 and server.listener.evicted == 2
        with pytest.raises(can.CanError, match="too many clients"):  # every kept client reads: refused
            python_can()
        assert server.listener.refused == 2
        reader.send(can.Message(arbitration_id=0x123, data=[1], is_extended_id=False))
        wait_until(lambda: data_frame(0x123, b"\x01") in dev.frames)  # the reader kept its place and works
        got = buses[-1].recv(timeout=5)  # and the last newcomer is served
        assert got is not None and got.arbitration_id == 0x123
    finally:
        for bus in buses:
            bus.shutdown()
        mute.close()
        deaf.close()


HUGE = "9" * 400


@pytest.mark.parametrize("command, what", [
    (f"< add {HUGE} 0 123 1 aa >", "interval"),
    (f"< add 0 {HUGE} 123 1 aa >", "interval"),
    ("< add 0 1000000 123 1 aa >", "interval"),  # the kernel's bound: fewer than a million microseconds
    (f"< add 0 1 {HUGE} 1 aa >", "identifier"),
    (f"< subscribe {HUGE} 0 123 >", "interval"),
    (f"< subscribe 0 0 {HUGE} >", "identifier"),
    (f"< filter 0 {HUGE} 123 1 ff >", "interval"),
    (f"< muxfilter {HUGE} 0 123 >", "interval"),
    (f"< delete {HUGE} >", "identifier"),
    (f"< send {HUGE} 1 aa >", "identifier"),
    ("< send 800 0 >", "identifier"),  # 3 digits: a standard identifier, at most 7FF
])
def test_numbers_out_of_range_are_answered_with_an_error_and_counted(can_bus, caplog, command, what):
    *_, port, _dev, _dport, address = can_bus()
    raw = Raw(address)
    raw.read()
    raw.send("< open can0 >")
    assert raw.read() == sc.OK
    raw.send(command)
    assert raw.read() == f"< error {what} out of range >"
    raw.send("< echo >")
    assert raw.read() == sc.ECHO  # still served
    assert port.socketcand.out_of_range == 1
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]  # no traceback, no log
    raw.close()


def test_a_statistics_interval_out_of_range_is_answered_with_an_error(can_bus):
    *_, address = can_bus()
    raw = Raw(address)
    raw.read()
    raw.send(f"< open can0 >< controlmode >< statistics {HUGE} >< statistics -5 >< statistics 4294967295 >")
    assert [raw.read() for _ in range(4)] == [sc.OK, sc.OK, "< error statistics interval out of range >",
                                              "< error statistics interval out of range >"]
    raw.send("< echo >")
    assert raw.read() == sc.ECHO  # 2^32 - 1 ms is the daemon's largest: taken, nothing due for 49 days
    raw.close()


def test_a_job_of_one_microsecond_fills_the_bus_but_never_deafens_it(can_bus):
    medium, port, dev, _dport, address = can_bus(paced=True)
    server = port.socketcand
    raw = Raw(address)
    raw.read()
    raw.send("< open can0 >< add 0 1 123 8 1 2 3 4 5 6 7 8 >")
    assert raw.read() == sc.OK
    wait_until(lambda: len(dev.frames) >= 200)
    t0, n0 = time.monotonic(), len(dev.frames)
    time.sleep(0.2)
    rate = (len(dev.frames) - n0) / (time.monotonic() - t0)
    frame_time = cf.frame_bits(data_frame(0x123, bytes(range(1, 9)))) / 500_000
    assert rate <= 1.1 / frame_time  # as fast as the bus carries it (about 4 400 frames/s), never faster
    # New clients are greeted at once while the job runs (a loop always behind its deadlines went deaf)
    other = Raw(address)
    assert other.read(timeout=1) == sc.HI
    raw.close()
    wait_until(lambda: len(server.clients) == 1)  # the job's client left: its job goes with it
    time.sleep(0.05)
    n = len(dev.frames)
    time.sleep(0.1)
    assert len(dev.frames) == n
    other.close()


def test_jobs_and_subscriptions_per_client_are_bounded(can_bus, monkeypatch):
    monkeypatch.setattr(socketcand_server, "MAX_BCM_ENTRIES", 2)
    *_, port, dev, _dport, address = can_bus()
    raw = Raw(address)
    raw.read()
    raw.send("< open can0 >< add 1 0 101 0 >< add 1 0 102 0 >< add 1 0 101 1 aa >< add 1 0 103 0 >")
    assert raw.read() == sc.OK
    assert raw.read() == "< error too many jobs >"  # 101 again is an update of its job, 103 one too many
    raw.send("< subscribe 0 0 201 >< subscribe 0 0 202 >< filter 0 0 203 1 ff >")
    assert raw.read() == "< error too many subscriptions >"
    assert port.socketcand.too_many == 2
    raw.close()


def test_a_client_that_reads_nothing_is_bounded_then_disconnected(can_bus, monkeypatch):
    monkeypatch.setattr(socketcand_server, "MAX_PENDING", 16 << 10)
    monkeypatch.setattr(socketcand_server, "STALL_TIMEOUT", 0.5)
    _m, port, _dev, dport, address = can_bus(rawmode_delay_ms=0)
    server = port.socketcand
    sleeper = socket.socket()
    sleeper.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sleeper.connect(address)
    sleeper.sendall(b"< open can0 >< rawmode >")
    reader = Raw(address)
    reader.read()
    reader.send("< open can0 >< rawmode >")
    assert reader.read() == sc.OK and reader.read() == sc.OK
    wait_until(lambda: all(c.mode == "raw" for c in server.clients) and len(server.clients) == 2)
    got = sent = 0
    deadline = time.monotonic() + 20
    while not server.stalled:  # the kernel holds ~100 kB for the sleeper, then its own 16 KiB fill up
        assert time.monotonic() < deadline
        for _ in range(100):
            dport.send(data_frame(0x100, (sent % 65536).to_bytes(2, "big")))
            sent += 1
        while reader.pending or got < sent - 200:  # the reader keeps up
            reader.read()
            got += 1
        assert server.queued <= 2 * (16 << 10) + 4096
    assert server.frames_dropped > 0  # the sleeper's share, dropped and counted, before it was disconnected
    assert len(server.clients) == 1
    while got < sent:  # the reader takes what it was behind by (up to 300 frames on a loaded machine) ...
        reader.read()
        got += 1
    wait_until(lambda: server.queued == 0)  # ... and nothing is left queued: the sleeper's share went with it
    reader.send("< echo >")
    while reader.read() != sc.ECHO:
        pass
    reader.close()
    sleeper.close()
