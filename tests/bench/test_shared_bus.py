"""One bus, several families: devices choose their family by model, an endpoint's bus kind carries them all.

Two families registered in code, as a lab's package would register them: a CANopen I/O node beside the
rover board on one CAN bus (both answer SDO through the unmodified ``canopen`` package), and a sensor
board beside Dynamixel servos on one RS-485 line (the official Dynamixel SDK pings and reads both over
the pty). Each family checks its own device keys; the bus refuses an address taken by another family.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import canopen
import dynamixel_sdk as sdk
import pytest

from hilbench import registry
from hilbench.bench import Bench, DeviceFamily, DeviceSpec
from hilbench.bench.profile import ProfileError, parse_profile
from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen as co
from hilbench.protocols import canopen_od as od
from hilbench.protocols.control_table import Field, Model
from hilbench.pytest_plugin import wait_until

canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0

# -- a second CANopen family: an 8-input I/O node ---------------------------------------------------------

IO_VENDOR = 0x0000ACE1
INPUTS = 0x6000


@dataclass
class IoSpec(DeviceSpec):
    node_id: int = 0
    inputs: int = 0


class AcmeIoFamily(DeviceFamily):
    """A lab's CANopen I/O node: CiA 301 (NMT, heartbeat, SDO) and its inputs at 0x6000."""

    name = "acme-io"
    models = ("acme-io-8",)
    joins = ("can",)
    device_keys = ("model", "name", "endpoint", "node_id", "inputs")
    device_word = "I/O node"

    def check_devices(self, c, key, raw, endpoint, profile) -> list[IoSpec]:
        node_id = c.integer(raw.get("node_id", 5), f"{key}.node_id", 1, 127)
        return [IoSpec(name=c.string(raw.get("name", "io"), f"{key}.name"), endpoint=endpoint.name,
                       model="acme-io-8", node_id=node_id, address=node_id,
                       inputs=c.integer(raw.get("inputs", 0), f"{key}.inputs", 0, 255))]

    def build(self, bench, endpoint, devices: list[IoSpec], t: float) -> None:
        from hilbench.fakes.canopen.node import CanopenNode

        for spec in devices:
            entries = [
                od.Variable(0x1000, 0, "Device type", od.UNSIGNED32, "ro", 401),
                od.Variable(0x1001, 0, "Error register", od.UNSIGNED8, "ro", 0),
                od.Variable(0x1017, 0, "Producer heartbeat time", od.UNSIGNED16, "rw", 100),
                od.Record(0x1018, "Identity object", (od.sub0(0x1018, 1),
                                                      od.Variable(0x1018, 1, "Vendor-ID", od.UNSIGNED32, "ro",
                                                                  IO_VENDOR))),
                od.Variable(INPUTS, 0, "Digital inputs", od.UNSIGNED8, "ro", spec.inputs),
            ]
            endpoint.add_device(spec.name, CanopenNode(spec.name, spec.node_id, entries))

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        for node in devices.values():
            node.start(time.monotonic())

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for node in devices.values():
            node.stop()


# -- a sensor board on a Dynamixel bus --------------------------------------------------------------------

SENSOR = Model(
    name="acme-ranger",
    number=0x5A5A,
    firmware=3,
    kind="board",
    firmware_address=2,
    id_address=3,
    table_size=12,
    fields=(
        Field(0, 2, "Model Number", "R", 0x5A5A),
        Field(2, 1, "Firmware Version", "R", 3),
        Field(3, 1, "ID", "RW", 1, 0, 252),
        Field(8, 2, "Range", "R", 0, unit="mm"),
    ),
)


@dataclass
class SensorSpec(DeviceSpec):
    id: int = 0
    range_mm: int = 0


class AcmeSensorFamily(DeviceFamily):
    """A lab's range-sensor board answering Dynamixel Protocol 2.0 at its own ID (as the Wolfgang boards do)."""

    name = "acme-sensor"
    models = ("acme-ranger",)
    joins = ("dynamixel",)
    device_keys = ("model", "name", "endpoint", "id", "range_mm")
    device_word = "sensor"

    def check_devices(self, c, key, raw, endpoint, profile) -> list[SensorSpec]:
        dxl_id = c.integer(raw.get("id"), f"{key}.id", 0, 252)
        return [SensorSpec(name=c.string(raw.get("name", f"ranger{dxl_id}"), f"{key}.name"), endpoint=endpoint.name,
                           model="acme-ranger", id=dxl_id, address=dxl_id,
                           range_mm=c.integer(raw.get("range_mm", 0), f"{key}.range_mm", 0, 65535))]

    def build(self, bench, endpoint, devices: list[SensorSpec], t: float) -> None:
        from hilbench.fakes.dynamixel.servo import Servo

        for spec in devices:
            endpoint.add_device(spec.name, Servo(SENSOR, spec.id, name=spec.name, initial={"range": spec.range_mm},
                                                 t=t))


@pytest.fixture
def families():
    """The two families registered in code for the test (and gone afterwards)."""
    registry.families.register("acme-io", AcmeIoFamily())
    registry.families.register("acme-sensor", AcmeSensorFamily())
    try:
        yield
    finally:
        registry.families.unregister("acme-io")
        registry.families.unregister("acme-sensor")


def can_profile(*devices: dict[str, Any]) -> dict[str, Any]:
    return {"schema": 1, "endpoints": {"can": {"type": "can", "protocol": "can", "bitrate": 500_000,
                                               "slcan": False, "socketcand": False}},
            "devices": list(devices)}


ROVER = {"model": "stm32f767-rover-canopen", "name": "rover", "node_id": 2, "heartbeat_ms": 100}
IO = {"model": "acme-io-8", "name": "io", "node_id": 5, "inputs": 0xA5}


def test_a_canopen_node_of_another_family_shares_the_bus_with_the_rover_board(families, tmp_path):
    profile = parse_profile(can_profile(ROVER, IO), "shared.toml")
    assert [(d.name, d.family, d.address) for d in profile.devices] == [("rover", "canopen", 2), ("io", "acme-io", 5)]
    with Bench(profile) as bench:
        assert bench.family_of("io").name == "acme-io" and bench.family_of("rover").name == "canopen"
        assert bench.device(5) is bench.devices["io"] and bench.device(2) is bench.devices["rover"]
        # each family's own lookups see its own devices only
        assert bench.family("canopen").node(2) is bench.devices["rover"]
        with pytest.raises(KeyError, match="no CANopen board at node id 5"):
            bench.family("canopen").node(5)
        assert bench.family("acme-io").device() is bench.devices["io"]  # a family without lookups of its own
        manifest = bench.manifest()
        assert [(d["name"], d["family"]) for d in manifest["devices"]] == [("rover", "canopen"), ("io", "acme-io")]
        assert manifest["endpoints"][0]["nodes"] == [2, 5]
        # control: each device's family's commands, and the bus's own addressed by endpoint (or a device on it)
        control = bench.serve_control()
        assert control.handle(b'{"cmd": "devices"}') == {
            "ok": True, "devices": {"rover": list(bench.family_of("rover").control_commands)},
            "endpoints": {"can": ["bus"]}}
        for request in (b'{"cmd": "bus"}', b'{"cmd": "bus", "endpoint": "can"}', b'{"cmd": "bus", "device": "io"}'):
            reply = control.handle(request)
            assert reply["ok"] is True and reply["bus"]["bitrate"] == 500_000, reply
        assert control.handle(b'{"cmd": "bus", "endpoint": "nope"}')["error"] == (
            "endpoint 'nope' has no command 'bus' (endpoints answering it: can)")
        assert control.handle(b'{"cmd": "status", "device": "rover"}')["ok"] is True
        eds = tmp_path / "rover.eds"
        eds.write_text(bc.eds(bc.BoardCanConfig()), newline="")
        net = canopen.Network(bench.endpoint("can").port.open_bus())
        net.connect()
        try:
            rover = net.add_node(2, str(eds))
            io = net.add_node(5, canopen.ObjectDictionary())
            for node in (rover, io):
                node.sdo.RESPONSE_TIMEOUT = 1.0
            wait_until(lambda: all(bench.device(n).state != co.BOOTUP for n in (2, 5)))
            # both answer SDO on one bus, each from its own dictionary
            assert rover.sdo[0x1018][1].raw == bc.BoardCanConfig().vendor_id
            assert io.sdo.upload(0x1018, 1) == IO_VENDOR.to_bytes(4, "little")
            assert io.sdo.upload(INPUTS, 0) == bytes([0xA5])
            with pytest.raises(canopen.SdoAbortedError):
                io.sdo.upload(0x2010, 0)  # the rover's object is not the I/O node's
            # and their heartbeats on it
            assert rover.nmt.wait_for_heartbeat(2) == "PRE-OPERATIONAL"
            assert io.nmt.wait_for_heartbeat(2) == "PRE-OPERATIONAL"
        finally:
            net.disconnect()


def test_a_node_id_taken_by_another_family_is_refused_naming_both(families):
    with pytest.raises(ProfileError) as exc:
        parse_profile(can_profile(ROVER, {**IO, "node_id": 2}), "shared.toml")
    assert str(exc.value) == ("shared.toml: devices[1].node_id: node id 2 is taken on endpoint 'can' by devices[0] "
                              "('rover', family canopen); 'io' (family acme-io) needs another")


def test_each_family_checks_only_its_own_device_keys(families):
    with pytest.raises(ProfileError) as exc:
        parse_profile(can_profile({**ROVER, "inputs": 3}), "shared.toml")
    message = str(exc.value)
    assert message.startswith("shared.toml: devices[0].inputs: unknown key (expected one of: model, name,")
    assert "inputs" not in message.split("expected one of:")[1]  # the rover's keys, not the I/O node's
    with pytest.raises(ProfileError, match=r"devices\[1\].heartbeat_ms: unknown key \(expected one of: model, name, "
                                           r"endpoint, node_id, inputs, body, pose\)"):
        parse_profile(can_profile(ROVER, {**IO, "heartbeat_ms": 5}), "shared.toml")
    with pytest.raises(ProfileError, match=r"devices\[1\].inputs: expected an integer 0..255, got 300"):
        parse_profile(can_profile(ROVER, {**IO, "inputs": 300}), "shared.toml")


def test_a_model_of_a_family_that_does_not_join_the_bus_is_refused(families):
    with pytest.raises(ProfileError) as exc:
        parse_profile(can_profile(ROVER, {"model": "acme-ranger", "id": 7}), "shared.toml")
    assert str(exc.value) == ("shared.toml: devices[1].endpoint: model 'acme-ranger' (family acme-sensor) needs an "
                              "endpoint with protocol = \"dynamixel\"; 'can' has protocol = \"can\"")


# -- RS-485 ---------------------------------------------------------------------------------------------------

SERVO_BUS = {"schema": 1, "endpoints": {"bus": {"protocol": "dynamixel", "baud": 1_000_000}},
             "devices": [{"model": "XM430-W350", "ids": [1, 2]},
                         {"model": "acme-ranger", "id": 50, "name": "ranger", "range_mm": 1234}]}


def test_a_sensor_board_of_another_family_shares_the_rs485_line_with_dynamixel_servos(families):
    profile = parse_profile(SERVO_BUS, "arm.toml")
    assert [(d.name, d.family) for d in profile.devices] == [("bus.1", "dynamixel"), ("bus.2", "dynamixel"),
                                                              ("ranger", "acme-sensor")]
    with Bench(profile) as bench:
        assert bench.device(50) is bench.devices["ranger"]
        servos = bench.family("dynamixel")
        assert servos.servo(1) is bench.device(1) and servos.bus() is bench.endpoint().bus
        with pytest.raises(KeyError, match="ID 50 on endpoint 'bus' is not a dynamixel device"):
            servos.servo(50)
        assert [d["family"] for d in bench.manifest()["devices"]] == ["dynamixel", "dynamixel", "acme-sensor"]
        port = sdk.PortHandler(bench.endpoint().path)
        assert port.openPort() and port.setBaudRate(1_000_000)
        ph = sdk.PacketHandler(2.0)
        try:
            assert ph.ping(port, 1) == (1020, sdk.COMM_SUCCESS, 0)  # an XM430-W350
            assert ph.ping(port, 50) == (0x5A5A, sdk.COMM_SUCCESS, 0)  # the sensor
            assert ph.read2ByteTxRx(port, 50, 8) == (1234, sdk.COMM_SUCCESS, 0)  # its range register
            found, result = ph.broadcastPing(port)
            assert result == sdk.COMM_SUCCESS and found == {1: [1020, 52], 2: [1020, 52], 50: [0x5A5A, 3]}
            reader = sdk.GroupSyncRead(port, ph, 0, 2)  # one Sync Read answered by devices of both families
            for dxl_id in (50, 1):
                reader.addParam(dxl_id)
            assert reader.txRxPacket() == sdk.COMM_SUCCESS
            assert (reader.getData(1, 0, 2), reader.getData(50, 0, 2)) == (1020, 0x5A5A)
        finally:
            port.closePort()
        assert bench.endpoint().bus.stats.requests["sync_read"] == 1


def test_a_servo_id_taken_by_another_family_is_refused_naming_both(families):
    devices = [SERVO_BUS["devices"][0], {**SERVO_BUS["devices"][1], "id": 2}]
    with pytest.raises(ProfileError) as exc:
        parse_profile({**SERVO_BUS, "devices": devices}, "arm.toml")
    assert str(exc.value) == ("arm.toml: devices[1].id: ID 2 is taken on endpoint 'bus' by devices[0] ('bus.2', "
                              "family dynamixel); 'ranger' (family acme-sensor) needs another")
