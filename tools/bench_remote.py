#!/usr/bin/env python3
"""Remote bench benchmark; prints one JSON object per figure (see DESIGN.md §11).

The official dynamixel-sdk's 20-servo control cycle (Sync Read of Present
Position + Sync Write of Goal Position) against ``hilbench emulate wolfgang
--serve rfc2217`` in another process, measured in the same run
- over the bench's pty (the reference), and
- over RFC 2217 on 127.0.0.1 (pyserial's rfc2217:// client under the SDK's
  PortHandler, :class:`hilbench.clients.dynamixel.UrlPortHandler`).
``ratio`` = RFC 2217 cycles/s / pty cycles/s (target >= 0.5), unpaced and
paced (2 Mbaud wire time modelled). Each is the median of ``--rounds``
alternating rounds, so a machine shared with other jobs disturbs both alike.

Usage: tools/bench_remote.py [--seconds S] [--rounds N] [--only unpaced|paced]
"""

from __future__ import annotations

import argparse
import statistics
import time

import dynamixel_sdk as sdk
from benchlib import emit, emulator, sdk_cycle

from hilbench.clients.dynamixel import port_handler

BAUD = 2_000_000
IDS = list(range(1, 21))


def cycles_per_second(path: str, seconds: float) -> float:
    """SDK cycles per second on ``path`` (a pty or an rfc2217:// URL), after a warm-up."""
    port = port_handler(path)
    if not (port.openPort() and port.setBaudRate(BAUD)):
        raise SystemExit(f"cannot open {path}")
    ph, reader, writer = sdk_cycle(port, IDS)
    failures = 0

    def cycle() -> None:
        nonlocal failures
        if reader.txRxPacket() != sdk.COMM_SUCCESS:
            failures += 1
        writer.txPacket()

    warm_end = time.perf_counter() + min(0.5, seconds / 4)
    while time.perf_counter() < warm_end:
        cycle()
    failures = n = 0
    t0 = time.perf_counter()
    while time.perf_counter() < t0 + seconds:
        cycle()
        n += 1
    dt = time.perf_counter() - t0
    port.closePort()
    if failures > n // 100:
        raise SystemExit(f"{path}: {failures} of {n} sync reads failed")
    return n / dt


def bench(paced: bool, seconds: float, rounds: int) -> None:
    local, remote = [], []
    with emulator("wolfgang", "--paced" if paced else "--unpaced", "--serve", "rfc2217", "--no-tap") as manifest:
        endpoint = manifest["endpoints"][0]
        for _ in range(rounds):
            local.append(cycles_per_second(endpoint["path"], seconds))
            remote.append(cycles_per_second(endpoint["rfc2217"], seconds))
    ref, value = statistics.median(local), statistics.median(remote)
    emit(f"rfc2217_sdk_cycle_{'paced_2M' if paced else 'unpaced'}", value, "cycles/s", ref, value / ref,
         target_ratio=0.5, reference_is="the same cycle over the bench's pty",
         rounds_rfc2217=[round(x, 1) for x in remote], rounds_pty=[round(x, 1) for x in local])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="measuring time per round and transport")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--only", choices=("unpaced", "paced"))
    args = ap.parse_args()
    if args.only in (None, "unpaced"):
        bench(False, args.seconds, args.rounds)
    if args.only in (None, "paced"):
        bench(True, args.seconds, args.rounds)


if __name__ == "__main__":
    main()
