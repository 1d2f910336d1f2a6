"""The bus tracker, fed bytes only: pairing, liveness rules, values with units, errors (spec sheet vectors)."""

from __future__ import annotations

from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.monitor.servo_bus.devices import CONNECTED, DISCONNECTED, UNKNOWN
from hilbench.monitor.servo_bus.summary import summary
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814


def h(s: str) -> bytes:
    return bytes.fromhex(s)


def inst(pid: int, code: int, params: bytes = b"") -> bytes:
    return dxl.instruction_packet_unstuffed(pid, code, params)


def status(pid: int, data: bytes = b"", err: int = 0) -> bytes:
    return dxl.status_packet(pid, err, data)


def u32(v: int) -> bytes:
    return v.to_bytes(4, "little")


class Bus:
    """Feeds packets one per chunk at increasing times (1 ms apart unless given)."""

    def __init__(self, **kw) -> None:
        self.tr = BusTracker(baud=1_000_000, **kw)
        self.t = 100.0

    def send(self, *packets: bytes, dt: float = 0.001, source: str = "bus") -> BusTracker:
        for p in packets:
            self.t += dt
            self.tr.feed(self.t, source, p)
        return self.tr


def sync_read(ids, address=132, length=4) -> bytes:
    return inst(0xFE, I.SYNC_READ, address.to_bytes(2, "little") + length.to_bytes(2, "little") + bytes(ids))


def test_spec_sync_read_and_bulk_read_vectors_give_values_with_units():
    bus = Bus()
    tr = bus.send(
        h("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"),  # v21 Sync Read 132/4 of 1, 2
        h("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),  # v10 ID 1 = 166
        h("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"),  # v22 ID 2 = 2079
        h("FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"),  # v24 Bulk Read (1,144,2) (2,146,1)
        h("FF FF FD 00 01 06 00 55 00 77 00 C3 69"),  # v25 11.9 V
        h("FF FF FD 00 02 05 00 55 00 24 8B A9"),  # v26 36 C
    )
    tr.finish()
    assert tr.unanswered == 0 and tr.unexpected == 0
    one = {f.field.key: f for f in tr.devices[1].fields(observed_only=True)}
    two = {f.field.key: f for f in tr.devices[2].fields(observed_only=True)}
    assert one["present_position"].raw == 166 and one["present_position"].how == "read"
    assert one["present_position"].text() == "14.59 deg (166)"
    assert one["present_input_voltage"].text() == "11.9 V (119)"
    assert two["present_position"].value == 2079 * 360 / 4096
    assert two["present_temperature"].text() == "36 C"
    assert tr.packet_counts()["status"] == 4 and tr.packet_counts()["bulk_read"] == 1
    assert {tr.replies(tr.devices[i]) for i in (1, 2)} == {2}
    assert tr.devices[1].requests == 2
    lat = tr.devices[2].latency()
    assert lat["n"] == 2 and abs(lat["min"] - 0.002) < 1e-9  # each reply 1 ms after the previous packet


def test_fast_sync_and_fast_bulk_read_replies_are_split_with_the_request_lengths():
    bus = Bus()
    tr = bus.send(
        h("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"),  # v28 Fast Sync Read 132/4 of 3, 7, 4
        h("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E"),
        h("FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D"),  # v30 Fast Bulk Read
        h("FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1"),  # v31
    )
    tr.finish()
    values = {i: {f.field.key: f.raw for f in tr.devices[i].fields(observed_only=True)} for i in (3, 4, 7)}
    assert values[3]["present_position"] == 166
    assert values[7]["present_position"] == 2079 and values[7]["present_pwm"] == 421
    assert values[4]["present_position"] == 1023 and values[4]["present_temperature"] == 31
    assert tr.unanswered == 0 and all(d.state == CONNECTED for d in tr.devices.values())
    assert tr.packet_counts()["fast_sync_read"] == 1 and tr.packet_counts()["status"] == 2


def test_a_truncated_fast_reply_counts_the_missing_slices_as_missed():
    bus = Bus()
    req = inst(0xFE, I.FAST_SYNC_READ, h("84000400 030704"))
    reply = dxl.build_fast_reply([(3, 0, u32(166))])
    tr = bus.send(req, reply)
    tr.finish()
    assert tr.devices[3].misses == 0 and tr.devices[7].misses == 1 and tr.devices[4].misses == 1


def test_ping_replies_identify_models_and_firmware():
    bus = Bus()
    tr = bus.send(
        inst(1, I.PING), h("FF FF FD 00 01 07 00 55 00 37 01 29 90 C0"),  # MX-64(2.0), fw 41
        inst(8, I.PING), h("FF FF FD 00 08 07 00 55 00 41 01 29 1D D6"),  # MX-106(2.0)
        inst(9, I.PING),  # nobody there: looking is not a failure
        inst(0xFE, I.PING), status(2, h("060426")), status(3, h("FC0334")),  # broadcast: XM430-W210, -W350
    )
    tr.finish()
    assert (tr.devices[1].model_name, tr.devices[1].firmware) == ("MX-64(2.0)", 41)
    assert tr.devices[8].model_name == "MX-106(2.0)"
    assert (tr.devices[2].model, tr.devices[3].model_name, tr.devices[3].firmware) == (1030, "XM430-W350", 52)
    assert 9 not in tr.devices and tr.unanswered == 0
    fields = {f.field.key: f for f in tr.devices[1].fields()}
    assert fields["model_number"].how == "read" and fields["id"].raw == 1  # what a ping tells
    assert fields["velocity_limit"].how == "default" and fields["velocity_limit"].raw == 435  # MX-64 default
    assert set(tr.models()) == {"MX-64(2.0)", "MX-106(2.0)", "XM430-W210", "XM430-W350"}


def test_model_number_read_identifies_a_device():
    tr = Bus().send(inst(5, I.READ, h("00000300")), status(5, h("FC0334")))
    assert (tr.devices[5].model_name, tr.devices[5].model_from) == ("XM430-W350", "read")


def test_fifth_consecutive_miss_disconnects_and_a_reply_reconnects():
    bus = Bus(silence=None)
    read = inst(1, I.READ, h("84000400"))
    bus.send(read, status(1, u32(2048)))
    for n in range(1, 6):
        bus.send(read)
        bus.send(inst(0xFE, I.SYNC_WRITE, h("74000400") + b"\x01" + u32(2000)))  # closes the read
        dev = bus.tr.devices[1]
        assert dev.consecutive == n
        assert dev.state == (DISCONNECTED if n == 5 else CONNECTED), n
    bus.send(read, status(1, u32(2100)))
    dev = bus.tr.devices[1]
    assert dev.state == CONNECTED and dev.disconnects == 1 and dev.misses == 5
    kinds = [e.kind for e in bus.tr.log.entries]
    assert kinds == ["missed_reply", "disconnected", "reconnected"]
    assert bus.tr.log.format(bus.tr.log.entries[1]).endswith("error: ID 1 disconnected: 5 consecutive missed replies")
    assert bus.tr.replies(dev) == 2


def test_a_device_that_never_answers_is_shown_as_such():
    bus = Bus(silence=None)
    for _ in range(6):
        bus.send(inst(101, I.READ, h("24001000")))
    bus.tr.finish()
    dev = bus.tr.devices[101]
    assert dev.state == DISCONNECTED and dev.never_answered and dev.misses == 6
    assert "never answered" in bus.tr.log.entries[-1].text
    report = summary(bus.tr)
    assert report["devices"]["101"]["never_answered"] is True
    assert report["devices"]["101"]["state"] == "disconnected"


def test_silence_and_reply_timeout_disconnect_a_device_without_more_traffic():
    bus = Bus(silence=0.5, reply_timeout=0.1)
    bus.send(inst(3, I.READ, h("84000400")), status(3, u32(1)))
    bus.send(inst(3, I.READ, h("84000400")))  # never answered, and the master goes quiet
    tr = bus.tr
    tr.tick(bus.t + 0.2)  # the reply timeout counts the miss
    assert tr.devices[3].misses == 1 and tr.devices[3].state == CONNECTED
    tr.tick(bus.t + 0.7)
    assert tr.devices[3].state == DISCONNECTED
    assert "silent for" in tr.log.entries[-1].text


def test_error_status_alert_and_hardware_error_bits():
    bus = Bus()
    tr = bus.send(
        inst(1, I.READ, h("00FF0100")), h("FF FF FD 00 01 04 00 55 07 B0 8C"),  # v35 Access Error
        inst(1, I.READ, h("46000100")), h("FF FF FD 00 01 05 00 55 80 24 82 A1"),  # v37 Alert + HW error 0x24
    )
    dev = tr.devices[1]
    assert dev.error_statuses == 1 and dev.alert and dev.hardware_error == 0x24
    assert dev.hardware_error_bits == ["overheating", "overload"]
    messages = [e.text for e in tr.log.entries]
    assert "ID 1 status packet has an error: access error (reply to read)" in messages
    assert any("raised the Alert bit" in m for m in messages)
    assert "ID 1 hardware error: overheating, overload" in messages
    assert dev.state == CONNECTED  # an error status still proves the device is there
    (hw,) = [f for f in dev.fields(observed_only=True) if f.field.address == 70]
    assert hw.text() == "36 (overheating, overload)"


def test_unicast_write_is_remembered_only_when_the_device_accepts_it():
    bus = Bus()
    bus.send(inst(1, I.PING), status(1, h("FC0334")))  # XM430-W350
    bus.send(inst(1, I.WRITE, h("7400") + u32(512)), status(1))  # v11: accepted
    bus.send(inst(1, I.WRITE, h("7400") + u32(9999)), status(1, err=6))  # Data Limit Error: refused
    goal = {f.field.key: f for f in bus.tr.devices[1].fields()}["goal_position"]
    assert (goal.raw, goal.how) == (512, "written")
    # Sync Write and Bulk Write data is taken from the instruction itself
    bus.send(h("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87"))  # v23
    bus.send(h("FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68"))  # v27
    one = {f.field.key: f for f in bus.tr.devices[1].fields()}
    assert one["goal_position"].raw == 150 and one["max_voltage_limit"].text() == "16 V (160)"
    two = {f.field.key: f.raw for f in bus.tr.devices[2].fields(observed_only=True)}
    assert two == {"goal_position": 170, "temperature_limit": 80}


def test_status_return_level_one_means_writes_owe_no_reply():
    bus = Bus(silence=None)
    bus.send(inst(4, I.WRITE, h("4400 01")), status(4))  # Status Return Level <- 1, still answered
    for _ in range(6):
        bus.send(inst(4, I.WRITE, h("7400") + u32(100)))  # no replies now, and none owed
    dev = bus.tr.devices[4]
    assert dev.status_return_level == 1 and dev.misses == 0 and dev.state == CONNECTED


def test_statuses_nobody_asked_for_are_logged_once_per_burst():
    bus = Bus()
    tr = bus.send(status(5, u32(1)), status(6, u32(2)), inst(0xFE, I.ACTION))
    assert tr.unexpected == 2
    assert tr.log.entries[-1].text == "2 status packets without a matching request (ID 5, 6)"
    assert tr.devices[5].state == CONNECTED


def test_crc_failures_are_counted_and_attributed():
    bus = Bus()
    good = status(2, u32(7))
    bad = good[:-1] + bytes([good[-1] ^ 0xFF])
    tr = bus.send(sync_read([1, 2]), status(1, u32(5)), bad)
    tr.finish()
    assert tr.crc_errors == 1 and tr.devices[2].crc_errors == 1 and tr.devices[2].misses == 1
    assert tr.log.counts["crc"] == 1
    assert "mismatched checksum (15 bytes, status from ID 2?)" in [e.text for e in tr.log.entries]


def test_main_cycle_rate_and_jitter():
    bus = Bus()
    for k in range(50):
        dt = 0.010 if k % 2 else 0.012
        bus.send(sync_read([1, 2]), dt=dt)
        bus.send(status(1, u32(k)), status(2, u32(k)), dt=0.0001)
        bus.send(inst(1, I.READ, h("90000300")), status(1, h("780023")), dt=0.0001)  # a read that is not the cycle
    report = summary(bus.tr)
    cycle = report["bus"]["main_cycle"]
    assert cycle["instruction"] == "sync_read" and cycle["ids"] == [1, 2] and cycle["count"] == 50
    assert abs(cycle["rate_hz"] - 1 / 0.0114) < 1  # mean period 11 ms + the 4 replies' 0.4 ms
    assert 0.9 < cycle["jitter_ms"] < 1.1
    assert report["bus"]["load"] > 0 and report["bus"]["packets_per_s"]["status"] > 0


def test_reboot_returns_ram_items_to_their_defaults():
    bus = Bus()
    bus.send(inst(1, I.PING), status(1, h("FC0334")))
    bus.send(inst(1, I.WRITE, h("4100 01")), status(1))  # LED on
    bus.send(inst(1, I.WRITE, h("0B00 01")), status(1))  # Operating Mode 1 (EEPROM)
    bus.send(inst(1, I.REBOOT), status(1))
    fields = {f.field.key: f for f in bus.tr.devices[1].fields()}
    assert fields["led"].how == "default" and fields["operating_mode"].raw == 1


def test_unknown_devices_keep_their_observed_ranges():
    tr = Bus().send(sync_read([9]), status(9, u32(3000)))
    (pos,) = tr.devices[9].fields()
    assert tr.devices[9].model_name == "<unknown>" and pos.field.name == "Present Position" and pos.raw == 3000


def test_untimed_input_skips_time_figures():
    tr = BusTracker(timestamps=False)
    for _ in range(3):
        tr.feed(0.0, "bus", sync_read([1]) + status(1, u32(1)))
    tr.finish()
    report = summary(tr)
    assert report["devices"]["1"]["latency_ms"] is None and report["bus"]["bytes_per_s"] is None
    assert report["bus"]["main_cycle"]["count"] == 3 and report["bus"]["main_cycle"]["rate_hz"] is None
    assert tr.log.format(tr.log.entries[0]).startswith("[--:--.---]") if tr.log.entries else True


def test_summary_shape_uses_the_sheets_instruction_names():
    tr = Bus().send(inst(1, I.PING), status(1, h("370129")))
    report = summary(tr, source="x")
    assert set(report) >= {"packets", "crc_errors", "devices", "bus", "errors", "models"}
    assert set(report["packets"]) >= {"ping", "read", "write", "reg_write", "action", "factory_reset", "reboot",
                                      "clear", "backup", "status", "sync_read", "sync_write", "fast_sync_read",
                                      "bulk_read", "bulk_write", "fast_bulk_read"}
    dev = report["devices"]["1"]
    assert (dev["model"], dev["model_name"], dev["firmware"], dev["state"]) == (311, "MX-64(2.0)", 41, "connected")
    assert report["models"]["MX-64(2.0)"]["connected"] == 1


def test_state_before_any_reply_is_unknown():
    tr = Bus().send(sync_read([4]))
    assert tr.devices[4].state == UNKNOWN


def test_input_lost_by_a_slow_monitor_is_logged_and_the_decoder_restarts():
    bus = Bus()
    read = inst(1, I.READ, h("84000400"))
    bus.send(read)
    bus.tr.feed(bus.t, "bus", status(1, u32(5))[:6])  # half a reply, then the rest was lost
    bus.tr.gap(bus.t + 0.001, "bus", 9)
    bus.send(read, status(1, u32(6)))
    tr = bus.tr
    assert tr.dropped_input == 9 and tr.log.counts["dropped_input"] == 1 and tr.problems()["truncated"] == 1
    assert {f.field.key: f.raw for f in tr.devices[1].fields(observed_only=True)}["present_position"] == 6


def test_many_different_ranges_stay_bounded_and_keep_their_values():
    bus = Bus()
    for address in range(0, 600, 2):  # 300 distinct 2-byte reads of one device
        bus.send(inst(1, I.READ, address.to_bytes(2, "little") + h("0200")), status(1, address.to_bytes(2, "little")))
    dev = bus.tr.devices[1]
    assert len(dev.obs) <= 256
    mem, how, _ = dev.table()
    assert all(mem[a] | mem[a + 1] << 8 == a for a in range(0, 600, 2)) and all(how[:600])


def test_error_log_lists_the_newest_entries_in_time_order():
    from hilbench.monitor.errorlog import ErrorLog

    log = ErrorLog()
    log.t0 = 0.0
    for t, text in ((2.641, "a"), (2.642, "b"), (2.638, "late detection of an earlier miss"), (2.650, "c")):
        log.add(t, "missed_reply", text)
    assert [e.t for e in log.newest(3)] == [2.650, 2.642, 2.638]  # the three detected last, by time
    assert log.lines(4)[-1] == "[+00:02.638] error: late detection of an earlier miss"


def test_the_xl320s_hardware_error_status_is_read_at_its_own_address():
    """The XL-320 keeps Hardware Error Status at 50 and Status Return Level at 17 (the X series: 70, 68)."""
    bus = Bus()
    tr = bus.send(
        inst(6, I.PING), status(6, bytes((0x5E, 0x01, 0x1E))),  # model 350: the XL-320
        inst(6, I.READ, h("11000100")), status(6, b"\x01"),  # Status Return Level 1
        inst(6, I.READ, h("32000100")), status(6, b"\x04", err=0x80),  # Alert, Hardware Error Status: overheating
    )
    dev = tr.devices[6]
    assert dev.model_name == "XL-320" and dev.status_return_level == 1
    assert dev.hardware_error == 0x04 and dev.hardware_error_bits == ["overheating"]
    assert "ID 6 hardware error: overheating" in [e.text for e in tr.log.entries]
