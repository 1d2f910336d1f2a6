"""What the benchmark scripts share: printing a figure, and a bench running in another process.

Each script prints one JSON object per figure (DESIGN.md §10):
``{"name", "value", "unit", "reference", "ratio", ...}``; :func:`emit` is that
line. :func:`emulator` runs ``hilbench emulate`` in its own process, as a user
would, and yields its manifest. The scripts run as ``tools/bench_*.py``, so
this module is imported from the scripts' folder.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]


def emit(name: str, value: float, unit: str, reference: float, ratio: float, *, digits: int = 3,
         ratio_digits: int = 3, **extra: Any) -> None:
    """Print one figure: ``value`` and ``reference`` rounded to ``digits``, ``ratio`` to ``ratio_digits``."""
    print(json.dumps({"name": name, "value": round(value, digits), "unit": unit,
                      "reference": round(reference, digits), "ratio": round(ratio, ratio_digits), **extra}),
          flush=True)


@contextlib.contextmanager
def emulator(*args: str, timeout: float = 20.0) -> Iterator[dict[str, Any]]:
    """``hilbench emulate ARGS --manifest M`` in another process: yields the manifest once written (SystemExit
    with its stderr if it does not start within ``timeout`` s), and stops the bench afterwards."""
    with tempfile.TemporaryDirectory(prefix="hilbench-bench-") as tmp:
        manifest = Path(tmp) / "manifest.json"
        proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", *args, "--manifest", str(manifest)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
        try:
            deadline = time.monotonic() + timeout
            while not manifest.exists():
                if proc.poll() is not None or time.monotonic() > deadline:
                    proc.kill()
                    raise SystemExit(f"emulator did not start: {proc.stderr.read().decode()}")
                time.sleep(0.01)
            yield json.loads(manifest.read_text())
        finally:
            proc.terminate()
            proc.wait(timeout=10)


__all__ = ["CYCLE_BYTES", "CYCLE_IDS", "REPO", "emit", "emulator", "sdk_cycle"]


#: The servos of the wolfgang bench's 20-servo SDK cycle.
CYCLE_IDS = list(range(1, 21))
#: Wire bytes of one :func:`sdk_cycle`: Sync Read (14 + 20) + 20 replies (11 + 4) + Sync Write (14 + 20 * 5).
CYCLE_BYTES = (14 + 20) + 20 * 15 + (14 + 20 * 5)


def sdk_cycle(port: Any, ids: list[int] = CYCLE_IDS) -> tuple[Any, Any, Any]:
    """The official SDK's 20-servo cycle on an open ``port``: ``(packet handler, GroupSyncRead of Present
    Position, GroupSyncWrite of Goal Position)`` with every servo's parameter added."""
    import dynamixel_sdk as sdk

    ph = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    writer = sdk.GroupSyncWrite(port, ph, 116, 4)
    for i in ids:
        reader.addParam(i)
        writer.addParam(i, [0x00, 0x08, 0, 0])
    return ph, reader, writer
