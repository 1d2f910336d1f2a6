"""The Protocol 1.0 and Feetech monitors: pairing, the USB2AX reply split, misses, models, sniffing, garbage."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench import registry
from hilbench.monitor.dynamixel1 import INSTRUMENT as DXL1
from hilbench.monitor.feetech import INSTRUMENT as FEETECH
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols import feetech as ft


def feed(tracker, packets, t0=0.0, step=0.001):
    t = t0
    for source, raw in packets:
        t += step
        tracker.feed(t, source, raw)
    return t


def usb2ax_cycle(ids, address, length, data_by_id):
    request = p1.build_instruction(0xFE, p1.Instruction1.SYNC_READ, address=address, length=length, ids=ids)
    data = b"".join(data_by_id.get(i, b"\xff" * length) for i in ids)
    return [("host", request), ("bus", p1.frame(0xFD, 0, data))]


def test_usb2ax_reply_is_split_per_servo_and_ff_counts_as_a_miss():
    tr = DXL1.make_tracker(baud=1_000_000, timestamps=True)
    traffic = [("host", p1.frame(11, 2, bytes((0, 2)))), ("bus", p1.frame(11, 0, (29).to_bytes(2, "little"))),
               ("host", p1.frame(12, 2, bytes((0, 2)))), ("bus", p1.frame(12, 0, (310).to_bytes(2, "little")))]
    t = feed(tr, traffic)
    for _ in range(10):
        t = feed(tr, usb2ax_cycle([11, 12, 13], 36, 6, {11: bytes(6), 12: b"\x00\x08\x00\x00\x00\x00"}), t, 0.005)
    tr.finish()
    report = DXL1.summary(tr, source="test", timestamps="measured")
    devs = report["devices"]
    assert devs["11"]["model_name"] == "MX-28(1.0)" and devs["12"]["model_name"] == "MX-64(1.0)"
    assert devs["12"]["values"]["present_position"]["raw"] == 2048
    assert devs["13"]["misses"] == 10 and devs["13"]["state"] == "disconnected"
    assert devs["11"]["misses"] == 0 and devs["11"]["state"] == "connected"
    cycle = report["bus"]["main_cycle"]
    assert (cycle["instruction"], cycle["address"], cycle["length"], cycle["ids"], cycle["count"]) == \
        ("sync_read", 36, 6, [11, 12, 13], 10)
    assert report["packets"]["sync_read"] == 10 and report["protocol"] == "dynamixel1"


def test_protocol1_statuses_errors_and_status_return_level():
    tr = DXL1.make_tracker(baud=1_000_000, timestamps=True)
    feed(tr, [("host", p1.frame(1, 3, bytes((30, 0, 2)))), ("bus", p1.frame(1, 0x02)),  # angle-limit error
              ("host", p1.frame(2, 3, bytes((16, 1)))), ("bus", p1.frame(2, 0)),  # SRL 1 from now on
              ("host", p1.frame(2, 3, bytes((25, 1)))),  # owes nothing now
              ("host", p1.frame(3, 1)),  # a scan for a device that is not there
              ("host", p1.frame(1, 1)), ("bus", p1.frame(1, 0))])
    tr.finish()
    assert tr.devices[1].error_statuses == 1 and "angle limit" in tr.log.lines(10)[0]
    assert tr.devices[2].status_return_level == 1 and tr.devices[2].misses == 0
    assert 3 not in tr.devices or tr.devices[3].misses == 0
    assert tr.unanswered == 0


def test_feetech_sync_read_replies_one_by_one_and_the_model_at_address_3():
    tr = FEETECH.make_tracker(baud=1_000_000, timestamps=True)
    traffic = []
    for i in (1, 2):
        traffic += [("host", ft.frame(i, 1)), ("bus", ft.frame(i, 0)),
                    ("host", ft.frame(i, 2, bytes((3, 2)))), ("bus", ft.frame(i, 0, bytes((9, 3))))]
    t = feed(tr, traffic)
    for _ in range(5):
        request = ft.build_instruction(0xFE, ft.Instruction.SYNC_READ, address=56, length=2, ids=[1, 2])
        t = feed(tr, [("host", request), ("bus", ft.frame(1, 0, bytes((0, 8)))), ("bus", ft.frame(2, 0, b"\x05\x80"))],
                 t, 0.002)
    tr.finish()
    report = FEETECH.summary(tr, source="t", timestamps="measured")
    assert report["devices"]["1"]["model_name"] == "STS3215"
    assert report["devices"]["2"]["values"]["present_position"]["raw"] == -5  # sign-magnitude
    assert report["bus"]["main_cycle"]["count"] == 5 and report["bus"]["unanswered"] == 0
    assert report["devices"]["1"]["replies"] == 7


def test_sniffing_tells_protocol_2_protocol_1_and_feetech_apart():
    p2 = (dxl.instruction_packet(1, dxl.Instruction.READ, bytes((132, 0, 4, 0))) + dxl.status_packet(1, 0, bytes(4))) * 3
    pypot = b"".join(raw for _ in range(3) for _, raw in usb2ax_cycle([11, 12], 36, 6, {11: bytes(6), 12: bytes(6)}))
    lerobot = b"".join(ft.build_instruction(0xFE, ft.Instruction.SYNC_READ, address=56, length=2, ids=[1, 2])
                       + ft.frame(1, 0, bytes(2)) + ft.frame(2, 0, bytes(2)) for _ in range(3))

    def best(data):
        scores = {i.protocol: i.sniff(data) for i in registry.instruments.values() if i.verb == "monitor"}
        return max(scores, key=scores.get)

    assert best(p2) == "dynamixel"
    assert best(pypot) == "dynamixel1"
    assert best(lerobot) == "feetech"


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.lists(st.integers(1, 40), max_size=12))
def test_garbage_never_raises(blob, cuts):
    for inst in (DXL1, FEETECH):
        tr = inst.make_tracker(baud=None, timestamps=True)
        pos, t = 0, 0.0
        for c in cuts:
            t += 0.01
            tr.feed(t, "x", blob[pos : pos + c])
            pos += c
        tr.feed(t + 0.01, "x", blob[pos:])
        tr.finish()
        inst.summary(tr, source="x", timestamps="measured")


def test_dashboard_and_recorder_replay_on_a_protocol1_bus(tmp_path):
    from rich.console import Console

    from hilbench.dashboard.app import Dashboard
    from hilbench.monitor import Monitor
    from hilbench.transports.capture_file import CaptureWriter
    from hilbench.transports.sources import open_source

    tr = DXL1.make_tracker(baud=1_000_000, timestamps=True)
    t = feed(tr, [("host", p1.frame(11, 2, bytes((0, 2)))), ("bus", p1.frame(11, 0, (29).to_bytes(2, "little")))])
    for _ in range(5):
        t = feed(tr, usb2ax_cycle([11, 12], 36, 6, {11: bytes(6)}), t, 0.02)
    console = Console(width=100, record=True)
    dash = Dashboard(tr, source="test")
    for view in ("devices", "models", "details", "log"):
        dash.view = view
        console.print(dash.render(100, 24))
    screen = console.export_text()
    assert "MX-28(1.0)" in screen  # the model overview names the 1.0 table
    assert "DISC" in screen and "ID 12 disconnected" in screen  # a servo the USB2AX filled with 0xFF
    assert "cycle 25 Hz" in screen  # the USB2AX SYNC_READ every 40 ms is the main cycle
    # a capture recorded with the protocol's name replays through the same instrument
    path = tmp_path / "p1.hbcap"
    with CaptureWriter(path, protocol="dynamixel1", baud=1_000_000) as rec:
        tt = 0.0
        for source, raw in usb2ax_cycle([11, 12], 36, 6, {11: bytes(6), 12: bytes(6)}) * 3:
            tt += 0.01
            rec.write(tt, source, raw)
    with Monitor(open_source(str(path))) as mon:
        mon.wait(5)
        report = mon.summary()
    assert report["protocol"] == "dynamixel1" and sorted(report["devices"]) == ["11", "12"]
