"""The ``[world]`` table and the devices' ``body``: bundled rover profiles have the body ``rover``; mistakes are
one line naming the file, the key and what was expected; the older ``[scene]`` still loads; the control
channel answers ``world`` and ``world_place``."""

from __future__ import annotations

import math

import pytest

from hilbench.bench import Bench
from hilbench.bench.control import ControlClient, ControlError
from hilbench.bench.profile import ProfileError, load_profile

ROVER = """
schema = 1
[endpoints.rover]
type = "pty"
protocol = "vel2d"
[[devices]]
model = "stm32f767-rover"
name = "rover"
endpoint = "rover"
preset = "freertos-1000"
{device}
{world}
"""
BODY = """
[[world.bodies]]
name = "rover"
shape = "box"
size = [0.5, 0.4]
"""


def write(tmp_path, device: str = 'body = "rover"', world: str = BODY):
    p = tmp_path / "bench.toml"
    p.write_text(ROVER.format(device=device, world=world))
    return p


@pytest.mark.parametrize("name", ["mecarover", "mecarover-can", "mecarover-udp", "mecarover-micro-ros",
                                  "mecarover-thesis"])
def test_every_rover_profile_has_the_body_rover_driven_by_its_board(name):
    prof = load_profile(name)
    assert prof.world.body_names() == ["rover"]
    board = next(d for d in prof.devices if d.name == "rover")
    assert board.body == "rover"
    if name in ("mecarover", "mecarover-can"):
        lidar = next(d for d in prof.devices if d.model == "rplidar-a1")
        assert (lidar.body, lidar.x, lidar.y) == ("rover", 0.1, 0.0)


def test_arena_has_two_rovers_each_with_board_and_lms200():
    prof = load_profile("arena")
    assert prof.world.body_names() == ["r1", "r2"]
    on = {d.name: (d.model, d.body) for d in prof.devices}
    assert on == {"r1": ("stm32f767-rover", "r1"), "r1-lms": ("lms200", "r1"),
                  "r2": ("stm32f767-rover", "r2"), "r2-lms": ("lms200", "r2")}
    assert len(prof.world.scene.movers) == 1


@pytest.mark.parametrize(("device", "world", "key", "expected"), [
    ('body = "rvr"', BODY, "devices[0].body", "expected the name of a world body (rover), got 'rvr'"),
    ('body = "rover"', "", "devices[0].body", "expected the name of a world body (none: add [[world.bodies]]"),
    ("body = 3", BODY, "devices[0].body", "got 3"),
    ('body = "rover"\nodometry = { slip = 2.0 }', BODY, "devices[0].odometry.slip", "expected a number 0.0..0.9"),
    ('body = "rover"\nodometry = { wobble = 1 }', BODY, "devices[0].odometry.wobble", "unknown key"),
    ("", BODY.replace('shape = "box"\n', 'shape = "triangle"\n'), "world.bodies[0].shape",
     "expected one of box, circle"),
    ("", BODY.replace("size = [0.5, 0.4]\n", ""), "world.bodies[0]", 'expected size = [length, width]'),
    ("", BODY.replace("size = [0.5, 0.4]", "size = [0.5, -1]"), "world.bodies[0].size", "expected sizes 0..100 m"),
    ("", BODY + "pose = { x = 1, heading = 90, theta = 1 }\n", "world.bodies[0].pose",
     "expected theta (radians) or heading (degrees), not both"),
    ("", BODY + 'colour = "red"\n', "world.bodies[0].colour", "unknown key"),
    ("", BODY + BODY, "world.bodies[1].name", "body name 'rover' is used twice"),
    ("", "[world]\nstep_hz = 5\n" + BODY, "world.step_hz", "expected a number 20.0..2000.0, got 5"),
    ("", "[world]\nwalls = 3\n", "world.walls", "expected an array of polylines"),
    ("", "[world]\nwalls = [[[0, 0], [1, 1]]]\n[scene]\nwalls = [[[0, 0], [1, 1]]]\n", "scene",
     "the world's geometry is given in [world] already"),
])
def test_world_mistakes_are_one_line_naming_file_key_and_expectation(tmp_path, device, world, key, expected):
    path = write(tmp_path, device, world)
    with pytest.raises(ProfileError) as err:
        load_profile(path)
    text = str(err.value)
    assert "\n" not in text and text.startswith(f"{path}: {key}: ") and expected in text, text


def test_the_older_scene_table_is_the_world_s_geometry(tmp_path):
    path = write(tmp_path, world="[scene]\nwalls = [[[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]]\n" + BODY)
    prof = load_profile(path)
    with Bench(prof) as bench:
        assert len(bench.world.world.scene.segments) == 4
        assert bench.manifest()["devices"][0]["body"] == "rover"


def test_overrides_reach_world_keys():
    prof = load_profile("arena", {"world.bodies.0.pose.x": -2.0})
    assert prof.world.bodies[0].x == -2.0


def client_address(client: ControlClient) -> str:
    host, port = client.address
    return f"{host}:{port}"


def test_control_channel_answers_world_and_places_bodies(tmp_path):
    with Bench("arena") as bench:
        client = ControlClient(bench.serve_control().address_text)
        doc = client.world(geometry=True)
        assert set(doc["bodies"]) == {"r1", "r2"}
        assert doc["bodies"]["r2"]["theta"] == pytest.approx(math.pi)
        assert doc["devices"]["r1-lms"] == {"body": "r1", "mount": {"x": 0.15, "y": 0.0, "theta": 0.0},
                                            "pose": {"x": pytest.approx(-1.35), "y": 0.0, "theta": 0.0}}
        assert len(doc["geometry"]["segments"]) == 4 + 4 + 4  # walls, the bench, the crate
        # Each rover's scanner sees the other: straight ahead (the LMS's 90-degree beam) the other's near face.
        assert bench.devices["r2-lms"].truth_range(90.0) == pytest.approx(2.6)
        assert bench.devices["r1-lms"].truth_range(90.0) == pytest.approx(2.6)
        client.place("r1", 0.5, -1.0, 0.25)
        assert bench.world.body("r1").pose == pytest.approx((0.5, -1.0, 0.25))
        # r2's scanner sees r1 where it was put: its 90-degree beam, west along y = 0, misses it now.
        assert bench.devices["r2-lms"].truth_range(90.0) == pytest.approx(1.35 + 4.0)
        for bad, says in (({"body": "r9"}, "body: expected one of r1, r2"), ({"body": "r1", "x": "a"}, "x: expected"),
                          ({"body": "r1", "theta": float("nan")}, "theta: expected")):
            with pytest.raises(ControlError, match=says) as err:
                client.call("world_place", **bad)
            assert err.value.exit_code == 2
        with pytest.raises(ControlError, match="since: expected"):
            client.call("world", since="yesterday")
        hist = client.world(since=doc["time"])["history"]
        assert hist["poses"] and set(hist["poses"][-1]["bodies"]) == {"r1", "r2"}
        # hilbench world's pictures: a PNG, and the terminal's top-down view.
        from hilbench.cli import main
        from hilbench.cli.world import render_text

        png = tmp_path / "world.png"
        assert main(["world", "--control", client_address(client), "--png", str(png)]) == 0
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        rows = [r for r in render_text(client.world(geometry=True, scans=True)) if r.strip()]
        assert rows[0].strip().startswith("#") and rows[0].strip().endswith("#")  # the north wall
        assert sum(r.count("1") for r in rows) > 4 and sum(r.count("2") for r in rows) > 4  # r1 and r2


def test_a_scanner_mount_pose_may_give_theta_in_radians(tmp_path):
    lidar = ('\n[endpoints.lidar]\ntype = "pty"\nprotocol = "rplidar"\n[[devices]]\nmodel = "rplidar-a1"\n'
             'endpoint = "lidar"\nbody = "rover"\n')
    path = write(tmp_path, world=BODY + lidar + "pose = { x = 0.1, theta = 1.5707963267948966 }\n")
    spec = next(d for d in load_profile(path).devices if d.model == "rplidar-a1")
    assert spec.heading == pytest.approx(90.0) and spec.body == "rover"
    path = write(tmp_path, world=BODY + lidar + "pose = { heading = 90, theta = 1.0 }\n")
    with pytest.raises(ProfileError, match=r"devices\[1\].pose: expected heading \(degrees\) or theta"):
        load_profile(path)


def test_any_device_sits_on_a_body_at_its_mount_pose(tmp_path):
    """``body`` and ``pose`` are core device keys: a servo (a family with no pose of its own) rides the rover at
    its mount pose; the manifest says where it is mounted and the world where it is now."""
    path = tmp_path / "arm.toml"
    path.write_text('schema = 1\n[endpoints.arm]\ntype = "pty"\nprotocol = "dynamixel"\n'
                    '[[devices]]\nmodel = "XL430-W250"\nid = 1\nendpoint = "arm"\nbody = "rover"\n'
                    'pose = { x = 0.2, y = 0.1, heading = 90 }\n'
                    '[[world.bodies]]\nname = "rover"\nshape = "circle"\nradius = 0.3\n')
    with Bench(load_profile(path)) as bench:
        entry = bench.manifest()["devices"][0]
        assert entry["body"] == "rover" and entry["pose"] == pytest.approx({"x": 0.2, "y": 0.1, "theta": math.pi / 2})
        bench.world.place("rover", 1.0, 0.0, math.pi / 2)
        now = bench.world.devices()["arm.1"]
        assert now["mount"] == entry["pose"]
        assert (now["pose"]["x"], now["pose"]["y"], now["pose"]["theta"]) == pytest.approx((0.9, 0.2, math.pi))
    path.write_text(path.read_text().replace("pose = { x = 0.2, y = 0.1, heading = 90 }\n",
                                             "pose = { x = 0.2, z = 0.1 }\n"))
    with pytest.raises(ProfileError, match=r"devices\[0\].pose.z: unknown key"):
        load_profile(path)


@pytest.mark.hilbench_profile("arena")
def test_the_pytest_fixture_hands_over_the_world(bench, hilbench_world, tmp_path):
    """``hilbench_world`` is the ``bench`` fixture's world: the truth, placing bodies, the recorder."""
    from hilbench.fakes.world import read_record
    from hilbench.pytest_plugin import wait_until

    assert hilbench_world is bench.world and hilbench_world.bodies == ["r1", "r2"]
    rec = hilbench_world.record(str(tmp_path / "truth.jsonl"))
    hilbench_world.place("r2", 0.0, 1.0, -math.pi / 2)
    assert hilbench_world.body("r2").pose == pytest.approx((0.0, 1.0, -math.pi / 2))
    assert bench.devices["r1-lms"].truth_range(90.0) == pytest.approx(4.0 + 1.35)  # r2 is out of r1's way...
    # ...and r2, at (0, 0.85) looking south, sees r1's east face x = -1.25 on its 35-degree beam (55 degrees
    # right of ahead: south-west), at y = 0.85 - 1.25 tan(35 deg) = -0.025.
    assert bench.devices["r2-lms"].truth_range(35.0) == pytest.approx(1.25 / math.cos(math.radians(35)))
    steps = hilbench_world.world.steps
    assert wait_until(lambda: hilbench_world.world.steps > steps + 20, 5)
    hilbench_world.stop_recording(rec)
    got = read_record(str(tmp_path / "truth.jsonl"))
    assert got["header"]["devices"]["r2-lms"]["body"] == "r2" and len(got["poses"]) > 20
    assert got["poses"][-1][1]["r2"] == pytest.approx((0.0, 1.0, -math.pi / 2), abs=1e-6)
