"""CDR of the ROS 2 messages: the sheet's payloads (R6, X7, X8), alignment, both byte orders, garbage."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.protocols import cdr


def test_sheet_payloads() -> None:
    assert cdr.ros_type("std_msgs/UInt32").encode({"data": 1638}) == bytes.fromhex("66060000")
    assert cdr.ros_type("std_msgs/UInt32").encode({"data": 2457}) == bytes.fromhex("99090000")
    assert cdr.ros_type("std_msgs/String").encode({"data": "Hello"}) == bytes.fromhex("06000000 48656C6C6F00")
    assert cdr.ros_type("std_msgs/Int32").encode({"data": 42}) == bytes.fromhex("2A000000")


def test_names() -> None:
    t = cdr.ros_type("std_msgs::msg::dds_::String_")
    assert t.ros_name == "std_msgs/msg/String" and t.dds_name == "std_msgs::msg::dds_::String_"
    assert t.short_name == "std_msgs/String" and cdr.ros_type("std_msgs/msg/String") == t
    assert cdr.ros_type("nope/Nothing") is None


def test_alignment_of_doubles_after_a_string() -> None:
    t = cdr.ros_type("control_msgs/msg/MecanumDriveControllerState")
    raw = t.encode({"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "abc"},
                    "front_left_wheel_velocity": 1.5, "reference_velocity": {"angular": {"z": -0.25}}})
    # sec, nanosec, len 4, "abc\0" = 16 bytes: the first double starts at 16 (already 8-aligned).
    assert len(raw) == 16 + 4 * 8 + 6 * 8
    t2 = cdr.ros_type("std_msgs/Header")
    assert len(t2.encode({"frame_id": "ab"})) == 8 + 4 + 3
    value, err = t.try_decode(raw)
    assert err is None and value["front_left_wheel_velocity"] == 1.5
    assert value["reference_velocity"]["angular"]["z"] == -0.25 and value["header"]["frame_id"] == "abc"


def test_twist_and_pose2d_both_byte_orders() -> None:
    tw = cdr.ros_type("geometry_msgs/Twist")
    v = {"linear": {"x": 0.1, "y": -0.2, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.3}}
    for le in (True, False):
        assert tw.try_decode(tw.encode(v, le), le)[0] == v
    assert tw.encode(v, True) != tw.encode(v, False)


def test_sequences() -> None:
    t = cdr.ros_type("sensor_msgs/LaserScan")
    v, err = t.try_decode(t.encode({"ranges": [1.0, 2.5], "intensities": [7.0]}))
    assert err is None and v["ranges"] == [1.0, 2.5] and v["intensities"] == [7.0]


def test_garbage_is_an_error_value_not_an_exception() -> None:
    assert cdr.ros_type("std_msgs/String").try_decode(b"\xff\xff\xff\xff")[0] is None
    assert cdr.ros_type("geometry_msgs/Twist").try_decode(b"\x00" * 5)[1]


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(cdr.known_types()), st.binary(max_size=120))
def test_decoding_never_raises(name: str, data: bytes) -> None:
    cdr.ros_type(name).try_decode(data)


@pytest.mark.parametrize("x", [0.0, -1.25, 1e300])
def test_float64_round_trip(x: float) -> None:
    t = cdr.ros_type("std_msgs/Float64")
    assert math.isclose(t.try_decode(t.encode({"data": x}))[0]["data"], x)
