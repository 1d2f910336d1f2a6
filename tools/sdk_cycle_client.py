"""The official SDK's 20-servo cycle as a program of its own: ``python tools/sdk_cycle_client.py PORT SECONDS``.

Runs :func:`benchlib.sdk_cycle` (Sync Read of Present Position, Sync Write of Goal Position) at 2 Mbaud for
SECONDS of its own clock and prints one JSON line: the cycle count, the failed reads and each Sync Read's
completion (``time.monotonic_ns()``). ``tools/bench_virtual_time.py`` and tests/run/test_virtual_time_sdk.py
run it under ``hilbench run``, where its clock is the bench's.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # benchlib, beside it

import dynamixel_sdk as sdk  # noqa: E402
from benchlib import sdk_cycle  # noqa: E402


def main(path: str, seconds: float) -> dict:
    port = sdk.PortHandler(path)
    port.openPort()
    assert port.setBaudRate(2_000_000)
    _, reader, writer = sdk_cycle(port)
    n = failed = 0
    done = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        failed += reader.txRxPacket() != sdk.COMM_SUCCESS
        done.append(time.monotonic_ns())
        writer.txPacket()
        n += 1
    port.closePort()
    return {"cycles": n, "failed": failed, "done": done}


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], float(sys.argv[2]))))
