"""The emulated RPLIDAR A1 byte by byte (pyserial on the bench's pty): replies, motor and DTR, faults, pacing."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
import serial

from hilbench.protocols import rplidar as rp
from hilbench.pytest_plugin import wait_until
from tests.fakes.scanners.conftest import fraction_within

H = bytes.fromhex


@pytest.fixture
def a1(scanners):
    port = serial.Serial(scanners.endpoint("lidar").path, 115200, timeout=1)
    yield scanners, scanners.device("lidar"), port
    port.close()


def _read(port, n: int, timeout: float = 2.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        out += port.read(n - len(out))
    return out


def _motor(bench, dtr: bool) -> None:
    """What `hilbench run`'s shim does when the client sets DTR: the pty's PortState changes."""
    bench.endpoint("lidar").port.port_state.host_sets(dtr=dtr)


def test_silent_on_open_and_single_responses(a1):
    _bench, _dev, port = a1
    assert port.in_waiting == 0
    port.write(rp.request(rp.Cmd.GET_INFO))
    assert _read(port, 27) == H("A5 5A 14 00 00 00 04 18 1D 01 07 D8 E0 ED F9 C7 E2 9B D1 A7 E3 9E F2 48 33 43 1B")
    port.write(rp.request(rp.Cmd.GET_HEALTH) + rp.request(rp.Cmd.GET_SAMPLERATE))
    assert _read(port, 21) == H("A5 5A 03 00 00 00 06 00 00 00 A5 5A 04 00 00 00 15 FC 01 FE 00")


def test_lidar_conf_answers_every_type(a1):
    _bench, _dev, port = a1
    # pyrplidar's 6-byte form and the SDK's 38-byte form (32 reserved bytes before the mode id).
    port.write(rp.request(rp.Cmd.GET_LIDAR_CONF, struct.pack("<IH", 0x7F, 1)))
    name = _read(port, 7 + 4 + 8)
    assert name[:7] == rp.descriptor(12, 0, 0x20) and name[7:] == struct.pack("<I", 0x7F) + b"Express\0"
    port.write(rp.request(rp.Cmd.GET_LIDAR_CONF, struct.pack("<I", 0x71) + bytes(32) + struct.pack("<H", 0)))
    assert _read(port, 15)[7:] == struct.pack("<II", 0x71, 508 * 256)
    port.write(rp.request(rp.Cmd.GET_LIDAR_CONF, struct.pack("<I", 0x01)))
    assert _read(port, 15)[7:] == struct.pack("<IHH", 0x01, 330, 660)
    port.write(rp.request(rp.Cmd.GET_LIDAR_CONF, struct.pack("<I", 0x55)))  # unknown: still an answer
    assert _read(port, 15)[:7] == rp.descriptor(8, 0, 0x20)


def test_bad_checksum_and_unknown_commands_get_no_answer(a1):
    _bench, dev, port = a1
    bad = bytearray(rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)))
    bad[-1] ^= 0xFF
    port.write(bytes(bad) + rp.request(0x33) + rp.request(rp.Cmd.GET_HEALTH))
    assert _read(port, 10) == rp.descriptor(3, 0, 6) + b"\0\0\0"  # only the health request was answered
    assert dev.decoder.bad_checksum == 1 and dev.counters["unknown_command"] == 1


def test_motor_follows_dtr(a1):
    bench, dev, port = a1
    assert dev.config.motor == "dtr" and not dev.motor_commanded()
    port.write(rp.request(rp.Cmd.SCAN))
    assert _read(port, 7) == H("A5 5A 05 00 00 40 81")
    port.timeout = 0.3
    assert port.read(5) == b""  # descriptor, then silence: the motor stands while DTR is asserted
    _motor(bench, dtr=False)  # the client clears DTR: the dev kit runs the motor
    port.timeout = 2.0
    t0 = time.monotonic()
    first = _read(port, 5)
    spun = time.monotonic() - t0
    assert rp.parse_node(first).start  # a revolution starts once the motor is stable
    assert spun >= dev.config.spin_up * 0.8
    _motor(bench, dtr=True)
    wait_until(lambda: not dev.motor_commanded())
    port.write(rp.request(rp.Cmd.STOP))
    wait_until(lambda: dev.state == "idle")


def test_force_scan_starts_without_the_motor(a1):
    _bench, dev, port = a1
    port.write(rp.request(rp.Cmd.FORCE_SCAN))  # starts at once, rotation not checked
    data = _read(port, 7 + 50)
    assert data[:7] == H("A5 5A 05 00 00 40 81") and len(data) == 57
    nodes = [rp.parse_node(data[k:k + 5]) for k in range(7, 57, 5)]
    assert len({n.angle for n in nodes}) == 1  # the head stands: every sample at one angle
    port.write(rp.request(rp.Cmd.STOP))
    assert not dev.motor_running


def test_profile_motor_always(hilbench_bench, tmp_path):
    from hilbench.bench.profile import resolve

    text = resolve("scanners").read_text().replace('motor = "dtr"', 'motor = "always"')
    path = tmp_path / "always.toml"
    path.write_text(text)
    bench = hilbench_bench(path)
    dev = bench.device("lidar")
    assert dev.motor_commanded() and dev.motor_running  # DTR asserted, and the motor turns anyway
    with serial.Serial(bench.endpoint("lidar").path, 115200, timeout=2) as port:
        port.write(rp.request(rp.Cmd.SCAN))
        data = _read(port, 12)
        assert data[:7] == rp.descriptor(5, 1, 0x81) and rp.parse_node(data[7:]).start
        port.write(rp.request(rp.Cmd.STOP))


def test_reset_banner_protection_stop(a1):
    _bench, dev, port = a1
    dev.port.call_at(None, lambda: dev.set_health(2, 0x0101))
    wait_until(lambda: dev.state == "protection")
    port.write(rp.request(rp.Cmd.GET_HEALTH))
    assert _read(port, 10)[7:] == H("02 01 01")
    port.write(rp.request(rp.Cmd.SCAN))  # ignored in protection stop: no descriptor
    port.write(rp.request(rp.Cmd.GET_HEALTH))
    assert _read(port, 10)[7:] == H("02 01 01")
    port.write(rp.request(rp.Cmd.RESET))
    banner = port.read_until(b"Model: 18\r\n")
    assert banner == b"RP LIDAR System.\r\nFirmware Ver 1.29 - rtm, HW Ver 7\r\nModel: 18\r\n"
    wait_until(lambda: time.monotonic() > dev.busy_until)
    port.write(rp.request(rp.Cmd.GET_HEALTH))
    assert _read(port, 10)[7:] == H("00 00 00")  # the fault was not sticky: RESET cleared it


def test_wrong_baud_is_garbage(a1):
    _bench, dev, port = a1
    port.baudrate = 57600
    port.write(rp.request(rp.Cmd.GET_INFO))
    wait_until(lambda: dev.baud_mismatch >= 2)
    port.baudrate = 115200
    port.write(rp.request(rp.Cmd.GET_HEALTH))
    assert _read(port, 10)[:7] == rp.descriptor(3, 0, 6)


def test_paced_nodes_and_own_decoder_agree_with_truth(scanners):
    dev = scanners.device("lidar")
    dev.config.motor = "always"
    dev.motor_since = 0.0
    dec = rp.ResponseDecoder()
    asm = rp.ScanAssembler(min_points=100)
    revs, chunks = [], []
    with serial.Serial(scanners.endpoint("lidar").path, 115200, timeout=0.05) as port:
        port.write(rp.request(rp.Cmd.SCAN))
        deadline = time.monotonic() + 5
        while len(revs) < 4 and time.monotonic() < deadline:
            called = time.monotonic()
            data = port.read(4096)
            if data:
                chunks.append((time.monotonic(), len(data), called))
            for item in dec.feed(data):
                if isinstance(item, rp.Node):
                    revs += asm.add_node(item)
        port.write(rp.request(rp.Cmd.STOP))
    assert len(revs) >= 3 and dec.dropped == 0
    t = np.array([c[0] for c in chunks])
    n = np.array([c[1] for c in chunks])
    span = t[-1] - t[0]
    rate = n[1:].sum() / span
    assert rate < 11520 * 1.05  # never faster than 115200 baud allows
    assert 0.85 * 9843 < rate < 1.15 * 9843  # 5 bytes every 508 us
    # per-sample pacing, no revolution-sized bursts (1 800 B at once): a read brings no more than the line
    # could carry since the one before (a reader the machine held up reads more, and as much later), except
    # where the bench itself was held up and caught up at once (rare; a fake sending whole revolutions
    # would break the rule once per revolution), and never ahead of the line since the first read
    over = n[1:] > 11520 * np.diff(t) * 1.1 + 60
    assert over.sum() < len(revs) - 1, list(zip(np.diff(t).round(4), n[1:], strict=True))
    # Since the first read's call (its return may have been noted late, the reader held up after it): every
    # byte read after it left the line after that instant.
    assert (np.cumsum(n[1:]) <= 11520 * (t[1:] - chunks[0][2]) * 1.05 + 60).all()
    rev = revs[-1]
    angles = np.array([p[0] for p in rev])
    dist = np.array([p[1] for p in rev]) / 1000.0
    assert np.all(dist > 0)  # every beam meets a wall of the room within 12 m
    assert fraction_within(-np.radians(angles), dist, sigma0=0.0005, sigma_k=0.005) > 0.97
    # The emulator's truth for that revolution: the decoded distances are its measurements, quantised.
    truths = [tr for tr in dev.truth if len(tr.angles) == len(rev)]
    match = [tr for tr in truths if np.allclose(np.round(tr.angles * 64) % 23040 / 64, angles)]
    assert match, "decoded revolution not found in the emulator's truth"
    assert np.allclose(match[0].measured * 1000.0, np.array([p[1] for p in rev]), atol=0.13)


def test_stalled_motor_gives_descriptor_then_silence(a1):
    bench, dev, port = a1
    dev.faults.stall = True
    _motor(bench, dtr=False)  # DTR says run, the motor is stuck
    port.write(rp.request(rp.Cmd.SCAN))
    assert _read(port, 7) == rp.descriptor(5, 1, 0x81)
    port.timeout = dev.config.spin_up + 0.3
    assert port.read(5) == b""
    assert dev.status()["motor"] == {"policy": "dtr", "dtr": False, "commanded": False, "running": False,
                                     "stall": True}
    port.write(rp.request(rp.Cmd.STOP))


def test_fault_knobs_reach_the_decoders(scanners):
    from hilbench.monitor.scanners.rplidar_tracker import RplidarTracker

    dev = scanners.device("lidar")
    dev.config.motor = "always"
    dev.motor_since = 0.0
    dev.faults.drop_byte_rate = 0.05
    dev.faults.bad_flags_rate = 0.05
    tr = RplidarTracker()
    with serial.Serial(scanners.endpoint("lidar").path, 115200, timeout=0.05) as port:
        port.write(rp.request(rp.Cmd.SCAN))
        deadline = time.monotonic() + 5
        while tr.scans < 3 and time.monotonic() < deadline:
            tr.feed(time.monotonic(), "device", port.read(4096))
        port.write(rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)))
        dev.faults.corrupt_rate = 0.2
        deadline = time.monotonic() + 5
        while tr.checksum_failures == 0 and time.monotonic() < deadline:
            tr.feed(time.monotonic(), "device", port.read(4096))
        port.write(rp.request(rp.Cmd.STOP))
    assert tr.scans >= 3  # the decoder resynchronised after every damaged node
    assert tr.dropped_bytes > 0 and dev.counters["dropped_bytes"] > 0 and dev.counters["bad_flag_nodes"] > 0
    assert tr.checksum_failures > 0 and dev.counters["corrupted_capsules"] > 0



def test_a_request_flood_fills_the_units_transmit_ring_and_the_rest_is_dropped(scanners):
    """Each 2-byte GET_INFO costs 27 bytes of reply at 115200 baud: replies that find the unit's transmit ring
    (TX_QUEUE bytes) full are dropped whole and counted, instead of queueing without end (52 MB in 3 s before);
    the unit answers again as soon as the ring has room."""
    import os
    import termios
    import tty

    from hilbench.fakes.scanners.uart import TX_QUEUE

    dev = scanners.device("lidar")
    fd = os.open(scanners.endpoint("lidar").path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        attrs = termios.tcgetattr(fd)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(fd, termios.TCSANOW, attrs)
        requests, written, most = rp.request(rp.Cmd.GET_INFO) * 2048, 0, 0.0
        end = time.monotonic() + 0.5
        while time.monotonic() < end or written % 2:  # (whole requests: a write may take an odd count)
            try:
                written += os.write(fd, requests[written % 2:])
            except BlockingIOError:
                time.sleep(0.001)
            most = max(most, dev.tx.busy_until - time.monotonic())

        # Every request is answered or its reply dropped (counted), and the ring empties.
        wait_until(lambda: dev.tx.bytes_sent // 27 + dev.counters["tx_dropped"] >= written // 2
                   and dev.tx.busy_until < time.monotonic(), timeout=10)
        dropped = dev.counters["tx_dropped"]
        assert dev.tx.bytes_sent // 27 + dropped == written // 2, dict(dev.counters)
        assert dropped > 0 and dev.counters["tx_dropped_bytes"] == 27 * dropped
        assert most <= TX_QUEUE * 10 / 115200 + 0.05, most  # the ring's 0.36 s, not minutes of replies
        termios.tcflush(fd, termios.TCIFLUSH)  # (the replies this client never read)
        os.write(fd, rp.request(rp.Cmd.GET_HEALTH))
        got = b""
        deadline = time.monotonic() + 2
        while len(got) < 10 and time.monotonic() < deadline:
            try:
                got += os.read(fd, 10 - len(got))
            except BlockingIOError:
                time.sleep(0.005)
        assert got == H("A5 5A 03 00 00 00 06 00 00 00")
    finally:
        os.close(fd)
