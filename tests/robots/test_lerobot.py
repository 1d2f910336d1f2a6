"""LeRobot's own robot classes (Koch v1.1, SO-101; follower and leader) against the bundled profiles.

The arms connect as ``lerobot-teleoperate`` connects them (handshake, calibration check against the
shipped calibration file, configure), run their control loop at 60 Hz, move (followers), and
disconnect, under `hilbench run` (Feetech's SDK drains its output with tcdrain before each packet).
LeRobot comes from `make install-robots` without its ML stack (see lerobot_client.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.robots.clients import need, run_client

pytestmark = [pytest.mark.robots, pytest.mark.slow]

PROFILES = Path(__file__).resolve().parents[2] / "profiles"
ARMS = {  # profile -> (LeRobot class, calibration directory, model names LeRobot uses)
    "koch-follower": ("koch_follower", "robots/koch_follower", ["xl430-w250"] * 2 + ["xl330-m288"] * 4),
    "koch-leader": ("koch_leader", "teleoperators/koch_leader", ["xl330-m077"] * 6),
    "so101-follower": ("so101_follower", "robots/so101_follower", ["sts3215"] * 6),
    "so101-leader": ("so101_leader", "teleoperators/so101_leader", ["sts3215"] * 6),
}


@pytest.mark.parametrize("profile", list(ARMS))
def test_lerobot_arm(profile, hilbench_bench, hilbench_run, watch):
    need("lerobot", "LeRobot")
    need("draccus", "LeRobot's configuration library (draccus)")
    kind, cal_dir, models = ARMS[profile]
    bench = hilbench_bench(profile)
    monitors = watch(bench)
    eeprom = {s.name: (s.get("homing_offset"), s.get("min_position_limit")) for s in bench.devices.values()}
    out = run_client("lerobot_client.py", kind, bench.endpoint().path, str(PROFILES / "lerobot" / cal_dir), "90",
                     run=hilbench_run, bench=bench)
    assert out["calibrated"] and not out["asked_to_calibrate"]
    assert list(out["models"].values()) == models
    assert out["warnings"] == []
    assert out["loop_errors"] == 0, out.get("error")
    assert 40 <= out["loop_hz"] <= 62
    if kind.endswith("follower"):
        for key, want in out["target"].items():
            assert abs(out["at_target"][key] - want) < 1.0, (key, out["at_target"][key], want)
        # disconnect() turns the torque off; a client opening the port again reads 0
        assert all(s.get("torque_enable") == 0 for s in bench.devices.values())
    # connecting rewrote nothing that mattered: the calibration in the EEPROM is the profile's
    assert {s.name: (s.get("homing_offset"), s.get("min_position_limit")) for s in bench.devices.values()} == eeprom
    report = monitors["arm"].summary()
    assert report["protocol"] == ("feetech" if kind.startswith("so") else "dynamixel")
    assert sorted(int(i) for i in report["devices"]) == [1, 2, 3, 4, 5, 6]
    assert all(d["state"] == "connected" for d in report["devices"].values())
    cycle = report["bus"]["main_cycle"]
    assert cycle["instruction"] == "sync_read" and cycle["address"] in (56, 132) and cycle["count"] >= 80
