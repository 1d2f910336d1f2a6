"""The official dynamixel-sdk's Protocol 1.0 handler, pypot-style USB2AX traffic and the P1 rules on a real pty."""

from __future__ import annotations

import time
from pathlib import Path

import dynamixel_sdk as sdk
import pytest

from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.pytest_plugin import wait_until

PROFILE = str(Path(__file__).resolve().parents[1] / "data" / "protocol1_bus.toml")
pytestmark = pytest.mark.hilbench_profile(PROFILE)
OK = sdk.COMM_SUCCESS


@pytest.fixture
def sdk1(official_sdk):
    return official_sdk(1.0)


def exchange(port, packet: bytes, expect: int, timeout: float = 2.0) -> bytes:
    """Send raw bytes and collect ``expect`` reply bytes (or what came until ``timeout``)."""
    port.ser.reset_input_buffer()
    port.writePort(packet)
    got = bytearray()
    deadline = time.monotonic() + timeout
    while len(got) < expect and time.monotonic() < deadline:
        got += bytes(port.readPort(expect - len(got)))
    return bytes(got)


def test_ping_reports_the_models_as_their_1_0_firmware_does(sdk1, bench):
    port, ph = sdk1
    assert [ph.ping(port, i)[:2] for i in (1, 2, 3, 4, 5)] == [(12, OK), (18, OK), (29, OK), (310, OK), (320, OK)]
    assert ph.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT
    assert bench.manifest()["endpoints"][0]["protocol_version"] == 1
    assert {d["protocol_version"] for d in bench.manifest()["devices"]} == {1}


def test_read_write_reg_write_action_and_goal_moves_the_horn(sdk1, bench):
    port, ph = sdk1
    assert ph.read2ByteTxRx(port, 3, 6) == (1024, OK, 0)  # CW angle limit from the profile
    assert ph.read2ByteTxRx(port, 4, 8) == (4095, OK, 0)  # CCW angle limit default of the MX
    assert ph.read1ByteTxRx(port, 1, 5) == (0, OK, 0)  # Return Delay Time from the profile
    assert ph.read1ByteTxRx(port, 2, 5) == (250, OK, 0)  # ... and the factory default
    assert ph.read2ByteTxRx(port, 4, 68) == (2048, OK, 0)  # MX-64 Current: 2048 = none
    assert ph.write2ByteTxRx(port, 3, 30, 2500) == (OK, 0)  # Goal Position: torque comes on by itself
    assert ph.read1ByteTxRx(port, 3, 24) == (1, OK, 0)
    wait_until(lambda: abs(ph.read2ByteTxRx(port, 3, 36)[0] - 2500) <= 1, timeout=5)
    assert ph.regWriteTxRx(port, 1, 30, 2, [0x00, 0x01]) == (OK, 0)  # 256
    assert ph.read1ByteTxRx(port, 1, 44) == (1, OK, 0)  # Registered
    assert ph.action(port, 1) == OK
    assert ph.read2ByteTxRx(port, 1, 30) == (256, OK, 0)
    assert ph.read1ByteTxRx(port, 1, 44) == (0, OK, 0)


def test_error_bits_of_protocol_1(sdk1, bench):
    port, ph = sdk1
    assert ph.write2ByteTxRx(port, 3, 30, 3500) == (OK, 0x02)  # beyond the CCW limit: angle-limit error
    assert ph.read2ByteTxRx(port, 3, 30)[0] == 3072  # ... and clamped to it
    assert ph.write1ByteTxRx(port, 1, 16, 3) == (OK, 0x08)  # Status Return Level 3: range error
    assert ph.write1ByteTxRx(port, 1, 36, 7) == (OK, 0x08)  # Present Position is read-only
    # an unknown instruction to a unicast ID: instruction error; a broken checksum: checksum error
    assert exchange(port, p1.build(1, 0x08), 6) == p1.frame(1, 0x40)
    assert exchange(port, bytes.fromhex("FFFF0104022B01CD"), 6) == p1.frame(1, 0x10)
    bench.device(2).supply_voltage = 20.0  # beyond its 14 V limit: every status says so
    assert ph.ping(port, 2) == (18, OK, 0x01)


def test_status_return_level_and_sync_write(sdk1, bench):
    port, ph = sdk1
    writer = sdk.GroupSyncWrite(port, ph, 32, 2)  # Moving Speed
    for i, v in ((1, 100), (3, 200), (5, 300)):
        writer.addParam(i, [v & 0xFF, v >> 8])
    assert writer.txPacket() == OK
    wait_until(lambda: bench.device(5).get("moving_speed") == 300)
    assert [ph.read2ByteTxRx(port, i, 32)[0] for i in (1, 3, 5)] == [100, 200, 300]
    assert ph.write1ByteTxRx(port, 4, 16, 1) == (OK, 0)  # from now on: only PING and READ answered
    assert ph.write1ByteTxRx(port, 4, 25, 1)[0] == sdk.COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 4, 25) == (1, OK, 0)
    assert ph.ping(port, 4)[1] == OK


def test_usb2ax_sync_read_fills_a_missing_servo_with_ff(sdk1, bench):
    port, ph = sdk1
    request = p1.build_instruction(0xFE, p1.Instruction1.SYNC_READ, address=36, length=6, ids=[3, 9, 1])
    reply = exchange(port, request, 6 + 18)
    assert reply[:5] == bytes.fromhex("FF FF FD 14 00")
    data = reply[5:-1]
    assert data[0:2] == (2048).to_bytes(2, "little") and data[12:14] == (512).to_bytes(2, "little")
    assert data[6:12] == b"\xff" * 6  # ID 9 is not on the bus
    assert reply == p1.frame(0xFD, 0, data)
    # the adapter's limits: L x N above 229 is a Range error without data
    too_much = p1.build_instruction(0xFE, p1.Instruction1.SYNC_READ, address=0, length=120, ids=[1, 2])
    assert exchange(port, too_much, 6) == bytes.fromhex("FF FF FD 02 08 F8")
    # the adapter's own table: model 16897 at address 0
    assert ph.read2ByteTxRx(port, 0xFD, 0) == (16897, OK, 0)
    bench.device(1).faults.drop_next = 1  # a reply lost on the adapter's bus is 0xFF too
    reply = exchange(port, p1.build_instruction(0xFE, p1.Instruction1.SYNC_READ, address=43, length=1, ids=[1, 3]),
                     8)
    assert reply[5:7] == bytes((0xFF, 30))


def test_bulk_read_is_answered_by_the_mx_servos_in_list_order(sdk1):
    port, ph = sdk1
    request = p1.build_instruction(0xFE, p1.Instruction1.BULK_READ, zero=None, entries=[
        {"length": 2, "id": 4, "address": 68}, {"length": 1, "id": 1, "address": 3},
        {"length": 2, "id": 3, "address": 0}])
    reply = exchange(port, request, 8 + 8)
    assert reply == p1.frame(4, 0, (2048).to_bytes(2, "little")) + p1.frame(3, 0, (29).to_bytes(2, "little"))


def test_eeprom_and_ram_survive_a_client_closing_and_reopening_the_port(bench, sdk1):
    port, ph = sdk1
    assert ph.write2ByteTxRx(port, 3, 8, 3000) == (OK, 0)  # CCW Angle Limit (EEPROM)
    assert ph.write1ByteTxRx(port, 3, 24, 1) == (OK, 0)
    assert ph.write1ByteTxRx(port, 3, 24, 0) == (OK, 0)  # the client turns the torque off
    port.closePort()
    again = sdk.PortHandler(bench.endpoint().path)
    assert again.openPort() and again.setBaudRate(1_000_000)
    try:
        assert ph.read2ByteTxRx(again, 3, 8) == (3000, OK, 0)
        assert ph.read1ByteTxRx(again, 3, 24) == (0, OK, 0)
    finally:
        again.closePort()
        port.openPort()
