"""The official dynamixel-sdk's 20-servo cycle under ``hilbench run`` on a virtual-time ``wolfgang`` bench
(issue 26's test (a), PLAN26 §9.1 (a)): cycles per virtual second equal the wire model (the cycle's bytes at
the bus's rate plus the servos' modelled response times) within 0.5 %, no failed read, no lockstep stall, and
the same count, and the same virtual instant for every cycle, in every run, also beside a CPU-bound
neighbour process (not under ``hilbench run``: it shares the machine, not the clock). Two runs' captures
(the bench's tap) are the same byte for byte but for the header's real date (test (h)).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hilbench.bench import Bench, serve_ring
from hilbench.bench import clock_page as vp
from hilbench.bench.port_state_server import serve_port_state
from hilbench.protocols import capture
from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader

pytestmark = pytest.mark.usefixtures("library")  # (tests/run/conftest.py: skipped without the shim)

sdk = pytest.importorskip("dynamixel_sdk")

HILBENCH = [sys.executable, "-m", "hilbench.cli"]
TOOLS = Path(__file__).resolve().parents[2] / "tools"
IDS = list(range(1, 21))
#: Wire bytes of one cycle (the test's own count, not the tools'): Sync Read (14 + 20) + 20 replies (11 + 4) +
#: Sync Write (14 + 20 * 5).
CYCLE_BYTES = (14 + 20) + 20 * 15 + (14 + 20 * 5)
#: The SDK's cycle as tools/bench_dynamixel.py drives it (tools/benchlib.sdk_cycle), as a program: PORT SECONDS;
#: prints the cycle count, the failed reads and each Sync Read's completion (virtual ns).
SDK_CLIENT = TOOLS / "sdk_cycle_client.py"


@contextlib.contextmanager
def neighbour(on: bool) -> Iterator[None]:
    """A CPU-bound process beside the run (``on``), outside the lockstep."""
    proc = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if on else None
    try:
        yield
    finally:
        if proc is not None:
            proc.kill()
            proc.wait()


def model_cycle(bench: Bench) -> float:
    """Virtual seconds per cycle the wire model gives: the cycle's bytes at the bus's rate (8N1) plus each
    servo's Return Delay Time before its reply."""
    ep = bench.endpoint("dxl")
    response = sum(bench.device(i, "dxl").return_delay for i in IDS)
    return CYCLE_BYTES * 10 / ep.spec.baud + response


def sdk_run(tmp_path: Path, seconds: float, *, busy: bool = False, serve: str | None = None,
            ring: dict | None = None) -> tuple[dict, dict, float]:
    """One SDK run on a fresh virtual-time wolfgang bench: (the client's figures, the clock's stats, model).
    ``serve``: HILBENCH_SERVE for the client (None: as in this environment); ``ring``: gets the pty's serving
    ring record and the clock page's read and discarded counters of the pty after the run."""
    with Bench("wolfgang", virtual_time=True) as bench:
        serve_port_state(bench)  # (the SDK's open sets DTR and RTS, and its drains ask the line)
        manifest = tmp_path / f"bench{len(list(tmp_path.glob('bench*.json')))}.json"
        bench.write_manifest(manifest)
        env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
        if serve is not None:
            env["HILBENCH_SERVE"] = serve
        with neighbour(busy):
            proc = subprocess.run([*HILBENCH, "run", "--manifest", str(manifest), "--", sys.executable, str(SDK_CLIENT),
                                   bench.endpoint("dxl").port.client_path, str(seconds)],
                                  capture_output=True, text=True, timeout=300, env=env)
        assert proc.returncode == 0, proc.stderr
        if ring is not None:
            port, clock = bench.endpoint("dxl").port, bench.services["clock"]
            ring.update(bench.services["port_state"].rings.read(port.rdev))
            ring["delivered"] = port.bytes_out - clock.ptys[0].base_out
            ring["read"], ring["discarded"] = clock._port(0, vp.P_READ), clock._port(0, vp.P_DISCARDED)
        return json.loads(proc.stdout), bench.services["clock"].stats(), model_cycle(bench)


def check_run(out: dict, stats: dict, model: float, seconds: float) -> None:
    done = out["done"]
    assert out["failed"] == 0 and stats["stalls"] == 0
    assert out["cycles"] == len(done) and out["cycles"] >= int(seconds / model) - 1
    # cycles per virtual second, between the first and the last cycle's end, against the model
    rate = (len(done) - 1) / ((done[-1] - done[0]) / 1e9)
    assert rate * model == pytest.approx(1.0, abs=0.005), f"{rate:.2f} cycles/s, model {1 / model:.2f}"
    # every cycle takes the model's time (to the ns the clock page's integer time rounds a float to)
    steps = {round((b - a) / 1e3) for a, b in zip(done, done[1:], strict=False)}
    assert steps == {round(model * 1e6)}, steps


def test_the_sdk_cycle_follows_the_wire_model_in_virtual_time(tmp_path):
    """A short run in the normal set (a quarter of a virtual second, two runs): the same cycles, each at the
    wire model's time."""
    seconds = 0.25
    first, stats, model = sdk_run(tmp_path, seconds)
    check_run(first, stats, model, seconds)
    again, stats, _ = sdk_run(tmp_path, seconds)
    check_run(again, stats, model, seconds)
    assert again["done"] == first["done"]


def test_served_and_kernel_paths_make_the_same_cycles(tmp_path):
    """The serving path (on by default under a virtual clock): the SDK's replies come through the bench's ring,
    not the tty layer, every one of them (the ring's head is its tail, the clock page counted each byte read),
    and the run is the kernel path's to the nanosecond (HILBENCH_SERVE=0)."""
    seconds = 0.1
    ring: dict = {}
    served, stats, model = sdk_run(tmp_path, seconds, serve="", ring=ring)
    check_run(served, stats, model, seconds)
    assert ring["mode"] == serve_ring.SERVED and ring["head"] == ring["tail"] > 20 * 15 * 40, ring
    assert ring["read"] + ring["discarded"] == ring["delivered"] and ring["dropped"] == 0, ring
    assert stats["settle_timeouts"] == 0
    plain: dict = {}
    kernel, stats, _ = sdk_run(tmp_path, seconds, serve="0", ring=plain)
    check_run(kernel, stats, model, seconds)
    assert plain["mode"] == serve_ring.KERNEL and plain["head"] == 0
    assert plain["read"] + plain["discarded"] == plain["delivered"] == ring["delivered"]
    assert kernel["done"] == served["done"]


@pytest.mark.slow
def test_the_sdk_cycle_is_the_same_in_every_run_with_or_without_a_neighbour(tmp_path):
    """Issue 26's test (a): 2 virtual seconds, three runs and a fourth beside a CPU-bound neighbour."""
    seconds = 2.0
    runs = []
    for busy in (False, False, False, True):
        out, stats, model = sdk_run(tmp_path, seconds, busy=busy)
        check_run(out, stats, model, seconds)
        runs.append(out)
    assert len({r["cycles"] for r in runs}) == 1, [r["cycles"] for r in runs]
    assert all(r["done"] == runs[0]["done"] for r in runs)
    assert runs[0]["cycles"] * model == pytest.approx(seconds, abs=2 * model)


def tap_capture(tmp_path: Path, seconds: float) -> tuple[bytes, bytes]:
    """The bench's own capture of one SDK run (its tap's stream, header and records, until the bench stops),
    and ``hilbench record``'s file of the same tap."""
    with Bench("wolfgang", virtual_time=True, tap=True) as bench:
        serve_port_state(bench)
        manifest = tmp_path / f"bench{len(list(tmp_path.glob('bench*.json')))}.json"
        bench.write_manifest(manifest)
        tap = bench.endpoint("dxl").tap
        sock = socket.create_connection((tap.host, tap.port))
        stream = bytearray()
        reader = threading.Thread(target=lambda: stream.extend(b"".join(iter(lambda: sock.recv(65536), b""))))
        reader.start()
        recording = tmp_path / f"run{len(list(tmp_path.glob('run*.hbcap')))}.hbcap"
        recorder = subprocess.Popen([*HILBENCH, "record", tap.url, str(recording)], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
        wait_until(lambda: tap.status()["clients"] == 2, timeout=20)
        env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
        proc = subprocess.run([*HILBENCH, "run", "--manifest", str(manifest), "--", sys.executable, str(SDK_CLIENT),
                               bench.endpoint("dxl").port.client_path, str(seconds)],
                              capture_output=True, text=True, timeout=120, env=env)
        assert proc.returncode == 0, proc.stderr
        stats = bench.services["clock"].stats()
    # (a run with a stall, or with delivered bytes given up on, is not deterministic: say so if it differs)
    assert stats["stalls"] == 0 and stats["settle_timeouts"] == 0, stats
    reader.join(timeout=20)  # (the tap closes with the bench: the stream ends, and so does the recorder)
    sock.close()
    assert not reader.is_alive()
    _, err = recorder.communicate(timeout=20)
    assert recorder.returncode == 0, err
    return bytes(stream), recording.read_bytes()


def test_two_sdk_runs_make_the_same_capture_but_for_the_header_date(tmp_path):
    """Issue 26's test (h): records in virtual time, byte for byte the same in two runs; the header's t0_wall
    (the real date the bench started) is the one field that differs."""
    started = time.time()
    (first, recorded), (again, recorded_again) = tap_capture(tmp_path, 0.05), tap_capture(tmp_path, 0.05)
    size = 12 + capture.header_body_size(first[:12])
    heads = [capture.parse_header(c) for c in (first, again)]
    assert all(h.t0_monotonic == 1000.0 and started - 1 <= h.t0_wall <= time.time() for h in heads)
    assert heads[0]._replace(t0_wall=0) == heads[1]._replace(t0_wall=0)
    assert first[size:] == again[size:] and len(first) - size > 10_000  # (20 cycles and more)
    chunks = list(CaptureReader(io.BytesIO(first)))
    assert {c.source for c in chunks} == {"dxl", "dxl-devices"}
    assert all(round(c.t * 1e9) % 5000 == 0 for c in chunks)  # virtual: each ends on a byte time (5 us)
    # hilbench record's files: the same but for the date too, which is the real one (the tap's clock mapped to
    # Unix time, not this machine's monotonic clock: a virtual 1000 s is not the machine's uptime)
    size = 12 + capture.header_body_size(recorded[:12])
    heads = [capture.parse_header(c) for c in (recorded, recorded_again)]
    assert heads[0]._replace(t0_wall=0) == heads[1]._replace(t0_wall=0)
    assert heads[0].description == "bench wolfgang, endpoint dxl"  # (not the tap's address: its port changes)
    assert all(started - 1 <= h.t0_wall <= time.time() for h in heads)
    assert recorded[size:] == recorded_again[size:]
    assert [(round(c.t * 1e9), c.source, bytes(c.data)) for c in CaptureReader(io.BytesIO(recorded))] == [
        (round(c.t * 1e9), c.source, bytes(c.data)) for c in chunks]
