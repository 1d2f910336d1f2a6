"""pypot runs the Poppy robots' own configuration against the bundled profiles, unmodified but for port names."""

from __future__ import annotations

import pytest

from hilbench import registry
from tests.robots.clients import need, run_client

pytestmark = [pytest.mark.robots, pytest.mark.slow]

#: pypot calls tcflush(TCOFLUSH) before every packet; on a pty that discards a SYNC_WRITE the bench has
#: not read yet. pypot sends Torque Enable once, when a motor stops being compliant: if that packet is
#: lost, the motor never moves. `hilbench run` (output flushes wait for the bench) is the cure.
FLUSH_RACE = ("pypot's tcflush(TCOFLUSH) discarded its Torque Enable SYNC_WRITE before the bench read it; "
              "this needs the client run under `hilbench run`")


def _check_run(out: dict, bench, monitors, expected_models: dict[int, str]) -> None:
    assert out["warnings"] == []  # no EEPROM rewrite, no missing motor, no timeout
    assert {m["id"]: m["model"] for m in out["motors"].values()} == expected_models
    names = {s.name: s for s in bench.devices.values()}
    for joint, goal in out["goals"].items():
        if abs(out["after"][joint] - goal) >= 1.0 and names[joint].get("torque_enable") == 0 \
                and "run" not in registry.verbs.names():
            pytest.xfail(FLUSH_RACE)
        assert abs(out["after"][joint] - goal) < 1.0, (joint, out["after"][joint], goal)
    assert all(20 <= t <= 40 for t in out["temperatures"].values())
    seen = {}
    for mon in monitors.values():
        report = mon.summary()
        cycle = report["bus"]["main_cycle"]
        # PosSpeedLoadDxlController: Present Position/Speed/Load of every motor at 50 Hz
        assert cycle["instruction"] == "sync_read" and 45 <= cycle["rate_hz"] <= 55, cycle
        assert report["bus"]["unanswered"] == 0
        for dev_id, dev in report["devices"].items():
            assert dev["state"] == "connected"
            seen[int(dev_id)] = dev["model_name"]
    assert sorted(seen) == sorted(expected_models)  # the monitor saw every motor


def test_poppy_humanoid(hilbench_bench, watch, tmp_path):
    need("poppy_humanoid", "poppy-humanoid (with pypot)")
    bench = hilbench_bench("poppy-humanoid")
    monitors = watch(bench)
    limits = {s.id: (s.get("cw_angle_limit"), s.get("ccw_angle_limit")) for s in bench.devices.values()}
    manifest = tmp_path / "bench.json"
    bench.write_manifest(manifest)
    out = run_client("pypot_client.py", "humanoid", str(manifest), "2")
    expected = {s.id: {12: "AX-12", 29: "MX-28", 310: "MX-64"}[s.model.number] for s in bench.devices.values()}
    _check_run(out, bench, monitors, expected)
    assert {s.id: (s.get("cw_angle_limit"), s.get("ccw_angle_limit")) for s in bench.devices.values()} == limits
    assert all(s.get("return_delay_time") == 0 for s in bench.devices.values())
    report = monitors["upper"].summary()
    assert report["protocol"] == "dynamixel1" and report["devices"]["36"]["model_name"] == "AX-12A"


def test_poppy_ergo_jr(hilbench_bench, watch, tmp_path):
    need("poppy_ergo_jr", "poppy-ergo-jr (with pypot)")
    bench = hilbench_bench("poppy-ergo-jr")
    monitors = watch(bench)
    manifest = tmp_path / "bench.json"
    bench.write_manifest(manifest)
    out = run_client("pypot_client.py", "ergo_jr", str(manifest), "2")
    _check_run(out, bench, monitors, dict.fromkeys(range(1, 7), "XL-320"))
    assert monitors["bus"].summary()["protocol"] == "dynamixel"
