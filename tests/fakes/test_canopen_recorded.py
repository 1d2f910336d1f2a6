"""A recorded CANopen node (``model = "recorded-node"``) driven by the unmodified canopen package over python-can."""

from __future__ import annotations

import threading
import time

import canopen
import pytest

from hilbench.bench import Bench
from hilbench.bench.checks import ProfileError
from hilbench.bench.profile import parse_profile
from hilbench.protocols import canopen as co
from hilbench.pytest_plugin import wait_until

canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0


def profile(**device) -> dict:
    return {
        "schema": 1,
        "endpoints": {"can": {"type": "can", "protocol": "can", "bitrate": 500_000, "paced": True, "slcan": False}},
        "devices": [{"model": "recorded-node", "name": "node5", "node_id": 5, "heartbeat_ms": 100,
                     "tpdos": [{"cob_id": 0x185, "period_ms": 20, "data": "01 02 03"},
                               {"cob_id": 0x285, "period_ms": 50, "data": "aa bb"}],
                     "objects": [{"index": 0x1018, "subindex": 1, "data": "4e 42 48 00"},
                                 {"index": 0x2000, "subindex": 0, "data": "2a", "access": "rw"},
                                 {"index": 0x2100, "subindex": 0, "data": "68 69 6c 62 65 6e 63 68"}],
                     **device}],
    }


@pytest.fixture
def node():
    benches, nets = [], []

    def start(**device):
        bench = Bench(parse_profile(profile(**device), "test.toml")).start()
        benches.append(bench)
        net = canopen.Network(bench.endpoint("can").port.open_bus())
        net.connect()
        nets.append(net)
        remote = canopen.RemoteNode(5, canopen.ObjectDictionary())
        net.add_node(remote)
        remote.sdo.RESPONSE_TIMEOUT = 1.0
        wait_until(lambda: bench.family("canopen").node(5).state != co.BOOTUP)
        return bench, net, remote

    yield start
    for net in nets:
        net.disconnect()
    for bench in benches:
        bench.stop()


def _frames(net, seconds: float) -> dict[int, list[float]]:
    seen: dict[int, list[float]] = {}
    lock = threading.Lock()

    def on(can_id, data, timestamp):
        with lock:
            seen.setdefault(can_id, []).append(time.monotonic())

    for cob in (0x185, 0x285, 0x705):
        net.subscribe(cob, on)
    time.sleep(seconds)
    for cob in (0x185, 0x285, 0x705):
        net.unsubscribe(cob, on)
    return seen


def _period(times: list[float]) -> float:
    return (times[-1] - times[0]) / (len(times) - 1)


def test_pdos_flow_in_operational_at_their_periods(node):
    bench, net, remote = node()
    quiet = _frames(net, 0.3)
    assert 0x185 not in quiet and 0x285 not in quiet  # PRE-OPERATIONAL: heartbeats only
    assert abs(_period(quiet[0x705]) - 0.1) < 0.02
    remote.nmt.send_command(co.NMT_START)
    wait_until(lambda: bench.family("canopen").node(5).state == co.OPERATIONAL)
    seen = _frames(net, 0.6)
    assert abs(_period(seen[0x185]) - 0.02) < 0.004 and abs(_period(seen[0x285]) - 0.05) < 0.01
    got = []
    net.subscribe(0x285, lambda can_id, data, t: got.append(bytes(data)))
    wait_until(lambda: got)
    assert got[0] == bytes([0xAA, 0xBB])
    remote.nmt.send_command(co.NMT_STOP)
    wait_until(lambda: bench.family("canopen").node(5).state == co.STOPPED)
    sent = bench.family("canopen").node(5).pdos_sent
    time.sleep(0.1)
    assert bench.family("canopen").node(5).pdos_sent == sent  # stopped: no PDOs


def test_sdo_uploads_answer_the_recorded_bytes(node):
    _bench, _net, remote = node()
    assert remote.sdo.upload(0x1018, 1) == bytes.fromhex("4e424800")
    assert remote.sdo.upload(0x2100, 0) == b"hilbench"  # eight bytes: a segmented upload
    assert remote.sdo.upload(0x1017, 0) == (100).to_bytes(2, "little")  # the heartbeat it was given
    assert remote.sdo.upload(0x1018, 2) == bytes(4)  # identity members the capture did not show: 0
    remote.sdo.download(0x2000, 0, b"\x07")  # the host wrote it in the capture: writable
    assert remote.sdo.upload(0x2000, 0) == b"\x07"
    with pytest.raises(canopen.SdoAbortedError) as ro:
        remote.sdo.download(0x1018, 1, bytes(4))
    assert ro.value.code == co.ABORT_READ_ONLY
    with pytest.raises(canopen.SdoAbortedError) as gone:
        remote.sdo.upload(0x3000, 0)
    assert gone.value.code == co.ABORT_NO_OBJECT


def test_fault_knobs(node):
    bench, net, remote = node(faults={"sdo_abort": 0x08000000})
    with pytest.raises(canopen.SdoAbortedError):
        remote.sdo.upload(0x1018, 1)
    assert bench.family("canopen").node(5).set_faults(sdo_abort=0) == {"heartbeat_stop": False, "silent": False, "sdo_abort": 0}
    assert remote.sdo.upload(0x1018, 1) == bytes.fromhex("4e424800")
    with pytest.raises(ValueError, match="unknown fault knob 'battery_v'"):
        bench.family("canopen").node(5).set_faults(battery_v=20)


@pytest.mark.parametrize(("change", "message"), [
    ({"tpdos": [{"cob_id": 0x185, "period_ms": 0, "data": ""}]},
     r"devices\[0\]\.tpdos\[0\]\.period_ms: expected an integer 1\.\.65535, got 0"),
    ({"tpdos": [{"cob_id": 0x185, "period_ms": 10, "data": "zz"}]}, r"tpdos\[0\]\.data: expected hex bytes"),
    ({"tpdos": [{"cob_id": 0x185, "period_ms": 10, "data": "00" * 9}]}, r"tpdos\[0\]\.data: at most 8 bytes"),
    ({"objects": [{"index": 0x2000, "data": "01"}, {"index": 0x2000, "data": "02"}]},
     r"objects\[1\]\.index: 0x2000 sub 0 is listed twice"),
    ({"objects": [{"index": 0x2000, "data": ""}]}, r"objects\[0\]\.data: expected at least one byte"),
    ({"setpoint_timeout_ms": 100}, r"devices\[0\]\.setpoint_timeout_ms: a recorded-node has none"),
])
def test_profile_errors_name_the_key(change, message):
    with pytest.raises(ProfileError, match=message):
        parse_profile(profile(**change), "test.toml")


def test_rover_boards_take_no_recorded_keys():
    data = profile()
    data["devices"][0] = {"model": "stm32f767-rover-canopen", "node_id": 2, "tpdos": []}
    with pytest.raises(ProfileError, match=r'devices\[0\]\.tpdos: only for model = "recorded-node" nodes'):
        parse_profile(data, "test.toml")
