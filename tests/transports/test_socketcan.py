"""SocketCAN: detected and skipped with a reason where the kernel has no AF_CAN; the door's code runs on a
SEQPACKET socket pair standing in for the kernel; a real vcan0 tier runs where there is one."""

from __future__ import annotations

import socket

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import data_frame, error_frame
from hilbench.pytest_plugin import wait_until
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.socketcan import SocketCanDoor, af_can_status
from tests.transports.conftest import Recorder

AF_CAN_OK, AF_CAN_WHY = af_can_status()


def _vcan0_up() -> bool:
    if not AF_CAN_OK:
        return False
    try:
        SocketCanDoor.open("vcan0").close()
        return True
    except OSError:
        return False


def test_status_says_why_when_missing():
    if AF_CAN_OK:
        assert AF_CAN_WHY == ""
    else:
        assert "AF_CAN" in AF_CAN_WHY  # one line a person can act on
        with pytest.raises(OSError, match="AF_CAN"):
            SocketCanDoor.open("vcan0")


def test_the_door_on_a_kernel_stand_in():
    """A SEQPACKET pair carries whole 16-byte can_frame records like a CAN_RAW socket does."""
    bench_side, kernel = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    link = SocketCanDoor(bench_side, "vcan0")
    medium = CanMedium("can", 500_000)
    dev = Recorder()
    dport = medium.add_device(dev)

    class Port:  # a host port with just this door
        name = "can"
        doors = [link]

        def filenos(self):
            return link.filenos()

        def read_frames(self, now):
            return link.read_frames(now)

        def write_frame(self, t, source, frame):
            link.write_frame(t, source, frame)

        def flush(self):
            pass

        def deadline(self):
            return None

        def poll(self, now):
            return []

    medium.add_host(Port())
    medium.start()
    try:
        kernel.send(cf.pack(data_frame(0x18FF50E5, b"\x01\x02", extended=True)))
        kernel.send(b"\x00" * 5)  # not a frame: counted, skipped
        kernel.send(cf.pack(error_frame(cf.CAN_ERR_BUSOFF)))  # the kernel's own error report: not bus traffic
        kernel.send(cf.pack(data_frame(0x123, b"")))
        wait_until(lambda: len(dev.frames) == 2)
        assert dev.frames == [data_frame(0x18FF50E5, b"\x01\x02", extended=True), data_frame(0x123, b"")]
        assert link.malformed == 1
        dport.send(data_frame(0x7FF, b"\xaa" * 8))
        kernel.settimeout(5)
        assert cf.unpack(kernel.recv(64)) == data_frame(0x7FF, b"\xaa" * 8)
    finally:
        medium.close()
        link.close()
        kernel.close()


PROFILE = {
    "schema": 1,
    "endpoints": {"can": {"type": "can", "protocol": "can", "socketcan": "vcan0", "slcan": False}},
    "devices": [{"model": "stm32f767-rover-canopen", "name": "rover"}],
}


@pytest.mark.skipif(AF_CAN_OK, reason="the kernel has AF_CAN: the skip path is not taken here")
def test_bench_skips_the_socketcan_door_with_the_reason():
    with Bench(parse_profile(PROFILE, "socketcan.toml")) as bench:
        entry = bench.manifest()["endpoints"][0]
        assert entry["socketcan"] is None
        assert "AF_CAN" in entry["socketcan_error"]
        assert entry["socketcand"]["port"] > 0  # the other doors still open
        assert "SocketCAN skipped" in bench.endpoint().bus_kind.summary(bench.endpoint())


VCAN_WHY = AF_CAN_WHY or "AF_CAN works, but vcan0 is missing or down (modprobe vcan; ip link add dev vcan0 type vcan)"


@pytest.mark.skipif(not _vcan0_up(), reason=f"no usable vcan0 here: {VCAN_WHY}")
def test_real_vcan0_both_ways():
    import can

    with Bench(parse_profile(PROFILE, "socketcan.toml")) as bench:
        bus = can.Bus(interface="socketcan", channel="vcan0")
        try:
            bus.send(can.Message(arbitration_id=0x000, data=[0x01, 0x02], is_extended_id=False))  # NMT start
            seen = set()
            while 0x182 not in seen:  # TPDO1 flows once the node is OPERATIONAL
                msg = bus.recv(3)
                assert msg is not None
                seen.add(msg.arbitration_id)
            wait_until(lambda: bench.family("canopen").node(2).state_name == "OPERATIONAL")
        finally:
            bus.shutdown()
