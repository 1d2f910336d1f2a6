"""Paced benches: what the official SDK measures matches wire time plus Return Delay Time.

The SDK runs in a process of its own, as it does against ``hilbench emulate``: in the test's process
its busy-polling would hold the GIL that the line's thread needs to deliver on time, and a machine
loaded by other jobs preempts a busy-polling thread while it holds it. Each exchange is timed in
the client; the test takes the fastest of N successful ones (the emulator must never beat the wire
model, and a loaded machine only adds delay) and drops the exchange after a failed one (a reply that
came after the SDK gave up is read as the next exchange's).

Both SDK generations run, under ``hilbench run`` as a user would: 4.x flushes input before every packet;
3.x (``make install`` puts it beside) drains output, a tcdrain, which must cost nothing when nothing is
pending (the delivery ledger of ``hilbench run``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import dynamixel_sdk as sdk
import pytest

from tests import dynamixel_sdk3

OK = sdk.COMM_SUCCESS

CLIENT = r'''
import json, sys, time
import dynamixel_sdk as sdk

class CustomBaudPortHandler(sdk.PortHandler):
    """The SDK's PortHandler with its list of rates lifted, as the README shows for 4.5 Mbaud."""
    def getCFlagBaud(self, baudrate):
        return baudrate

path, baud, steps = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
port = (CustomBaudPortHandler if baud == 4_500_000 else sdk.PortHandler)(path)
assert port.openPort() and port.setBaudRate(baud)
ph = sdk.PacketHandler(2.0)
out = []
for step in steps:
    kind, n = step["do"], step.get("n", 30)
    if kind == "write1":
        out.append(list(ph.write1ByteTxRx(port, step["id"], step["address"], step["value"])))
        continue
    if kind == "ping":
        fn = lambda: ph.ping(port, step["id"])[1]
    else:
        reader = sdk.GroupSyncRead(port, ph, 132, 4)
        for i in step["ids"]:
            reader.addParam(i)
        fn = reader.txRxPacket
    times, failed, skip = [], 0, False
    for _ in range(n):
        t0 = time.perf_counter()
        result = fn()
        dt = time.perf_counter() - t0
        if result != sdk.COMM_SUCCESS:
            failed, skip = failed + 1, True
        elif skip:
            skip = False  # it may have read the late reply of the failed one
        else:
            times.append(dt)
    out.append({"fastest": min(times, default=None), "samples": len(times), "failed": failed})
port.closePort()
print(json.dumps(out))
'''


@pytest.fixture(params=["sdk4", pytest.param("sdk3", marks=pytest.mark.skipif(
    not dynamixel_sdk3.available(), reason=dynamixel_sdk3.MISSING))])
def sdk_client(request, hilbench_run):
    """``sdk_client(bench, baud, *steps)``: run ``steps`` with the official SDK (4.x, or 3.x) in another
    process under ``hilbench run``; returns each step's result."""

    def run_steps(bench, baud: int, *steps: dict) -> list:
        env = hilbench_run.env(bench)
        if request.param == "sdk3":  # its package directory first: `import dynamixel_sdk` is 3.x there
            env["PYTHONPATH"] = f"{dynamixel_sdk3.SDK3_DIR}:{env.get('PYTHONPATH', '')}"
        run = subprocess.run([sys.executable, "-c", CLIENT, bench.endpoint().path, str(baud), json.dumps(steps)],
                             capture_output=True, text=True, timeout=120, env=env)
        assert run.returncode == 0, run.stderr
        return json.loads(run.stdout)

    return run_steps


def test_return_delay_time_and_wire_time_as_the_sdk_sees_them(hilbench_bench, sdk_client):
    bench = hilbench_bench("arm", paced=True)  # 1 Mbaud, factory Return Delay Time 250 (500 us)
    slow, written, fast = sdk_client(bench, 1_000_000, {"do": "ping", "id": 1},
                                     {"do": "write1", "id": 1, "address": 9, "value": 0},  # Return Delay Time 0
                                     {"do": "ping", "id": 1})
    # Ping: 10 bytes out, 500 us delay, 14 bytes back at 10 us per byte = 740 us
    assert 0.00074 <= slow["fastest"] < 0.00074 + 0.0015
    assert written == [OK, 0]
    assert 0.00024 <= fast["fastest"] < 0.00024 + 0.0015
    assert slow["fastest"] - fast["fastest"] > 0.0004  # the 500 us the servo waited


def test_sync_read_chain_adds_every_device_delay(hilbench_bench, sdk_client):
    bench = hilbench_bench("arm", paced=True)
    (chain,) = sdk_client(bench, 1_000_000, {"do": "sync_read", "ids": [1, 2, 3, 4, 5], "n": 20})
    # 19 bytes out, then 5 x (500 us + 15 bytes) = 190 + 5 x 650 us = 3.44 ms
    assert 0.00344 <= chain["fastest"] < 0.00344 + 0.0015


def test_unpaced_bench_ignores_wire_time(hilbench_bench, sdk_client):
    bench = hilbench_bench("arm", paced=False)
    (ping,) = sdk_client(bench, 1_000_000, {"do": "ping", "id": 1, "n": 200})  # (an unpaced line is not real-time)
    assert ping["fastest"] < 0.00074


def test_a_4_5_mbaud_bus_opened_by_the_sdk(hilbench_bench, tmp_path, sdk_client):
    text = (Path(__file__).resolve().parents[2] / "profiles" / "wolfgang.toml").read_text()
    profile = tmp_path / "wolfgang45.toml"
    profile.write_text(text.replace("baud = 2_000_000", "baud = 4_500_000", 1))
    bench = hilbench_bench(str(profile), paced=True)
    entry = bench.manifest()["endpoints"][0]
    assert entry["baud"] == 4_500_000 and entry["scheduling"].startswith("SCHED_")
    assert not sdk.PortHandler(bench.endpoint().path).setBaudRate(4_500_000)  # spec 7.1: not in the SDK's list
    # the PortHandler with its list lifted opens it (pyserial: BOTHER through termios2) and the servos answer
    ping, chain = sdk_client(bench, 4_500_000, {"do": "ping", "id": 1, "n": 5},
                             {"do": "sync_read", "ids": list(range(1, 21)), "n": 20})
    assert ping["samples"] >= 3
    # 34 bytes out, 20 x 15 bytes back at 2.22 us per byte, Return Delay Time 0: 742 us
    assert 334 * 10 / 4_500_000 <= chain["fastest"] < 334 * 10 / 4_500_000 + 0.0015
    # at 4 Mbaud (the SDK's list) the servos stay silent, as real ones at another rate do
    (silent,) = sdk_client(bench, 4_000_000, {"do": "ping", "id": 1, "n": 1})
    assert silent["failed"] == 1 and silent["samples"] == 0
