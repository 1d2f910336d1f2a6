"""Clients under ``hilbench run`` on a virtual-time bench's clock (PLAN26 §9.1): real benches, real client
processes with the preload shim, the bench's lockstep controller (:mod:`hilbench.bench.lockstep`).

A Python client's sleeps take exactly their virtual durations and a fraction of the wall time; python-can
over socketcand sees exactly the heartbeats the virtual period implies; a thread that never waits makes a
counted stall named on stderr, after which time follows the wall clock (and with no stall it never moves).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.control import ControlClient
from hilbench.bench.port_state_server import serve_port_state
from hilbench.pytest_plugin import wait_until
from hilbench.run.build import ShimBuildError, shim_library

HILBENCH = [sys.executable, "-m", "hilbench.cli"]
S = 10**9


@pytest.fixture(scope="module", autouse=True)
def library() -> Path:
    try:
        return shim_library()
    except ShimBuildError as exc:
        pytest.skip(f"the preload library cannot be built: {exc}")


def client(bench: Bench, tmp_path: Path, code: str, *args: str, timeout: float = 60.0,
           check: bool = True) -> tuple[subprocess.CompletedProcess, float]:
    """Run ``code`` as a Python client under ``hilbench run`` against ``bench``; (process, wall seconds)."""
    manifest = tmp_path / "bench.json"
    if not manifest.exists():
        bench.write_manifest(manifest)
    script = tmp_path / "client.py"
    script.write_text(textwrap.dedent(code))
    env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
    t0 = time.monotonic()
    proc = subprocess.run([*HILBENCH, "run", "--manifest", str(manifest), "--", sys.executable, str(script), *args],
                          capture_output=True, text=True, timeout=timeout, env=env)
    wall = time.monotonic() - t0
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc, wall


SLEEPER = """
    import json, os, time
    m0, w0 = time.monotonic_ns(), time.time()
    steps = []
    for _ in range(60):
        a = time.monotonic_ns()
        time.sleep(1)
        steps.append(time.monotonic_ns() - a)
    print(json.dumps({"m0": m0, "steps": steps, "total": time.monotonic_ns() - m0, "real": time.time() - w0,
                      "hashseed": os.environ.get("PYTHONHASHSEED")}))
"""


def test_a_sleeping_client_takes_exact_virtual_seconds_and_little_wall_time(tmp_path):
    with Bench("mecarover-can", virtual_time=True) as bench:
        proc, wall = client(bench, tmp_path, SLEEPER)
        out = json.loads(proc.stdout)
        stats = bench.services["clock"].stats()
        now = bench.clock.now()
    assert out["steps"] == [S] * 60 and out["total"] == 60 * S
    # the held clock did not move before the client joined: it starts where the bench started
    assert out["m0"] == 1000 * S and now == 1060.0  # (and a held bench holds again once its client left)
    assert out["real"] == pytest.approx(60.0, abs=1e-3)  # virtual realtime moves with the monotonic clock
    assert out["hashseed"] == "0"
    assert stats["stalls"] == 0 and stats["threads"] == 0 and stats["threads_seen"] >= 1
    assert wall < 6.0, f"60 virtual seconds took {wall:.2f} s of wall time"


HEARTBEATS = """
    import json, sys, time
    import can
    host, port = sys.argv[1], int(sys.argv[2])
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    beats, t0 = [], time.monotonic()
    for _ in range(60):
        time.sleep(1)
        while (msg := bus.recv(timeout=0)) is not None:
            if msg.arbitration_id == 0x702:
                beats.append((round(time.monotonic() - t0, 6), bytes(msg.data).hex()))
    bus.shutdown()
    print(json.dumps({"beats": beats, "v": time.monotonic() - t0}))
"""


def test_python_can_over_socketcand_sees_the_virtual_heartbeats(tmp_path):
    """PLAN26 §9.1 (b): node 2's heartbeat (1 s) over socketcand, 60 virtual seconds in 1 s sleeps."""
    pytest.importorskip("can")
    with Bench("mecarover-can", virtual_time=True) as bench:
        bench.clock.run_for(0.5, timeout=10)  # past the node's boot-up (0.02 s), then NMT start
        bench.serve_control()
        ControlClient(bench.control.address_text).call("nmt", device="rover", state="operational")
        s = bench.manifest()["endpoints"][0]["socketcand"]
        proc, wall = client(bench, tmp_path, HEARTBEATS, s["host"], str(s["port"]))
        stats = bench.services["clock"].stats()
    out = json.loads(proc.stdout)
    assert out["v"] == pytest.approx(60.0, abs=1e-6)
    # one heartbeat per virtual second (at 1001.02, 1002.02, ...: the boot-up came at 1000.02), OPERATIONAL
    # (0x05), each seen right after the sleep that covered it (the client joined at 1000.5)
    assert [data for _t, data in out["beats"]] == ["05"] * 60
    assert [t for t, _ in out["beats"]] == [float(k) for k in range(1, 61)]
    assert stats["stalls"] == 0
    assert wall < 8.0, f"60 virtual seconds took {wall:.2f} s of wall time"


SPINNER = """
    import ctypes, json, sys, threading, time
    stop = False
    def spin():
        ctypes.CDLL(None).prctl(15, b"spinner", 0, 0, 0)  # PR_SET_NAME: what the warning names
        x = 0
        while not stop:
            x += 1
    t = threading.Thread(target=spin)
    t.start()
    t0 = time.monotonic()
    for _ in range(int(sys.argv[1])):
        time.sleep(0.2)
    stop = True
    t.join()
    print(json.dumps({"v": time.monotonic() - t0}))
"""


def test_a_thread_that_never_waits_makes_a_counted_stall(tmp_path, capfd):
    """PLAN26 §9.1 (g): after the stall threshold time follows the wall clock, counted and warned once."""
    with Bench("mecarover-can", virtual_time=True, lockstep_stall=0.3) as bench:
        proc, wall = client(bench, tmp_path, SPINNER, "5")
        lockstep = bench.services["clock"]
        wait_until(lambda: not lockstep.stats()["stalling"], timeout=5)  # (the loop sees the client's end)
        stats = lockstep.stats()
    out = json.loads(proc.stdout)
    # in the stall virtual time runs at the wall's rate: the main thread's wake-ups (the spinner gives the GIL up
    # every 5 ms) take time too
    assert 1.0 <= out["v"] < 1.5
    assert stats["stalls"] == 1 and 0.9 < stats["stalled_s"] < 2.0 and not stats["stalling"]
    assert stats["last_stall"]["comm"] == "spinner" and stats["last_stall"]["state"] in ("RUNNING", "RUNNABLE")
    warnings = [w for w in lockstep.warnings if "spinner" in w]
    assert len(warnings) == 1 and "ran 0.3 s without waiting; time follows the wall clock" in warnings[0]
    assert "lockstep stall: thread" in capfd.readouterr().err
    assert 0.9 < wall < 6.0


def test_without_a_stall_limit_a_spinning_thread_holds_the_clock(tmp_path):
    with Bench("mecarover-can", virtual_time=True, lockstep_stall=None) as bench:
        manifest = tmp_path / "bench.json"
        bench.write_manifest(manifest)
        script = tmp_path / "client.py"
        script.write_text(textwrap.dedent(SPINNER))
        proc = subprocess.Popen([*HILBENCH, "run", "--manifest", str(manifest), "--", sys.executable, str(script),
                                 "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            with pytest.raises(subprocess.TimeoutExpired):
                proc.wait(timeout=2.0)  # 0.2 virtual seconds of sleep never end: nothing moves time
            assert bench.clock.now() == 1000.0 and bench.services["clock"].stats()["stalls"] == 0
        finally:
            proc.kill()
            proc.wait()


PYSERIAL = """
    import json, sys, time
    import serial
    port = serial.Serial(sys.argv[1], 115200, timeout=1)
    out = []
    for _ in range(3):
        t0 = time.monotonic_ns()
        port.write(bytes([0xA5, 0x50]))  # RPLIDAR GET_INFO
        port.flush()  # tcdrain
        port.dtr = False  # a modem-line request to the port-state server: the clock waits for its answer
        port.dtr = True
        reply = port.read(27)
        t1 = time.monotonic_ns()
        silence = port.read(10)  # nothing more comes: the whole timeout, in virtual time
        out.append([len(reply), t1 - t0, len(silence), time.monotonic_ns() - t1])
    print(json.dumps(out))
"""


def test_a_pyserial_client_on_a_bench_pty_sees_the_wire_model_exactly(tmp_path):
    """The pty path in lockstep: the request is taken before time moves (written == taken), the reply is
    settled on the client's side before the client wakes, and a read's timeout is virtual. DTR changes go
    through the port-state server while the client sleeps in a call the shim does not see: time waits for their
    answers (before, one exchange in three took 247 ms: time had jumped to the motor's next event)."""
    with Bench("mecarover-can", virtual_time=True) as bench:
        serve_port_state(bench)
        path = bench.endpoint("lidar").port.client_path
        proc, wall = client(bench, tmp_path, PYSERIAL, path)
        stats = bench.services["clock"].stats()
    runs = json.loads(proc.stdout)
    wire = (2 + 27) * 10 * S // 115_200  # request and reply at 115200 baud, 8N1
    assert all(r[0] == 27 and r[2] == 0 and r[3] == S for r in runs), runs
    assert len({r[1] for r in runs}) == 1, runs  # the same exchange takes the same virtual time every time
    assert wire <= runs[0][1] < wire + S // 1000
    assert stats["stalls"] == 0 and stats["settle_timeouts"] == 0
    assert wall < 6.0


def test_the_fixture_bench_and_hilbench_run_share_the_clock(hilbench_bench, hilbench_run, tmp_path):
    bench = hilbench_bench("mecarover-can", virtual_time=True, virtual_epoch=1_767_225_600.0, lockstep_stall=None)
    script = tmp_path / "client.py"
    script.write_text("import time\nw = time.time()\ntime.sleep(2.5)\nprint(time.monotonic(), w, time.time())\n")
    proc = subprocess.run(hilbench_run.command(bench, sys.executable, str(script)), capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert [float(x) for x in proc.stdout.split()] == [1002.5, 1_767_225_600.0, 1_767_225_602.5]
    assert bench.clock.now() == 1002.5 and bench.manifest()["clock"]["stall"] is None


def test_emulate_virtual_time_from_the_command_line(hilbench_emulator, hilbench_run, tmp_path):
    manifest = hilbench_emulator("mecarover-can", "--virtual-epoch", "2026-01-01T00:00:00Z", "--lockstep-stall",
                                 "2.5", "--seed", "7", virtual_time=True)
    clock = manifest["clock"]
    assert clock["virtual"] and clock["epoch"] == 1_767_225_600.0 and clock["stall"] == 2.5
    script = tmp_path / "client.py"
    script.write_text("import time\nfor _ in range(30):\n    time.sleep(1)\nprint(time.monotonic(), time.time())\n")
    t0 = time.monotonic()
    proc = subprocess.run(hilbench_run.command(manifest, sys.executable, str(script)), capture_output=True,
                          text=True, timeout=60)
    wall = time.monotonic() - t0
    assert proc.returncode == 0, proc.stderr
    assert [float(x) for x in proc.stdout.split()] == [1030.0, 1_767_225_630.0]
    status = ControlClient(manifest["control"]).call("clock")["clock"]
    assert status["virtual"] and status["mode"] == "hold" and status["now"] == 1030.0
    assert status["stats"]["stalls"] == 0 and status["stats"]["threads_seen"] >= 1
    assert wall < 5.0


@pytest.mark.parametrize(("args", "error"), [
    (["--lockstep-stall", "2", "--seed", "1"], "hilbench: error: --lockstep-stall and --seed need --virtual-time"),
    (["--virtual-time", "--unpaced"], "hilbench: error: virtual time is paced: --unpaced and --virtual-time do not"),
    (["--virtual-time", "--lockstep-stall", "0"], "'0': expected seconds above 0, or never"),
    (["--virtual-time", "--virtual-epoch", "yesterday"], "'yesterday' is neither an ISO 8601 time"),
])
def test_emulate_refuses_bad_virtual_time_options_in_one_line(args, error):
    proc = subprocess.run([*HILBENCH, "emulate", "mecarover-can", *args], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and error in proc.stderr and proc.stderr.count("\n") == 1, proc.stderr


def test_hilbench_run_refuses_the_python_fallback_on_a_virtual_clock(tmp_path):
    with Bench("mecarover-can", virtual_time=True) as bench:
        manifest = tmp_path / "bench.json"
        bench.write_manifest(manifest)
        shim = subprocess.run([*HILBENCH, "run", "--shim", "python", "--manifest", str(manifest), "--", "true"],
                              capture_output=True, text=True, timeout=60)
        env = {**os.environ, "CC": str(tmp_path / "no-cc"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
        cc = subprocess.run([*HILBENCH, "run", "--manifest", str(manifest), "--", "true"], capture_output=True,
                            text=True, timeout=60, env=env)
        assert bench.clock.now() == 1000.0 and bench.services["clock"].stats()["threads_seen"] == 0
    assert shim.returncode == 2 and shim.stderr.count("\n") == 1
    assert "virtual time needs the preload shim: --shim python cannot put a client on the bench's clock" in shim.stderr
    assert cc.returncode == 1 and cc.stderr.count("\n") == 1
    assert "virtual time needs the preload shim: no C compiler" in cc.stderr
