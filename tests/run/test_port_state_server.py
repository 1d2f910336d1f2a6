"""The bench's port-state server, driven by pyserial in the test's own process (the pytest plugin's patch) and
by raw requests: modem lines, BREAK, flushes, drains and settings reach the devices in order."""

from __future__ import annotations

import errno
import os
import socket
import termios
import time

import pytest
import serial

from hilbench.bench import port_state_server
from hilbench.bench.port_state_server import TIOCM
from hilbench.pytest_plugin import wait_until
from hilbench.run import pyserial_shim
from tests.run.port_event_recorder import (
    BreakCondition,
    ModemSignals,
    OutputFlushed,
    PortEventRecorder,
    SerialSettings,
)

PAYLOAD = bytes(range(0x20, 0x7F)) * 40  # 3 800 bytes, nothing a Dynamixel servo would take for a packet


def ask(server, line: str) -> str:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(5)
        s.connect(server.path)
        s.sendall(line.encode() + b"\n")
        return s.recv(256).decode()


@pytest.fixture
def arm(hilbench_bench):
    bench = hilbench_bench("arm")
    return bench, PortEventRecorder().attach(bench.endpoint())


def test_pyserial_modem_lines_reach_the_device_and_read_back(arm):
    bench, rec = arm
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        assert not (ser.cts or ser.dsr or ser.ri or ser.cd)  # nothing driven yet
        ser.write(b"before")
        ser.dtr = False
        ser.rts = False
        # The device answered the cleared lines in its on_port_event, before the ioctl returned.
        assert (ser.cts, ser.dsr, ser.ri, ser.cd) == (True, True, False, True)
        ser.dtr = True
        assert rec.sequence(settings=False) == [b"before", ModemSignals(False, True), ModemSignals(False, False),
                                                ModemSignals(True, False)]
        snap = bench.endpoint().port.port_state.snapshot()
        assert (snap["dtr"], snap["rts"], snap["cts"]) == (True, False, True)


def test_reset_output_buffer_delivers_instead_of_discarding(arm):
    bench, rec = arm
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        for _ in range(5):
            ser.write(PAYLOAD)
            ser.reset_output_buffer()  # pypot does this before every packet
    # Every byte was taken before each flush returned; OutputFlushed follows its bytes.
    assert rec.received() == PAYLOAD * 5
    seq = rec.sequence(settings=False)
    assert seq == [PAYLOAD, OutputFlushed()] * 5


def test_flush_discards_on_a_plain_pty(hilbench_bench):
    """What the port-state server fixes: without it (port_state=False), tcflush(TCOFLUSH) drops unread bytes."""
    bench = hilbench_bench("arm", port_state=False)
    rec = PortEventRecorder().attach(bench.endpoint())
    medium = bench.endpoint().medium
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        # the line's thread paused: nothing reads the pty, so whether a flush finds the bytes unread is no race
        medium.stop()
        try:
            for _ in range(20):
                ser.write(PAYLOAD)
                ser.reset_output_buffer()
            ser.write(b"end")
        finally:
            medium.start()
        wait_until(lambda: rec.received().endswith(b"end"))
    # the flushes discarded everything but what the master's line discipline had already taken in (its read
    # buffer holds 4095 bytes): of 76 000 bytes written, at most that much arrives before "end"
    assert len(rec.received()) <= 4095 + 3
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser, pytest.raises(OSError) as info:
        ser.dtr = False
    assert info.value.errno == errno.ENOTTY


@pytest.mark.parametrize("paced", [False, True])
def test_flush_drain_waits_until_the_bytes_are_delivered(hilbench_bench, paced):
    bench = hilbench_bench("arm", paced=paced)
    rec = PortEventRecorder().attach(bench.endpoint())
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        t0 = time.monotonic()
        ser.write(PAYLOAD)
        ser.flush()  # tcdrain: on an adapter it returns once the bytes are on the wire
        elapsed = time.monotonic() - t0
        assert rec.received() == PAYLOAD  # no waiting: delivered before flush() returned
    if paced:
        assert elapsed >= len(PAYLOAD) * 10 / 1_000_000  # 38 ms of wire time at 1 Mbaud


def test_a_write_faster_than_the_wire_waits_and_a_drain_waits_for_all_of_it(hilbench_bench):
    """A paced line holds a writer back as an adapter does (write() returns once the bytes beyond its FIFO and
    the pty's buffer could be taken); tcdrain then waits until every byte is delivered, however far ahead."""
    bench = hilbench_bench("arm", paced=True)
    rec = PortEventRecorder().attach(bench.endpoint())
    data = PAYLOAD * 17  # 64 600 bytes: 0.65 s at 1 Mbaud
    wire = len(data) * 10 / 1_000_000
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        t0 = time.monotonic()
        ser.write(data)
        wrote = time.monotonic() - t0
        ser.flush()
        drained = time.monotonic() - t0
        assert rec.received() == data  # every byte delivered before flush() returned
    assert wrote >= 0.5 * wire  # held back: not read at once (the pty and the FIFO hold ~22 KiB of it)
    assert drained >= wire
    assert bench.endpoint().medium.stats.held_back > 0


def test_break_events(arm):
    bench, rec = arm
    with serial.Serial(bench.endpoint().path, 1_000_000) as ser:
        t0 = time.monotonic()
        ser.send_break(0.25)  # pyserial: tcsendbreak(fd, 1) -> glibc: one tenth of a second
        assert time.monotonic() - t0 >= 0.1
        ser.break_condition = True
        assert bench.endpoint().port.port_state.break_active
        ser.break_condition = False
    assert rec.sequence(settings=False) == [BreakCondition(True, 0.1), BreakCondition(True), BreakCondition(False)]


def test_baud_rate_and_framing_become_settings_events(arm):
    bench, rec = arm
    with serial.Serial(bench.endpoint().path, 57_600) as ser:
        ser.parity = serial.PARITY_EVEN
        ser.bytesize = serial.SEVENBITS
        ser.stopbits = serial.STOPBITS_TWO
        ser.baudrate = 4_500_000  # no B constant: BOTHER through TCSETS2
        ser.write(b"x")
        wait_until(lambda: rec.received() == b"x")
    settings = [e for e in rec.events() if isinstance(e, SerialSettings)]
    assert settings == [SerialSettings(57_600), SerialSettings(57_600, 8, "E", 1.0), SerialSettings(57_600, 7, "E", 1.0),
                        SerialSettings(57_600, 7, "E", 2.0), SerialSettings(4_500_000, 7, "E", 2.0)]
    assert bench.endpoint().port.port_state.settings == SerialSettings(4_500_000, 7, "E", 2.0)


def test_settings_are_seen_without_the_shim_too(hilbench_bench):
    """A client nobody intercepts: the bench reads the rate from termios on every read (framing it cannot
    see: a pty forces 8 data bits, no parity)."""
    bench = hilbench_bench("arm", port_state=False)
    rec = PortEventRecorder().attach(bench.endpoint())
    with serial.Serial(bench.endpoint().path, 115_200) as ser:
        ser.write(b"a")
        wait_until(lambda: rec.received() == b"a")
    assert rec.sequence() == [SerialSettings(115_200), b"a"]  # the settings before the bytes they carry


def test_requests_and_errors_on_the_socket(arm):
    bench, _ = arm
    server = bench.services["port_state"]
    rdev = bench.endpoint().port.rdev
    assert server.describe()["ports"]["arm"] == {"rdev": rdev, "path": bench.endpoint().path}
    assert oct(os.stat(os.path.dirname(server.path)).st_mode & 0o777) == "0o700"
    assert ask(server, "0 ping") == "ok 1\n"
    assert ask(server, f"{rdev} mget") == f"ok {TIOCM['dtr'] | TIOCM['rts']}\n"
    assert ask(server, f"{rdev} mbic {termios.TIOCM_RTS}") == f"ok {TIOCM['dtr']}\n"
    answer = TIOCM["cts"] | TIOCM["dsr"] | TIOCM["cd"]  # the recorder answers cleared lines
    assert ask(server, f"{rdev} mset 0") == f"ok {answer}\n"
    assert ask(server, f"{rdev} framing") == "ok -1\n"  # nobody set any
    assert ask(server, "12 mget").startswith("err no pty of this bench has device number 12")
    assert ask(server, f"{rdev} jump").startswith("err unknown request 'jump'")
    assert ask(server, f"{rdev} break 99").startswith("err break duration 99.0 s is outside")
    assert ask(server, f"{rdev} mset lots").startswith("err expected an integer")
    assert ask(server, f"{rdev} sync {'9' * 200}") == "err integer out of range (32 bits)\n"
    assert ask(server, "nonsense").startswith("err expected: RDEV VERB")
    assert ask(server, "1" * 300).startswith("err request too long")
    # Nothing above stopped the server.
    assert ask(server, "0 ping") == "ok 1\n"


def test_in_process_patch_leaves_other_ptys_alone(arm):
    master, slave = os.openpty()
    try:
        with serial.Serial(os.ttyname(slave)) as ser, pytest.raises(OSError) as info:
            ser.dtr = False
        assert info.value.errno == errno.ENOTTY
    finally:
        os.close(master)
        os.close(slave)


def test_patch_is_removed_when_the_bench_stops(hilbench_bench):
    import serial.serialposix as posix

    bench = hilbench_bench("arm")
    assert isinstance(posix.termios, pyserial_shim.TermiosProxy)
    rdev = bench.endpoint().port.rdev
    from hilbench.pytest_plugin import stop_lines_in_process

    stop_lines_in_process([rdev])
    assert rdev not in pyserial_shim.PORTS
    assert posix.termios is termios


def test_connections_beyond_the_limit_are_refused_and_idle_ones_closed(hilbench_bench, monkeypatch):
    monkeypatch.setattr(port_state_server, "MAX_CLIENTS", 2)
    monkeypatch.setattr(port_state_server, "IDLE_TIMEOUT", 0.5)
    monkeypatch.setattr(port_state_server, "EVICT_IDLE", 60.0)  # (none waited long enough to be closed for the newcomer)
    server = hilbench_bench("arm").services["port_state"]
    held = []
    for _ in range(2):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(5)
        s.connect(server.path)
        s.sendall(b"0 ping\n")
        assert s.recv(256) == b"ok 1\n"
        held.append(s)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as extra:
        extra.settimeout(5)
        extra.connect(server.path)
        assert extra.recv(256) == b"err too many clients (2 clients at most)\n"  # what the shim fails open on
        assert extra.recv(256) == b""
    for s in held:  # idle for IDLE_TIMEOUT: closed (clients connect anew for their next request)
        assert s.recv(256) == b""
        s.close()
    assert ask(server, "0 ping") == "ok 1\n"


def test_a_newcomer_takes_the_place_of_the_connection_idle_longest(hilbench_bench, monkeypatch):
    monkeypatch.setattr(port_state_server, "MAX_CLIENTS", 2)
    monkeypatch.setattr(port_state_server, "EVICT_IDLE", 0.2)
    server = hilbench_bench("arm").services["port_state"]
    held = []
    for _ in range(2):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(5)
        s.connect(server.path)
        s.sendall(b"0 ping\n")
        assert s.recv(256) == b"ok 1\n"
        held.append(s)
        t_last = time.monotonic()
    wait_until(lambda: time.monotonic() - t_last > 0.2)  # both have waited long enough for a next request
    assert ask(server, "0 ping") == "ok 1\n"  # served: the one idle longest made room
    assert held[0].recv(256) == b""  # closed as an idle one is (a client connects anew for its next request)
    held[1].sendall(b"0 ping\n")
    assert held[1].recv(256) == b"ok 1\n"  # the other keeps its connection
    for s in held:
        s.close()
