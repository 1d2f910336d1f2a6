"""Published scanner clients, unmodified, in their own processes, read the ``scanners`` bench.

Each test compares what the client decoded with the room's truth computed by
hand (conftest.room_range), in the vendor's angle convention: RPLIDAR angles
grow clockwise from straight ahead, hokuyolx angles counter-clockwise from the
front step. A mirrored or rotated scan fails (each test also checks that the
mirrored reading of the same data does). Revolution and scan rates must be
those of the real units.

DTR: the RPLIDAR A1's motor follows DTR (profile motor = "dtr"). pyserial's
DTR changes reach the bench's LineState through tests/fakes/scanners/pyserial_lines
(the path `hilbench run` takes; see the README); Slamtec's SDK sets DTR from C,
which only `hilbench run`'s LD_PRELOAD shim can carry, so its test runs the
unit with motor = "always".
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.fakes.scanners.conftest import fraction_within, need, room_range, run_client

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


def test_rplidar_roboticia_standard_scan_motor_follows_dtr(scanners):
    need("rplidar")
    lidar = scanners.device("lidar")
    assert not lidar.motor_commanded()  # DTR asserted by default: the dev kit's motor stands
    out = run_client("rplidar_roboticia.py", scanners.endpoint("lidar").path, "normal", "8",
                     bench=scanners, lines_device="lidar")
    assert out["info"] == {"model": 24, "firmware": [1, 29], "hardware": 7,
                           "serialnumber": "D8E0EDF9C7E29BD1A7E39EF24833431B"}
    assert out["health"] == ["Good", 0]
    rate = _rates(out["times"][1:])
    assert 5.0 < rate < 6.0, rate  # ~5.5 Hz
    assert all(330 <= n <= 390 for n in out["counts"][1:]), out["counts"]  # ~358 samples a revolution
    _check_rplidar_scan(out["scan"])
    assert lidar.dtr is True and not lidar.motor_commanded()  # stop_motor() set DTR again: the motor stands
    assert "SET_MOTOR_PWM" in lidar.requests and lidar.requests[-2:] == ["STOP", "SET_MOTOR_PWM"]


def test_rplidar_roboticia_express_scan(scanners):
    need("rplidar")
    out = run_client("rplidar_roboticia.py", scanners.endpoint("lidar").path, "express", "6",
                     bench=scanners, lines_device="lidar")
    assert 5.0 < _rates(out["times"][1:]) < 6.0
    assert all(660 <= n <= 780 for n in out["counts"][1:]), out["counts"]  # ~716 at 254 us
    # rplidar-roboticia places sample k one sample later than the SDK (k+1)/32: correct that quirk.
    step = 360.0 * 5.5 * 254e-6
    _check_rplidar_scan(out["scan"], shift_deg=step)


@pytest.mark.parametrize("mode", ["standard", "express"])
def test_pyrplidar(scanners, mode):
    need("pyrplidar")
    out = run_client("pyrplidar_client.py", scanners.endpoint("lidar").path, mode, "6",
                     bench=scanners, lines_device="lidar")
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


def test_slamtec_sdk_typical_scan(scanners):
    need("pyrplidarsdk")
    lidar = scanners.device("lidar")
    lidar.config.motor = "always"  # the SDK sets DTR from C: only `hilbench run`'s shim carries that
    lidar.motor_since = 0.0
    out = run_client("slamtec_sdk.py", scanners.endpoint("lidar").path, "8", bench=scanners)
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
