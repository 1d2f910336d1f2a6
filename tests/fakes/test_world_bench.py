"""One world per bench, end to end: clients in their own processes drive the rovers and read their scanners.

- ``mecarover``: Vel2d frames (from another process, as the ROS bridge sends them) drive the rover toward the wall; its RPLIDAR, read with
  rplidar-roboticia, sees the wall come closer by what the truth says the rover moved;
- ``mecarover-can``: the same through RPDO1 setpoints over socketcand (python-can in another process);
  odometry (TPDO2, read with python-can in another process) equals the truth without slip, drifts from it
  while slip is on and stops drifting when it is off again;
- a third robot is one more block in ``arena``;
- a rover that meets the wall stops while its wheels and odometry run on;
- ``arena``: r2's LMS 200 sees r1's footprint where the truth puts it, and follows it when r1 drives; the
  truth is read and recorded with ``hilbench world`` (JSON, record) from another process.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hilbench.pytest_plugin import wait_until

CLIENTS = Path(__file__).parent / "world_clients"
HB = [sys.executable, "-m", "hilbench.cli"]


class Lines:
    """A client process whose JSON lines are collected in a thread."""

    def __init__(self, *argv: str, env: dict[str, str] | None = None) -> None:
        self.proc = subprocess.Popen([sys.executable, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env=env)
        self.items: list[dict] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            try:
                self.items.append(json.loads(line))
            except ValueError:
                pass

    def after(self, t: float) -> list[dict]:
        return [i for i in self.items if i["t"] > t]

    def wait_after(self, t: float, n: int = 2, timeout: float = 15.0) -> list[dict]:
        ok = wait_until(lambda: len(self.after(t)) >= n or self.proc.poll() is not None, timeout)
        got = self.after(t)
        assert ok and len(got) >= n, f"client gave {len(got)} items after t={t:.3f}: {self.proc.stderr.read()[-3000:]}"
        return got

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait(5)


def drive(port: str, vx: float, vy: float, wz: float, seconds: float) -> None:
    """Vel2d frames from another process (the ROS bridge's wire format), then stop frames."""
    subprocess.run([sys.executable, str(CLIENTS / "vel2d_drive.py"), port, str(vx), str(vy), str(wz), str(seconds)],
                   check=True, capture_output=True, timeout=60)


def still(bench, name: str, timeout: float = 5.0) -> float:
    """Wait until body ``name`` stands still; the bench time then."""
    assert wait_until(lambda: bench.world.body(name).velocity == (0.0, 0.0, 0.0), timeout), \
        bench.world.body(name).velocity
    return time.monotonic()


def ahead(items: list[dict]) -> float:
    return float(np.median([i["ahead"] for i in items if i["ahead"] is not None]))


def test_mecarover_vel2d_frames_move_the_rover_and_its_rplidar_sees_the_wall_come_closer(hilbench_bench,
                                                                                         hilbench_run):
    pytest.importorskip("rplidar")
    bench = hilbench_bench("mecarover")
    # (under hilbench run's environment: rplidar-roboticia sets DTR, which a bare pty refuses)
    lidar = Lines(str(CLIENTS / "rplidar_ahead.py"), bench.endpoint("lidar").path, "30",
                  env=hilbench_run.env(bench, "python"))
    try:
        before = ahead(lidar.wait_after(time.monotonic(), 3))
        x0 = bench.world.body("rover").pose[0]
        assert before == pytest.approx(2.9, abs=0.03)  # wall x = 3, scanner 0.1 m ahead of the centre
        drive(bench.endpoint("rover").path, 0.4, 0.0, 0.0, 1.5)
        t_stop = still(bench, "rover")
        after = ahead(lidar.wait_after(t_stop, 3))
        x1, y1, th1 = bench.world.body("rover").pose
        moved = x1 - x0
        assert moved > 0.4 and abs(y1) < 1e-6 and abs(th1) < 1e-6
        # The A1's noise at 2.5 m is ~12 mm per point; medians of a few points each.
        assert before - after == pytest.approx(moved, abs=0.03)
        robot = bench.family("stm32-rover").board().status()["robot"]  # (hilbench board status --json)
        # What the wheels measured (every encoder delta) is the truth...
        assert robot["measured"][0] / 1000.0 == pytest.approx(moved, abs=0.001)
        # ...but the freertos-50-30 firmware integrates one wheel period (20 ms) per pose cycle (33.3 ms): its
        # odometry says 60 % of what the wheels did (the mailbox semantics of spec §2.4 it reproduces).
        assert robot["pose"][0] / 1000.0 == pytest.approx(moved * 0.6, rel=0.05)
    finally:
        lidar.close()


def socketcand(bench) -> list[str]:
    """The bench's socketcand server as the client scripts take it: HOST PORT CHANNEL NODE_ID."""
    sc = next(e for e in bench.manifest()["endpoints"] if e["name"] == "can")["socketcand"]
    return [sc["host"], str(sc["port"]), sc["channel"], "2"]


def can_drive(bench, vx: float, seconds: float) -> None:
    """RPDO1 setpoints from another process (python-can over socketcand), then stop setpoints."""
    out = subprocess.run([sys.executable, str(CLIENTS / "can_drive.py"), *socketcand(bench), str(vx), "0", "0",
                          str(seconds)], check=True, capture_output=True, text=True, timeout=60)
    assert int(out.stdout.split()[-1]) >= 25


def test_mecarover_can_rpdo1_over_socketcand_drives_the_body_and_its_rplidar_sees_it(hilbench_bench, hilbench_run):
    pytest.importorskip("rplidar")
    bench = hilbench_bench("mecarover-can")
    lidar = Lines(str(CLIENTS / "rplidar_ahead.py"), bench.endpoint("lidar").path, "30",
                  env=hilbench_run.env(bench, "python"))
    try:
        before = ahead(lidar.wait_after(time.monotonic(), 3))
        can_drive(bench, 0.4, 1.5)
        t_stop = still(bench, "rover")
        after = ahead(lidar.wait_after(t_stop, 3))
        moved = bench.world.body("rover").pose[0]
        assert moved > 0.4
        assert before - after == pytest.approx(moved, abs=0.03)  # the scanner sees the truth
        assert bench.family("canopen").node().pose()[0] == pytest.approx(moved, abs=0.005)  # odometry = truth
    finally:
        lidar.close()


def test_odometry_drifts_from_the_truth_with_slip_on_and_stops_drifting_with_it_off(hilbench_bench):
    """mecarover-can, odometry as a client gets it (TPDO2, python-can over socketcand, another process): slip
    on (the profile's ``odometry.slip``), the gap between odometry and truth grows as the rover drives; slip
    off (the control channel's ``world_slip``), it drives as far again and the gap stays where it was."""
    from hilbench.bench.control import ControlClient

    bench = hilbench_bench("mecarover-can", set={"devices.rover.odometry.slip": 0.3})
    control = ControlClient(bench.serve_control().address_text)
    odo = Lines(str(CLIENTS / "can_odometry.py"), *socketcand(bench), "40")

    def leg() -> tuple[float, float]:
        """Drive 1.5 s at 0.4 m/s; then (odometry x from TPDO2, true x)."""
        can_drive(bench, 0.4, 1.5)
        t_stop = still(bench, "rover")
        return odo.wait_after(t_stop + 0.1, 2)[-1]["x"], bench.world.body("rover").pose[0]

    try:
        odo1, true1 = leg()
        assert true1 > 0.3 and odo1 - true1 > 0.15  # slip 0.3: the body went 70 % of what the wheels counted
        assert true1 == pytest.approx(0.7 * odo1, rel=0.02)
        control.slip("rover", 0.0)
        odo2, true2 = leg()
        assert true2 - true1 > 0.4  # it drove on...
        assert (odo2 - true2) == pytest.approx(odo1 - true1, abs=0.003)  # ...and the drift did not grow (TPDO: mm)
    finally:
        odo.close()


def test_a_rover_meeting_the_wall_stops_while_its_wheels_and_odometry_run_on(hilbench_bench):
    bench = hilbench_bench("mecarover")
    bench.world.place("rover", 2.6, 0.0, 0.0)  # its front 0.15 m from the wall
    board = bench.family("stm32-rover").board()
    sender = subprocess.Popen([sys.executable, str(CLIENTS / "vel2d_drive.py"), bench.endpoint("rover").path, "0.3",
                               "0", "0", "5"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_until(lambda: bench.world.body("rover").blocked, 5)
        x_hit = bench.world.body("rover").pose[0]
        odo_hit = board.status()["robot"]["pose"][0]
        assert x_hit == pytest.approx(2.75, abs=0.001)  # its front at the wall x = 3
        assert wait_until(lambda: board.status()["robot"]["pose"][0] > odo_hit + 50, 3)  # mm: odometry runs on
        # The wheels' measurement (from where the board started: the place moved the body, not the wheels)
        # says the rover went on past the wall.
        assert board.status()["robot"]["measured"][0] / 1000.0 > (x_hit - 2.6) + 0.05
        assert max(board.status()["robot"]["wheels"]) > 1.0  # rad/s: the wheels keep turning
        assert bench.world.body("rover").pose[0] == pytest.approx(x_hit, abs=1e-4)  # the truth does not move
        assert bench.world.body("rover").body.collisions == 1
    finally:
        sender.kill()
        sender.wait(5)


def r1_hand_ranges(lms_deg: np.ndarray, r1: tuple[float, float]) -> np.ndarray:
    """What r2's LMS (at (1.35, 0), looking west) sees along its beams, by hand: r1's 0.5 x 0.4 footprint at
    ``r1`` (heading 0) in front of the arena's west wall x = -4 and the walls y = +-3."""
    phi = math.pi + np.radians(lms_deg - 90.0)
    c, s = np.cos(phi), np.sin(phi)
    ox = 1.35
    with np.errstate(divide="ignore", invalid="ignore"):
        wall = np.minimum((-4.0 - ox) / c, np.where(s > 0, 3.0 / s, np.where(s < 0, -3.0 / s, np.inf)))
        tx = np.sort(np.stack([(r1[0] - 0.25 - ox) / c, (r1[0] + 0.25 - ox) / c]), axis=0)
        ty = np.sort(np.stack([(r1[1] - 0.2) / s, (r1[1] + 0.2) / s]), axis=0)
    near, far = np.maximum(tx[0], ty[0]), np.minimum(tx[1], ty[1])
    return np.where((near <= far) & (near > 0), near, wall)


def test_arena_r2_lms_sees_r1_where_the_truth_puts_it_and_follows_it(hilbench_bench, hilbench_run, tmp_path):
    bench = hilbench_bench("arena")
    bench.serve_control()
    manifest = hilbench_run.manifest(bench)
    record = tmp_path / "truth.jsonl"
    recorder = subprocess.Popen([*HB, "world", manifest, "--record", str(record), "--duration", "30"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lms = Lines(str(CLIENTS / "lms_scans.py"), bench.endpoint("r2-lms").path, "30")
    angles = np.arange(181.0)
    sector = np.abs(angles - 90) <= 15  # around straight ahead: r1, the west wall (the bin is at 25 degrees)

    def check(items: list[dict]) -> None:
        x, y, _ = bench.world.body("r1").pose
        truth = r1_hand_ranges(angles, (x, y))
        for item in items:
            got = np.asarray(item["values"], float) / 1000.0
            ok = np.abs(got - truth)[sector] < 0.02  # LMS: 5 mm; beams grazing r1's corners may differ
            assert ok.mean() > 0.9, list(zip(angles[sector], got[sector], truth[sector], strict=True))
            assert np.sum(np.abs(got[sector] - truth[sector]) < 0.02) > 0

    try:
        check(lms.wait_after(time.monotonic(), 2))
        x0, y0, _ = bench.world.body("r1").pose
        assert (x0, y0) == (-1.5, 0.0)
        # r1 strafes to its left (+y) and forward: from r2 its footprint moves to r2's right and closer.
        drive(bench.endpoint("r1").path, 0.2, 0.3, 0.0, 1.2)
        t_stop = still(bench, "r1")
        x1, y1, _ = bench.world.body("r1").pose
        assert x1 - x0 > 0.15 and y1 - y0 > 0.25
        items = lms.wait_after(t_stop, 2)
        check(items)
        got = np.asarray(items[-1]["values"], float) / 1000.0
        hit = sector & (got < 3.5)
        assert np.mean(angles[hit]) < 90 - 5  # r1 is to r2's right now
        # The truth as another process sees it.
        doc = json.loads(subprocess.run([*HB, "world", manifest, "--json"], check=True, capture_output=True,
                                        text=True, timeout=30).stdout)
        assert doc["bodies"]["r1"]["x"] == pytest.approx(x1, abs=1e-6)
        assert doc["bodies"]["r1"]["shape"] == {"kind": "box", "size": [0.5, 0.4]}
        assert doc["devices"]["r2-lms"]["body"] == "r2"
        assert doc["devices"]["r2-lms"]["pose"]["x"] == pytest.approx(1.35)
        assert doc["unix_time"] == pytest.approx(time.time(), abs=5)
    finally:
        lms.close()
        recorder.terminate()  # (SIGTERM: the verb's file is flushed after every poll)
        recorder.wait(10)
    from hilbench.fakes.world import read_record

    rec = read_record(str(record))
    times = np.asarray([t for t, _ in rec["poses"]])
    assert len(times) > 100 and (len(times) - 1) / (times[-1] - times[0]) >= 100  # poses at >= 100 Hz
    assert rec["poses"][-1][1]["r1"][0] == pytest.approx(x1, abs=1e-5)
    scans = [s for s in rec["scans"] if s.device == "r2-lms"]
    assert len(scans) >= 3
    # 0..180 degrees at 1 degree: half a turn of the 75 Hz mirror between the first and the last ray.
    assert all(s.t_last - s.t_first == pytest.approx(0.5 / 75, rel=0.01) for s in scans)
    assert all(s.body == "r2" for s in scans)


def test_mecarover_udp_datagrams_turn_the_body(hilbench_bench):
    """The UDP door moves the same body (here a turn on the spot: theta, not x); the freertos-1000 firmware
    (wheels 1000 Hz, pose 500 Hz) counts one wheel period of every pose cycle: half the turn."""
    import socket

    bench = hilbench_bench("mecarover-udp")
    host, port = bench.endpoint("rover").path.removeprefix("udp://").rsplit(":", 1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    board = bench.family("stm32-rover").board()
    try:
        end = time.monotonic() + 1.0
        while time.monotonic() < end:  # (datagrams from this process: the door is the bench's socket)
            sock.sendto(vel2d_frame(0.0, 0.0, 0.8), (host, int(port)))
            time.sleep(0.05)
        sock.sendto(vel2d_frame(0.0, 0.0, 0.0), (host, int(port)))
        still(bench, "rover")
        x, y, theta = bench.world.body("rover").pose
        assert theta > 0.5 and abs(x) < 1e-6 and abs(y) < 1e-6
        robot = board.status()["robot"]
        assert robot["pose"][2] == pytest.approx(theta / 2, abs=0.01)
        assert robot["measured"][2] == pytest.approx(theta, abs=1e-3)  # the wheels measured the whole turn
    finally:
        sock.close()


def vel2d_frame(x: float, y: float, z: float) -> bytes:
    from hilbench.protocols import vel2d

    return vel2d.build(x, y, z)


R3_BLOCK = """
[[world.bodies]]
name = "r3"
shape = "box"
size = [0.5, 0.4]
pose = { x = 0.0, y = -1.2, theta = 1.5707963267948966 }   # facing north, south of the line r1-r2

[endpoints.r3]
type = "pty"
protocol = "vel2d"
baud = 115_200

[[devices]]
model = "stm32f767-rover"
name = "r3"
endpoint = "r3"
body = "r3"
preset = "freertos-50-30"
output = "v3"
seed = 3

[endpoints.r3-lms]
type = "pty"
protocol = "sick-lms200"
baud = 9600

[[devices]]
model = "lms200"
name = "r3-lms"
endpoint = "r3-lms"
body = "r3"
pose = { x = 0.15, y = 0.0, heading = 0.0 }
variant = [180, 100]
seed = 3
"""


def test_a_third_robot_is_one_more_block_in_the_arena_profile(hilbench_bench, tmp_path):
    """arena.toml plus one block (body, board on its pty, LMS 200 on its pty): r3 is seen by r1's scanner where
    it stands, its own scanner sees the arena (not itself), and Vel2d frames from another process drive it."""
    from hilbench.bench.profile import bundled_profiles

    path = tmp_path / "arena3.toml"
    path.write_text(bundled_profiles()["arena"].read_text() + R3_BLOCK)
    bench = hilbench_bench(str(path))
    assert bench.world.bodies == ["r1", "r2", "r3"]
    assert {d["name"]: d["body"] for d in bench.manifest()["devices"]} == \
        {"r1": "r1", "r1-lms": "r1", "r2": "r2", "r2-lms": "r2", "r3": "r3", "r3-lms": "r3"}
    # r1's LMS at (-1.35, 0) looking east: its 55-degree beam (35 degrees right of ahead) meets r3's front
    # face y = -0.95 (r3 spans x -0.2..0.2, y -1.45..-0.95) at x = -1.35 + 0.95 / tan(35 deg) = 0.007.
    assert bench.devices["r1-lms"].truth_range(55.0) == pytest.approx(0.95 / math.sin(math.radians(35)), abs=1e-6)
    # r3's LMS at (0, -1.05) looking north: straight ahead the bench's south face y = 1.8.
    assert bench.devices["r3-lms"].truth_range(90.0) == pytest.approx(1.8 + 1.05, abs=1e-6)
    drive(bench.endpoint("r3").path, 0.3, 0.0, 0.0, 1.0)
    still(bench, "r3")
    x, y, theta = bench.world.body("r3").pose
    assert y > -1.2 + 0.2 and abs(x) < 1e-6 and theta == pytest.approx(math.pi / 2)  # north, as it faces
    # Now the beam meets r3's west face x = -0.2 (1.15 m east of the scanner), where r3 spans it in y.
    y_hit = -1.15 * math.tan(math.radians(35))
    assert y - 0.25 < y_hit < y + 0.25
    assert bench.devices["r1-lms"].truth_range(55.0) == pytest.approx(1.15 / math.cos(math.radians(35)), abs=1e-6)
