"""The servo-bus sheet's vectors (servo_buses.md §1.4, §2.4, §4.4, §7): Protocol 1.0, the USB2AX, Feetech, XL-320/XL330."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols import feetech as ft
from hilbench.protocols.control_table import Field
from hilbench.protocols.dynamixel_models import find_model
from hilbench.protocols.feetech_models import STS3215


def h(s: str) -> bytes:
    return bytes.fromhex(s)


P1_VECTORS = [  # (bytes, id, code, params)
    ("FF FF 01 02 01 FB", 1, 0x01, ""),
    ("FF FF 01 04 02 00 02 F6", 1, 0x02, "00 02"),
    ("FF FF 01 04 00 0C 00 EE", 1, 0x00, "0C 00"),  # status: model 12 (AX-12A)
    ("FF FF 01 04 00 1D 00 DD", 1, 0x00, "1D 00"),  # MX-28
    ("FF FF 01 04 00 36 01 C3", 1, 0x00, "36 01"),  # MX-64
    ("FF FF 01 04 00 40 01 B9", 1, 0x00, "40 01"),  # MX-106
    ("FF FF 01 05 03 1E 00 02 D6", 1, 0x03, "1E 00 02"),
    ("FF FF 01 05 04 1E F4 01 E2", 1, 0x04, "1E F4 01"),
    ("FF FF FE 02 05 FA", 0xFE, 0x05, ""),
    ("FF FF 00 02 06 F7", 0, 0x06, ""),
    ("FF FF FE 0E 83 1E 04 00 10 00 50 01 01 20 02 60 03 67", 0xFE, 0x83, "1E 04 00 10 00 50 01 01 20 02 60 03"),
    ("FF FF FE 09 92 00 02 01 1E 02 02 24 1D", 0xFE, 0x92, "00 02 01 1E 02 02 24"),
    ("FF FF 01 02 24 D8", 1, 0x24, ""),
    ("FF FF 25 04 02 06 04 CA", 37, 0x02, "06 04"),
    ("FF FF 25 04 02 05 01 CE", 37, 0x02, "05 01"),
    ("FF FF FE 12 83 1E 06 0B 00 08 00 00 FF 03 0C 00 08 00 00 FF 03 1D", 0xFE, 0x83,
     "1E 06 0B 00 08 00 00 FF 03 0C 00 08 00 00 FF 03"),
    # the USB2AX (§2.4)
    ("FF FF FE 06 84 24 06 0B 0C 36", 0xFE, 0x84, "24 06 0B 0C"),
    ("FF FF FD 0E 00 00 08 00 00 00 00 FF FF FF FF FF FF F2", 0xFD, 0x00, "00 08 00 00 00 00 FF FF FF FF FF FF"),
    ("FF FF FE 06 84 2B 01 24 25 02", 0xFE, 0x84, "2B 01 24 25"),
    ("FF FF FD 04 00 23 25 B6", 0xFD, 0x00, "23 25"),
    ("FF FF FD 02 08 F8", 0xFD, 0x08, ""),
    # Feetech (§4.4): the same framing
    ("FF FF 01 04 02 03 02 F3", 1, 0x02, "03 02"),
    ("FF FF 01 04 00 09 03 EE", 1, 0x00, "09 03"),
    ("FF FF 01 04 02 00 01 F7", 1, 0x02, "00 01"),
    ("FF FF 01 05 03 2A 00 08 C4", 1, 0x03, "2A 00 08"),
    ("FF FF 01 04 03 28 01 CE", 1, 0x03, "28 01"),
    ("FF FF FE 0A 82 38 02 01 02 03 04 05 06 26", 0xFE, 0x82, "38 02 01 02 03 04 05 06"),
    ("FF FF 01 04 00 00 08 F2", 1, 0x00, "00 08"),
    ("FF FF 02 04 00 05 80 74", 2, 0x00, "05 80"),
    ("FF FF FE 0A 83 2A 02 01 00 08 02 00 04 39", 0xFE, 0x83, "2A 02 01 00 08 02 00 04"),
    ("FF FF FE 02 01 FE", 0xFE, 0x01, ""),
    ("FF FF 01 04 00 05 04 F1", 1, 0x00, "05 04"),
]


@pytest.mark.parametrize("hexbytes,pid,code,params", P1_VECTORS)
def test_protocol1_framed_vectors(hexbytes, pid, code, params):
    raw, params = h(hexbytes), h(params)
    assert p1.build(pid, code, params) == raw  # the construct definition
    assert p1.frame(pid, code, params) == raw  # the emulators' fast path agrees
    assert ft.frame(pid, code, params) == raw  # Feetech's is the same framing
    (pkt,) = p1.Decoder1().feed(raw)
    assert (pkt.id, pkt.code, pkt.params) == (pid, code, params)


def test_named_layouts_of_the_usb2ax_and_feetech_instructions():
    assert p1.build_instruction(0xFE, p1.Instruction1.SYNC_READ, address=36, length=6, ids=[11, 12]) == \
        h("FF FF FE 06 84 24 06 0B 0C 36")
    assert ft.build_instruction(0xFE, ft.Instruction.SYNC_READ, address=56, length=2, ids=[1, 2, 3, 4, 5, 6]) == \
        h("FF FF FE 0A 82 38 02 01 02 03 04 05 06 26")
    assert ft.build_instruction(0xFE, ft.Instruction.SYNC_WRITE, address=42, length=2,
                                entries=[{"id": 1, "data": h("0008")}, {"id": 2, "data": h("0004")}]) == \
        h("FF FF FE 0A 83 2A 02 01 00 08 02 00 04 39")


P2_VECTORS = [  # §7: XL-320 and XL330 ping statuses (the P2 codec builds them)
    ("FF FF FD 00 01 07 00 55 00 5E 01 1D 1F 47", 1, 0, "5E 01 1D"),
    ("FF FF FD 00 03 07 00 55 00 B0 04 2E E1 74", 3, 0, "B0 04 2E"),
    ("FF FF FD 00 01 07 00 55 00 A6 04 2E D6 D5", 1, 0, "A6 04 2E"),
    ("FF FF FD 00 01 0A 00 55 00 00 02 00 00 00 00 53 D3", 1, 0, "00 02 00 00 00 00"),
]


@pytest.mark.parametrize("hexbytes,pid,err,data", P2_VECTORS)
def test_protocol2_status_vectors_of_the_new_models(hexbytes, pid, err, data):
    assert dxl.status_packet(pid, err, h(data)) == h(hexbytes)


def test_model_numbers_as_the_firmware_reports_them():
    assert {name: find_model(name, protocol=1).number for name in ("AX-12A", "AX-18A", "MX-28", "MX-64", "MX-106")} \
        == {"AX-12A": 12, "AX-18A": 18, "MX-28": 29, "MX-64": 310, "MX-106": 320}
    assert {name: find_model(name).number for name in ("XL-320", "XL330-M288", "XL330-M077", "XC330-T288",
                                                        "XC330-T181", "MX-28")} == \
        {"XL-320": 350, "XL330-M288": 1200, "XL330-M077": 1190, "XC330-T288": 1220, "XC330-T181": 1210,
         "MX-28": 30}
    assert STS3215.number == 777 and STS3215.defaults()[3:5] == h("09 03")


def test_sign_magnitude_fields_as_feetech_and_lerobot_encode_them():
    offset = STS3215.field_named("homing_offset")
    assert offset.encode(-1000) == (0x800 | 1000).to_bytes(2, "little")
    assert offset.decode(h("E8 0B")) == -1000
    assert STS3215.field_named("present_position").decode(h("05 80")) == -5  # the sheet's 0x8005
    assert ft.sign_magnitude(-5, 15) == 0x8005 and ft.from_sign_magnitude(0x8005, 15) == -5
    load = find_model("AX-12A").field_named("present_load")
    assert load.decode((1024 | 300).to_bytes(2, "little")) == -300  # bit 10 set: clockwise


@given(st.integers(-2047, 2047))
def test_sign_magnitude_round_trip(value):
    f = Field(31, 2, "Offset", sign_bit=11)
    assert f.decode(f.encode(value)) == value
    big = Field(42, 2, "Goal", big_endian=True)
    assert big.encode(abs(value)) == abs(value).to_bytes(2, "big")
