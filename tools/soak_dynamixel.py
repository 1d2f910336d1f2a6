#!/usr/bin/env python3
"""Soak test of a paced Dynamixel bus: the official SDK's 20-servo cycle for minutes on end.

``hilbench emulate`` runs the ``wolfgang`` profile with its bus at 4.5 Mbaud,
paced; this process drives it with the official SDK (Sync Read of Present
Position + Sync Write of Goal Position to 20 servos) on a 1 kHz schedule: a
cycle starts at its slot, or at once when the previous one ran over (the wire
alone needs 995.6 us of each millisecond at 4.5 Mbaud, so the schedule is
the bus's limit as much as the client's; ``overruns`` counts the cycles that
took longer than a period). It counts every reply that did not
come (a failed Sync Read costs the replies it lacked) and samples both
processes' resident memory over time. For each failed read it notes how long
this process waited for a CPU meanwhile (/proc schedstat): the SDK checks its
34 ms timeout after each read, so a client kept off the CPU that long fails
although the replies came.

Prints one JSON object per sample (``"sample"``) and a summary
(``"name": "dxl_soak_..."``): cycles, achieved rate, missed replies, cycle
time percentiles, the emulator's CPU per cycle, resident memory (first,
last, max, and its slope over the second half of the run in kB/min: flat
memory is a slope near 0), the machine's load average.

Usage: tools/soak_dynamixel.py [--minutes 10] [--rate 1000] [--baud 4500000] [--load N] [--sample 10]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import dynamixel_sdk as sdk
from bench_dynamixel import CustomBaudPortHandler, neighbours, process_cpu_s, start_emulator, wolfgang_at
from benchlib import CYCLE_BYTES, sdk_cycle

IDS = list(range(1, 21))
HIST_BIN = 10e-6
HIST_BINS = 5000  # up to 50 ms; longer cycles land in the last bin (the maximum is kept apart)


def percentile(hist: list[int], q: float) -> float:
    """The ``q`` quantile of a histogram of cycle times, in ms (upper edge of its bin)."""
    total, seen = sum(hist), 0
    for i, n in enumerate(hist):
        seen += n
        if seen >= q * total:
            return round((i + 1) * HIST_BIN * 1e3, 3)
    return float("inf")


def runqueue_wait_s(fd: int) -> float:
    """Seconds this thread has spent runnable but waiting for a CPU (/proc/thread-self/schedstat, field 2)."""
    return int(os.pread(fd, 128, 0).split()[1]) / 1e9


def rss_kb(pid: int) -> int:
    """Resident memory of a process (VmRSS, kB)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def slope_kb_per_min(samples: list[tuple[float, int]]) -> float:
    """Least-squares slope of (seconds, kB) samples, in kB per minute."""
    if len(samples) < 2:
        return 0.0
    ts = [t for t, _ in samples]
    vs = [v for _, v in samples]
    mt, mv = statistics.fmean(ts), statistics.fmean(vs)
    den = sum((t - mt) ** 2 for t in ts)
    return 0.0 if den == 0 else sum((t - mt) * (v - mv) for t, v in samples) / den * 60


def soak(minutes: float, rate: float, baud: int, sample_every: float) -> dict:
    proc, path, tmp = start_emulator(True, wolfgang_at(baud))
    try:
        port = CustomBaudPortHandler(path)
        if not (port.openPort() and port.setBaudRate(baud)):
            raise SystemExit(f"the SDK did not open {path} at {baud}")
        ph, reader, writer = sdk_cycle(port, IDS)
        period = 1.0 / rate
        cycles = failed_reads = missed = overruns = 0
        hist = [0] * (HIST_BINS + 1)  # cycle times in 10 us bins (a list of every time would grow: not a soak)
        longest = 0.0
        emu_rss: list[tuple[float, int]] = []
        own_rss: list[tuple[float, int]] = []
        failures: list[dict] = []  # what each failed read looked like (the first 50)
        sched = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        cpu0 = process_cpu_s(proc.pid)
        t0 = time.perf_counter()
        end = t0 + minutes * 60
        next_slot = t0
        next_sample = t0
        while True:
            now = time.perf_counter()
            if now >= next_sample:
                emu_rss.append((now - t0, rss_kb(proc.pid)))
                own_rss.append((now - t0, rss_kb(os.getpid())))
                print(json.dumps({"sample": round(now - t0, 1), "cycles": cycles, "missed_replies": missed,
                                  "failed_reads": failed_reads, "rss_emulator_kb": emu_rss[-1][1],
                                  "rss_client_kb": own_rss[-1][1], "loadavg": round(os.getloadavg()[0], 2)}),
                      flush=True)
                next_sample += sample_every
            if now >= end:
                break
            if now < next_slot:
                time.sleep(next_slot - now)  # (the SDK busy-polls anyway; this only waits for the slot)
            started = time.perf_counter()
            next_slot = max(next_slot, started) + period  # behind schedule: no burst to catch up
            waited = runqueue_wait_s(sched)
            if reader.txRxPacket() != sdk.COMM_SUCCESS:
                failed_reads += 1
                if len(failures) < 50:
                    # the SDK gives up after 34 ms; if this process waited that long for a CPU meanwhile, the
                    # replies may have come while it was not running (it checks its timeout after a read)
                    failures.append({"at_s": round(started - t0, 1),
                                     "took_ms": round((time.perf_counter() - started) * 1e3, 1),
                                     "client_waited_for_cpu_ms": round((runqueue_wait_s(sched) - waited) * 1e3, 1),
                                     "bytes_waiting_after": port.getBytesAvailable()})
            missed += sum(not reader.isAvailable(i, 132, 4) for i in IDS)
            writer.txPacket()
            took = time.perf_counter() - started
            hist[min(int(took / HIST_BIN), HIST_BINS)] += 1
            overruns += took > period
            longest = max(longest, took)
            cycles += 1
        elapsed = time.perf_counter() - t0
        cpu = process_cpu_s(proc.pid) - cpu0
        os.close(sched)
        port.closePort()
    finally:
        proc.terminate()
        proc.wait(timeout=5)
        tmp.cleanup()
    half = [s for s in emu_rss if s[0] >= elapsed / 2]
    wire = CYCLE_BYTES * 10 / baud
    return {
        "name": f"dxl_soak_{baud / 1e6:g}M".replace(".5M", "M5"), "minutes": round(elapsed / 60, 2),
        "cycles": cycles, "rate_hz": round(cycles / elapsed, 1), "target_rate_hz": rate,
        "wire_cycle_us": round(wire * 1e6, 1), "missed_replies": missed, "failed_reads": failed_reads,
        "overruns": overruns,
        "cycle_ms": {"p50": percentile(hist, 0.5), "p99": percentile(hist, 0.99), "max": round(longest * 1e3, 3)},
        "emulator_cpu_us_per_cycle": round(cpu / max(cycles, 1) * 1e6, 1),
        "rss_emulator_kb": {"first": emu_rss[0][1], "last": emu_rss[-1][1], "max": max(v for _, v in emu_rss),
                            "slope_second_half_kb_per_min": round(slope_kb_per_min(half), 2)},
        "rss_client_kb": {"first": own_rss[0][1], "last": own_rss[-1][1], "max": max(v for _, v in own_rss)},
        "failures": failures,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=1000.0, help="cycles per second to aim at")
    ap.add_argument("--baud", type=int, default=4_500_000)
    ap.add_argument("--load", type=int, default=0, metavar="N", help="N CPU-bound neighbour processes meanwhile")
    ap.add_argument("--sample", type=float, default=10.0, help="seconds between memory samples")
    args = ap.parse_args()
    avg = round(os.getloadavg()[0], 2)
    with neighbours(args.load):
        result = soak(args.minutes, args.rate, args.baud, args.sample)
    print(json.dumps({**result, "load": args.load, "loadavg_at_start": avg,
                      "loadavg_at_end": round(os.getloadavg()[0], 2)}), flush=True)


if __name__ == "__main__":
    main()
