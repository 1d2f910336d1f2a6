"""The real Wolfgang capture replayed through the monitor gives what the data README and spec §8.3/§8.4 say."""

from __future__ import annotations

import pytest

from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.monitor.servo_bus.devices import CONNECTED, DISCONNECTED
from hilbench.monitor.servo_bus.summary import summary

MX64 = {1, 2, 3, 4, 5, 6, 19, 20}
MX106 = {8, 9, 11, 13, 14, 15, 16, 17, 18}
FOOT_READ = bytes.fromhex("FF FF FD 00 65 07 00 02 24 00 10 00 62 2C")  # vector 40


def replay(data: bytes, **kw) -> BusTracker:
    tr = BusTracker(timestamps=False, **kw)
    for i in range(0, len(data), 65536):
        tr.feed(0.0, "bus", data[i : i + 65536])
    tr.finish()
    return tr


@pytest.fixture(scope="module")
def tracked(wolfgang_capture) -> BusTracker:
    return replay(wolfgang_capture)


def test_device_set_models_and_firmware(tracked):
    devs = tracked.devices
    assert set(devs) == set(range(1, 21)) | {101}
    assert {i for i, d in devs.items() if d.model_name == "MX-64(2.0)"} == MX64
    assert {i for i, d in devs.items() if d.model_name == "MX-106(2.0)"} == MX106
    # 7, 10 and 12: their ping replies fail the CRC; 101 never answers at all
    assert {i for i, d in devs.items() if d.model is None} == {7, 10, 12, 101}
    assert {i for i, d in devs.items() if d.firmware == 42} == {11, 16, 18}
    models = tracked.models()
    assert [d.id for d in models["<unknown>"]] == [7, 10, 12, 101]


def test_the_foot_sensor_never_answers_and_is_disconnected(tracked):
    foot = tracked.devices[101]
    assert foot.never_answered and foot.state == DISCONNECTED
    assert foot.misses == 889 and tracked.replies(foot) == 0 and foot.requests == 889
    assert all(d.state == CONNECTED for i, d in tracked.devices.items() if i != 101)


def test_the_foot_sensor_is_disconnected_from_its_fifth_unanswered_read(wolfgang_capture):
    fifth = -1
    for _ in range(5):
        fifth = wolfgang_capture.index(FOOT_READ, fifth + 1)
    sixth = wolfgang_capture.index(FOOT_READ, fifth + 1)
    before = replay(wolfgang_capture[:fifth])  # four reads, each closed by the next instruction
    assert (before.devices[101].misses, before.devices[101].state) == (4, "unknown")
    after = replay(wolfgang_capture[:sixth])
    assert (after.devices[101].misses, after.devices[101].state) == (5, DISCONNECTED)


def test_the_thesis_flicker_of_servos_18_19_20(tracked):
    # "IDs 18, 19 and 20 each touching 5 consecutive misses once before recovering" (spec §8.4)
    flicker = {i for i, d in tracked.devices.items() if d.disconnects}
    assert flicker == {18, 19, 20, 101}
    assert all(tracked.devices[i].disconnects == 1 for i in (18, 19, 20))
    assert tracked.log.counts["reconnected"] == 3


def test_packets_and_crc_failures_as_the_sheet_counts_them(wolfgang_capture, tracked):
    counts = tracked.packet_counts()
    assert {k: v for k, v in counts.items() if v} == {
        "status": 21_069, "sync_read": 1_057, "read": 889, "sync_write": 426, "write": 17, "ping": 20}
    # default LENGTH cap (1024, the SDK's): 856 CRC mismatches + 96 impossible LENGTHs
    assert tracked.crc_errors == 952
    # the sheet frames every candidate by LENGTH: 948 CRC failures, 4 running past the end of the file
    sheet = replay(wolfgang_capture, max_length=0xFFFF)
    assert sheet.crc_errors == 948 and sheet.problems()["truncated"] == 4
    assert sheet.log.counts["crc"] + sheet.log.counts["bad_length"] == 948


def test_main_cycle_and_observed_values(tracked):
    main = tracked.main_cycle()
    assert (main.name, main.ranges[0], main.ids, main.count) == ("sync_read", (132, 4), tuple(range(1, 21)), 1038)
    for dev_id in range(1, 21):
        values = {f.field.key: f for f in tracked.devices[dev_id].fields(observed_only=True)}
        assert 1104 <= values["present_position"].raw <= 2969
        assert 13.5 <= values["present_input_voltage"].value <= 14.3
        assert 33 <= values["present_temperature"].raw <= 41
        assert values["hardware_error_status"].raw == 0
        assert values["status_return_level"].how == "written"  # the re-initialisation block
    report = summary(tracked)
    assert report["devices"]["101"]["never_answered"] and report["bus"]["main_cycle"]["count"] == 1038
