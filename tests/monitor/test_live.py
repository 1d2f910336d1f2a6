"""Live monitoring of an emulated bench while the official SDK drives it; recordings replay to the same summary."""

from __future__ import annotations

import io
import math

import dynamixel_sdk as sdk
import pytest

from hilbench.monitor import Monitor
from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.sources import FileSource, MediumSource

OK = sdk.COMM_SUCCESS


def caught_up(mon: Monitor, medium) -> bool:
    with mon.lock:
        return mon.tracker.bytes >= medium.stats.bytes


def open_sdk(ep):
    port = sdk.PortHandler(ep.path)
    assert port.openPort() and port.setBaudRate(ep.spec.baud)
    return port, sdk.PacketHandler(2.0)


def assert_same(a, b, path="summary"):
    """Equal, with floats allowed the nanosecond rounding of recorded times."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_same(x, y, f"{path}[{k}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert math.isclose(a, b, rel_tol=1e-6, abs_tol=2e-3), (path, a, b)
    else:
        assert a == b, (path, a, b)


@pytest.fixture
def watched(hilbench_bench, patient_sdk):
    """The Wolfgang bench paced at 2 Mbaud, watched by a monitor that also records."""
    bench = hilbench_bench("wolfgang", paced=True)
    ep = bench.endpoint()
    recording = io.BytesIO()
    recording.close = lambda: None  # keep the bytes after the monitor stops
    source = MediumSource(ep.medium)
    mon = Monitor(source, record=CaptureWriter(recording, baud=ep.spec.baud)).start()
    yield bench, ep, mon, recording
    mon.stop()


def test_live_monitor_agrees_with_what_the_sdk_did(watched):
    bench, ep, mon, recording = watched
    port, ph = open_sdk(ep)
    for dev_id in (1, 2, 3, 101):
        ph.ping(port, dev_id)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    ids = list(range(1, 21))
    for i in ids:
        reader.addParam(i)
    for _ in range(30):
        assert reader.txRxPacket() == OK
    bulk = sdk.GroupBulkRead(port, ph)
    bulk.addParam(1, 144, 2)
    bulk.addParam(2, 146, 1)
    assert bulk.txRxPacket() == OK
    assert ph.write1ByteTxRx(port, 5, 65, 1) == (OK, 0)
    assert ph.read1ByteTxRx(port, 5, 65) == (1, OK, 0)
    assert ph.readTxRx(port, 101, 36, 16)[1] == sdk.COMM_RX_TIMEOUT  # the silent foot sensor
    port.closePort()
    # the last Read's reply is missed once the reply timeout (0.1 s) passes on the monitor's own clock
    wait_until(lambda: caught_up(mon, ep.medium) and mon.tracker.unanswered == 1)
    live = mon.summary()
    packets = {k: v for k, v in live["packets"].items() if v}
    assert packets == {"ping": 4, "sync_read": 30, "bulk_read": 1, "write": 1, "read": 2,
                       "status": 3 + 30 * 20 + 2 + 1 + 1}
    assert live["crc_errors"] == 0 and live["bus"]["unanswered"] == 1  # the Read of 101 (its Ping is a scan)
    devs = live["devices"]
    assert devs["1"]["model_name"] == "MX-64(2.0)" and devs["1"]["replies"] == 32
    assert devs["5"]["values"]["led"]["raw"] == 1 and devs["5"]["values"]["led"]["how"] == "read"
    assert devs["2"]["values"]["present_temperature"]["unit"] == "C"
    assert devs["101"]["state"] == "unknown" and devs["101"]["never_answered"]
    # latencies (end of request to end of reply) are plausible: at least the reply's wire time (Return
    # Delay Time is 0 on this robot), and each later servo of the chain answers later
    reply_wire = 14 * 10 / 2_000_000
    assert reply_wire * 0.99 <= devs["3"]["latency_ms"]["min"] / 1000 < 0.005
    means = [devs[str(i)]["latency_ms"]["mean"] for i in ids]
    assert means == sorted(means) and means[-1] - means[0] > 19 * 15 * 10 / 2_000_000 * 1000 * 0.9
    cycle = live["bus"]["main_cycle"]
    assert cycle["count"] == 30 and cycle["rate_hz"] > 50 and cycle["jitter_ms"] is not None
    assert 0 < live["bus"]["load"] < 1
    # the recording, replayed, gives the same summary
    mon.stop()
    live = mon.summary()
    replay = Monitor(FileSource(io.BytesIO(recording.getvalue()))).start()
    replay.wait(10)
    again = replay.summary()
    for report in (live, again):
        report.pop("source")
    assert_same(live, again)
    with CaptureReader(io.BytesIO(recording.getvalue())) as r:
        assert {c.source for c in r} == {"dxl", "dxl-devices"}


def test_a_servo_that_drops_out_and_one_that_overheats(watched):
    bench, ep, mon, _ = watched
    port, ph = open_sdk(ep)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in (1, 2, 3):
        reader.addParam(i)
    assert reader.txRxPacket() == OK
    bench.device(2).vanish(bench.now(), math.inf)
    for _ in range(5):
        assert reader.txRxPacket() == sdk.COMM_RX_TIMEOUT
    wait_until(lambda: caught_up(mon, ep.medium) and mon.tracker.devices[2].state == "disconnected")
    bench.device(2).revive()
    bench.device(3).raise_hardware_error(0x04, bench.now())
    assert reader.txRxPacket() == OK
    assert ph.read1ByteTxRx(port, 3, 70)[0] == 0x04
    port.closePort()
    wait_until(lambda: caught_up(mon, ep.medium) and mon.tracker.devices[3].hardware_error == 0x04)
    devs = mon.summary()["devices"]
    assert devs["2"]["state"] == "connected" and devs["2"]["disconnects"] == 1 and devs["2"]["misses"] == 5
    assert devs["3"]["alert"] and devs["3"]["hardware_error_bits"] == ["overheating"]
    log = "\n".join(mon.summary()["errors"]["last"])
    for text in ("ID 2 disconnected: 5 consecutive missed replies", "ID 2 reconnected",
                 "ID 3 raised the Alert bit", "ID 3 hardware error: overheating"):
        assert text in log


def test_fast_sync_read_on_x_series_servos(hilbench_bench, patient_sdk):
    bench = hilbench_bench("arm")
    ep = bench.endpoint()
    mon = Monitor(MediumSource(ep.medium)).start()
    try:
        port, ph = open_sdk(ep)
        reader = sdk.GroupSyncRead(port, ph, 132, 4)
        for i in (1, 2, 3):
            reader.addParam(i)
        assert reader.fastSyncRead() == OK
        port.closePort()
        wait_until(lambda: caught_up(mon, ep.medium))
        report = mon.summary()
    finally:
        mon.stop()
    assert report["packets"]["fast_sync_read"] == 1 and report["packets"]["status"] == 1
    for i in ("1", "2", "3"):
        assert report["devices"][i]["replies"] == 1 and report["devices"][i]["misses"] == 0
        assert report["devices"][i]["values"]["present_position"]["how"] == "read"


def test_a_reply_delayed_on_its_way_to_the_monitor_is_not_a_miss():
    """A busy machine delivers bytes to the monitor late (a bench's line thread, a TCP tap): the quiet
    source's clock must not declare a reply missed that is still on its way."""
    import time

    from hilbench.protocols import dynamixel as dxl
    from hilbench.transports.sources import PushSource

    src = PushSource("stalled", baud=2_000_000)
    src.live = True
    with Monitor(src) as mon:
        t0 = time.monotonic()
        src.push(t0, "host", dxl.instruction_packet(1, dxl.Instruction.READ, b"\x84\x00\x04\x00"))
        # The reply was on the wire 0.3 ms later, but reaches the monitor 0.3 s late; meanwhile the
        # monitor's quiet-source ticks run (reply timeout 0.1 s).
        wait_until(lambda: time.monotonic() > t0 + 0.3, timeout=2)
        src.push(t0 + 0.0003, "device", dxl.status_packet(1, 0, (2048).to_bytes(4, "little")))
        wait_until(lambda: mon.summary()["packets"]["status"] == 1)
        dev = mon.summary()["devices"]["1"]
    assert (dev["replies"], dev["misses"], dev["state"]) == (1, 0, "connected")
    assert dev["values"]["present_position"]["raw"] == 2048
