#!/usr/bin/env python3
"""Rough input at line rate: every registered decoder and instrument on noise and on mutated input.

For each target of the ``hilbench.fuzz_targets`` registry (:mod:`hilbench.fuzzing`; a new
family's decoder joins with one entry-point line) this prints one JSON object per figure,
as the other benchmarks do: the bytes per second it reads

- ``<name>_noise``: 1 MB of random bytes;
- ``<name>_mutated``: its clean traffic (or a real capture the calling benchmark gives)
  with 1 % of the bytes damaged (bits flipped, bytes replaced, lost or added);
- ``<name>_clean``: the same traffic undamaged, for comparison;

against the reference of its fastest line (``line_rate``: 450 kB/s for a 4.5 Mbaud servo
bus, 1.25 MB/s for a 12.5 Mbit/s UART). The target is a ratio of at least 10 on noise and
on mutated input: resynchronising must cost linear time. Each figure is the median of
``--repeats`` runs (wall clock) with the best run and the CPU-time median beside it: the
machine is shared and noisy.

The benchmarks import :func:`measure` for their own decoders with real seeds (the
Wolfgang capture, the emulated board's traces); run alone it measures every target
with the traffic its registration makes.

Usage: tools/rough.py [--only NAME,...] [--size BYTES] [--repeats N] [--rate R] [--chunk BYTES]
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import time

from hilbench.fuzzing import FuzzTarget, mutate, run, targets

TARGET_RATIO = 10


def timed(target: FuzzTarget, data: bytes, chunk: int, repeats: int) -> tuple[list[float], list[float], object]:
    """Wall and CPU seconds of ``repeats`` runs of a fresh reader over ``data``."""
    wall, cpu, reader = [], [], None
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        reader = run(target.make(), data, chunk)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return wall, cpu, reader


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 3), "unit": unit, "reference": round(reference, 3),
                      "ratio": round(ratio, 2), **extra}), flush=True)


def measure(target: FuzzTarget, *, seed: bytes | None = None, seed_name: str = "", size: int = 1_000_000,
            repeats: int = 3, rate: float = 0.01, chunk: int = 65536, prefix: str = "",
            kinds: tuple[str, ...] = ("clean", "noise", "mutated")) -> dict[str, float]:
    """Print the figures of one target; returns ``{kind: ratio}`` (median)."""
    rng = random.Random(11)
    clean = seed if seed is not None else target.sample(rng, size)
    inputs = {
        "clean": (clean, seed_name or "its clean traffic"),
        "noise": (target.noise(rng, size), f"{size} random bytes" + (" after a sound header" if target.frame
                                                                     else "")),
        "mutated": (mutate(rng, clean, rate=rate), f"{seed_name or 'its clean traffic'} with {rate:.0%} of the "
                                                   "bytes damaged"),
    }
    ref = target.line_rate / 1e6
    ratios = {}
    for kind in kinds:
        data, what = inputs[kind]
        wall, cpu, reader = timed(target, data, chunk, repeats)
        mbs = len(data) / statistics.median(wall) / 1e6
        ratios[kind] = mbs / ref
        emit(f"{prefix}{target.name}_{kind}", mbs, "MB/s", ref, mbs / ref,
             best_ratio=round(len(data) / min(wall) / 1e6 / ref, 2),
             cpu_ratio=round(len(data) / statistics.median(cpu) / 1e6 / ref, 2),
             target_ratio=TARGET_RATIO if kind != "clean" else None, line=target.line, input=what,
             bytes=len(data), good=reader.good(), dropped=reader.dropped(), chunk=chunk, repeats=repeats)
    return ratios


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", help="comma-separated target names (default: every registered decoder and "
                                   "instrument; servers only by name)")
    ap.add_argument("--size", type=int, default=1_000_000, help="bytes of noise and of clean traffic")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rate", type=float, default=0.01, help="share of bytes damaged in mutated input")
    ap.add_argument("--chunk", type=int, default=65536, help="bytes per feed() call")
    args = ap.parse_args()
    names = set(args.only.split(",")) if args.only else None
    for target in targets():
        if target.kind == "server" and names is None:
            continue  # a client's session, not a line's bytes: tools/fuzz.py drives the servers
        if names is None or target.name in names:
            measure(target, size=args.size, repeats=args.repeats, rate=args.rate, chunk=args.chunk)


if __name__ == "__main__":
    main()
