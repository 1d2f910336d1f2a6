"""The CAN tracker, fed frames with times: rates and jitter, heartbeats and misses, SDO, EMCY, load, garbage."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.monitor.can import INSTRUMENT
from hilbench.monitor.can.decoders import load_dbc
from hilbench.monitor.can.summary import summary
from hilbench.monitor.can.tracker import CanTracker
from hilbench.protocols import board_can as bc
from hilbench.protocols import can_frame as cf
from hilbench.protocols import canopen as co
from hilbench.protocols.can_frame import data_frame, error_frame


def feed(tr: CanTracker, t: float, frame, source: str = "bus") -> None:
    tr.feed(t, source, cf.pack(frame))


def test_rate_period_and_jitter():
    tr = CanTracker(baud=500_000)
    for i in range(101):
        feed(tr, i * 0.02 + (0.001 if i % 2 else 0.0), data_frame(0x182, bytes(8)))
    s = tr.ids[(0x182, False)]
    assert s.count == 101 and s.rate() == pytest.approx(50.0, rel=0.01)
    assert s.intervals.mean == pytest.approx(0.02, abs=1e-4)
    assert s.intervals.std == pytest.approx(0.001, rel=0.05)  # alternating 21/19 ms
    assert s.label == "TPDO1 node 2"
    rep = summary(tr, source="x")
    assert rep["ids"]["0x182"]["jitter_ms"] == pytest.approx(1.0, rel=0.05)
    bits = cf.frame_bits(data_frame(0x182, bytes(8)))
    assert rep["bus"]["mean_load"] == pytest.approx(101 * bits / (500_000 * 2.001), rel=0.01)
    json.dumps(rep)


def test_heartbeats_misses_and_loss():
    tr = CanTracker()
    node = 2
    feed(tr, 0.0, data_frame(0x702, b"\x00"))  # boot-up
    t = 0.1
    for _ in range(5):
        feed(tr, t, data_frame(0x702, b"\x7f"))
        t += 0.1
    feed(tr, t + 0.3, data_frame(0x702, b"\x05"))  # three missing, then operational
    n = tr.nodes[node]
    assert n.bootups == 1 and n.heartbeats == 6 and n.misses == 3
    assert n.state_name == "OPERATIONAL"
    last = t + 0.3
    tr.tick(last + 0.14)
    assert not n.lost  # within 1.5 periods
    tr.tick(last + 0.16)
    assert n.lost and n.state_name == "LOST" and n.losses == 1
    tr.tick(last + 0.5)
    assert n.losses == 1  # one loss per silence
    feed(tr, t + 1.0, data_frame(0x702, b"\x05"))
    assert not n.lost
    texts = [e.text for e in tr.events]
    assert any("3 heartbeat(s) missed" in x for x in texts) and any("PRE-OPERATIONAL -> OPERATIONAL" in x for x in texts)
    assert any("lost" in x for x in texts) and any("heard again" in x for x in texts)


def test_a_written_heartbeat_period_is_used_at_once():
    tr = CanTracker()
    for i in range(4):
        feed(tr, i * 1.0, data_frame(0x702, b"\x7f"))
    # SDO download 0x1017 = 100 at t = 3.5 and its confirmation
    feed(tr, 3.5, data_frame(0x602, co.expedited_download_request(0x1017, 0, (100).to_bytes(2, "little"))))
    feed(tr, 3.501, data_frame(0x582, co.initiate(0x60, 0x1017, 0)))
    for i in range(5):
        feed(tr, 3.6 + i * 0.1, data_frame(0x702, b"\x7f"))
    n = tr.nodes[2]
    assert n.configured_ms == 100 and n.misses == 0
    assert summary(tr)["nodes"]["2"]["heartbeat_period_ms"] == 100.0


def test_sdo_transfers_are_followed():
    tr = CanTracker()
    t = 0.0

    def req(data):
        nonlocal t
        t += 0.001
        feed(tr, t, data_frame(0x602, data))

    def resp(data):
        nonlocal t
        t += 0.001
        feed(tr, t, data_frame(0x582, data))

    req(co.initiate(0x40, 0x1018, 1))
    resp(co.expedited_upload_response(0x1018, 1, (0x48424E).to_bytes(4, "little")))
    # segmented upload of a 10-byte string
    req(co.initiate(0x40, 0x1008, 0))
    resp(co.initiate(0x41, 0x1008, 0, (10).to_bytes(4, "little")))
    req(bytes([0x60]) + bytes(7))
    resp(co.segment(0, b"hilbenc", False, server=True))
    req(bytes([0x70]) + bytes(7))
    resp(co.segment(1, b"h r", True, server=True))
    req(co.initiate(0x40, 0x5555, 0))
    resp(co.sdo_abort(0x5555, 0, co.ABORT_NO_OBJECT))
    rep = summary(tr)
    last = rep["sdo"]["last"]
    assert [x["index"] for x in last] == ["0x1018", "0x1008", "0x5555"]
    assert last[0]["value"] == 0x48424E and last[0]["kind"] == "expedited"
    assert last[1]["value"] == "hilbench r" and last[1]["kind"] == "segmented" and last[1]["size"] == 10
    assert last[2]["abort_text"] == "object does not exist in the object dictionary"
    assert rep["nodes"]["2"]["sdo"] == {"uploads": 2, "downloads": 0, "aborts": 1}


def test_emcy_nmt_and_error_frames():
    tr = CanTracker(baud=500_000)
    feed(tr, 0.0, data_frame(0x000, co.nmt_command(co.NMT_START, 2)))
    feed(tr, 0.1, data_frame(0x082, co.emcy_frame(0x8250, 0x11)))
    feed(tr, 0.2, error_frame(cf.CAN_ERR_PROT | cf.CAN_ERR_BUSERROR | cf.CAN_ERR_CNT, bytes([0, 0, 0, 0, 0, 0, 8, 0])))
    feed(tr, 0.3, error_frame(cf.CAN_ERR_BUSOFF))
    rep = summary(tr)
    assert rep["nodes"]["2"]["last_emcy"]["text"] == "RPDO timeout" and rep["nodes"]["2"]["emcy"] == 1
    assert rep["nmt_commands"] == 1 and rep["error_frames"]["total"] == 2
    assert rep["error_frames"]["classes"] == {"protocol": 1, "bus-error": 1, "counters": 1, "bus-off": 1}
    assert any("TEC 8" in line for line in rep["events"]["last"])
    assert any("NMT start -> node 2" in line for line in rep["events"]["last"])


def test_garbage_and_losses_never_raise():
    tr = CanTracker()
    tr.feed(0.0, "bus", b"\x01\x02\x03")
    tr.gap(0.1, "bus", 64)
    assert tr.dropped_bytes == 3 and tr.lost_frames == 4
    assert summary(tr)["frames"]["total"] == 0


ROVER_DBC = load_dbc("mecarover-can")


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 0x7FF), st.binary(max_size=8)), max_size=60))
def test_random_traffic_never_raises(frames):
    tr = CanTracker(baud=125_000, decoders=[ROVER_DBC])
    for i, (cid, data) in enumerate(frames):
        feed(tr, i * 0.001, data_frame(cid, data))
    tr.tick(1.0)
    tr.finish()
    json.dumps(summary(tr))


def test_dbc_decoding_and_decode_errors():
    tr = CanTracker(decoders=[ROVER_DBC])
    feed(tr, 0.0, data_frame(0x282, bc.encode("odometry", x=1.5, y=-0.25, theta=0.5)))
    feed(tr, 0.1, data_frame(0x282, bytes(5)))  # too short for its DBC message
    s = tr.ids[(0x282, False)]
    assert s.name == "OdometryPose_02"
    assert s.signals == pytest.approx({"x": 1.5, "y": -0.25, "theta": 0.5})  # the last good decode stays
    assert s.decode_errors == 1 and s.dlc_changes == 1


def test_instrument_options(tmp_path):
    import argparse

    parser = argparse.ArgumentParser()
    INSTRUMENT.add_arguments(parser)
    eds = tmp_path / "rover.eds"
    eds.write_text(bc.eds(bc.BoardCanConfig()), newline="")
    opts = INSTRUMENT.tracker_options(parser.parse_args(["--eds", f"{eds}:2"]))
    tr = INSTRUMENT.make_tracker(baud=500_000, timestamps=True, **opts)
    feed(tr, 0.0, data_frame(0x282, bc.encode("odometry", x=0.5)))
    assert tr.ids[(0x282, False)].signals["Odometry pose.x"] == pytest.approx(0.5)
    feed(tr, 0.1, data_frame(0x602, co.initiate(0x40, 0x1017, 0)))
    feed(tr, 0.2, data_frame(0x582, co.expedited_upload_response(0x1017, 0, b"\xe8\x03")))
    assert "Producer heartbeat time" in tr.events[-1].text
    from hilbench.errors import UsageError

    with pytest.raises(UsageError, match="FILE:NODE"):
        INSTRUMENT.tracker_options(parser.parse_args(["--eds", str(eds)]))
    with pytest.raises(UsageError, match="no such database"):
        INSTRUMENT.tracker_options(parser.parse_args(["--dbc", str(tmp_path / "none.dbc")]))
    assert INSTRUMENT.sniff(cf.pack(data_frame(1, b"")) * 4) > 0
    assert INSTRUMENT.sniff(b"\xff" * 64) == 0
