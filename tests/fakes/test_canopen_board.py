"""The rover board as a CANopen node, driven by the unmodified canopen package (in this process over python-can's
virtual interface, and in another process over socketcand)."""

from __future__ import annotations

import itertools
import json
import subprocess
import sys
import time

import canopen
import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen as co
from hilbench.pytest_plugin import wait_until
from tests.conftest import REPO

canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0


def profile(**device) -> dict:
    return {
        "schema": 1,
        "endpoints": {"can": {"type": "can", "protocol": "can", "bitrate": 500_000, "paced": True,
                              "slcan": False}},
        "devices": [{"model": "stm32f767-rover-canopen", "name": "rover", "node_id": 2, "heartbeat_ms": 100,
                     **device}],
    }


@pytest.fixture
def rover(tmp_path):
    """A bench with the board, a canopen Network on it (virtual), the RemoteNode with the board's EDS."""
    benches, nets = [], []

    def start(**device):
        bench = Bench(parse_profile(profile(**device), "test.toml")).start()
        benches.append(bench)
        eds = tmp_path / "rover.eds"
        eds.write_text(bc.eds(bc.BoardCanConfig()), newline="")
        net = canopen.Network(bench.endpoint("can").port.open_bus())
        net.connect()
        nets.append(net)
        node = net.add_node(2, str(eds))
        node.sdo.RESPONSE_TIMEOUT = 1.0
        wait_until(lambda: bench.family("canopen").node(2).state != co.BOOTUP)  # NMT commands count once the node has booted
        return bench, net, node

    yield start
    for net in nets:
        net.disconnect()
    for bench in benches:
        bench.stop()


def test_boot_heartbeat_and_nmt(rover):
    bench, net, node = rover()
    node.nmt.wait_for_heartbeat(2)
    assert node.nmt.state == "PRE-OPERATIONAL"
    node.nmt.state = "OPERATIONAL"
    wait_until(lambda: node.nmt.wait_for_heartbeat(1) == "OPERATIONAL")
    node.nmt.state = "STOPPED"
    wait_until(lambda: node.nmt.wait_for_heartbeat(1) == "STOPPED")
    with pytest.raises(canopen.SdoCommunicationError):  # no SDO in STOPPED
        node.sdo.RESPONSE_TIMEOUT = 0.3
        node.sdo.upload(0x1000, 0)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    node.nmt.state = "PRE-OPERATIONAL"
    wait_until(lambda: node.nmt.wait_for_heartbeat(1) == "PRE-OPERATIONAL")


def test_identity_strings_and_aborts(rover):
    bench, net, node = rover(identity={"serial": 0x1234})
    node.nmt.wait_for_heartbeat(2)
    assert node.sdo[0x1018][1].raw == bc.BoardCanConfig().vendor_id
    assert node.sdo[0x1018][4].raw == 0x1234
    assert node.sdo[0x1000].raw == 0
    assert node.sdo[0x1008].raw == bc.BoardCanConfig().device_name  # segmented upload
    with pytest.raises(canopen.SdoAbortedError) as exc:
        node.sdo.upload(0x5555, 0)
    assert exc.value.code == co.ABORT_NO_OBJECT
    with pytest.raises(canopen.SdoAbortedError) as exc:
        node.sdo.upload(0x1018, 9)
    assert exc.value.code == co.ABORT_NO_SUBINDEX
    with pytest.raises(canopen.SdoAbortedError) as exc:
        node.sdo.download(0x1018, 1, b"\x01\x00\x00\x00")
    assert exc.value.code == co.ABORT_READ_ONLY
    with pytest.raises(canopen.SdoAbortedError) as exc:
        node.sdo.download(0x1017, 0, b"\x01\x00\x00\x00")
    assert exc.value.code == co.ABORT_TOO_LONG
    with pytest.raises(canopen.SdoAbortedError) as exc:
        node.sdo.open(0x1008, 0, "rb", block_transfer=True).read()
    assert exc.value.code == co.ABORT_COMMAND  # block transfers are refused
    node.sdo.download(0x1017, 0, (250).to_bytes(2, "little"), force_segment=True)  # segmented download
    assert node.sdo[0x1017].raw == 250


def test_heartbeat_follows_a_write_at_once(rover):
    bench, net, node = rover(heartbeat_ms=1000)
    node.nmt.wait_for_heartbeat(3)
    node.sdo[0x1017].raw = 50
    written = time.monotonic()
    node.nmt.wait_for_heartbeat(0.5)  # the next one comes within the new period, not the old second
    assert time.monotonic() - written < 0.5
    stamps = []
    for _ in range(6):
        node.nmt.wait_for_heartbeat(0.5)
        stamps.append(time.monotonic())
    gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    assert sum(gaps) / len(gaps) == pytest.approx(0.05, abs=0.015)
    node.sdo[0x1017].raw = 0  # off
    time.sleep(0.2)
    with pytest.raises(canopen.nmt.NmtError):
        node.nmt.wait_for_heartbeat(0.3)


def test_setpoints_move_the_odometry_as_commanded(rover):
    bench, net, node = rover()
    node.nmt.state = "OPERATIONAL"
    node.tpdo.read()
    poses = []
    node.tpdo[2].add_callback(lambda m: poses.append({v.name.split(".")[-1]: v.phys for v in m}))
    board = bench.family("canopen").node(2)
    start = time.monotonic()
    counter = 0
    while time.monotonic() - start < 1.0:  # 0.25 m/s forward, 0.4 rad/s yaw, repeated every 50 ms
        net.send_message(0x202, bc.build_setpoint(0.25, 0.0, 0.4, counter))
        counter += 1
        time.sleep(0.05)
    wait_until(lambda: board.mode == bc.MODE_TIMEOUT, timeout=2)  # the stream stopped: the watchdog stops it
    x, y, theta = board.pose()
    stats = board.stats
    assert stats["accepted"] == counter and stats["timeouts"] == 1
    # ~1.1 s of yaw at up to 0.4 rad/s (ramped at 5.3 rad/s^2), ~0.25 m travelled on an arc
    assert 0.30 < theta < 0.50
    assert 0.2 < (x * x + y * y) ** 0.5 < 0.32 and y > 0
    # Once the rover stands still (the ramp ran down after the timeout) the odometry PDO says the same.
    wait_until(lambda: len(poses) > 3 and poses[-1] == poses[-2] == poses[-3], timeout=3)
    x, y, theta = board.pose()
    assert poses[-1]["x"] == pytest.approx(x, abs=0.0011) and poses[-1]["theta"] == pytest.approx(theta, abs=2e-4)
    assert any(e.code == co.ERR_RPDO_TIMEOUT for e in node.emcy.log)


def test_rejected_setpoints_and_emcy(rover):
    bench, net, node = rover()
    node.nmt.state = "OPERATIONAL"
    board = bench.family("canopen").node(2)
    good = bc.build_setpoint(0.1, 0, 0, 1)
    net.send_message(0x202, good)
    net.send_message(0x202, good)  # the same counter again: a frozen sender
    net.send_message(0x202, good[:7] + bytes([good[7] ^ 0xFF]))  # bad checksum
    net.send_message(0x202, good[:6])  # short
    net.send_message(0x202, bc.build_setpoint(0.1, 0, 0, 5))  # counter jump: 3 lost
    wait_until(lambda: board.stats["length_errors"] == 1 and board.stats["accepted"] == 2)
    assert node.sdo[0x2012][2].raw == 1 and node.sdo[0x2012][3].raw == 1 and node.sdo[0x2012][4].raw == 3
    emcy = wait_until(lambda: next((e for e in node.emcy.log if e.code == co.ERR_PDO_LENGTH), None))
    assert emcy.register & co.REG_COMMUNICATION
    assert sum(e.code == co.ERR_PROTOCOL for e in node.emcy.log) == 1  # once per burst of bad checksums
    ctl = bench.family_of("rover")
    ctl.control(bench, board, "fault", {"knobs": {"motor_fault": True}})
    emcy = wait_until(lambda: next((e for e in node.emcy.log if e.code == co.ERR_MOTOR_BLOCKED), None))
    assert emcy.register & co.REG_CURRENT and node.sdo[0x1001].raw & co.REG_CURRENT
    assert node.sdo[0x1003][1].raw & 0xFFFF == co.ERR_MOTOR_BLOCKED  # kept in the error history
    ctl.control(bench, board, "fault", {"knobs": {"motor_fault": False}})
    wait_until(lambda: any(e.code == 0 for e in node.emcy.log))  # error reset once nothing is left
    node.sdo[0x1003][0].raw = 0  # clearing the history is allowed
    assert node.sdo[0x1003][0].raw == 0


def test_reset_restores_defaults_and_boots_again(rover):
    bench, net, node = rover()
    node.nmt.wait_for_heartbeat(2)
    node.sdo[0x1017].raw = 300
    node.nmt.state = "OPERATIONAL"
    bootups = []
    net.subscribe(0x702, lambda cid, data, ts: bootups.append(bytes(data)) if data == b"\x00" else None)
    node.nmt.state = "RESET COMMUNICATION"
    wait_until(lambda: bootups)
    node.nmt.wait_for_heartbeat(1)
    assert node.nmt.state == "PRE-OPERATIONAL" and node.sdo[0x1017].raw == 100
    node.nmt.state = "RESET"
    wait_until(lambda: len(bootups) == 2)
    assert bench.family("canopen").node(2).bootups == 3


def test_tpdo_timer_writes_take_effect(rover):
    bench, net, node = rover()
    node.nmt.state = "OPERATIONAL"
    stamps = []
    # the frames' own timestamps (taken as the bench hands them to the bus), not when this thread got them:
    # a loaded machine delays the receiving thread by tens of milliseconds
    net.subscribe(0x182, lambda cid, data, ts: stamps.append(ts))
    wait_until(lambda: len(stamps) > 5)
    before = [b - a for a, b in itertools.pairwise(stamps[-5:])]
    assert sum(before) / len(before) == pytest.approx(0.02, abs=0.01)
    node.sdo[0x1800][5].raw = 100  # encoders from every 20 ms to every 100 ms
    stamps.clear()
    wait_until(lambda: len(stamps) >= 6, timeout=3)
    gaps = [b - a for a, b in itertools.pairwise(stamps[1:])]  # (the first may be a frame sent before the write)
    assert sum(gaps) / len(gaps) == pytest.approx(0.1, abs=0.02)


def test_node_guarding_answers_remote_frames_when_the_heartbeat_is_off(rover):
    import can

    bench, net, node = rover(heartbeat_ms=0)
    time.sleep(0.1)
    answers = []
    net.subscribe(0x702, lambda cid, data, ts: answers.append(bytes(data)))
    for _ in range(2):
        net.bus.send(can.Message(arbitration_id=0x702, is_remote_frame=True, dlc=1, is_extended_id=False))
        time.sleep(0.05)
    wait_until(lambda: len(answers) == 2)
    assert answers == [bytes([0x7F]), bytes([0xFF])]  # state with the toggle bit alternating


def test_canopen_in_another_process_over_socketcand(tmp_path):
    eds = tmp_path / "rover.eds"
    eds.write_text(bc.eds(bc.BoardCanConfig()), newline="")
    toml = tmp_path / "can.toml"  # the bundled profile with a 300 ms heartbeat (a quicker test)
    toml.write_text((REPO / "profiles" / "mecarover-can.toml").read_text().replace("heartbeat_ms = 1000",
                                                                                   "heartbeat_ms = 300"))
    with Bench(str(toml)) as bench:
        s = bench.manifest()["endpoints"][0]["socketcand"]
        proc = subprocess.run([sys.executable, str(REPO / "tests" / "canopen_client.py"), s["host"], str(s["port"]),
                               s["channel"], str(eds)], capture_output=True, text=True, timeout=60, cwd=REPO)
        assert proc.returncode == 0, proc.stderr
        res = json.loads(proc.stdout.strip().splitlines()[-1])
        assert res["first_state"] == "PRE-OPERATIONAL"
        assert res["vendor_id"] == bc.BoardCanConfig().vendor_id and res["device_name"].startswith("hilbench")
        assert res["period_before"] == pytest.approx(0.3, abs=0.05)
        assert res["period_after"] == pytest.approx(0.1, abs=0.03)
        assert res["odometry_x"] > 0.1 and abs(res["odometry_y"]) < 0.01
        assert bench.family("canopen").node(2).heartbeat_ms == 100


def test_bus_off_and_recovery_raise_emcy(rover):
    bench, net, node = rover()
    board = bench.family("canopen").node(2)
    ep = bench.endpoint()
    states = []
    original = board.on_bus_state

    def spy(state, t):
        states.append(state)
        original(state, t)

    board.on_bus_state = spy
    reply = ep.bus_kind.control(bench, ep, "bus", {"knobs": {"bus_off": "rover"}})
    assert reply["bus"]["bitrate"] == 500_000
    wait_until(lambda: "recovered" in states, timeout=2)  # 128 x 11 bits later
    assert states[0] == "bus-off"
    emcy = wait_until(lambda: next((e for e in node.emcy.log if e.code == co.ERR_BUS_OFF_RECOVERED), None))
    assert emcy.register & co.REG_COMMUNICATION
    wait_until(lambda: any(e.code == 0 for e in node.emcy.log))  # and the error reset after it
    with pytest.raises(Exception, match="bus fault error_rate"):
        ep.bus_kind.control(bench, ep, "bus", {"knobs": {"error_rate": 5}})
