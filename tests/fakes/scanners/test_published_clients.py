"""Published scanner clients, unmodified, in their own processes, read the ``scanners`` bench.

Each test compares what the client decoded with the room's truth computed by
hand (conftest.room_range), in the vendor's angle convention: RPLIDAR angles
grow clockwise from straight ahead, hokuyolx angles counter-clockwise from the
front step. A mirrored or rotated scan fails (each test also checks that the
mirrored reading of the same data does). Revolution and scan rates must be
those of the real units.

DTR: the RPLIDAR A1's motor follows DTR (profile motor = "dtr"), and every
RPLIDAR client runs under ``hilbench run`` (the ``hilbench_run`` fixture): its
modem-line ioctls on the bench's pty (pyserial's ``.dtr``; the SDK's TIOCMBIC
from C through the LD_PRELOAD shim) reach the emulated unit, whose motor then
turns; without them the unit answers SCAN with a descriptor and silence.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.fakes.scanners.conftest import fraction_within, need, room_range, run_client

pytestmark = pytest.mark.slow  # published scanner clients, some built from C: the slow real-client set

# The A1's range model in the profile: sigma = max(0.5 mm, 0.5 % of the range).
A1 = {"sigma0": 0.0005, "sigma_k": 0.005}


def _rates(times: list[float]) -> float:
    t = np.asarray(times)
    return (len(t) - 1) / (t[-1] - t[0])


def _check_rplidar_scan(scan: list, *, shift_deg: float = 0.0) -> None:
    angles = np.array([p[1] for p in scan]) - shift_deg
    ranges = np.array([p[2] for p in scan]) / 1000.0
    phi = -np.radians(angles)  # clockwise from straight ahead
    assert fraction_within(phi, ranges, **A1) > 0.97
    assert fraction_within(np.radians(angles), ranges, **A1) < 0.5  # the mirrored reading fails
    assert fraction_within(phi + np.radians(5), ranges, **A1) < 0.6  # and a rotated one


@pytest.mark.parametrize("shim", ["c", "python"])
def test_rplidar_roboticia_standard_scan_motor_follows_dtr(scanners, hilbench_run, shim):
    need("rplidar")
    lidar = scanners.device("lidar")
    assert not lidar.motor_commanded()  # DTR asserted by default: the dev kit's motor stands
    out = run_client("rplidar_roboticia.py", scanners.endpoint("lidar").path, "normal", "8",
                     run=hilbench_run, bench=scanners, shim=shim)
    assert out["info"] == {"model": 24, "firmware": [1, 29], "hardware": 7,
                           "serialnumber": "D8E0EDF9C7E29BD1A7E39EF24833431B"}
    assert out["health"] == ["Good", 0]
    rate = _rates(out["times"][1:])
    assert 5.0 < rate < 6.0, rate  # ~5.5 Hz
    assert all(330 <= n <= 390 for n in out["counts"][1:]), out["counts"]  # ~358 samples a revolution
    _check_rplidar_scan(out["scan"])
    assert lidar.dtr is True and not lidar.motor_commanded()  # stop_motor() set DTR again: the motor stands
    assert "SET_MOTOR_PWM" in lidar.requests and lidar.requests[-2:] == ["STOP", "SET_MOTOR_PWM"]


def test_rplidar_roboticia_express_scan(scanners, hilbench_run):
    need("rplidar")
    out = run_client("rplidar_roboticia.py", scanners.endpoint("lidar").path, "express", "6",
                     run=hilbench_run, bench=scanners)
    assert 5.0 < _rates(out["times"][1:]) < 6.0
    assert all(660 <= n <= 780 for n in out["counts"][1:]), out["counts"]  # ~716 at 254 us
    # rplidar-roboticia places sample k one sample later than the SDK (k+1)/32: correct that quirk.
    step = 360.0 * 5.5 * 254e-6
    _check_rplidar_scan(out["scan"], shift_deg=step)


@pytest.mark.parametrize("mode", ["standard", "express"])
def test_pyrplidar(scanners, hilbench_run, mode):
    need("pyrplidar")
    out = run_client("pyrplidar_client.py", scanners.endpoint("lidar").path, mode, "6",
                     run=hilbench_run, bench=scanners)
    assert out["info"] == [24, 1, 29, 7, "D8E0EDF9C7E29BD1A7E39EF24833431B"]
    assert out["health"] == [0, 0]
    assert out["rate"] == [508, 254]
    assert out["modes"] == [["Standard", 3072, 130048, 0x81], ["Express", 3072, 65024, 0x82]]
    assert out["typical"] == 1
    assert 5.0 < _rates(out["times"][1:]) < 6.0
    lo, hi = (330, 390) if mode == "standard" else (660, 780)
    assert all(lo <= n <= hi for n in out["counts"][1:]), out["counts"]
    _check_rplidar_scan(out["scan"])
    assert scanners.device("lidar").dtr is False  # pyrplidar never sets DTR again: the motor keeps running


def test_slamtec_sdk_typical_scan(scanners, hilbench_run):
    need("pyrplidarsdk")
    lidar = scanners.device("lidar")
    assert lidar.config.motor == "dtr" and not lidar.motor_commanded()
    # The SDK clears DTR from C (raw_serial::open, setMotorSpeed): the LD_PRELOAD shim carries it.
    out = run_client("slamtec_sdk.py", scanners.endpoint("lidar").path, "8", run=hilbench_run, bench=scanners,
                     shim="c")
    assert out["connected"] and out["started"]
    assert out["info"] == [24, 0x011D, 7, "d8e0edf9c7e29bd1a7e39ef24833431b"]
    assert out["health"] == [0, 0]
    assert "EXPRESS_SCAN" in lidar.requests  # the typical mode (Express) found through GET_LIDAR_CONF
    assert lidar.counters.get("unknown_command", 0) == 0
    assert 5.0 < _rates(out["times"][1:]) < 6.0
    assert all(660 <= n <= 780 for n in out["counts"][1:]), out["counts"]
    angles = np.degrees(np.asarray(out["angles"]))
    ranges = np.asarray(out["ranges"])
    phi = -np.radians(angles)
    assert fraction_within(phi, ranges, **A1) > 0.97
    assert fraction_within(-phi, ranges, **A1) < 0.5
    # The SDK's stop() only stops PWM-driven motors (A2/A3); pyrplidarsdk never calls stopMotor(), so DTR stays
    # cleared and the A1 keeps turning, as on the real dev kit.
    assert lidar.dtr is False and lidar.motor_commanded()
    assert "SCAN" not in lidar.requests and lidar.revolutions >= 8


def test_rplidar_client_without_hilbench_run_gets_silence(scanners):
    """Without `hilbench run` the SDK's DTR never reaches the pty: descriptor, then no nodes (as a dev kit
    whose motor does not turn) -- the motor really follows DTR, not the client's requests."""
    need("pyrplidarsdk")
    import subprocess
    import sys

    from tests.fakes.scanners.conftest import CLIENTS

    proc = subprocess.run([sys.executable, str(CLIENTS / "slamtec_sdk.py"), scanners.endpoint("lidar").path, "1",
                           "3"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert '"counts": []' in proc.stdout  # no revolution within the client's wait
    assert scanners.device("lidar").revolutions == 0


def test_hokuyolx_over_tcp(scanners):
    need("hokuyolx")
    ep = scanners.endpoint("ust")
    host, port = ep.port.address
    manifest = {e["name"]: e for e in scanners.manifest()["endpoints"]}
    assert (manifest["ust"]["host"], manifest["ust"]["port"]) == (host, port)
    out = run_client("hokuyolx_client.py", host, str(port), "20")
    assert out["params"] == {"amin": 0, "amax": 1080, "aforw": 540, "ares": 1440, "dmin": 20, "dmax": 30000,
                             "scan_freq": 40, "model": "UST-10LX"}
    angles = np.asarray(out["angles"])
    ust = {"sigma0": 0.01, "sigma_k": 0.0}
    for scan in (out["single"], out["last"]):
        r = np.asarray(scan) / 1000.0
        assert len(r) == 1081
        assert fraction_within(angles, r, **ust) > 0.97
        assert fraction_within(-angles, r, **ust) < 0.5  # mirrored
    assert out["pendings"] == list(range(19, -1, -1))
    rate = _rates(out["times"])
    assert 36.0 < rate < 44.0, rate  # 2400 rpm = 40 Hz
    stamps = np.diff(out["stamps"])
    assert np.all(np.abs(stamps - 25) <= 1), stamps  # device timestamps 60000/rpm ms apart
    assert out["state"][0] == 3  # laser on (single scan state) after MD ended
    assert room_range(0.0) == pytest.approx(2.5)
