"""Generic bench parts: host ports (the one-client TCP port), line events reaching devices, endpoint
attributes families declare."""

from __future__ import annotations

import socket
import time

import pytest

from hilbench.bench import Bench
from hilbench.pytest_plugin import wait_until
from hilbench.transports.port_state import BreakCondition, ModemSignals, SerialSettings
from hilbench.transports.serial_medium import SerialMedium
from hilbench.transports.tcp import TcpPort


class Recorder:
    """A device that records what reaches it."""

    def __init__(self, name: str = "rec") -> None:
        self.name = name
        self.data = b""
        self.events: list = []

    def on_bytes(self, data: bytes, t: float, baud) -> None:
        self.data += data

    def on_port_event(self, event, t: float) -> None:
        self.events.append(event)


def test_tcp_port_serves_one_client_and_refuses_a_second():
    port = TcpPort("scanner")
    medium = SerialMedium("scanner", 115_200)
    rec = Recorder()
    dport = medium.add_device(rec)
    medium.add_host(port)
    medium.start()
    try:
        host, number = port.address
        assert host == "127.0.0.1" and port.describe() == {"path": f"tcp://127.0.0.1:{number}", "host": host,
                                                            "port": number}
        a = socket.create_connection((host, number), timeout=5)
        a.sendall(b"VV\n")
        wait_until(lambda: rec.data == b"VV\n")
        b = socket.create_connection((host, number), timeout=5)
        assert b.recv(10) == b""  # closed at once: the device is busy with the first client
        assert port.refused == 1
        dport.transmit(b"reply")
        a.settimeout(5)
        assert a.recv(10) == b"reply"
        a.close()
        wait_until(lambda: port.client is None)
        c = socket.create_connection((host, number), timeout=5)  # the next client is served
        c.sendall(b"II\n")
        wait_until(lambda: rec.data.endswith(b"II\n"))
        c.close()
        b.close()
    finally:
        medium.close()
        port.close()


def test_line_events_of_a_host_port_reach_the_devices_and_device_lines_reach_the_host():
    with Bench("arm") as bench:
        ep = bench.endpoint()
        rec = Recorder()
        dport = ep.medium.add_device(rec)
        lines = ep.port.port_state
        assert (lines.dtr, lines.rts) == (True, True)  # as a host's open() leaves them
        lines.host_sets(dtr=False)
        lines.host_break(True, 0.25)
        lines.host_settings(SerialSettings(1_000_000, 8, "N", 1))
        lines.host_sets(dtr=False)  # no change, no event
        wait_until(lambda: len(rec.events) == 3)
        assert rec.events == [ModemSignals(False, True), BreakCondition(True, 0.25), SerialSettings(1_000_000, 8, "N", 1)]
        dport.set_lines(dsr=True, cts=True)
        assert lines.device_lines() == {"cts": True, "dsr": True, "ri": False, "cd": False}


def test_endpoints_and_families_have_explicit_typed_accessors():
    from hilbench.bench.family import FamilyAccess
    from hilbench.errors import UsageError
    from hilbench.families.dynamixel import DynamixelServos

    with Bench("arm") as bench:
        ep = bench.endpoint()
        assert ep.bus is not None and ep.bus_kind.protocol == "dynamixel" and ep.port.kind == "pty"
        assert bench.device(1) is ep.bus.servo(1)
        assert bench.family_of(next(iter(bench.devices))).name == "dynamixel"
        servos = bench.family("dynamixel")
        assert isinstance(servos, DynamixelServos) and DynamixelServos.of(bench) is servos
        assert servos.servo(1) is bench.device(1) and servos.bus() is ep.bus
        assert servos.device("arm.1") is bench.device(1) and list(servos.devices()) == list(bench.devices)
        with pytest.raises(KeyError, match="bench has servos .* of family dynamixel; name one"):
            servos.device()
        with pytest.raises(KeyError, match="no servo at ID 42"):
            servos.servo(42)
        with pytest.raises(UsageError, match="bench 'arm' has no device of family 'stm32-rover' .families: dynamixel."):
            bench.family("stm32-rover")
        with pytest.raises(UsageError, match="unknown device family 'nope'"):
            bench.family("nope")
        # nothing is grown through __getattr__ any more: a typo is an AttributeError, not another family's None
        for owner, name in ((bench, "board"), (ep, "board"), (ep, "pty"), (bench.profile, "servos"),
                            (ep.spec, "chain_policy")):
            with pytest.raises(AttributeError):
                getattr(owner, name)
        for cls in (type(bench), type(ep), type(bench.profile), type(ep.spec), FamilyAccess):
            assert "__getattr__" not in vars(cls)


def test_manifest_names_the_bench_and_describes_ports_and_devices():
    with Bench("mecarover-udp") as bench:
        m = bench.manifest()
        (ep,) = m["endpoints"]
        assert m["name"] == "mecarover-udp"
        assert ep["type"] == "udp" and ep["path"].startswith("udp://127.0.0.1:") and ep["paced"] is True
        assert ep["address"] == [ep["host"], ep["port"]]
        (dev,) = m["devices"]
        assert dev["protocol"] == "vel2d" and dev["output"] == "binary"
    t0 = time.monotonic()
    assert time.monotonic() - t0 < 5
