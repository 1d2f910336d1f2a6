"""`hilbench lidar` and `hilbench monitor` on scanners, as a user runs them: `hilbench emulate` in one process,
the verb in another, through the bench's manifest (ptys, TCP on 127.0.0.1, the control channel for DTR)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys

import pytest

from hilbench.pytest_plugin import wait_until


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def emulator(tmp_path_factory):
    path = tmp_path_factory.mktemp("scanners") / "bench.json"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "scanners", "--manifest", str(path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: path.exists() or proc.poll() is not None, timeout=30)
    assert proc.poll() is None, proc.stderr.read()
    manifest = json.loads(path.read_text())
    yield path, manifest
    proc.terminate()
    proc.wait(timeout=10)
    proc.stdout.close()
    proc.stderr.close()


def test_manifest_lists_scanner_endpoints(emulator):
    _path, m = emulator
    eps = {e["name"]: e for e in m["endpoints"]}
    assert {n: e["protocol"] for n, e in eps.items()} == {"lidar": "rplidar", "lms": "sick-lms200", "ust": "scip2",
                                                          "urg": "scip2"}
    assert eps["ust"]["host"] == "127.0.0.1" and isinstance(eps["ust"]["port"], int) and eps["ust"]["port"] > 0
    assert eps["lidar"]["path"].startswith("/dev/pts/")
    devs = {d["name"]: d for d in m["devices"]}
    assert devs["lidar"]["pose"] == {"x": 0.5, "y": 0.3, "heading": 0.0} and devs["lidar"]["motor"] == "dtr"
    assert m["control"]


@pytest.mark.parametrize(("endpoint", "protocol", "rate", "points"), [
    ("lidar", "rplidar", (5.0, 6.0), (330, 390)),
    ("ust", "scip2", (30.0, 50.0), (1081, 1081)),
    ("urg", "scip2", (8.0, 12.0), (682, 682)),
])
def test_lidar_json_against_the_emulator(emulator, endpoint, protocol, rate, points):
    path, _ = emulator
    proc = hb("lidar", f"{path}#{endpoint}", "--scans", "6", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["protocol"] == protocol and rep["scans"] >= 6 and rep["error_count"] == 0
    assert rate[0] <= rep["scan_rate_hz"] <= rate[1]
    # The first RPLIDAR revolution is partial (the head starts at a random phase).
    assert points[0] * 0.8 <= rep["points_per_scan"] <= points[1]


def test_lidar_png_over_the_scene(emulator, tmp_path):
    path, _ = emulator
    png = tmp_path / "scan.png"
    proc = hb("lidar", f"{path}#lms", "--png", str(png), "--lms-baud", "38400")
    assert proc.returncode == 0, proc.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert "361 points" in proc.stdout


def test_lidar_errors_are_one_line(tmp_path):
    proc = hb("lidar", str(tmp_path / "missing.json"))  # no manifest: the bench is not running (exit 1)
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1 and "no such manifest" in proc.stderr
    bad = tmp_path / "bad.json"
    bad.write_text("[1]")
    proc = hb("lidar", str(bad))  # a file that is no manifest: what was asked (exit 2)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "not a bench manifest" in proc.stderr
    proc = hb("lidar", "bench:scanners#nope")
    assert proc.returncode == 2 and "no endpoint named 'nope'" in proc.stderr


def test_monitor_taps_a_scanner_while_lidar_reads_it(emulator):
    from hilbench.bench.control import ControlClient

    path, manifest = emulator
    control = ControlClient(manifest["control"])
    before = control.taps()["urg"]["clients"]
    mon = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "monitor", f"{path}#urg", "--json",
                            "--seconds", "30"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: control.taps()["urg"]["clients"] > before, timeout=20)  # the monitor listens
    reader = hb("lidar", f"{path}#urg", "--scans", "10", "--summary")
    assert reader.returncode == 0, reader.stderr
    mon.send_signal(signal.SIGINT)  # Ctrl-C ends a monitor with its report, as a user would stop it
    out, err = mon.communicate(timeout=30)
    assert mon.returncode == 0, err
    rep = json.loads(out)
    assert rep["protocol"] == "scip2" and rep["scans"] >= 8 and rep["checksum_failures"] == 0
    assert rep["requests"] >= 4 and 8.0 <= rep["scan_rate_hz"] <= 12.0
    assert rep["device"]["model"] == "URG-04LX"


def test_control_channel_turns_scanner_knobs(emulator):
    from hilbench.bench.control import ControlClient, ControlError

    _path, manifest = emulator
    c = ControlClient(manifest["control"])
    assert c.call("scanner_status", device="lidar")["status"]["motor"]["policy"] == "dtr"
    assert c.call("dtr", device="lidar", dtr=False)["dtr"] is False
    wait_until(lambda: c.call("scanner_status", device="lidar")["status"]["motor"]["commanded"])
    c.call("dtr", device="lidar", dtr=True)
    faults = c.call("scanner_fault", device="urg", knobs={"unstable_next": 2})["faults"]
    assert faults["unstable_next"] == 2
    with pytest.raises(ControlError, match="unknown fault knob"):
        c.call("scanner_fault", device="lms", knobs={"melt": True})


def test_mecarover_lidar_sees_the_lab():
    proc = hb("lidar", "bench:mecarover#lidar", "--scans", "8", "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["protocol"] == "rplidar" and rep["scans"] >= 8 and 5.0 <= rep["scan_rate_hz"] <= 6.0  # over 7 intervals: a late read under load moves the rate a few %, not 30 %


def test_lidar_finds_an_lms200_left_at_another_speed_and_leaves_it_at_9600(emulator):
    """A host that switched the LMS 200 to 38 400 baud and died leaves it there (until power-off): the next
    `lidar` finds the speed with status requests, as sicktoolbox does, and switches back when done."""
    import serial

    from hilbench.bench.control import ControlClient
    from hilbench.protocols import sick_lms200 as lms

    path, manifest = emulator
    control = ControlClient(manifest["control"])
    pty = next(e["path"] for e in manifest["endpoints"] if e["name"] == "lms")

    def unit_baud() -> int:
        return control.call("scanner_status", device="lms")["status"]["baud"]

    with serial.Serial(pty, 9600, timeout=0.1) as host:  # the host that dies after switching
        host.write(lms.mode_request(lms.Mode.BAUD_38400))
        wait_until(lambda: unit_baud() == 38_400, timeout=5)
    proc = hb("lidar", f"{path}#lms", "--scans", "3", "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["scans"] >= 3
    assert unit_baud() == 9600  # switched back, as sicktoolbox's Uninitialize does
    proc = hb("lidar", f"{path}#lms", "--scans", "2", "--summary", "--lms-baud", "500000")
    assert proc.returncode == 0, proc.stderr
    assert unit_baud() == 9600


def test_lidar_says_which_speeds_an_lms200_did_not_answer_at(monkeypatch, capsys):
    import os

    from hilbench.cli import main
    from hilbench.clients.sick_lms200 import SickDriver

    monkeypatch.setattr(SickDriver, "PROBE_TIMEOUT", 0.1)
    master, slave = os.openpty()  # a port with nothing behind it
    name = os.ttyname(slave)
    try:
        assert main(["lidar", name, "--protocol", "sick", "--json"]) == 1
    finally:
        os.close(slave)
        os.close(master)
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        f"hilbench: error: {name}: no LMS 200 answers a status request at 9600, 38400, 19200, 500000 baud "
        "(is it powered, on this port, and not used by another program?)"]


def test_a_scanner_client_brings_its_protocol_speed_and_options_to_lidar():
    """`hilbench lidar` names no scanner: a client registered like any family's (here in code) gets its protocol
    and aliases into --protocol, its options into the verb, its speed onto the port and its driver run."""
    import argparse
    import os

    from hilbench import registry
    from hilbench.cli import lidar
    from hilbench.clients.scanners import ScannerClient, ScannerDriver
    from hilbench.monitor.scanners.tracker import ScannerTracker

    opened = []

    class AcmeDriver(ScannerDriver):
        protocol = "acme-scan"

        def new_tracker(self):  # (no instrument registered for acme-scan here)
            return ScannerTracker(protocol="acme-scan")

    class AcmeClient(ScannerClient):
        protocol = "acme-scan"
        aliases = ("acme",)
        driver = AcmeDriver
        default_baud = 57_600

        def add_arguments(self, parser):
            parser.add_argument("--acme-range", type=float, default=4.0)

        def open(self, link, args=None, *, set_dtr=None):
            opened.append((link.handle.baudrate, args.acme_range))
            return super().open(link, args)

    class Clashing(AcmeClient):
        protocol = "other-scan"
        aliases = ()

        def add_arguments(self, parser):
            parser.add_argument("--lms-baud")  # the LMS 200's option

    registry.clients.register("acme-scan", AcmeClient())
    try:
        with pytest.raises(ValueError, match="scanner option '--lms-baud' is taken by client driver 'sick-lms200'"):
            registry.clients.register("other-scan", Clashing())
        parser = argparse.ArgumentParser()
        lidar.register(parser.add_subparsers())
        master, slave = os.openpty()
        try:
            args = parser.parse_args(["lidar", os.ttyname(slave), "--protocol", "acme", "--acme-range", "8"])
            drv = lidar._driver(lidar.ScannerAddress(os.ttyname(slave), None), args)
            drv.connection.close()
        finally:
            os.close(slave)
            os.close(master)
        assert opened == [(57_600, 8.0)] and isinstance(drv, AcmeDriver)
        assert "--express" in parser._subparsers._group_actions[0].choices["lidar"].format_help()
    finally:
        registry.clients.unregister("acme-scan")


def test_a_scanner_on_a_body_is_drawn_where_the_body_took_it():
    """mecarover's A1 sits 0.1 m ahead of the rover's centre: ``--png`` draws the scan from the rover's pose
    in the world (the truth's), not from the mount pose as if the rover had never moved."""
    from hilbench.cli.lidar import resolve

    address = resolve("bench:mecarover#lidar")
    try:
        assert address.pose["x"] == pytest.approx(0.1)  # the mount on the body
        address.bench.world.place("rover", 1.0, 0.5, math.pi / 2)
        pose = address.world_pose()
        assert pose["x"] == pytest.approx(1.0, abs=1e-6) and pose["y"] == pytest.approx(0.6, abs=1e-6)
        assert pose["heading"] == pytest.approx(90.0 + address.pose["heading"], abs=1e-6)
    finally:
        address.bench.stop()
