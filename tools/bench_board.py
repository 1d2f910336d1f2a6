#!/usr/bin/env python3
"""Rover board benchmarks; prints one JSON object per figure (see DESIGN.md §10).

1. Simulation speed: simulated seconds per wall second for the 10000|5000 Hz
   preset (≈ 80,000 stamps per simulated second) with a sampling window open,
   per output path (V1 text at 1,152,000 baud, binary words at 1,152,000
   baud, V3 recording), and with sampling off; then the micro-ROS presets at
   100|50 and 1000 Hz (V1 at 2,000,000 baud), which run on the exact path
   (their executor and network tasks have no periodic model). Reference: real
   time (1.0). Target: ratio >= 10 for every path. ``cpu_ratio`` divides by
   this process's CPU time instead of wall time (steadier on a shared machine).
2. Frame round trip over a pty: a host writes a Vel2d frame and waits for the
   board's ``[recv vel]`` log line, against ``hilbench emulate mecarover`` in
   another process (115200 baud, the ST-LINK link). Reference: the wire-time
   model of one round trip (frame, one idle character, log line at the baud).

Usage: tools/bench_board.py [--seconds S] [--only sim|roundtrip]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import serial

from hilbench.bench.manifest import read_manifest
from hilbench.fakes.stm32_board import Board, BoardConfig, make_preset
from hilbench.protocols import vel2d

REPO = Path(__file__).resolve().parents[1]


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 3), "unit": unit, "reference": round(reference, 3),
                      "ratio": round(ratio, 3), **extra}), flush=True)


def bench_sim(seconds: float, repeats: int = 3) -> None:
    fast = "freertos-10000-5000"
    cases = [(fast, "v1", 1_152_000, True), (fast, "binary", 1_152_000, True), (fast, "v3", 1_152_000, True),
             (fast, "v1", 1_152_000, False), ("micro-ros-100-50", "v1", 2_000_000, True),
             ("micro-ros-1000", "v1", 2_000_000, True)]
    for preset, output, baud, sampling in cases:
        ratios, cpu_ratios, stamps_rates = [], [], []
        truth = None
        for _ in range(repeats):
            board = Board(BoardConfig(make_preset(preset), output=output, baud=baud,
                                      window_ms=seconds * 1000 + 100 if output == "v3" else None))
            board.run_for(0.05)
            if sampling:
                board.press_button()
            board.run_for(0.01)
            c0 = time.process_time()
            t0 = time.perf_counter()
            board.run_for(seconds)
            wall = time.perf_counter() - t0
            cpu = time.process_time() - c0
            truth = board.truth
            ratios.append(seconds / wall)
            cpu_ratios.append(seconds / cpu)
            stamps_rates.append(board.fw.kernel.ctx_switches / wall)
        ratio = statistics.median(ratios)
        rates = preset.split("-", 1)[1] if preset.startswith("freertos-") else preset.replace("-", "_")
        label = f"board_sim_{rates.replace('-', '_')}_{output}" + ("" if sampling else "_not_sampling")
        emit(label, ratio, "sim s/wall s", 1.0, ratio, target_ratio=10, best_ratio=round(max(ratios), 3),
             cpu_ratio=round(statistics.median(cpu_ratios), 3),
             stamps_per_wall_s=round(statistics.median(stamps_rates)), stamps_recorded=truth.stamps_recorded,
             stamps_sent=truth.stamps_sent, stamps_dropped=truth.stamps_dropped, records_lost=truth.records_lost,
             simulated_s=seconds, baud=baud)


def bench_roundtrip(seconds: float) -> None:
    tmp = tempfile.TemporaryDirectory(prefix="hilbench-bench-")
    manifest = Path(tmp.name) / "manifest.json"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "mecarover", "--manifest",
                             str(manifest)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
    try:
        deadline = time.monotonic() + 20
        while not manifest.exists():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"emulator did not start: {proc.stderr.read().decode()}")
            time.sleep(0.01)
        ep = read_manifest(manifest)["endpoints"][0]
        baud = ep["baud"]
        port = serial.Serial(ep["path"], baud, timeout=1)
        frame = vel2d.build(0.1, -0.2, 0.3)
        expect = b"[recv vel] [100.000000 -200.000000 0.300000]\n"
        line_len = len(b"00:00:00 [INFO]: ") + len(expect)
        port.reset_input_buffer()
        times = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            t0 = time.perf_counter()
            port.write(frame)
            port.flush()
            buf = b""
            while not buf.endswith(expect):
                chunk = port.read_until(b"\n")
                if not chunk:
                    raise SystemExit("the board did not answer within 1 s")
                buf = chunk
            times.append(time.perf_counter() - t0)
        port.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        tmp.cleanup()
    model = (28 + 1 + line_len) * 10 / baud  # frame, idle detection, log line
    rate = len(times) / sum(times)
    emit("board_frame_round_trip_pty", rate, "round trips/s", 1 / model, rate * model, baud=baud,
         round_trips=len(times), median_ms=round(statistics.median(times) * 1e3, 3),
         model_ms=round(model * 1e3, 3), p90_ms=round(sorted(times)[int(0.9 * len(times))] * 1e3, 3))


def bench_rough() -> None:
    """The board's receiver (idle-line framing and CRC of Vel2d frames) on noise and on a stream of frames
    with 1 % of the bytes damaged, against a 12.5 Mbit/s UART (tools/rough.py). A continuous stream that
    lost a byte stays misaligned until the line idles, as on the board: few frames pass, none wrongly."""
    from rough import measure

    from hilbench.protocols.vel2d_targets import VEL2D

    measure(VEL2D, prefix="board_rough_")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds per sim run, wall seconds "
                                                               "for the round trip (default: 3)")
    ap.add_argument("--only", choices=("sim", "rough", "roundtrip"))
    args = ap.parse_args()
    if args.only in (None, "sim"):
        bench_sim(args.seconds)
    if args.only in (None, "rough"):
        bench_rough()
    if args.only in (None, "roundtrip"):
        bench_roundtrip(args.seconds)


if __name__ == "__main__":
    main()
