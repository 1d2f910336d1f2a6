"""X-series servos on a Protocol 1.0 bus (Protocol Type 1), driven as ROBOTIS's Protocol 1.0 examples drive
them: the official SDK's 1.0 packet handler at the X-series control table's addresses."""

from __future__ import annotations

from pathlib import Path

import dynamixel_sdk as sdk
import pytest

from hilbench.bench.profile import parse_profile
from hilbench.errors import HilbenchError
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.pytest_plugin import wait_until
from tests.fakes.test_protocol1_bus import exchange

PROFILE = str(Path(__file__).resolve().parents[1] / "data" / "protocol1_x_bus.toml")
pytestmark = pytest.mark.hilbench_profile(PROFILE)
OK = sdk.COMM_SUCCESS
TORQUE_ENABLE, GOAL_POSITION, PRESENT_POSITION = 64, 116, 132


@pytest.fixture
def sdk1(official_sdk):
    return official_sdk(1.0)


def test_ping_and_the_protocol_type_register(sdk1):
    port, ph = sdk1
    assert ph.ping(port, 1) == (1020, OK, 0)  # the SDK reads the model number at address 0 after the PING
    assert ph.read1ByteTxRx(port, 2, 13) == (1, OK, 0)  # Protocol Type: 1.0


def test_read_write_moves_the_horn(sdk1):
    port, ph = sdk1
    assert ph.write1ByteTxRx(port, 1, TORQUE_ENABLE, 1) == (OK, 0)
    assert ph.write4ByteTxRx(port, 1, GOAL_POSITION, 1000) == (OK, 0)
    wait_until(lambda: abs(ph.read4ByteTxRx(port, 1, PRESENT_POSITION)[0] - 1000) <= 20, timeout=10)


def test_a_goal_written_in_two_of_its_four_bytes_is_refused_with_the_range_bit(sdk1, bench):
    """What ROBOTIS's protocol1_0/read_write.py does since 2020 (write2ByteTxRx at 116): a Protocol 2.0
    firmware refuses a write shorter than its item (Data Length Error), which Protocol 1.0 reports as a
    range error; the horn stays."""
    port, ph = sdk1
    assert ph.write1ByteTxRx(port, 1, TORQUE_ENABLE, 1) == (OK, 0)
    assert ph.write2ByteTxRx(port, 1, GOAL_POSITION, 10) == (OK, 0x08)
    assert bench.device(1).profile.at(bench.now() + 60).position == 2048


def test_sync_write_and_bulk_read(sdk1):
    port, ph = sdk1
    for i in (1, 2):
        assert ph.write1ByteTxRx(port, i, TORQUE_ENABLE, 1) == (OK, 0)
    writer = sdk.GroupSyncWrite(port, ph, GOAL_POSITION, 4)
    for i in (1, 2):
        writer.addParam(i, list((3000).to_bytes(4, "little")))
    assert writer.txPacket() == OK
    request = p1.build_instruction(0xFE, p1.Instruction1.BULK_READ, zero=None, entries=[
        {"length": 4, "id": 1, "address": GOAL_POSITION}, {"length": 1, "id": 2, "address": TORQUE_ENABLE}])
    assert exchange(port, request, 10 + 7) == p1.frame(1, 0, (3000).to_bytes(4, "little")) + p1.frame(2, 0, b"\x01")
    wait_until(lambda: all(abs(ph.read4ByteTxRx(port, i, PRESENT_POSITION)[0] - 3000) <= 20 for i in (1, 2)),
               timeout=10)


def test_a_servo_with_no_protocol_1_firmware_is_refused_on_a_protocol_1_bus():
    raw = {"schema": 1, "endpoints": {"bus": {"protocol": "dynamixel", "protocol_version": 1}},
           "devices": [{"model": "XL-320", "id": 1}]}
    with pytest.raises(HilbenchError, match=r"devices\[0\]\.model: XL-320 speaks Protocol 2\.0"):
        parse_profile(raw, "x.toml")


def test_a_servo_switched_to_protocol_2_or_factory_reset_goes_quiet_on_the_protocol_1_bus(sdk1, bench):
    """The write is answered in 1.0, then the servo speaks 2.0 (whose packets this bus does not carry); a
    factory reset brings Protocol Type back to 2 as well (what ROBOTIS's protocol1_0/factory_reset.py would
    meet on an X-series servo)."""
    port, ph = sdk1
    assert ph.write1ByteTxRx(port, 2, 13, 2) == (OK, 0)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.factoryReset(port, 1) == (OK, 0)  # (the 1.0 handler takes no mode)
    servo = bench.device(1)
    wait_until(lambda: not servo.silent(bench.now()), timeout=5)  # past the reboot after the reset
    assert servo.get("protocol_type") == 2
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
