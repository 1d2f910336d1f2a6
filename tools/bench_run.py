#!/usr/bin/env python3
"""``hilbench run`` benchmarks: what a client pays per call for a serial adapter's semantics.

A pyserial client in its own process, under ``hilbench run`` (the preload shim, then the Python
fallback), against an unpaced ``arm`` bench in this process, times each call (median of
``--samples``; p90 alongside):

- ``run_tiocmget_<shim>``: ``ser.cts`` (TIOCMGET, answered by the port-state server);
- ``run_set_dtr_<shim>``: ``ser.dtr = ...`` (TIOCMBIS/TIOCMBIC, taken in the line's thread);
- ``run_flush_<shim>``: ``ser.write(16 bytes); ser.reset_output_buffer()`` (the flush takes them);
- ``run_drain_<shim>``: ``ser.write(16 bytes); ser.flush()`` (tcdrain: returns once delivered);
- ``run_untouched_ioctl_c``: ``ser.in_waiting`` (an ioctl the shim passes through), with the
  shim loaded; its reference is the same call without it, measured in the same run;
- ``run_idle_drain_<shim>``: ``ser.flush()`` with everything written already delivered (what
  dynamixel-sdk 3.x does before every packet); reference: the same call on the plain pty;
- ``run_sdk_ping_<shim>``: the official SDK's ``ping`` (dynamixel-sdk 3.x from ``make install``'s
  ``.venv/dynamixel-sdk-3`` if there, whose ``clearPort()`` drains before every packet; else the
  installed one); reference: the same client on the plain pty. ``--rounds`` rounds of ``--pings``
  pings alternate plain and shim; value and reference are the medians of the rounds' medians, the
  ratio the median of the rounds' ratios (``ratios``: each round's; ``min_*``: fastest pings).

The reference of the first four is 1 ms: one full-speed USB frame, what a modem-line change or a
flush costs at least on a real USB serial adapter. Prints one JSON object per figure.

Usage: tools/bench_run.py [--samples N] [--pings N] [--rounds N]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import benchlib

from hilbench.bench import Bench
from hilbench.bench.port_state_server import serve_port_state

USB_FRAME = 0.001

WORKER = r"""
import json, statistics, sys, time
import serial
n = int(sys.argv[2])
ser = serial.Serial(sys.argv[1], 1_000_000)
def timed(fn):
    times = []
    for _ in range(n):
        t0 = time.perf_counter(); fn(); times.append(time.perf_counter() - t0)
    times.sort()
    return [statistics.median(times), times[int(len(times) * 0.9)]]
state = [False]
def toggle():
    state[0] = not state[0]; ser.dtr = state[0]
def flush():
    ser.write(b"0123456789abcdef"); ser.reset_output_buffer()
def drain():
    ser.write(b"0123456789abcdef"); ser.flush()
ser.write(b"0123456789abcdef"); ser.flush()
out = {"untouched_ioctl": timed(lambda: ser.in_waiting), "idle_drain": timed(ser.flush)}
try:
    out.update(tiocmget=timed(lambda: ser.cts), set_dtr=timed(toggle), flush=timed(flush), drain=timed(drain))
except OSError:
    pass  # a plain pty: no modem lines
print(json.dumps(out))
"""


SDK_WORKER = r"""
import json, statistics, sys, time
import dynamixel_sdk as sdk
port = sdk.PortHandler(sys.argv[1])
assert port.openPort()
ph = sdk.PacketHandler(2.0)
times, failed = [], 0
for _ in range(int(sys.argv[2])):
    t0 = time.perf_counter(); _, result, _ = ph.ping(port, 1); dt = time.perf_counter() - t0
    if result == sdk.COMM_SUCCESS:
        times.append(dt)
    else:
        failed += 1  # the SDK's ~35 ms reply timeout, hit when a loaded machine stalls either side
times.sort()
print(json.dumps({"median": statistics.median(times), "min": times[0], "failed": failed, "sdk": sdk.__file__}))
"""

#: dynamixel-sdk 3.x beside the venv's packages (the Makefile installs it there).
SDK3 = os.path.join(sys.prefix, "dynamixel-sdk-3")


emit = functools.partial(benchlib.emit, digits=6)


def worker(path: str, samples: int, prefix: list[str], code: str = WORKER, env: dict | None = None) -> dict:
    proc = subprocess.run([*prefix, sys.executable, "-c", code, path, str(samples)], capture_output=True,
                          text=True, timeout=600, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"worker failed: {proc.stderr.strip()}")
    return json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=2000, help="calls timed per figure (default 2000)")
    parser.add_argument("--pings", type=int, default=300, help="SDK pings timed per round (default 300)")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of plain and shim SDK pings (default 5)")
    args = parser.parse_args()
    sdk_env = dict(os.environ)
    if os.path.isdir(os.path.join(SDK3, "dynamixel_sdk")):
        sdk_env["PYTHONPATH"] = os.pathsep.join(p for p in (SDK3, os.environ.get("PYTHONPATH")) if p)
    with Bench("arm", paced=False) as bench, tempfile.TemporaryDirectory() as tmp:
        serve_port_state(bench)
        manifest = str(Path(tmp) / "arm.json")
        bench.write_manifest(manifest)
        path = bench.endpoint().path
        plain = worker(path, args.samples, [])
        shims = ["c", "python"] if shutil.which("cc") else ["python"]
        for shim in shims:
            prefix = [sys.executable, "-m", "hilbench.cli", "run", "--shim", shim, "--manifest", manifest, "--"]
            got = worker(path, args.samples, prefix)
            for key in ("tiocmget", "set_dtr", "flush", "drain"):
                median, p90 = got[key]
                emit(f"run_{key}_{shim}", median * 1e6, "us", USB_FRAME * 1e6, median / USB_FRAME,
                     p90_us=round(p90 * 1e6, 1))
            median, p90 = got["idle_drain"]
            ref = plain["idle_drain"][0]
            emit(f"run_idle_drain_{shim}", median * 1e6, "us", ref * 1e6, median / ref, p90_us=round(p90 * 1e6, 2))
            # The load of a shared machine moves a whole run: alternate the two, compare each pair.
            pairs = [(worker(path, args.pings, [], SDK_WORKER, sdk_env),
                      worker(path, args.pings, prefix, SDK_WORKER, sdk_env)) for _ in range(args.rounds)]
            ratios = [got["median"] / ref["median"] for ref, got in pairs]
            emit(f"run_sdk_ping_{shim}", statistics.median(got["median"] for _, got in pairs) * 1e6, "us",
                 statistics.median(ref["median"] for ref, _ in pairs) * 1e6, statistics.median(ratios),
                 sdk="3.x" if "dynamixel-sdk-3" in pairs[0][0]["sdk"] else "installed",
                 ratios=[round(r, 2) for r in ratios], min_us=round(min(g["min"] for _, g in pairs) * 1e6, 1),
                 min_reference_us=round(min(r["min"] for r, _ in pairs) * 1e6, 1),
                 failed=sum(g["failed"] for _, g in pairs), failed_reference=sum(r["failed"] for r, _ in pairs))
            if shim == "c":
                median, p90 = got["untouched_ioctl"]
                ref = plain["untouched_ioctl"][0]
                emit("run_untouched_ioctl_c", median * 1e6, "us", ref * 1e6, median / ref,
                     p90_us=round(p90 * 1e6, 2))


if __name__ == "__main__":
    main()
