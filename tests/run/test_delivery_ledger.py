"""Drains and output flushes with nothing pending cost no request (the delivery ledger), and everything
written is still delivered before a drain returns, through dup(), fork(), a reopened descriptor and stdio;
requests reuse connections; the official SDK's ping costs what it costs on a plain pty."""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from hilbench.bench import delivery_ledger
from hilbench.pytest_plugin import wait_until
from hilbench.run import pyserial_shim
from tests import dynamixel_sdk3
from tests.run.port_event_recorder import OutputFlushed, PortEventRecorder

CLIENTS = Path(__file__).parent / "clients"
HAVE_CC = shutil.which("cc") is not None
SHIMS = [pytest.param("c", marks=pytest.mark.skipif(not HAVE_CC, reason="no C compiler (cc)")), "python"]
IDLE = 300


class Stepper:
    """Drives a client that answers each line on its stdin with one line on its stdout."""

    def __init__(self, cmd: list[str]) -> None:
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)

    def step(self, name: str, answer: str | None = None) -> None:
        self.proc.stdin.write(name + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline().strip()
        assert line == (answer or name), f"{line!r}; stderr: {self.proc.stderr.read() if not line else ''}"

    def close(self) -> int:
        self.proc.stdin.close()
        code = self.proc.wait(timeout=30)
        self.proc.stdout.close()
        self.proc.stderr.close()
        return code


def flushed(before: bytes, last: bytes) -> list[list]:
    """What the devices may hear after ``write(last); tcflush(TCOFLUSH)`` on a paced line: the flush while
    ``last`` is still on the wire (the usual case), or after it (the client was slower than its wire time)."""
    return [[before, OutputFlushed(), last], [before + last, OutputFlushed()]]


@pytest.fixture(scope="module")
def drain_client(tmp_path_factory) -> str:
    if not HAVE_CC:
        pytest.skip("no C compiler (cc): the test client cannot be built")
    exe = tmp_path_factory.mktemp("drain-client") / "drain_client"
    subprocess.run(["cc", "-O1", "-Wall", "-o", str(exe), str(CLIENTS / "drain_client.c")], check=True,
                   capture_output=True)
    return str(exe)


def test_board_layout_is_the_same_for_every_reader():
    ledger, shim = delivery_ledger, pyserial_shim
    assert (ledger.MAGIC, ledger.VERSION, ledger.HEADER_SIZE, ledger.SLOT_SIZE, ledger.FILE_NAME) == (
        shim.LEDGER_MAGIC, shim.LEDGER_VERSION, shim.LEDGER_HEADER, shim.LEDGER_SLOT, shim.LEDGER_FILE)
    assert (ledger.RDEV, ledger.IDLE_NS, ledger.DIRTY_NS, ledger.DIRTY_PY_NS, ledger.WRITING, ledger.WRITING_PY,
            ledger.DRAIN_NS) == (shim.LEDGER_RDEV, shim.LEDGER_IDLE_NS, shim.LEDGER_DIRTY_NS, shim.LEDGER_DIRTY_PY_NS,
                                shim.LEDGER_WRITING, shim.LEDGER_WRITING_PY, shim.LEDGER_DRAIN_NS)
    source = (Path(pyserial_shim.__file__).parent / "shim.c").read_text()
    fields = re.search(r"struct ledger_slot \{(.*?)\};", source, re.S).group(1)
    assert re.findall(r"uint64_t (\w+)", fields) == ["rdev", "idle_ns", "dirty_ns", "dirty_py_ns", "writing",
                                                     "writing_py", "drain_ns", "reserved"]
    assert f'#define LEDGER_MAGIC "{ledger.MAGIC.decode()}"' in source
    assert f"#define LEDGER_VERSION {ledger.VERSION}" in source
    assert f"#define LEDGER_HEADER {ledger.HEADER_SIZE}" in source


def test_the_bench_publishes_only_after_writers_returned(hilbench_bench):
    """``idle_ns`` moves past a write once its bytes are delivered, not while a write is counted."""
    bench = hilbench_bench("arm")
    rec = PortEventRecorder().attach(bench.endpoint())
    server = bench.services["port_state"]
    rdev = bench.endpoint().port.rdev
    words = memoryview(server.ledger._map).cast("Q")
    writing = (delivery_ledger.HEADER_SIZE + delivery_ledger.SLOT_SIZE * 0) // 8 + delivery_ledger.WRITING
    try:
        fd = os.open(bench.endpoint().path, os.O_RDWR | os.O_NOCTTY)
        stamp = time.monotonic_ns()
        os.write(fd, b"one")
        wait_until(lambda: server.ledger.read(rdev)["idle_ns"] > stamp)
        assert rec.received() == b"one"
        words[writing] = 1  # as a C client inside write()
        stamp = time.monotonic_ns()
        os.write(fd, b"two")
        wait_until(lambda: rec.received() == b"onetwo")
        assert server.ledger.read(rdev)["idle_ns"] < stamp  # a writer is counted: nothing published
        words[writing] = 0
        assert server.handle(f"{rdev} drain") == "ok 0"  # nothing left to take; it looks again
        assert server.ledger.read(rdev)["idle_ns"] > stamp
        os.close(fd)
    finally:
        words.release()


def test_the_manifest_names_the_board(hilbench_bench):
    bench = hilbench_bench("arm")
    lines = bench.manifest()["port_state"]
    assert lines["ledger"] == os.path.join(os.path.dirname(lines["socket"]), "port_state.ledger")
    assert os.path.exists(lines["ledger"])
    bench.stop()
    assert not os.path.exists(lines["ledger"])


@pytest.mark.slow
def test_c_client_drains_deliver_and_idle_ones_ask_nothing(hilbench_bench, hilbench_run, drain_client):
    bench = hilbench_bench("arm", paced=True)  # 9600 baud from the client: ~1 ms a byte on the wire
    rec = PortEventRecorder().attach(bench.endpoint())
    server = bench.services["port_state"]
    client = Stepper(hilbench_run.command(bench, drain_client, bench.endpoint().path, str(IDLE), shim="c"))
    client.step("start", "hello")
    assert rec.received() == b"hello"  # delivered (5 ms of wire time) before tcdrain returned
    before = server.requests
    client.step("idle")
    assert server.requests == before  # 3 x 300 drains and flushes with nothing pending: not one request
    for name, data in [("dup", b"dup"), ("fork", b"fork"), ("reopen", b"again"), ("stdio", b"stdio")]:
        client.step(name)
        assert rec.received().endswith(data), name  # delivered before the drain returned
    client.step("flush")  # a flush after a write asks
    wait_until(lambda: rec.received().endswith(b"bye"))
    assert rec.sequence(settings=False) in flushed(b"hellodupforkagainstdio", b"bye")
    assert client.close() == 0


@pytest.mark.parametrize("shim", SHIMS)
def test_pyserial_drains_deliver_and_idle_ones_ask_nothing(hilbench_bench, hilbench_run, shim):
    bench = hilbench_bench("arm", paced=True)
    rec = PortEventRecorder().attach(bench.endpoint())
    server = bench.services["port_state"]
    client = Stepper(hilbench_run.command(bench, sys.executable, str(CLIENTS / "drain_pyserial.py"),
                                          bench.endpoint().path, str(IDLE), shim=shim))
    client.step("start", "hello")
    assert rec.received() == b"hello"
    before = server.requests
    client.step("idle")
    assert server.requests == before
    client.step("flush")  # a flush after a write asks
    wait_until(lambda: rec.received().endswith(b"bye"))
    assert rec.sequence(settings=False) in flushed(b"hello", b"bye")
    assert client.close() == 0


def test_in_process_idle_drains_ask_nothing(hilbench_bench):
    bench = hilbench_bench("arm", paced=True)
    rec = PortEventRecorder().attach(bench.endpoint())
    server = bench.services["port_state"]
    with serial.Serial(bench.endpoint().path, 9600) as ser:
        ser.write(b"hello")
        ser.flush()
        assert rec.received() == b"hello"
        before = server.requests
        for _ in range(IDLE):
            ser.flush()
            ser.reset_output_buffer()
        assert server.requests == before
        ser.write(b"bye")
        ser.flush()
        assert rec.received() == b"hellobye"  # 3 ms on the wire, delivered before flush() returned
    assert OutputFlushed() not in rec.events()  # nothing was ever pending at a reset_output_buffer()


def test_requests_reuse_connections_and_survive_a_closed_one(hilbench_bench):
    bench = hilbench_bench("arm")
    server = bench.services["port_state"]
    rdev = bench.endpoint().port.rdev
    pyserial_shim.register(rdev, server.path)  # as a client in another process: through the socket
    try:
        port = (rdev, server.path)
        for _ in range(20):
            assert pyserial_shim.ask(port, "mget") is not None
        assert len(server._conns) == 1  # one kept connection served all 20
        for conn in list(server._conns):  # the server drops it (as a restarted one would have)
            conn.shutdown(socket.SHUT_RDWR)
        wait_until(lambda: not server._conns)
        assert pyserial_shim.ask(port, "mget") is not None  # sent again on a new connection
    finally:
        pyserial_shim.register(rdev, server.handle, server.ledger.path)


# ---------------------------------------------------------------------- the official SDK's timing

PINGS = 150


def fastest_ping(sdk, path: str, n: int = PINGS) -> float:
    port = sdk.PortHandler(path)
    assert port.openPort()
    ph = sdk.PacketHandler(2.0)
    best = 1.0
    for _ in range(n):
        t0 = time.perf_counter()
        _, result, _ = ph.ping(port, 1)
        best = min(best, time.perf_counter() - t0)
        assert result == sdk.COMM_SUCCESS
    port.closePort()
    return best


def close_to(got: float, reference: float) -> bool:
    """Within 10 % or 0.1 ms of the reference (fastest of N each: load only adds)."""
    return got <= reference * 1.1 or got - reference <= 0.0001


@pytest.mark.skipif(not dynamixel_sdk3.available(), reason=dynamixel_sdk3.MISSING)
def test_sdk3_ping_through_the_in_process_patch_costs_what_a_plain_pty_does(hilbench_bench):
    sdk = dynamixel_sdk3.load()
    assert "flush()" in Path(sdk.port_handler.__file__).read_text()  # clearPort() drains before every packet
    plain = hilbench_bench("arm", port_state=False)
    patched = hilbench_bench("arm")
    server = patched.services["port_state"]
    before = server.requests
    got = fastest_ping(sdk, patched.endpoint().path)
    requests = server.requests - before
    reference = fastest_ping(sdk, plain.endpoint().path)
    # each drain a round trip would be at least PINGS; on a quiet machine almost none ask the bench, under
    # load a drain that meets a reply still on its way does (128 of 150 once in a loaded full run)
    assert requests < PINGS
    assert close_to(got, reference), (got, reference)


SDK_WORKER = """
import sys, time
import dynamixel_sdk as sdk
assert "flush()" in open(sdk.port_handler.__file__).read()
port = sdk.PortHandler(sys.argv[1]); assert port.openPort()
ph = sdk.PacketHandler(2.0)
best, lost = 1.0, 0
for _ in range(int(sys.argv[2])):
    t0 = time.perf_counter(); _, result, _ = ph.ping(port, 1)
    if result == sdk.COMM_SUCCESS:
        best = min(best, time.perf_counter() - t0)
    else:  # the SDK's timeout on a loaded machine: the cost is the best of the answered ones
        lost += 1
assert lost <= int(sys.argv[2]) // 10, f"{lost} pings unanswered"
print(best)
"""


@pytest.mark.skipif(not dynamixel_sdk3.available(), reason=dynamixel_sdk3.MISSING)
@pytest.mark.parametrize("shim", SHIMS)
def test_sdk3_ping_under_hilbench_run_costs_what_a_plain_pty_does(hilbench_bench, hilbench_run, shim):
    bench = hilbench_bench("arm")
    server = bench.services["port_state"]
    path = bench.endpoint().path
    env = {**os.environ, "PYTHONPATH": str(dynamixel_sdk3.SDK3_DIR)}

    def ping(prefix: list[str]) -> float:
        proc = subprocess.run([*prefix, sys.executable, "-c", SDK_WORKER, path, str(PINGS)], capture_output=True,
                              text=True, timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr
        return float(proc.stdout)

    before = server.requests
    got = ping(hilbench_run.command(bench, shim=shim))
    requests = server.requests - before
    reference = ping([])
    assert requests < PINGS  # as above: every drain a round trip would be at least PINGS
    assert close_to(got, reference), (got, reference)

