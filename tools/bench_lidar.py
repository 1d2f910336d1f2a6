#!/usr/bin/env python3
"""Laser-scanner benchmarks; prints one JSON object per figure (see DESIGN.md §11).

1. What the emulated RPLIDAR A1 delivers to a client: ``hilbench emulate
   scanners`` runs in its own process (motor started through the control
   channel's DTR, as a client's DTR would), and a client in this process reads
   the pty for ``--seconds`` and decodes the nodes (standard scan, then
   express). Figures, each as a ratio to the A1's nominal value (target:
   within 5 %):
   - ``a1_revolutions_per_s``: revolutions per second (S = 1 flags) vs 5.5 Hz;
   - ``a1_samples_per_revolution``: vs 1e6 / 508 us / 5.5 Hz = 357.9;
   - ``a1_express_samples_per_revolution``: vs 1e6 / 254 us / 5.5 Hz = 715.8;
   - ``a1_line_bytes_per_s``: bytes per second vs 5 bytes every 508 us (9843 B/s).
2. Ray casting throughput for a 100-segment scene (a room and 24 boxes), in
   1081-beam batches (one UST-10LX scan), as a ratio to what the three units of
   the ``scanners`` bench need together in real time: A1 express 3937 beams/s
   + LMS 200 at its 75 Hz mirror, 181 beams = 13575 + UST-10LX 1081 x 40 Hz =
   43240, 60752 beams/s in all (target: >= 100x):
   - ``raycast_beams_per_s``: what the emulators do for a scanner whose pose stays put (the static
     segments' visibility map from that origin, built once, then one binary search and one
     intersection per beam);
   - ``raycast_moving_origin_beams_per_s``: a new origin every scan (no map: each edge against the
     beams inside the angle it subtends);
   - ``raycast_dense_beams_per_s``: every beam against every edge, for comparison.
   Each is the median of ``--repeats`` runs (best in ``best_ratio``): the machine is shared and noisy.

Usage: tools/bench_lidar.py [--seconds S] [--repeats N] [--only delivery|raycast]
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time

import benchlib
import numpy as np

NOMINAL_HZ = 5.5
NEEDED_BEAMS = 1e6 / 254 + 75 * 181 + 1081 * 40


emit = functools.partial(benchlib.emit, digits=4, ratio_digits=4)


def _read_revolutions(path: str, request: bytes, seconds: float) -> tuple[list[float], list[int], int, float]:
    """Decode what the A1 sends for ``seconds``: revolution start times, samples per revolution, bytes."""
    import serial

    from hilbench.protocols import rplidar as rp

    dec = rp.ResponseDecoder()
    asm = rp.ScanAssembler(min_points=10)
    starts: list[float] = []
    counts: list[int] = []
    total = 0
    with serial.Serial(path, 115200, timeout=0.02) as port:
        port.write(request)
        t_first = None
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            data = port.read(4096)
            if not data:
                continue
            now = time.monotonic()
            if t_first is None:
                t_first = now
            else:
                total += len(data)
            for item in dec.feed(data):
                if isinstance(item, rp.Node):
                    for rev in asm.add_node(item):
                        starts.append(now)
                        counts.append(len(rev))
                elif isinstance(item, rp.CapsuleItem):
                    for rev in asm.add_capsule(item):
                        starts.append(now)
                        counts.append(len(rev))
        span = time.monotonic() - (t_first or time.monotonic())
        port.write(rp.request(rp.Cmd.STOP))
    return starts, counts[1:], total, span  # the first revolution is partial (random phase)


def bench_delivery(seconds: float) -> None:
    from hilbench.bench.control import ControlClient

    with benchlib.emulator("scanners", timeout=30) as m:
        path = next(e["path"] for e in m["endpoints"] if e["name"] == "lidar")
        ControlClient(m["control"]).call("dtr", device="lidar", dtr=False)  # the motor runs, as a client's DTR
        time.sleep(1.0)  # spin-up, so the revolution count starts at speed
        from hilbench.protocols import rplidar as rp

        starts, counts, nbytes, span = _read_revolutions(path, rp.request(rp.Cmd.SCAN), seconds)
        rate = (len(starts) - 1) / (starts[-1] - starts[0])
        spr = statistics.mean(counts)
        cond = {"seconds": seconds, "revolutions": len(starts), "client": "pyserial + hilbench decoder, "
                "separate process from the emulator"}
        emit("a1_revolutions_per_s", rate, "Hz", NOMINAL_HZ, rate / NOMINAL_HZ, **cond)
        nominal_spr = 1e6 / 508 / NOMINAL_HZ
        emit("a1_samples_per_revolution", spr, "samples", nominal_spr, spr / nominal_spr,
             min=min(counts), max=max(counts), **cond)
        line = 5 * 1e6 / 508
        emit("a1_line_bytes_per_s", nbytes / span, "B/s", line, nbytes / span / line, **cond)
        time.sleep(0.3)
        starts, counts, _, _ = _read_revolutions(path, rp.request(rp.Cmd.EXPRESS_SCAN, bytes(5)), seconds)
        spr = statistics.mean(counts)
        nominal_spr = 1e6 / 254 / NOMINAL_HZ
        emit("a1_express_samples_per_revolution", spr, "samples", nominal_spr, spr / nominal_spr,
             min=min(counts), max=max(counts), seconds=seconds, revolutions=len(starts))


def bench_raycast(repeats: int) -> None:
    from hilbench.fakes.scene import Scene

    rng = np.random.default_rng(7)
    boxes = [{"center": (rng.uniform(-5, 5), rng.uniform(-3.5, 3.5)), "size": tuple(rng.uniform(0.2, 0.6, 2)),
              "heading": rng.uniform(0, 90)} for _ in range(24)]
    scene = Scene.build(walls=[[(-6, -4), (6, -4), (6, 4), (-6, 4), (-6, -4)]], boxes=boxes)
    assert len(scene.segments) == 100
    beams = np.radians(np.arange(1081) * 0.25 - 135.0)
    for name, dense in (("raycast_beams_per_s", False), ("raycast_dense_beams_per_s", True)):
        runs, cpu = [], []
        for _ in range(repeats):
            n = 0
            t0, c0 = time.perf_counter(), time.process_time()
            while time.perf_counter() - t0 < 0.5:
                scene.cast(0.1, 0.2, beams + n * 1e-4, dense=dense)  # a slightly different scan each time
                n += 1
            runs.append(n * len(beams) / (time.perf_counter() - t0))
            cpu.append(n * len(beams) / max(time.process_time() - c0, 1e-9))
        med = statistics.median(runs)
        emit(name, med, "beams/s", NEEDED_BEAMS, med / NEEDED_BEAMS, best_ratio=round(max(runs) / NEEDED_BEAMS, 2),
             cpu_ratio=round(statistics.median(cpu) / NEEDED_BEAMS, 2), segments=100, batch=1081, repeats=repeats)
    # A scanner that moves (a new origin every scan) gets no visibility map: the culled caster alone.
    runs = []
    for _ in range(repeats):
        n = 0
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.5:
            scene.cast(0.1 + n * 1e-3, 0.2, beams)
            n += 1
        runs.append(n * len(beams) / (time.perf_counter() - t0))
    med = statistics.median(runs)
    emit("raycast_moving_origin_beams_per_s", med, "beams/s", NEEDED_BEAMS, med / NEEDED_BEAMS,
         best_ratio=round(max(runs) / NEEDED_BEAMS, 2), segments=100, batch=1081, repeats=repeats)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="client read time per scan mode (default 10)")
    ap.add_argument("--repeats", type=int, default=7, help="ray casting runs of 0.5 s (default 7)")
    ap.add_argument("--only", choices=("delivery", "raycast"))
    args = ap.parse_args()
    if args.only in (None, "raycast"):
        bench_raycast(args.repeats)
    if args.only in (None, "delivery"):
        bench_delivery(args.seconds)


if __name__ == "__main__":
    main()
