"""python-can's virtual interface in the bench's process: the CAN port's open_bus(), a named channel, the client API."""

from __future__ import annotations

import can
import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from hilbench.clients.can_rover import RoverCanClient
from hilbench.protocols import board_can as bc
from hilbench.pytest_plugin import wait_until


@pytest.mark.hilbench_profile("mecarover-can")
def test_can_bus_fixture_and_rover_client(bench):
    bus = bench.endpoint("can").port.open_bus()
    try:
        with RoverCanClient(bus, node_id=2) as rover:
            wait_until(lambda: rover.heartbeats >= 1, timeout=3)
            assert rover.nmt_state == 0x7F
            rover.start()
            rover.drive(0.3, 0.1, 0.0)
            odo = wait_until(lambda: (rover.pose() or (0, 0, 0))[0] > 0.05 and rover.pose(), timeout=3)
            assert odo[1] > 0  # moving left as well
            rover.drive(0.0)
            accepted = bench.family("canopen").node(2).stats["accepted"]
            assert accepted == rover.sent or rover.sent - accepted <= 1
            status = rover.wait_for("status")
            assert status["battery"] == pytest.approx(24.6, abs=1.3) and status["mode"] in (0, 1)
    finally:
        bus.shutdown()
    assert bench.manifest()["endpoints"][0]["virtual"].startswith("hilbench-can-")


def test_a_named_virtual_channel():
    data = {"schema": 1,
            "endpoints": {"can": {"type": "can", "protocol": "can", "virtual": "rover-bus", "slcan": False,
                                  "socketcand": False}},
            "devices": [{"model": "stm32f767-rover-canopen", "heartbeat_ms": 50, "autostart": True}]}
    with Bench(parse_profile(data, "v.toml")) as bench:
        assert bench.manifest()["endpoints"][0]["path"] == "virtual://rover-bus"
        bus = can.Bus(interface="virtual", channel="rover-bus")
        try:
            seen = set()
            while not {0x702, 0x182, 0x282} <= seen:  # autostart: heartbeats and PDOs without an NMT start
                msg = bus.recv(2)
                assert msg is not None
                seen.add(msg.arbitration_id)
            bus.send(can.Message(arbitration_id=0x202, data=bc.build_setpoint(0.1, 0, 0, 1), is_extended_id=False))
            wait_until(lambda: bench.family("canopen").node(2).stats["accepted"] == 1)
        finally:
            bus.shutdown()
