"""Feetech's own Python SDK (feetech-servo-sdk, module scservo_sdk) drives the emulated bus over a real pty."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from hilbench.protocols import feetech as ft
from hilbench.pytest_plugin import wait_until

scs = pytest.importorskip("scservo_sdk", reason="feetech-servo-sdk is not installed (it is in the test extra)")

PROFILE = str(Path(__file__).resolve().parents[1] / "data" / "feetech_bus.toml")
pytestmark = pytest.mark.hilbench_profile(PROFILE)
OK = scs.COMM_SUCCESS


@pytest.fixture
def ftsdk(bench, monkeypatch):
    # The SDK's per-packet timeout is LATENCY_TIMER-based (~34 ms at 1 Mbaud); give a loaded machine more room.
    monkeypatch.setattr(scs.port_handler, "LATENCY_TIMER", 100)
    port = scs.PortHandler(bench.endpoint().path)
    assert port.openPort()
    assert port.setBaudRate(1_000_000)
    scs.scservo_def.SCS_SETEND(0)  # the STS stores words little-endian (LeRobot's protocol_version 0)
    yield port, scs.PacketHandler(0)
    port.closePort()


def test_ping_reads_the_model_number_at_address_3(ftsdk, bench):
    port, ph = ftsdk
    assert ph.ping(port, 1) == (777, OK, 0)
    assert ph.ping(port, 4) == (777, OK, 0)
    assert ph.ping(port, 7)[1] == scs.COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 1, 0)[:2] == (3, OK)  # firmware major
    assert bench.manifest()["endpoints"][0]["protocol"] == "feetech"


def test_scs_stores_words_big_endian(ftsdk):
    port, _ = ftsdk
    scs.scservo_def.SCS_SETEND(1)
    try:
        assert scs.PacketHandler(1).ping(port, 9) == (1284, OK, 0)
    finally:
        scs.scservo_def.SCS_SETEND(0)


def test_write_read_sign_magnitude_offset_and_motion(ftsdk, bench):
    port, ph = ftsdk
    # ID 4: horn at 1500 and Homing Offset -1000 (sign bit 11): Present = Actual - Offset = 2500
    assert ph.read2ByteTxRx(port, 4, 31) == (0x800 | 1000, OK, 0)
    assert ph.read2ByteTxRx(port, 4, 56) == (2500, OK, 0)
    assert ph.write1ByteTxRx(port, 4, 40, 1) == (OK, 0)  # torque on
    assert ph.write2ByteTxRx(port, 4, 42, 3000) == (OK, 0)  # Goal Position in Present terms
    wait_until(lambda: ph.read2ByteTxRx(port, 4, 56)[0] == 3000, timeout=5)
    assert round(bench.device(4).profile.at(bench.now()).position) == 2000  # the horn: 3000 + (-1000)
    assert ph.write2ByteTxRx(port, 4, 42, 3900) == (OK, 0)  # beyond Max Position Limit 3500: clamped
    assert ph.read2ByteTxRx(port, 4, 42)[0] == 3500


def test_sync_read_answers_in_request_order_and_sync_write(ftsdk, bench):
    port, ph = ftsdk
    writer = scs.GroupSyncWrite(port, ph, 41, 1)  # Acceleration
    for i in (1, 2, 3):
        writer.addParam(i, [10 * i])
    assert writer.txPacket() == OK
    wait_until(lambda: bench.device(3).get("acceleration") == 30)
    reader = scs.GroupSyncRead(port, ph, 41, 1)
    for i in (3, 1, 2):
        reader.addParam(i)
    assert reader.txRxPacket() == OK
    assert [reader.getData(i, 41, 1) for i in (1, 2, 3)] == [10, 20, 30]
    # on the wire: one status per servo, in the order the request listed them
    port.ser.reset_input_buffer()
    port.writePort(ft.build_instruction(0xFE, ft.Instruction.SYNC_READ, address=5, length=1, ids=[2, 1, 3]))
    got = bytearray()
    deadline = time.monotonic() + 2
    while len(got) < 21 and time.monotonic() < deadline:
        got += bytes(port.readPort(21 - len(got)))
    assert bytes(got) == ft.frame(2, 0, b"\x02") + ft.frame(1, 0, b"\x01") + ft.frame(3, 0, b"\x03")


def test_broadcast_ping_is_answered_by_every_servo(ftsdk):
    port, _ = ftsdk
    port.ser.reset_input_buffer()
    port.writePort(ft.frame(0xFE, ft.Instruction.PING))
    got = bytearray()
    deadline = time.monotonic() + 2
    while len(got) < 30 and time.monotonic() < deadline:
        got += bytes(port.readPort(30 - len(got)))
    assert bytes(got) == b"".join(ft.frame(i, 0) for i in (1, 2, 3, 4, 9))


def test_reg_write_action_and_state_across_a_reopen(ftsdk, bench):
    port, ph = ftsdk
    assert ph.regWriteTxRx(port, 2, 21, 1, [16]) == (OK, 0)  # P Coefficient, applied on ACTION
    assert ph.read1ByteTxRx(port, 2, 21)[0] == 32
    assert ph.action(port, 2) == OK
    assert ph.read1ByteTxRx(port, 2, 21)[0] == 16
    assert ph.write1ByteTxRx(port, 2, 40, 1) == (OK, 0)
    assert ph.write1ByteTxRx(port, 2, 40, 0) == (OK, 0)  # the client turns the torque off, closes, comes back
    port.closePort()
    again = scs.PortHandler(bench.endpoint().path)
    assert again.openPort() and again.setBaudRate(1_000_000)
    try:
        assert ph.read1ByteTxRx(again, 2, 21)[:2] == (16, OK)
        assert ph.read1ByteTxRx(again, 2, 40)[:2] == (0, OK)
    finally:
        again.closePort()
        port.openPort()


def test_a_servo_powers_on_holding_and_a_goal_moves_it_with_no_torque_write(ftsdk, bench):
    """What Feetech's own examples do (sms_sts.WritePosEx: Acceleration, Goal Position, Goal Time, Goal
    Velocity in one write at 41, no Torque Enable first): the servo powers on with its torque on, holding
    where its horn is, and goes to the goal."""
    port, ph = ftsdk
    assert ph.read1ByteTxRx(port, 3, 40)[:2] == (1, OK)
    assert ph.read2ByteTxRx(port, 3, 42)[:2] == ph.read2ByteTxRx(port, 3, 56)[:2] == (2048, OK)
    assert ph.writeTxRx(port, 3, 41, 7, [50, 3000 & 0xFF, 3000 >> 8, 0, 0, 600 & 0xFF, 600 >> 8]) == (OK, 0)
    assert ph.read1ByteTxRx(port, 3, 66)[:2] == (1, OK)  # Moving
    wait_until(lambda: ph.read1ByteTxRx(port, 3, 66)[0] == 0, timeout=10)  # read_write.py's loop: until it stops
    assert ph.read2ByteTxRx(port, 3, 56)[:2] == (3000, OK)


def test_a_goal_does_not_switch_the_torque_on_again(ftsdk, bench):
    port, ph = ftsdk
    assert ph.write1ByteTxRx(port, 2, 40, 0) == (OK, 0)
    assert ph.write2ByteTxRx(port, 2, 42, 1000) == (OK, 0)
    assert ph.read1ByteTxRx(port, 2, 40)[:2] == (0, OK)
    profile = bench.device(2).profile
    assert profile.at(bench.now() + 60).position == 2048  # no motion planned, ever
