"""The serving path (``hilbench run``: HILBENCH_SERVE=1 on the wall clock, the default under a virtual clock): the bench hands a pty's
device->host bytes to shim clients through a ring in shared memory (hilbench/bench/serve_ring.py); the
shim's read/select/poll/FIONREAD answer from it. The official SDK gets the same bytes as on the kernel
path; a non-shim opener keeps the port on the kernel path; VMIN/VTIME and FIONREAD keep their meaning."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from hilbench.bench import serve_ring
from hilbench.pytest_plugin import wait_until

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc)")

SDK_CLIENT = """
import json, sys
import dynamixel_sdk as sdk
port = sdk.PortHandler(sys.argv[1]); assert port.openPort(); assert port.setBaudRate(1_000_000)
ph = sdk.PacketHandler(2.0)
pings = [list(ph.ping(port, i)) for i in (1, 2, 3, 4, 5, 9)]
reader = sdk.GroupSyncRead(port, ph, 132, 4)
for i in (1, 2, 3, 4):
    reader.addParam(i)
cycles = []
for _ in range(20):
    rc = reader.txRxPacket()
    cycles.append([rc] + [reader.getData(i, 132, 4) for i in (1, 2, 3, 4)])
print(json.dumps({"pings": pings, "cycles": cycles}))
"""

HOLDER = "import os, sys; fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY); print('open', flush=True); sys.stdin.read()"

# A raw client of the pty: FIONREAD, then a VMIN read, a VTIME timeout, and a VMIN=0/VTIME=0 read. It asks
# for bytes on stdin-driven steps so that the test decides when the bench sends (no sleeps).
RAW_CLIENT = r"""
import fcntl, json, os, select, struct, sys, termios, time, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY)
tty.setraw(fd)
def inq():
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]
def cc(vmin, vtime):
    a = termios.tcgetattr(fd); a[6][termios.VMIN] = vmin; a[6][termios.VTIME] = vtime
    termios.tcsetattr(fd, termios.TCSANOW, a)
out = {}
print("ready", flush=True); sys.stdin.readline()          # the bench sent 10 bytes
while inq() < 10:
    select.select([fd], [], [], 1.0)
out["inq"] = inq()
cc(4, 0); out["vmin4"] = os.read(fd, 100).hex()           # 4 of them at least (VMIN), all 10 there
out["inq_after"] = inq()
cc(0, 0); out["vmin0_empty"] = os.read(fd, 100).hex()     # nothing left: 0 bytes at once
cc(0, 2); t0 = time.monotonic(); out["vtime"] = os.read(fd, 100).hex(); out["vtime_s"] = time.monotonic() - t0
print(json.dumps(out), flush=True)
"""


def served_client(bench, hilbench_run, code: str, *args: str) -> subprocess.Popen:
    """``code`` in Python under ``hilbench run`` (the C library) with HILBENCH_SERVE=1, its stdio piped (text)."""
    return subprocess.Popen(hilbench_run.command(bench, shim="c") + [sys.executable, "-c", code, *args],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "HILBENCH_SERVE": "1"})


def run_json(cmd: list[str], env: dict) -> dict:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_sdk_ping_and_sync_read_through_a_served_port_are_the_kernel_paths(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    path, rdev = bench.endpoint().path, bench.endpoint().port.rdev
    cmd = [sys.executable, "-c", SDK_CLIENT, path]
    kernel = run_json(hilbench_run.command(bench, shim="c") + cmd, {**os.environ, "HILBENCH_SERVE": "0"})
    assert rings.read(rdev)["mode"] == serve_ring.KERNEL  # not asked for: never served
    served = run_json(hilbench_run.command(bench, shim="c") + cmd, {**os.environ, "HILBENCH_SERVE": "1"})
    state = rings.read(rdev)
    assert state["mode"] == serve_ring.SERVED
    assert state["head"] > 20 * 4 * 15 and state["head"] == state["tail"]  # every reply went through the ring
    assert served == kernel
    assert [p[1] for p in served["pings"]] == [0, 0, 0, 0, 0, -3001]  # 9 is absent: the SDK's own timeout


def test_a_port_whose_served_clients_are_gone_goes_back_to_the_pty(hilbench_bench, hilbench_run):
    """A client is served, then ends; a program without the shim opens the pty afterwards (it never asks, so no
    /proc scan sees it): the bench notices that no process that asked for the ring is alive and writes to the
    pty again. Before, every reply went on into a ring nobody read and the SDK's every ping timed out."""
    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    path, rdev = bench.endpoint().path, bench.endpoint().port.rdev
    served = run_json(hilbench_run.command(bench, shim="c") + [sys.executable, "-c", SDK_CLIENT, path],
                      {**os.environ, "HILBENCH_SERVE": "1"})
    assert rings.read(rdev)["mode"] == serve_ring.SERVED
    plain = run_json([sys.executable, "-c", SDK_CLIENT, path], dict(os.environ))  # (no shim: the pty itself)
    assert plain == served
    assert rings.read(rdev)["mode"] == serve_ring.KERNEL  # (a later shim client may ask again)


def test_a_non_shim_opener_keeps_the_port_on_the_kernel_path(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    path, rdev = bench.endpoint().path, bench.endpoint().port.rdev
    # another process holds the pty open without the shim (the bench's own descriptors do not count)
    plain = subprocess.Popen([sys.executable, "-c", HOLDER, path], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    try:
        assert plain.stdout.readline().strip() == "open"
        served = run_json(hilbench_run.command(bench, shim="c") + [sys.executable, "-c", SDK_CLIENT, path],
                          {**os.environ, "HILBENCH_SERVE": "1"})
    finally:
        plain.stdin.close()
        plain.wait(timeout=30)
        plain.stdout.close()
    state = rings.read(rdev)
    assert state["mode"] == serve_ring.FALLBACK and state["head"] == 0
    assert [p[1] for p in served["pings"]] == [0, 0, 0, 0, 0, -3001]
    # for good: a later client with every opener a shim is not served either
    run_json(hilbench_run.command(bench, shim="c") + [sys.executable, "-c", SDK_CLIENT, path],
             {**os.environ, "HILBENCH_SERVE": "1"})
    assert rings.read(rdev)["mode"] == serve_ring.FALLBACK


def test_fionread_vmin_and_vtime_on_the_ring(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    port = bench.endpoint().port
    proc = served_client(bench, hilbench_run, RAW_CLIENT, port.path)
    try:
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        # the client's first FIONREAD will claim the port; the test claims it first, then sends as the devices do
        assert bench.services["port_state"].handle(f"{port.rdev} serve") == f"ok {serve_ring.SERVED}"
        assert port.write(bytes(range(10))) == 10
        assert rings.read(port.rdev)["head"] == 10  # in the ring, not the pty
        assert serve_ring.mode_in(rings.path, port.rdev) == serve_ring.SERVED  # as another process reads it
        assert serve_ring.mode_in(rings.path, port.rdev + 1) is None
        proc.stdin.write("go\n")
        proc.stdin.flush()
        out = json.loads(proc.stdout.readline())
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.wait()
    assert out["inq"] == 10
    assert out["vmin4"] == bytes(range(10)).hex() and out["inq_after"] == 0
    assert out["vmin0_empty"] == ""
    assert out["vtime"] == "" and 0.19 <= out["vtime_s"] < 1.0  # VTIME=2: 0.2 s without a byte


EPOLL_CLIENT = r"""
import fcntl, os, select, struct, sys, termios, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
tty.setraw(fd)
fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0")  # claims the port: served
print("claimed", flush=True); sys.stdin.readline()
ep = select.epoll(); ep.register(fd, select.EPOLLIN)  # epoll is not served: back to the kernel path
print("registered", flush=True); sys.stdin.readline()
print(ep.poll(10)[0][0] == fd and os.read(fd, 10).hex(), flush=True)
"""


def test_an_epoll_set_sends_the_port_back_to_the_kernel_path(hilbench_bench, hilbench_run):
    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    port = bench.endpoint().port
    proc = served_client(bench, hilbench_run, EPOLL_CLIENT, port.path)
    try:
        assert proc.stdout.readline().strip() == "claimed", proc.stderr.read()
        assert rings.read(port.rdev)["mode"] == serve_ring.SERVED
        proc.stdin.write("\n")
        proc.stdin.flush()
        assert proc.stdout.readline().strip() == "registered"
        assert rings.read(port.rdev)["mode"] == serve_ring.FALLBACK
        assert port.write(b"\x01\x02\x03") == 3 and rings.read(port.rdev)["head"] == 0  # to the pty
        proc.stdin.write("\n")
        proc.stdin.flush()
        assert proc.stdout.readline().strip() == "010203"
        assert proc.wait(timeout=30) == 0
    finally:
        proc.kill()
        proc.wait()


STREAM_CLIENT = r"""
import hashlib, os, select, sys, tty
fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
tty.setraw(fd)
select.select([fd], [], [], 0)  # claims the port
print("claimed", flush=True)
want, got = int(sys.argv[2]), bytearray()
while len(got) < want:  # pyserial's way: select, then a non-blocking read
    r, _, _ = select.select([fd], [], [], 5.0)
    if not r:
        break
    got += os.read(fd, 4096)
print(len(got), hashlib.sha256(got).hexdigest(), flush=True)
"""


def test_a_stream_in_uneven_chunks_arrives_whole_and_in_order(hilbench_bench, hilbench_run):
    import hashlib
    import random

    bench = hilbench_bench("arm")
    rings = bench.services["port_state"].rings
    port = bench.endpoint().port
    data = random.Random(26).randbytes(1 << 20)  # 16 times the ring: it wraps, the client keeps up
    proc = served_client(bench, hilbench_run, STREAM_CLIENT, port.path, str(len(data)))
    try:
        assert proc.stdout.readline().strip() == "claimed", proc.stderr.read()
        chunks = random.Random(1)
        sent = 0
        while sent < len(data):
            n = min(chunks.randint(1, 700), len(data) - sent)
            wait_until(lambda n=n: (lambda r: r["head"] - r["tail"] + n <= serve_ring.RING)(rings.read(port.rdev)),
                       interval=0.0005)
            assert port.write(data[sent:sent + n]) == n
            sent += n
        assert proc.stdout.readline().split() == [str(len(data)), hashlib.sha256(data).hexdigest()]
        assert proc.wait(timeout=30) == 0
        assert rings.read(port.rdev)["dropped"] == 0
    finally:
        proc.kill()
        proc.wait()
