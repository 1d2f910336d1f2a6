#!/usr/bin/env python3
"""CAN benchmarks; prints one JSON object per figure (see DESIGN.md §10).

Reference for every figure: a saturated 1 Mbit/s classic CAN bus carrying
8-byte standard frames, computed in this run from the exact (stuffed) bit
length of the frames sent (1e6 / bits per frame, about 8,400 frames/s).

1. ``socketcand_to_python_can``: frames per second from the emulated bus
   through the socketcand server to an unmodified python-can client
   (``interface="socketcand"``) in another process, which counts them. The
   bus is unpaced and a device floods it, so the bridge is the bottleneck.
   Target: ratio >= 2.
2. ``bus_unpaced``: the emulated bus's own frame rate unpaced: one device
   sends, another receives, a tap sees every frame (no host ports).
3. ``bus_paced_1m``: the paced bus at 1 Mbit/s under a flood: frames per
   second it delivers, against the bus's theoretical capacity (ratio 1.0
   means it keeps wire time exactly).

Usage: tools/bench_can.py [--frames N] [--only socketcand|unpaced|paced]
"""

from __future__ import annotations

import argparse
import functools
import json
import subprocess
import sys
import threading
import time

import benchlib
from benchlib import REPO

from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import data_frame
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.can_port import CanPort

CLIENT = r"""
import json, logging, sys, time, can
# python-can logs a warning for every read that ends inside a message (a flooded link splits them); count them.
class Count(logging.Handler):
    n = 0
    def emit(self, record):
        Count.n += 1
logging.getLogger("can").addHandler(Count())
logging.getLogger("can").propagate = False
bus = can.Bus(interface="socketcand", host=sys.argv[1], port=int(sys.argv[2]), channel="can0")
n = int(sys.argv[3])
print("ready", flush=True)
got = 0
first = last = None
while got < n:
    msg = bus.recv(5)
    if msg is None:
        break
    if msg.arbitration_id != 0x555:
        continue
    now = time.perf_counter()
    first = first or now
    last = now
    got += 1
bus.shutdown()
print(json.dumps({"frames": got, "seconds": (last - first) if first else 0.0, "split_reads": Count.n}), flush=True)
"""


emit = functools.partial(benchlib.emit, digits=1)


FRAME = data_frame(0x555, bytes(range(8)))
SATURATED_1M = 1_000_000 / cf.frame_bits(FRAME)


class Source:
    """The flooding device (it hears nothing it cares about)."""

    name = "flood"

    def on_frame(self, frame, t) -> None:
        pass


class Sink:
    def __init__(self, name: str, expect: int) -> None:
        self.name = name
        self.expect = expect
        self.count = 0
        self.done = threading.Event()
        self.t_last = 0.0

    def on_frame(self, frame, t) -> None:
        self.count += 1
        if self.count == self.expect:
            self.t_last = time.perf_counter()
            self.done.set()


def flood(medium: CanMedium, port, n: int, batch: int = 500, backlog: int | None = None) -> None:
    """Send n frames from the bus thread, a batch per event, so the sender never waits on anything.

    With ``backlog`` (a paced bus) the sender keeps at most that many frames queued, as a real
    controller's transmit queue blocks its writer."""
    left = [n]

    def step() -> None:
        k = min(batch, left[0])
        if backlog is not None:
            queued = len(medium._queues.get(port.name, ()))
            k = min(k, max(0, backlog - queued))
        for _ in range(k):
            port.send(FRAME)
        left[0] -= k
        if left[0] > 0:
            medium.call_at(None if backlog is None else time.monotonic() + 0.002, step)

    medium.call_at(None, step)


def bench_socketcand(n: int) -> None:
    port = CanPort.open("can", CanPort.check_options({"slcan": False, "socketcand": {"rawmode_delay_ms": 0}}))
    medium = CanMedium("can", 1_000_000, paced=False)
    dport = medium.add_device(Source())
    medium.add_host(port)
    medium.start()
    host, tcp = port.socketcand.address
    proc = subprocess.Popen([sys.executable, "-c", CLIENT, host, str(tcp), str(n)], stdout=subprocess.PIPE,
                            text=True, cwd=REPO)
    try:
        assert proc.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 10
        while not (port.socketcand.clients and port.socketcand.clients[0].mode == "raw"):
            if time.monotonic() > deadline:
                raise RuntimeError("the client never switched to rawmode")
            time.sleep(0.005)
        flood(medium, dport, n)
        result = json.loads(proc.stdout.readline())
    finally:
        proc.wait(timeout=30)
        medium.close()
        port.close()
    rate = result["frames"] / result["seconds"] if result["seconds"] else 0.0
    emit("socketcand_to_python_can", rate, "frames/s", SATURATED_1M, rate / SATURATED_1M, frames=result["frames"],
         split_reads=result["split_reads"],
         condition="unpaced bus flooded by one device; python-can socketcand client in another process")


def bench_bus(n: int, paced: bool) -> None:
    """One device floods the bus, another receives every frame (unpaced: a tap sees them too)."""
    medium = CanMedium("can", 1_000_000, paced=paced)
    tapped = [0]
    if not paced:
        medium.add_tap(lambda t, s, d: tapped.__setitem__(0, tapped[0] + 1))
    sink = Sink("sink", n)
    dport = medium.add_device(Source())
    medium.add_device(sink)
    medium.start()
    t0 = time.perf_counter()
    if paced:
        flood(medium, dport, n, batch=200, backlog=400)
    else:
        flood(medium, dport, n)
    if not sink.done.wait(120):
        raise RuntimeError(f"the {'paced ' if paced else ''}bus delivered {sink.count} of {n} frames in 120 s")
    rate = n / (sink.t_last - t0)
    medium.close()
    if paced:
        emit("bus_paced_1m", rate, "frames/s", SATURATED_1M, rate / SATURATED_1M,
             condition="1 Mbit/s, one sender flooding 8-byte frames, exact bit stuffing")
    else:
        emit("bus_unpaced", rate, "frames/s", SATURATED_1M, rate / SATURATED_1M, tapped=tapped[0],
             condition="one sender, one receiving device, one tap")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40_000, help="frames per measurement (default 40000)")
    ap.add_argument("--only", choices=("socketcand", "unpaced", "paced"))
    args = ap.parse_args()
    if args.only in (None, "socketcand"):
        bench_socketcand(args.frames)
    if args.only in (None, "unpaced"):
        bench_bus(args.frames, paced=False)
    if args.only in (None, "paced"):
        bench_bus(min(args.frames, 20_000), paced=True)


if __name__ == "__main__":
    main()
