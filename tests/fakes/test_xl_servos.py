"""XL-320 (Protocol 2.0, its own table), XL330 and XL430 with homing offsets and drive modes, via the official SDK."""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

from hilbench.pytest_plugin import wait_until

OK = sdk.COMM_SUCCESS


@pytest.fixture
def sdk2(official_sdk):
    return official_sdk(2.0)


@pytest.mark.hilbench_profile("poppy-ergo-jr")
def test_xl320_has_its_own_table(sdk2, bench):
    port, ph = sdk2
    assert ph.ping(port, 1) == (350, OK, 0)
    found, result = ph.broadcastPing(port)
    assert result == OK and sorted(found) == [1, 2, 3, 4, 5, 6]
    assert ph.read2ByteTxRx(port, 2, 6) == (205, OK, 0)  # CW Angle Limit: -90 deg as pypot writes it
    assert ph.read1ByteTxRx(port, 1, 4) == (3, OK, 0)  # Baud Rate code 3: 1 Mbaud on the XL-320
    assert ph.write1ByteTxRx(port, 1, 24, 1) == (OK, 0)
    assert ph.write1ByteTxRx(port, 1, 5, 10) == (OK, 7)  # EEPROM with the torque on: Access Error
    assert ph.write2ByteTxRx(port, 1, 30, 700) == (OK, 0)
    wait_until(lambda: ph.read2ByteTxRx(port, 1, 37)[0] == 700, timeout=5)  # (699 is still on the way)
    reader = sdk.GroupSyncRead(port, ph, 37, 6)  # pypot's present position/speed/load
    for i in range(1, 7):
        reader.addParam(i)
    assert reader.txRxPacket() == OK
    assert reader.getData(1, 37, 2) == 700 and reader.getData(2, 37, 2) == 512


@pytest.mark.hilbench_profile("koch-follower")
def test_x_series_homing_offset_adds_and_reverse_mode(sdk2, bench):
    port, ph = sdk2
    assert [ph.ping(port, i)[0] for i in range(1, 7)] == [1060, 1060, 1200, 1200, 1200, 1200]
    horn = round(bench.device(3).profile.at(bench.now()).position)
    offset = ph.read4ByteTxRx(port, 3, 20)[0]
    offset = offset - (1 << 32) if offset >= 1 << 31 else offset
    assert ph.read4ByteTxRx(port, 3, 132)[0] == horn + offset  # Present = Actual + Homing Offset
    assert ph.read1ByteTxRx(port, 6, 11) == (5, OK, 0)  # the gripper: current-based position
    assert ph.write1ByteTxRx(port, 6, 64, 1) == (OK, 0)
    goal = ph.read4ByteTxRx(port, 6, 132)[0] + 300
    assert ph.write4ByteTxRx(port, 6, 116, goal) == (OK, 0)
    wait_until(lambda: ph.read4ByteTxRx(port, 6, 132)[0] == goal, timeout=5)
    # Drive Mode bit 0 reverses the direction: the horn does not move, Present Position changes sign
    before = ph.read4ByteTxRx(port, 4, 132)[0]
    assert ph.write1ByteTxRx(port, 4, 10, 1) == (OK, 0)
    after = ph.read4ByteTxRx(port, 4, 132)[0]
    after = after - (1 << 32) if after >= 1 << 31 else after
    off4 = bench.device(4).get("homing_offset")
    assert after == -(before - off4) + off4


@pytest.mark.hilbench_profile("koch-leader")
def test_xl330_m077_and_writes_of_the_homing_offset_keep_the_horn(sdk2, bench):
    port, ph = sdk2
    assert ph.ping(port, 1) == (1190, OK, 0)
    horn = bench.device(1).profile.at(bench.now()).position
    assert ph.write4ByteTxRx(port, 1, 20, 500) == (OK, 0)
    assert bench.device(1).profile.at(bench.now()).position == horn
    assert ph.read4ByteTxRx(port, 1, 132)[0] == round(horn) + 500
