#!/usr/bin/env python3
"""Dynamixel benchmarks; prints one JSON object per figure (see DESIGN.md §10).

1. Decoder throughput on the real Wolfgang capture, as a ratio to the
   4.5 Mbaud line rate (450,000 bytes/s). Target: >= 30x.
2. A 20-servo control cycle (Sync Read of Present Position + Sync Write of
   Goal Position) driven by the official SDK in this process against
   ``hilbench emulate wolfgang`` in another:
   - unpaced: cycles/s (target >= 1000/s on a 2-core machine); the reference
     is the cycle rate the 2 Mbaud wire allows;
   - paced at 2 Mbaud: measured cycle time against the wire-time model of the
     cycle (target: within 10%, i.e. ratio 0.9..1.1).

Usage: tools/bench_dynamixel.py [--capture PATH] [--seconds S] [--only decoder|unpaced|paced]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dynamixel_sdk as sdk

from hilbench.bench.manifest import read_manifest
from hilbench.protocols.dynamixel import Decoder

REPO = Path(__file__).resolve().parents[1]
LINE_RATE_4M5 = 450_000  # bytes/s at 4.5 Mbaud, 8N1
BAUD = 2_000_000
IDS = list(range(1, 21))
# Wire bytes of one cycle: Sync Read (14 + 20) + 20 replies (11 + 4) + Sync Write (14 + 20 * 5).
CYCLE_BYTES = (14 + 20) + 20 * 15 + (14 + 20 * 5)


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 3), "unit": unit, "reference": round(reference, 3),
                      "ratio": round(ratio, 3), **extra}), flush=True)


def bench_decoder(capture: Path, repeats: int = 9) -> None:
    """``ratio``: median wall time; ``best_ratio``: best run; ``cpu_ratio``: median of this process's CPU time
    (``time.process_time``), which a machine shared with other jobs disturbs less."""
    data = capture.read_bytes()
    for label, chunk in (("whole", len(data)), ("4k_chunks", 4096)):
        times, cpu = [], []
        for _ in range(repeats):
            dec = Decoder()
            t0, c0 = time.perf_counter(), time.process_time()
            for i in range(0, len(data), chunk):
                dec.feed(data[i : i + chunk])
            dec.flush()
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        rate = len(data) / statistics.median(times)
        emit(f"dxl_decoder_{label}", rate, "bytes/s", LINE_RATE_4M5, rate / LINE_RATE_4M5, target_ratio=30,
             best_ratio=round(len(data) / min(times) / LINE_RATE_4M5, 3),
             cpu_ratio=round(len(data) / statistics.median(cpu) / LINE_RATE_4M5, 3), packets=dec.packets)


def start_emulator(paced: bool) -> tuple[subprocess.Popen, str, tempfile.TemporaryDirectory]:
    tmp = tempfile.TemporaryDirectory(prefix="hilbench-bench-")
    manifest = Path(tmp.name) / "manifest.json"
    cmd = [sys.executable, "-m", "hilbench.cli", "emulate", "wolfgang", "--manifest", str(manifest),
           "--paced" if paced else "--unpaced"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
    deadline = time.monotonic() + 20
    while not manifest.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise SystemExit(f"emulator did not start: {proc.stderr.read().decode()}")
        time.sleep(0.01)
    path = read_manifest(manifest)["endpoints"][0]["path"]
    return proc, path, tmp


def process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_cycles(path: str, seconds: float, emulator_pid: int) -> tuple[int, float, float]:
    """(cycles, seconds, emulator CPU seconds) of the measured cycles, after a warm-up."""
    port = sdk.PortHandler(path)
    port.openPort()
    port.setBaudRate(BAUD)
    ph = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    writer = sdk.GroupSyncWrite(port, ph, 116, 4)
    for i in IDS:
        reader.addParam(i)
        writer.addParam(i, [0x00, 0x08, 0, 0])

    def cycle() -> None:
        if reader.txRxPacket() != sdk.COMM_SUCCESS:
            raise SystemExit("sync read failed")
        writer.txPacket()

    warm_end = time.perf_counter() + min(0.5, seconds / 4)
    while time.perf_counter() < warm_end:
        cycle()
    n = 0
    cpu0 = process_cpu_s(emulator_pid)
    t0 = time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        cycle()
        n += 1
    dt = time.perf_counter() - t0
    cpu = process_cpu_s(emulator_pid) - cpu0
    port.closePort()
    return n, dt, cpu


def bench_cycle(paced: bool, seconds: float) -> None:
    proc, path, tmp = start_emulator(paced)
    try:
        n, dt, emulator_cpu = run_cycles(path, seconds, proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=5)
        tmp.cleanup()
    wire_cycle = CYCLE_BYTES * 10 / BAUD  # seconds per cycle on the wire, Return Delay Time 0
    if paced:
        measured = dt / n
        emit("dxl_sdk_cycle_paced_2M", measured * 1e3, "ms/cycle", wire_cycle * 1e3, measured / wire_cycle,
             target="ratio within 0.9..1.1", cycles=n)
    else:
        rate = n / dt
        emit("dxl_sdk_cycle_unpaced", rate, "cycles/s", 1 / wire_cycle, rate * wire_cycle, target_value=1000,
             cycles=n, cpus=os.cpu_count())
        # The emulator's CPU per cycle varies far less with the machine's load than the cycle rate,
        # which also includes the SDK's own (busy-polling) side and both processes' wake-ups.
        per_cycle = emulator_cpu / n
        emit("dxl_emulator_cpu_per_cycle", per_cycle * 1e6, "us", wire_cycle * 1e6, per_cycle / wire_cycle,
             note="emulator process CPU per 20-servo cycle, against the cycle's wire time")


def bench_rough(capture: Path) -> None:
    """Both decoders on 1 MB of noise and on damaged input (the Wolfgang capture with 1 % of its bytes
    damaged; Protocol 1.0 traffic of its own), against the 4.5 Mbaud line (tools/rough.py)."""
    from rough import measure

    from hilbench.protocols.targets import DYNAMIXEL, DYNAMIXEL1

    measure(DYNAMIXEL, seed=capture.read_bytes(), seed_name="the Wolfgang capture", prefix="dxl_rough_")
    measure(DYNAMIXEL1, prefix="dxl_rough_")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=REPO / "tests/data/dynamixel/wolfgang_trace.bin")
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per cycle benchmark")
    ap.add_argument("--only", choices=("decoder", "rough", "unpaced", "paced"))
    args = ap.parse_args()
    if args.only in (None, "decoder"):
        bench_decoder(args.capture)
    if args.only in (None, "rough"):
        bench_rough(args.capture)
    if args.only in (None, "unpaced"):
        bench_cycle(False, args.seconds)
    if args.only in (None, "paced"):
        bench_cycle(True, args.seconds)


if __name__ == "__main__":
    main()
