#!/usr/bin/env python3
"""``hilbench run`` benchmarks: what a client pays per call for a serial adapter's semantics.

A pyserial client in its own process, under ``hilbench run`` (the preload shim, then the Python
fallback), against an unpaced ``arm`` bench in this process, times each call (median of
``--samples``; p90 alongside):

- ``run_tiocmget_<shim>``: ``ser.cts`` (TIOCMGET, answered by the line server);
- ``run_set_dtr_<shim>``: ``ser.dtr = ...`` (TIOCMBIS/TIOCMBIC, taken in the line's thread);
- ``run_flush_<shim>``: ``ser.write(16 bytes); ser.reset_output_buffer()`` (the flush takes them);
- ``run_drain_<shim>``: ``ser.write(16 bytes); ser.flush()`` (tcdrain: returns once delivered);
- ``run_untouched_ioctl_c``: ``ser.in_waiting`` (an ioctl the shim passes through), with the
  shim loaded; its reference is the same call without it, measured in the same run.

The reference of the others is 1 ms: one full-speed USB frame, what a modem-line change or a
flush costs at least on a real USB serial adapter. Prints one JSON object per figure.

Usage: tools/bench_run.py [--samples N]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from hilbench.bench import Bench
from hilbench.bench.line_server import serve_lines

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
out = {"untouched_ioctl": timed(lambda: ser.in_waiting)}
try:
    out.update(tiocmget=timed(lambda: ser.cts), set_dtr=timed(toggle), flush=timed(flush), drain=timed(drain))
except OSError:
    pass  # a plain pty: no modem lines
print(json.dumps(out))
"""


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 6), "unit": unit, "reference": round(reference, 6),
                      "ratio": round(ratio, 3), **extra}), flush=True)


def worker(path: str, samples: int, prefix: list[str]) -> dict:
    proc = subprocess.run([*prefix, sys.executable, "-c", WORKER, path, str(samples)], capture_output=True,
                          text=True, timeout=600)
    if proc.returncode != 0:
        raise SystemExit(f"worker failed: {proc.stderr.strip()}")
    return json.loads(proc.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=2000, help="calls timed per figure (default 2000)")
    args = parser.parse_args()
    with Bench("arm", paced=False) as bench, tempfile.TemporaryDirectory() as tmp:
        serve_lines(bench)
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
            if shim == "c":
                median, p90 = got["untouched_ioctl"]
                ref = plain["untouched_ioctl"][0]
                emit("run_untouched_ioctl_c", median * 1e6, "us", ref * 1e6, median / ref,
                     p90_us=round(p90 * 1e6, 2))


if __name__ == "__main__":
    main()
