"""pypot runs the Poppy robots' own configuration against the bundled profiles, unmodified but for port names.

The bench runs as users run it (``hilbench emulate`` in a process of its own), the robot's software in
another, under ``hilbench run``: pypot calls tcflush(TCOFLUSH) before every packet, which on a plain pty
discards a SYNC_WRITE the bench has not read yet (its one Torque Enable packet, say); under `hilbench
run` the flush waits for the bench, as on a USB adapter. A monitor on each bus's tap watches.
"""

from __future__ import annotations

import dynamixel_sdk as sdk
import pytest

from hilbench.bench.profile import load_profile
from hilbench.pytest_plugin import wait_until
from tests.robots.clients import need, run_client

pytestmark = [pytest.mark.robots, pytest.mark.slow]


def _check_run(out: dict, monitors, expected_models: dict[int, str]) -> None:
    assert out["warnings"] == []  # no EEPROM rewrite, no missing motor, no timeout
    assert {m["id"]: m["model"] for m in out["motors"].values()} == expected_models
    for joint, goal in out["goals"].items():
        assert abs(out["after"][joint] - goal) < 1.0, (joint, out["after"][joint], goal)
    assert all(20 <= t <= 40 for t in out["temperatures"].values())
    seen = {}
    for mon in monitors.values():
        wait_until(lambda m=mon: m.summary()["bus"]["main_cycle"] is not None, timeout=5)
        report = mon.summary()
        cycle = report["bus"]["main_cycle"]
        # PosSpeedLoadDxlController: Present Position/Speed/Load of every motor at 50 Hz (pypot's own
        # thread slips a little when both cores are busy: 44-50 Hz seen with a load average of 3.5)
        assert cycle["instruction"] == "sync_read" and 40 <= cycle["rate_hz"] <= 55, cycle
        assert report["bus"]["unanswered"] == 0
        for dev_id, dev in report["devices"].items():
            assert dev["state"] == "connected"
            seen[int(dev_id)] = dev["model_name"]
    assert sorted(seen) == sorted(expected_models)  # the monitor saw every motor


def _eeprom_after(manifest: dict, profile: str, protocol: float) -> None:
    """After pypot closed its ports: a client opening them again reads the profile's EEPROM, untouched."""
    ph = sdk.PacketHandler(protocol)
    specs = load_profile(profile).devices
    for ep in manifest["endpoints"]:
        port = sdk.PortHandler(ep["path"])
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            for spec in (s for s in specs if s.endpoint == ep["name"]):
                init = spec.init
                assert ph.read2ByteTxRx(port, spec.id, 6) == (init["cw_angle_limit"], 0, 0)
                assert ph.read2ByteTxRx(port, spec.id, 8) == (init["ccw_angle_limit"], 0, 0)
                assert ph.read1ByteTxRx(port, spec.id, 5) == (0, 0, 0)
        finally:
            port.closePort()


def test_poppy_humanoid(hilbench_emulator, hilbench_run, watch):
    need("poppy_humanoid", "poppy-humanoid (with pypot)")
    manifest = hilbench_emulator("poppy-humanoid")
    monitors = watch(manifest)
    out = run_client("pypot_client.py", "humanoid", manifest["manifest_path"], "2", run=hilbench_run,
                     bench=manifest)
    specs = load_profile("poppy-humanoid").devices
    expected = {s.id: {"AX-12A": "AX-12", "MX-28(1.0)": "MX-28", "MX-64(1.0)": "MX-64"}[s.model] for s in specs}
    _check_run(out, monitors, expected)
    report = monitors["upper"].summary()
    assert report["protocol"] == "dynamixel1" and report["devices"]["36"]["model_name"] == "AX-12A"
    _eeprom_after(manifest, "poppy-humanoid", 1.0)


def test_poppy_ergo_jr(hilbench_emulator, hilbench_run, watch):
    need("poppy_ergo_jr", "poppy-ergo-jr (with pypot)")
    manifest = hilbench_emulator("poppy-ergo-jr")
    monitors = watch(manifest)
    out = run_client("pypot_client.py", "ergo_jr", manifest["manifest_path"], "2", run=hilbench_run,
                     bench=manifest)
    _check_run(out, monitors, dict.fromkeys(range(1, 7), "XL-320"))
    assert monitors["bus"].summary()["protocol"] == "dynamixel"
    _eeprom_after(manifest, "poppy-ergo-jr", 2.0)
