"""The rover board's CAN layout: construct layouts, the DBC cantools reads, the EDS canopen imports, all agreeing."""

from __future__ import annotations

import canopen
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen_od as od
from hilbench.protocols.checksums import crc8_sae_j1850

CFG = bc.BoardCanConfig(node_id=2)


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_string(bc.dbc([("rover", CFG)]), "dbc")


@pytest.fixture(scope="module")
def eds_od(tmp_path_factory):
    path = tmp_path_factory.mktemp("eds") / "rover.eds"
    path.write_text(bc.eds(CFG), newline="")
    return canopen.import_od(str(path), 2)


def test_crc8_check_value():
    assert crc8_sae_j1850(b"123456789") == 0x4B  # the catalogue's check value for CRC-8/SAE-J1850


def test_setpoint_vector():
    data = bc.build_setpoint(0.3, -0.1, 0.5, 7)
    assert data[:7] == bytes.fromhex("2C019CFFF40107")  # 300 mm/s, -100 mm/s, 500 mrad/s, counter 7
    assert data[7] == crc8_sae_j1850(data[:7])
    assert bc.check_setpoint(data) == bc.Setpoint(0.3, -0.1, 0.5, 7)
    bad = data[:7] + bytes([data[7] ^ 1])
    assert bc.check_setpoint(bad).kind == "checksum"
    assert bc.check_setpoint(data[:6]).kind == "length"


def test_dbc_names_units_and_ids(db):
    names = {m.name: m for m in db.messages}
    sp = names["VelocitySetpoint_02"]
    assert sp.frame_id == 0x202 and [s.name for s in sp.signals][:3] == ["vx", "vy", "omega"]
    assert {s.name: s.unit for s in sp.signals}["vx"] == "m/s"
    assert {s.name: s.unit for s in sp.signals}["omega"] == "rad/s"
    odo = names["OdometryPose_02"]
    assert odo.frame_id == 0x282 and [s.name for s in odo.signals] == ["x", "y", "theta"]
    assert [s.unit for s in odo.signals] == ["m", "m", "rad"]
    assert names["Heartbeat_02"].frame_id == 0x702 and names["EMCY_02"].frame_id == 0x082
    assert names["SDO_Request_02"].frame_id == 0x602 and names["SDO_Response_02"].frame_id == 0x582
    assert names["NMT"].frame_id == 0 and names["WheelEncoders_02"].cycle_time == 20


def test_cantools_decodes_what_the_layout_builds(db):
    data = bc.encode("odometry", x=1.234, y=-0.5, theta=-3.1)
    assert db.decode_message(0x282, data) == pytest.approx({"x": 1.234, "y": -0.5, "theta": -3.1})
    heartbeat = db.decode_message(0x702, b"\x7f")
    assert str(heartbeat["nmt_state"]) == "PRE_OPERATIONAL"
    emcy = db.decode_message(0x082, bytes.fromhex("5082110000000000"))
    assert str(emcy["error_code"]) == "RPDO timeout"
    status = db.decode_message(0x482, bc.encode("status", mode=1, battery=24.6, counter=3))
    assert str(status["mode"]) == "driving" and status["battery"] == pytest.approx(24.6)


@settings(max_examples=50)
@given(st.sampled_from([p for p in bc.PDOS]), st.data())
def test_layouts_and_dbc_agree(pdo, data):
    db = cantools.database.load_string(bc.dbc([("rover", CFG)]), "dbc")
    raw = {}
    for s in pdo.signals:
        lo, hi = s.raw_range
        raw[s.name] = data.draw(st.integers(lo, hi))
    frame = bc.LAYOUTS[pdo.key].build(raw)
    decoded = db.decode_message(pdo.cob_id(2), frame, decode_choices=False, scaling=False)
    assert decoded == raw


def test_canopen_imports_the_eds(eds_od):
    assert eds_od[0x1018][1].default == CFG.vendor_id
    assert eds_od[0x1017].default == 1000 and eds_od[0x1017].access_type == "rw"
    assert eds_od[0x1800][1].default == 0x182  # $NODEID resolved
    assert eds_od[0x1400][5].default == 150
    assert eds_od[0x2002]["x"].data_type == od.INTEGER24 and eds_od[0x2002]["x"].factor == pytest.approx(0.001)
    assert eds_od.device_information.nr_of_TXPDO == 4 and 500_000 in eds_od.device_information.allowed_baudrates


def test_eds_pdo_mappings_describe_the_frames(eds_od):
    for pdo in bc.PDOS:
        mapping = eds_od[pdo.map_index]
        count = mapping[0].default
        assert count == len(pdo.signals)
        total = 0
        for i, signal in enumerate(pdo.signals, 1):
            word = mapping[i].default
            index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            assert (index, sub) == signal.od and bits == signal.bits
            var = eds_od[index] if sub == 0 and index == 0x1001 else eds_od[index][sub]
            assert len(var) == bits and var.pdo_mappable
            total += bits
        assert total == 8 * pdo.length


def test_dummy_usage_section_is_complete():
    text = bc.eds(CFG)
    section = text.split("[DummyUsage]")[1].split("\r\n\r\n")[0]
    assert [f"Dummy{i:04d}=0" for i in range(1, 8)] == section.strip().split("\r\n")


def test_object_dictionary_values():
    values = od.variables(bc.object_dictionary(CFG))
    assert od.resolve(values[(0x1200, 1)].default, 2) == 0x602
    assert values[(0x1008, 0)].data_type == od.VISIBLE_STRING
    assert od.encode(od.INTEGER24, -2) == b"\xfe\xff\xff" and od.decode(od.INTEGER24, b"\xfe\xff\xff") == -2
    with pytest.raises(ValueError):
        od.decode(od.UNSIGNED16, b"\x01")
