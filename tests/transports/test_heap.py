"""Memory goes back to the system once a flood's queues are freed (glibc's malloc keeps it otherwise)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from hilbench.transports import heap
from tests.conftest import REPO

# Tap clients that never read fill their 1 MiB buffers while the bench goes on allocating (kept here: a
# few kB among them); then they leave. The first flood raises glibc's mmap threshold (a freed mmapped
# chunk does), so the second one's buffers come from the heap, between the kept allocations: without a
# trim the process stayed ~20 MB larger (measured: 21 -> 41 MB after the second flood).
SCRIPT = r"""
import json, socket, time
from hilbench.transports import heap
from hilbench.transports.tap_server import TapServer

def wait_until(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            raise SystemExit("timed out")
        time.sleep(0.01)

def rss():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024

server = TapServer()
kept = []

def flood(n=16):
    clients = []
    for _ in range(n):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect((server.host, server.port))
        clients.append(s)
    wait_until(lambda: server.clients == n)
    k = 0
    while server.status()["buffered_bytes"] < n * server.max_buffer:
        server.feed(time.monotonic(), "bus", bytes(1000))
        k += 1
        if k % 256 == 0:
            kept.append(bytearray(2048))
    peak = rss()
    for s in clients:
        s.close()
    wait_until(lambda: server.clients == 0)
    return peak

before = rss()
flood()
wait_until(lambda: heap.trims >= 1)
peak = flood()
wait_until(lambda: heap.trims >= 2)
print(json.dumps({"before": before, "peak": peak, "after": rss()}))
server.close()
"""


@pytest.mark.skipif(heap._malloc_trim() is None, reason="the C library has no malloc_trim (not glibc)")
def test_a_tap_flood_gives_its_memory_back_when_its_clients_leave():
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=60, cwd=REPO)
    assert done.returncode == 0, done.stderr
    mb = json.loads(done.stdout)
    assert mb["peak"] - mb["before"] > 12  # the flood did take memory (16 clients x 1 MiB, and more)
    assert mb["after"] - mb["before"] < 5, mb


def test_an_ebb_asks_once_per_flood(monkeypatch):
    asked = []
    monkeypatch.setattr(heap, "give_back", lambda: asked.append(1))
    ebb = heap.Ebb(high=1 << 20)
    for size in (10, 500_000, 2 << 20, 900_000, 3 << 20, heap.LOW):  # filling up, draining: still holding a lot
        ebb.note(size)
    assert asked == []
    ebb.note(0)  # emptied after holding more than 1 MiB
    ebb.note(0)
    assert asked == [1]
    ebb.note(500_000)
    ebb.note(0)  # never above its mark again: nothing to give back
    assert asked == [1]
