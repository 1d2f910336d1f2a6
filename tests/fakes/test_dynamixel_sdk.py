"""The unmodified official dynamixel-sdk drives the emulated bus over a real pty."""

from __future__ import annotations

import os
import time
from pathlib import Path

import dynamixel_sdk as sdk
import pytest

from hilbench.pytest_plugin import wait_until

PROFILE = str(Path(__file__).resolve().parents[1] / "data" / "mixed_bus.toml")
pytestmark = pytest.mark.hilbench_profile(PROFILE)

OK = sdk.COMM_SUCCESS


@pytest.fixture
def sdk_port(bench):
    port = sdk.PortHandler(bench.endpoint().path)
    assert port.openPort()
    assert port.setBaudRate(1_000_000)
    yield port, sdk.PacketHandler(2.0)
    port.closePort()


def test_ping_unicast_and_broadcast(sdk_port):
    port, ph = sdk_port
    assert ph.ping(port, 1) == (1020, OK, 0)
    assert ph.ping(port, 3) == (1060, OK, 0)
    assert ph.ping(port, 4) == (311, OK, 0)
    found, result = ph.broadcastPing(port)
    assert result == OK
    assert found == {1: [1020, 52], 2: [1020, 52], 3: [1060, 52], 4: [311, 42]}


def test_read_and_write_1_2_4_byte_fields(sdk_port):
    port, ph = sdk_port
    assert ph.read1ByteTxRx(port, 1, 7) == (1, OK, 0)  # ID
    assert ph.read2ByteTxRx(port, 1, 0) == (1020, OK, 0)  # Model Number
    assert ph.read4ByteTxRx(port, 1, 44) == (200, OK, 0)  # Velocity Limit default of the XM430-W350
    assert ph.write1ByteTxRx(port, 1, 65, 1) == (OK, 0)  # LED
    assert ph.read1ByteTxRx(port, 1, 65) == (1, OK, 0)
    assert ph.write2ByteTxRx(port, 1, 84, 1234) == (OK, 0)  # Position P Gain
    assert ph.read2ByteTxRx(port, 1, 84) == (1234, OK, 0)
    assert ph.write4ByteTxRx(port, 1, 112, 77) == (OK, 0)  # Profile Velocity
    assert ph.read4ByteTxRx(port, 1, 112) == (77, OK, 0)
    # a value whose bytes contain the header pattern, as the SDK sends it (unstuffed)
    assert ph.write4ByteTxRx(port, 1, 104, 0) == (OK, 0)
    data, result, err = ph.readTxRx(port, 1, 126, 10)
    assert result == OK and len(data) == 10


def test_sync_read_and_sync_write(sdk_port, bench):
    port, ph = sdk_port
    writer = sdk.GroupSyncWrite(port, ph, 112, 4)  # Profile Velocity
    for i, value in ((1, 11), (2, 22), (3, 33), (4, 44)):
        writer.addParam(i, list(value.to_bytes(4, "little")))
    assert writer.txPacket() == OK
    reader = sdk.GroupSyncRead(port, ph, 112, 4)
    for i in (4, 2, 1, 3):  # replies must come in this list order
        reader.addParam(i)
    assert reader.txRxPacket() == OK
    assert [reader.getData(i, 112, 4) for i in (1, 2, 3, 4)] == [11, 22, 33, 44]
    assert bench.endpoint().bus.stats.requests["sync_write"] == 1


def test_bulk_read_and_bulk_write(sdk_port):
    port, ph = sdk_port
    writer = sdk.GroupBulkWrite(port, ph)
    writer.addParam(1, 65, 1, [1])  # LED
    writer.addParam(2, 84, 2, [0x10, 0x02])  # Position P Gain 528
    assert writer.txPacket() == OK
    reader = sdk.GroupBulkRead(port, ph)
    reader.addParam(2, 84, 2)
    reader.addParam(1, 65, 1)
    reader.addParam(4, 0, 2)
    assert reader.txRxPacket() == OK
    assert reader.getData(1, 65, 1) == 1
    assert reader.getData(2, 84, 2) == 528
    assert reader.getData(4, 0, 2) == 311


def test_fast_sync_read_and_fast_bulk_read_on_x_series(sdk_port):
    port, ph = sdk_port
    reader = sdk.GroupSyncRead(port, ph, 0, 2)
    reader.addParam(2)
    reader.addParam(1)
    assert reader.fastSyncRead() == OK
    assert reader.getData(1, 0, 2) == 1020 and reader.getData(2, 0, 2) == 1020
    bulk = sdk.GroupBulkRead(port, ph)
    bulk.addParam(1, 7, 1)
    bulk.addParam(3, 0, 2)
    assert bulk.fastBulkRead() == OK
    assert bulk.getData(1, 7, 1) == 1 and bulk.getData(3, 0, 2) == 1060


def test_fast_read_to_an_mx_stays_silent_by_default(sdk_port):
    # The e-Manual does not list Fast reads for MX(2.0): hilbench's policy is silence.
    port, ph = sdk_port
    reader = sdk.GroupSyncRead(port, ph, 0, 2)
    reader.addParam(4)
    assert reader.fastSyncRead() == sdk.COMM_RX_TIMEOUT


def test_reg_write_and_action(sdk_port, bench):
    port, ph = sdk_port
    assert ph.regWriteTxRx(port, 1, 65, 1, [1]) == (OK, 0)
    assert ph.read1ByteTxRx(port, 1, 69) == (1, OK, 0)  # Registered Instruction
    assert ph.read1ByteTxRx(port, 1, 65) == (0, OK, 0)  # not applied yet
    assert ph.action(port, sdk.BROADCAST_ID) == OK
    wait_until(lambda: bench.device(1).get("led") == 1)
    assert ph.read1ByteTxRx(port, 1, 69) == (0, OK, 0)


def test_action_without_reg_write_is_an_instruction_error(sdk_port):
    port, ph = sdk_port
    # the SDK's action() does not wait for a reply, so send Action unicast and read the status ourselves
    assert ph.action(port, 2) == OK
    port.setPacketTimeout(11)
    data, result, err = ph.readRx(port, 2, 0)
    assert result == OK and err == sdk.ERRNUM_INSTRUCTION


def test_reboot_is_briefly_silent_and_resets_ram(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 2, 65, 1) == (OK, 0)
    assert ph.reboot(port, 2) == (OK, 0)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT  # booting
    wait_until(lambda: ph.ping(port, 2)[1] == OK, timeout=3)
    assert ph.read1ByteTxRx(port, 2, 65) == (0, OK, 0)  # LED back to its default


def test_factory_reset_modes(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 2, 9, 100) == (OK, 0)  # Return Delay Time (EEPROM)
    assert ph.factoryReset(port, 2, 0x02) == (OK, 0)  # everything but the ID and the baud
    wait_until(lambda: ph.ping(port, 2)[1] == OK, timeout=3)
    assert ph.read1ByteTxRx(port, 2, 9) == (250, OK, 0)
    assert ph.write1ByteTxRx(port, 2, 9, 100) == (OK, 0)
    assert ph.factoryReset(port, 2, 0x01) == (OK, 0)  # everything but the ID: back to 57600 baud
    assert port.setBaudRate(57_600)
    wait_until(lambda: ph.ping(port, 2)[1] == OK, timeout=3)
    assert ph.read1ByteTxRx(port, 2, 9) == (250, OK, 0)
    assert ph.factoryReset(port, 2, 0xFF) == (OK, 0)  # everything: ID 1, 57600 baud
    servo = bench.device("bus.2")  # the reply came; the device now lives at ID 1
    assert servo.id == 1 and servo.baud == 57_600
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT
    wait_until(lambda: ph.ping(port, 1)[1] == OK, timeout=3)  # the reset device answers as ID 1 at 57600


def test_clear_multi_turn_and_result_fail_while_moving(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 1, 11, 4) == (OK, 0)  # extended position mode
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (OK, 0)
    assert ph.write4ByteTxRx(port, 1, 116, 4096 * 2 + 100) == (OK, 0)
    assert ph.clearMultiTurn(port, 1) == (OK, sdk.ERRNUM_RESULT_FAIL)  # still moving
    wait_until(lambda: ph.read1ByteTxRx(port, 1, 122)[0] == 0, timeout=10)
    pos = ph.read4ByteTxRx(port, 1, 132)[0]
    assert pos == 4096 * 2 + 100
    assert ph.clearMultiTurn(port, 1) == (OK, 0)
    assert ph.read4ByteTxRx(port, 1, 132)[0] == 100


@pytest.mark.parametrize(
    "address,value,size,error",
    [
        (8, 3, 1, sdk.ERRNUM_ACCESS),  # EEPROM while torque is on
        (132, 5, 4, sdk.ERRNUM_ACCESS),  # read-only item
        (66, 1, 1, sdk.ERRNUM_ACCESS),  # reserved address
        (65, 2, 1, sdk.ERRNUM_DATA_RANGE),  # LED is 0..1
        (116, 5000, 4, sdk.ERRNUM_DATA_LIMIT),  # beyond Max Position Limit
        (116, 5, 2, sdk.ERRNUM_DATA_LENGTH),  # 2 bytes of a 4-byte item
    ],
)
def test_error_statuses(sdk_port, address, value, size, error):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (OK, 0)
    result, err = ph.writeTxRx(port, 1, address, size, list(value.to_bytes(size, "little")))
    assert (result, err) == (OK, error)


def test_read_past_the_table_is_an_access_error_without_data(sdk_port):
    port, ph = sdk_port
    # (the SDK hands back the CRC bytes as "data" of a data-less status; the ERR is what counts)
    data, result, err = ph.readTxRx(port, 1, 660, 4)
    assert result == OK and err == sdk.ERRNUM_ACCESS


def test_hardware_error_sets_alert_and_shuts_down(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (OK, 0)
    bench.device(2).raise_hardware_error(0x04, bench.now())  # overheating, in Shutdown by default
    model, result, err = ph.ping(port, 2)
    assert result == OK and err & sdk.ERRBIT_ALERT
    assert ph.read1ByteTxRx(port, 2, 70) == (0x04, OK, sdk.ERRBIT_ALERT)
    assert ph.read1ByteTxRx(port, 2, 64)[0] == 0  # torque forced off
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (OK, sdk.ERRBIT_ALERT)
    assert ph.read1ByteTxRx(port, 2, 64)[0] == 0  # and it stays off until a reboot
    assert ph.reboot(port, 2)[0] == OK
    wait_until(lambda: ph.ping(port, 2) == (1020, OK, 0), timeout=3)


def test_torque_gates_motion_and_present_values_follow(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write4ByteTxRx(port, 3, 116, 3000) == (OK, 0)
    assert ph.read4ByteTxRx(port, 3, 132)[0] == 2048
    assert bench.device(3).get("present_position", bench.now() + 1.0) == 2048  # torque off: no motion, ever
    assert ph.write1ByteTxRx(port, 3, 64, 1) == (OK, 0)
    t0 = time.monotonic()
    velocities = []
    while ph.read4ByteTxRx(port, 3, 132)[0] != 3000:
        velocities.append(ph.read4ByteTxRx(port, 3, 128)[0])
        assert time.monotonic() - t0 < 5
    elapsed = time.monotonic() - t0
    # 952 pulses at the XL430's Velocity Limit of 265 x 0.229 rpm (4142 pulse/s) take at least 0.23 s
    assert elapsed > 0.2
    assert max(velocities) <= 265 and max(velocities) > 200
    wait_until(lambda: ph.read1ByteTxRx(port, 3, 122)[0] == 0)  # Moving ends with the profile
    assert ph.read2ByteTxRx(port, 3, 144)[0] == 120  # 12.0 V supply
    assert 25 <= ph.read1ByteTxRx(port, 3, 146)[0] <= 40


def test_torque_on_after_power_up_or_reboot_holds_the_position(sdk_port, bench):
    port, ph = sdk_port
    servo = bench.device(3)
    assert ph.read4ByteTxRx(port, 3, 116)[0] == 2048  # Goal Position starts where the horn is
    assert ph.write1ByteTxRx(port, 3, 64, 1) == (OK, 0)
    assert servo.get("present_position", bench.now() + 1.0) == 2048  # no swing to 0
    assert ph.write4ByteTxRx(port, 3, 116, 2500) == (OK, 0)
    wait_until(lambda: ph.read4ByteTxRx(port, 3, 132)[0] == 2500)
    assert ph.reboot(port, 3) == (OK, 0)
    wait_until(lambda: ph.ping(port, 3)[1] == OK, timeout=3)
    assert ph.read4ByteTxRx(port, 3, 116)[0] == 2500  # after the reboot too
    assert ph.write1ByteTxRx(port, 3, 64, 1) == (OK, 0)
    assert servo.get("present_position", bench.now() + 1.0) == 2500


def test_status_return_level(sdk_port):
    port, ph = sdk_port
    # the write that lowers the level is answered by the level it sets
    assert ph.write1ByteTxRx(port, 2, 68, 1)[0] == sdk.COMM_RX_TIMEOUT
    assert ph.write1ByteTxRx(port, 2, 65, 1)[0] == sdk.COMM_RX_TIMEOUT  # writes no longer answered
    assert ph.read1ByteTxRx(port, 2, 65) == (1, OK, 0)  # reads still are
    assert ph.write1ByteTxOnly(port, 2, 68, 0) == OK
    assert ph.read1ByteTxRx(port, 2, 65)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.ping(port, 2) == (1020, OK, 0)  # Ping always


def test_id_change_answers_from_the_old_id_then_moves(sdk_port):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 2, 7, 9) == (OK, 0)
    assert ph.ping(port, 9) == (1020, OK, 0)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT


def test_baud_change_takes_effect(sdk_port, bench):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 2, 8, 4) == (OK, 0)  # 2 Mbaud (torque is off)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT  # we still talk at 1 Mbaud
    assert port.setBaudRate(2_000_000)
    assert ph.ping(port, 2) == (1020, OK, 0)
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT  # the others stayed at 1 Mbaud


def test_missing_id_times_out_as_the_sdk_expects(sdk_port):
    port, ph = sdk_port
    t0 = time.monotonic()
    model, result, err = ph.ping(port, 77)
    elapsed = time.monotonic() - t0
    assert result == sdk.COMM_RX_TIMEOUT
    assert 0.030 < elapsed < 0.2  # the SDK's own ~34 ms budget


def test_client_closes_and_reopens_the_port(bench):
    path = bench.endpoint().path
    ph = sdk.PacketHandler(2.0)
    for _ in range(3):
        port = sdk.PortHandler(path)
        assert port.openPort()
        assert ph.ping(port, 1) == (1020, OK, 0)
        port.closePort()


def test_garbage_on_the_bus_does_not_disturb_the_next_exchange(sdk_port, bench):
    port, ph = sdk_port
    fd = os.open(bench.endpoint().path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, bytes([0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x40, 0x00, 0x55, 0x13, 0x00, 0xFF]) + bytes(range(40)))
    finally:
        os.close(fd)
    decoder = bench.endpoint().bus.decoder
    wait_until(lambda: decoder.bytes_in >= 51)
    # The garbage ends in a candidate claiming 64 bytes: like a servo, the bus takes what follows
    # within its 1.5 ms inter-byte timeout (spec §1.1) as part of it, so the line must be quiet
    # that long before the next exchange (a ping sent sooner is lost on hardware too).
    time.sleep(0.002)
    assert ph.ping(port, 1) == (1020, OK, 0)
    assert ph.read2ByteTxRx(port, 3, 0) == (1060, OK, 0)


def test_fault_knobs_drop_corrupt_delay_vanish(sdk_port, bench):
    port, ph = sdk_port
    servo = bench.device(1)
    servo.faults.drop_next = 1
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.ping(port, 1)[1] == OK
    servo.faults.corrupt_next = 1
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_CORRUPT
    servo.faults.delay = 0.015
    t0 = time.monotonic()
    assert ph.ping(port, 1)[1] == OK
    assert time.monotonic() - t0 >= 0.015
    servo.faults.delay = 0.0
    servo.vanish(bench.now(), duration=0.3)
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    wait_until(lambda: ph.ping(port, 1)[1] == OK, timeout=3)


def test_a_silent_device_in_a_sync_read(sdk_port, bench):
    port, ph = sdk_port
    bench.device(2).vanish(bench.now())
    reader = sdk.GroupSyncRead(port, ph, 0, 2)
    for i in (1, 2, 3):
        reader.addParam(i)
    assert reader.txRxPacket() == sdk.COMM_RX_TIMEOUT
    bench.device(2).revive()
    assert reader.txRxPacket() == OK


def test_a_servo_switched_to_protocol_1_goes_quiet_on_a_protocol_2_bus(sdk_port):
    port, ph = sdk_port
    assert ph.write1ByteTxRx(port, 1, 13, 1) == (OK, 0)  # Protocol Type (EEPROM, torque off): answered in 2.0
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert ph.ping(port, 3) == (1060, OK, 0)  # the others are untouched
