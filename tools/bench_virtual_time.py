#!/usr/bin/env python3
"""Virtual-time benchmarks (issue 26, PLAN26 §9.2); prints one JSON object per figure (DESIGN.md §10).

Every bench runs in its own ``hilbench emulate PROFILE --virtual-time`` process and every client under
``hilbench run`` against it, as a user would run them.

- ``vt_idle_speed``: ``mecarover-can`` and a client sleeping 60 virtual seconds in 1 s steps: virtual
  seconds per wall second (reference 1.0: the wall clock); the client's start-up (interpreter, imports)
  is measured apart with a client that sleeps 0 s and taken off.
- ``vt_busy_speed``: the official SDK's 20-servo Sync Read + Sync Write cycle on ``wolfgang`` (the loop of
  tools/benchlib.sdk_cycle) for ``--seconds`` virtual seconds: virtual seconds per wall second, start-up
  taken off the same way; ``vt_busy_speed_one_cpu`` the same with the bench and the client on one CPU.
- ``vt_sdk_cycle_spread`` and ``wall_sdk_cycle_spread``: ``--runs`` runs of that cycle beside ``--load``
  CPU-bound neighbour processes, in virtual time and on the wall clock (``emulate wolfgang --paced``, the
  SDK in this process as tools/bench_dynamixel.py drives it) side by side: the spread of the cycle time,
  (max - min) / median, with each run's cycle time as a ratio to the wire model (``runs_ratio``), its
  cycle count and failed reads. The model is the cycle's bytes at 2 Mbaud, 8N1 (the servos' Return Delay
  Time is 0 on this profile).

- ``vt_flood``: a client writing ``--flood-mib`` MiB as fast as it can into the ``arm`` bench's 1 Mbaud bus:
  the virtual time its writes took against the wire's time for those bytes (reference 1.0: held back as
  on the wall clock), virtual seconds per wall second, and the bench's RSS before and at the end (MB).

- ``vt_trace_speed``: ``mecarover`` (the FreeRTOS board at 115200 baud, its log lines, and after a button
  press its 1000 ms trace window dumped) and a pyserial reader under ``hilbench run`` reading
  ``--trace-seconds`` virtual seconds: virtual seconds per wall second, start-up taken off, and the bytes
  read against what the wire can carry in that time.

- ``vt_micro_ros_speed``: ``mecarover-micro-ros`` (the rover board's micro-ROS session with the bench's agent,
  encoder_data at 50 Hz, odometry and wheel_vel at 33.3 Hz, each routed back to the board) and a client
  under ``hilbench run`` sleeping ``--micro-ros-seconds`` virtual seconds, twice on fresh benches: virtual
  seconds per wall second, start-up taken off, and the board's samples (the same in both runs).

Usage: tools/bench_virtual_time.py [--seconds S] [--runs N] [--load N] [--flood-mib M] [--trace-seconds S]
                                  [--micro-ros-seconds S] [--only idle|busy|spread|flood|trace|micro-ros]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from benchlib import CYCLE_BYTES, REPO, emit, emulator

BAUD = 2_000_000
MODEL = CYCLE_BYTES * 10 / BAUD  # seconds per cycle

SLEEPER = "import sys, time\nfor _ in range(int(sys.argv[1])):\n    time.sleep(1)\n"

#: The SDK's cycle as a program under `hilbench run` (PORT SECONDS: one JSON line).
SDK_CLIENT = REPO / "tools" / "sdk_cycle_client.py"


def loadavg() -> float:
    return round(os.getloadavg()[0], 2)


@contextlib.contextmanager
def neighbours(n: int) -> Iterator[None]:
    """``n`` CPU-bound neighbour processes (pure-Python spinning), outside any lockstep."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def run_client(manifest: dict, code: str | Path, *args: str) -> tuple[str, float]:
    """``hilbench run --manifest M -- python CODE ARGS`` (``code``: Python source, or a script's path): (its
    stdout, wall seconds)."""
    with tempfile.TemporaryDirectory(prefix="hilbench-vt-") as tmp:
        path = Path(tmp) / "manifest.json"
        path.write_text(json.dumps(manifest))
        script = code if isinstance(code, Path) else Path(tmp) / "client.py"
        if not isinstance(code, Path):
            script.write_text(code)
        env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
        t0 = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "run", "--manifest", str(path), "--",
                               sys.executable, str(script), *args], capture_output=True, text=True, env=env,
                              cwd=REPO, timeout=600)
        wall = time.monotonic() - t0
    if proc.returncode != 0:
        raise SystemExit(f"the client failed: {proc.stderr}")
    return proc.stdout, wall


def clock_stats(manifest: dict) -> dict:
    from hilbench.bench.control import ControlClient

    return ControlClient(manifest["control"]).call("clock")["clock"]["stats"]


def bench_idle(seconds: int = 60) -> None:
    avg = loadavg()
    with emulator("mecarover-can", "--virtual-time") as m:
        _, startup = run_client(m, SLEEPER, "0")
        _, wall = run_client(m, SLEEPER, str(seconds))
        stats = clock_stats(m)
    speed = seconds / max(wall - startup, 1e-6)
    emit("vt_idle_speed", speed, "virtual s per wall s", 1.0, speed, digits=1, virtual_s=seconds,
         wall_s=round(wall, 3), startup_s=round(startup, 3), stalls=stats["stalls"], loadavg=avg)


def sdk_virtual(seconds: float) -> tuple[dict, float, float, dict]:
    """One SDK run on a fresh virtual-time wolfgang emulator: (figures, wall s, start-up wall s, clock stats)."""
    with emulator("wolfgang", "--virtual-time") as m:
        path = m["endpoints"][0]["path"]
        _, startup = run_client(m, SDK_CLIENT, path, "0")
        out, wall = run_client(m, SDK_CLIENT, path, str(seconds))
        stats = clock_stats(m)
    return json.loads(out), wall, startup, stats


FLOOD = """
import json, os, sys, termios, time, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
attrs = termios.tcgetattr(fd)
attrs[4] = attrs[5] = termios.B1000000
termios.tcsetattr(fd, termios.TCSANOW, attrs)
n, total, chunk = 0, int(sys.argv[2]), bytes(4096)
t0 = time.monotonic_ns()
while n < total:
    n += os.write(fd, chunk[:total - n])
print(json.dumps({"written": n, "ns": time.monotonic_ns() - t0}))
"""


TRACE_READER = """
import json, sys, time
import serial
port = serial.Serial(sys.argv[1], 115200, timeout=0.05)
seconds = float(sys.argv[2])
n, t0 = 0, time.monotonic()
while time.monotonic() - t0 < seconds:
    n += len(port.read(4096))
print(json.dumps({"bytes": n, "virtual_s": time.monotonic() - t0}))
"""


def bench_trace(seconds: float) -> None:
    from hilbench.clients.stm32_rover import BoardClient

    avg = loadavg()
    with emulator("mecarover", "--virtual-time") as m:
        path = next(e["path"] for e in m["endpoints"] if e["name"] == "rover")
        _, startup = run_client(m, TRACE_READER, path, "0")
        BoardClient(m["control"]).button()  # (the trace window starts at the next virtual instant)
        out, wall = run_client(m, TRACE_READER, path, str(seconds))
        stats = clock_stats(m)
    got = json.loads(out)
    speed = seconds / max(wall - startup, 1e-6)
    emit("vt_trace_speed", speed, "virtual s per wall s", 1.0, speed, digits=2, virtual_s=seconds,
         wall_s=round(wall, 3), startup_s=round(startup, 3), bytes=got["bytes"],
         line_share=round(got["bytes"] * 10 / 115_200 / got["virtual_s"], 3), stalls=stats["stalls"],
         loadavg=avg)


def bench_micro_ros(seconds: int) -> None:
    from hilbench.clients.stm32_rover import BoardClient

    avg = loadavg()
    runs = []
    for _ in range(2):
        with emulator("mecarover-micro-ros", "--virtual-time") as m:
            _, startup = run_client(m, SLEEPER, "0")
            _, wall = run_client(m, SLEEPER, str(seconds))
            link = BoardClient(m["control"]).micro_ros()
            stats = clock_stats(m)
        runs.append((seconds / max(wall - startup, 1e-6), wall, startup, link["counters"], stats["stalls"]))
    speed = statistics.median(r[0] for r in runs)
    emit("vt_micro_ros_speed", speed, "virtual s per wall s", 1.0, speed, digits=2, virtual_s=seconds,
         runs_speed=[round(r[0], 2) for r in runs], wall_s=[round(r[1], 3) for r in runs],
         startup_s=[round(r[2], 3) for r in runs], samples_out=[r[3]["samples_out"] for r in runs],
         samples_in=[r[3]["samples_in"] for r in runs], datagrams=[r[3]["datagrams_out"] for r in runs],
         stalls=[r[4] for r in runs], loadavg=avg)


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024


def bench_flood(mib: int) -> None:
    avg = loadavg()
    total = mib * 1024 * 1024
    with emulator("arm", "--virtual-time") as m:
        path = m["endpoints"][0]["path"]
        before = rss_mb(m["pid"])
        out, wall = run_client(m, FLOOD, path, str(total))
        after = rss_mb(m["pid"])
        stats = clock_stats(m)
    virtual = json.loads(out)["ns"] / 1e9
    wire = total * 10 / 1_000_000
    emit("vt_flood", virtual / wire, "client's write time / wire time", 1.0, virtual / wire, digits=4,
         ratio_digits=4, mib=mib, virtual_s=round(virtual, 3), wire_s=round(wire, 3), wall_s=round(wall, 2),
         speed=round(virtual / wall, 1), rss_mb=[round(before, 1), round(after, 1)], stalls=stats["stalls"],
         loadavg=avg)


def cycle_time(done: list[int]) -> float:
    """Seconds per cycle between the first and the last cycle's end."""
    return (done[-1] - done[0]) / 1e9 / (len(done) - 1)


def bench_busy(seconds: float) -> None:
    """vt_busy_speed, then vt_busy_speed_one_cpu: the same with the bench and its client on one CPU (as
    ``taskset -c N`` runs them). The lockstep runs one of them at a time, so one CPU loses no parallelism and
    spares every hand-over a wake-up on another CPU."""
    allowed = os.sched_getaffinity(0)
    for name, cpus in (("vt_busy_speed", allowed), ("vt_busy_speed_one_cpu", {max(allowed)})):
        if name.endswith("one_cpu") and len(allowed) < 2:
            continue
        avg = loadavg()
        os.sched_setaffinity(0, cpus)  # (the processes started below inherit it)
        try:
            out, wall, startup, stats = sdk_virtual(seconds)
        finally:
            os.sched_setaffinity(0, allowed)
        speed = seconds / max(wall - startup, 1e-6)
        emit(name, speed, "virtual s per wall s", 1.0, speed, virtual_s=seconds, wall_s=round(wall, 3),
             startup_s=round(startup, 3), cycles=out["cycles"], failed_reads=out["failed"],
             cycle_ratio=round(cycle_time(out["done"]) / MODEL, 6), stalls=stats["stalls"], loadavg=avg,
             cpus=sorted(cpus), serving=os.environ.get("HILBENCH_SERVE") != "0")


def sdk_wall(seconds: float) -> tuple[float, int, int]:
    """One wall-clock paced run (tools/bench_dynamixel.py's): (seconds per cycle, cycles, failed reads)."""
    import bench_dynamixel as bd

    proc, path, tmp = bd.start_emulator(True)
    try:
        n, dt, _cpu, _own = bd.run_cycles(path, seconds, proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=5)
        tmp.cleanup()
    return dt / n, n, bd.CONDITION["failed_reads"]


def spread(times: list[float]) -> float:
    return (max(times) - min(times)) / statistics.median(times)


def bench_spread(seconds: float, runs: int, load: int) -> None:
    avg = loadavg()
    vt, vt_counts, vt_failed, vt_stalls, vt_walls = [], [], [], [], []
    with neighbours(load):
        for _ in range(runs):
            out, wall, _startup, stats = sdk_virtual(seconds)
            vt.append(cycle_time(out["done"]))
            vt_counts.append(out["cycles"])
            vt_failed.append(out["failed"])
            vt_stalls.append(stats["stalls"])
            vt_walls.append(round(wall, 2))
        wall_runs = [sdk_wall(seconds) for _ in range(runs)]
    emit("vt_sdk_cycle_spread", spread(vt), "(max-min)/median", 0.0, spread(vt), digits=6, load=load, loadavg=avg,
         runs=runs, runs_ratio=[round(t / MODEL, 6) for t in vt], cycles=vt_counts, failed_reads=vt_failed,
         stalls=vt_stalls, wall_s=vt_walls, model_ms=round(MODEL * 1e3, 6),
         note=f"{seconds:g} virtual s per run; runs_ratio: cycle time / wire model")
    wt = [t for t, _, _ in wall_runs]
    emit("wall_sdk_cycle_spread", spread(wt), "(max-min)/median", 0.0, spread(wt), digits=6, load=load,
         loadavg=avg, runs=runs, runs_ratio=[round(t / MODEL, 4) for t in wt], cycles=[n for _, n, _ in wall_runs],
         failed_reads=[f for _, _, f in wall_runs], model_ms=round(MODEL * 1e3, 6),
         note=f"{seconds:g} wall s per run, emulate --paced; runs_ratio: cycle time / wire model")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="virtual (or wall) seconds per SDK run")
    ap.add_argument("--runs", type=int, default=5, help="SDK runs per mode for the spread")
    ap.add_argument("--load", type=int, default=1, metavar="N", help="CPU-bound neighbours during the spread runs")
    ap.add_argument("--flood-mib", type=int, default=16, metavar="M", help="MiB the flood client writes")
    ap.add_argument("--trace-seconds", type=float, default=5.0, metavar="S",
                    help="virtual seconds the trace reader reads")
    ap.add_argument("--micro-ros-seconds", type=int, default=20, metavar="S",
                    help="virtual seconds of the micro-ROS bench")
    ap.add_argument("--only", choices=("idle", "busy", "spread", "flood", "trace", "micro-ros"))
    args = ap.parse_args()
    if args.only in (None, "idle"):
        bench_idle()
    if args.only in (None, "busy"):
        bench_busy(args.seconds)
    if args.only in (None, "spread"):
        bench_spread(args.seconds, args.runs, args.load)
    if args.only in (None, "flood"):
        bench_flood(args.flood_mib)
    if args.only in (None, "trace"):
        bench_trace(args.trace_seconds)
    if args.only in (None, "micro-ros"):
        bench_micro_ros(args.micro_ros_seconds)


if __name__ == "__main__":
    main()
