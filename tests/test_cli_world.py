"""``hilbench world`` as a user runs it against a running bench (another process): ``--json`` with the issue's
fields (and the control channel's ``world`` answering the same), the live top-down view in a terminal, and
``--record`` (poses at >= 100 Hz, each scan's true first and last ray time: a scan's age at its host)."""

from __future__ import annotations

import json
import os
import pty
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.bench.control import ControlClient
from hilbench.fakes.world import read_record

HB = [sys.executable, "-m", "hilbench.cli"]
CLIENTS = Path(__file__).parent / "fakes" / "world_clients"
BODY_KEYS = {"x", "y", "theta", "vx", "vy", "omega", "shape"}


def test_world_json_has_the_fields_and_the_control_channel_answers_the_same(hilbench_bench, hilbench_run):
    bench = hilbench_bench("mecarover")
    client = ControlClient(bench.serve_control().address_text)
    bench.world.place("rover", 0.5, -0.25, 0.5)
    doc = json.loads(subprocess.run([*HB, "world", hilbench_run.manifest(bench), "--json"], check=True,
                                    capture_output=True, text=True, timeout=30).stdout)
    assert {"time", "unix_time", "bodies", "devices"} <= set(doc) <= {"time", "unix_time", "steps", "bodies",
                                                                       "moving", "devices"}
    assert doc["unix_time"] == pytest.approx(time.time(), abs=5)
    assert doc["time"] == pytest.approx(bench.world.world.clock(), abs=5)  # the bench clock
    rover = doc["bodies"]["rover"]
    assert set(rover) >= BODY_KEYS
    assert (rover["x"], rover["y"], rover["theta"]) == pytest.approx((0.5, -0.25, 0.5))
    assert (rover["vx"], rover["vy"], rover["omega"]) == (0.0, 0.0, 0.0)
    assert rover["shape"] == {"kind": "box", "size": [0.5, 0.4]}
    assert set(doc["devices"]) == {"rover", "lidar"}
    lidar = doc["devices"]["lidar"]
    assert lidar["body"] == "rover" and lidar["mount"] == {"x": 0.1, "y": 0.0, "theta": 0.0}
    # where the lidar is: 0.1 m ahead of the rover's centre, along its heading
    assert (lidar["pose"]["x"], lidar["pose"]["y"]) == pytest.approx((0.5 + 0.1 * 0.8775826, -0.25 + 0.1 * 0.4794255))
    same = client.world()
    assert set(same) - {"ok"} == set(doc)
    assert same["bodies"]["rover"] == rover and same["devices"] == doc["devices"]  # (it stands still)


def test_world_live_view_draws_the_world_from_above_in_a_terminal(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arena")
    bench.serve_control()
    manifest = hilbench_run.manifest(bench)
    controller, terminal = pty.openpty()
    env = dict(os.environ, TERM="xterm-256color", COLUMNS="100", LINES="45")
    proc = subprocess.Popen([*HB, "world", manifest, "--duration", "1.5"], stdin=terminal, stdout=terminal,
                            stderr=terminal, env=env, close_fds=True)
    os.close(terminal)
    out = b""
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end:
            try:
                chunk = os.read(controller, 65536)
            except OSError:  # (the terminal's other side closed: the view ended)
                break
            if not chunk:
                break
            out += chunk
        assert proc.wait(30) == 0
    finally:
        proc.kill()
        os.close(controller)
    text = out.decode(errors="replace")
    assert "world at t = " in text
    assert "#" * 40 in text  # the arena's north and south walls
    assert "1111*" in text and "*222" in text  # r1 facing east, r2 facing west, each its front *
    for row in ("r1    -1.500  0.000  0.0", "r2    1.500   0.000  180.0"):
        assert row in text, text[-3000:]


def test_world_record_has_every_pose_at_100_hz_and_each_scan_s_ray_times(hilbench_bench, hilbench_run, tmp_path):
    """A host's scan age = the time its code got the scan minus the record's ``t_last`` (bench clock: the
    monotonic clock of the bench's machine, as ``time.monotonic()`` in a client on the same machine)."""
    bench = hilbench_bench("arena")
    bench.serve_control()
    manifest = hilbench_run.manifest(bench)
    record = tmp_path / "truth.jsonl"
    host = subprocess.Popen([sys.executable, str(CLIENTS / "lms_scans.py"), bench.endpoint("r2-lms").path, "4"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    subprocess.run([*HB, "world", manifest, "--record", str(record), "--duration", "3"], check=True,
                   capture_output=True, text=True, timeout=60)
    got = [json.loads(line) for line in host.communicate(timeout=30)[0].splitlines()]
    rec = read_record(str(record))
    assert set(rec["header"]["bodies"]) == {"r1", "r2"} and rec["header"]["devices"]["r2-lms"]["body"] == "r2"
    times = [t for t, _ in rec["poses"]]
    assert times == sorted(times) and (len(times) - 1) / (times[-1] - times[0]) >= 100
    assert all(set(p) == {"r1", "r2"} for _, p in rec["poses"])
    scans = [sc for sc in rec["scans"] if sc.device == "r2-lms"]
    assert len(scans) >= 5 and all(sc.body == "r2" and sc.t_first < sc.t_last for sc in scans)
    # Each scan the host got, against the newest scan the truth says ended before it arrived: its age.
    ages = []
    for item in got:
        done = [sc.t_last for sc in scans if sc.t_last < item["t"]]
        if done and item["t"] < scans[-1].t_last:
            ages.append(item["t"] - max(done))
    # 38400 baud: a 181-value reply takes ~0.1 s on the wire after its last ray; a host reads it soon after.
    assert len(ages) >= 3 and all(0.09 < a < 1.0 for a in ages), ages
