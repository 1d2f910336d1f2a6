"""Shared helpers of the scanner tests: the room's truth by hand, and published clients in subprocesses.

The ``scanners`` profile puts every scanner at (0.5, 0.3) looking along +x in
a room whose inner walls are x = -3, x = +3, y = -2, y = +2 (metres).
:func:`room_range` computes the distance to the wall along a world direction
from those numbers alone (no hilbench code), so a test compares what a client
decoded with geometry, not with the emulator's own ray caster.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

HERE = Path(__file__).parent
CLIENTS = HERE / "clients"
X0, Y0 = 0.5, 0.3


def room_range(phi: np.ndarray | float) -> np.ndarray:
    """Distance (m) from (0.5, 0.3) to the room's walls along world direction ``phi`` (rad, CCW from +x)."""
    phi = np.asarray(phi, dtype=float)
    c, s = np.cos(phi), np.sin(phi)
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(c > 1e-12, (3.0 - X0) / c, np.where(c < -1e-12, (-3.0 - X0) / c, np.inf))
        ty = np.where(s > 1e-12, (2.0 - Y0) / s, np.where(s < -1e-12, (-2.0 - Y0) / s, np.inf))
    return np.minimum(tx, ty)


def fraction_within(phi: np.ndarray, ranges_m: np.ndarray, *, sigma0: float, sigma_k: float,
                    k: float = 3.0, slack: float = 0.002) -> float:
    """Share of points whose range is within k sigma (+ slack for quantisation) of the room's truth."""
    truth = room_range(phi)
    tol = k * np.maximum(sigma0, sigma_k * truth) + slack
    return float(np.mean(np.abs(np.asarray(ranges_m) - truth) <= tol))


def need(module: str) -> None:
    """Skip unless the published client ``module`` is installed (the ``scanners`` extra)."""
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not installed (pip install -e '.[scanners]'; make install does it)")


def run_client(script: str, *args: str, run=None, bench=None, shim: str | None = None,
               timeout: float = 60.0) -> dict:
    """Run ``clients/SCRIPT`` (an unmodified published library doing the work) in its own process.

    With ``run`` (the ``hilbench_run`` fixture) and ``bench``, it runs under ``hilbench run``: the
    client's modem-line ioctls on the bench's ptys (pyserial's ``.dtr``, the SDK's TIOCMBIC) reach the
    emulated devices. Returns the JSON object the script printed last.
    """
    argv = [sys.executable, str(CLIENTS / script), *args]
    if run is not None:
        argv = run.command(bench, *argv, shim=shim)
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env={**os.environ})
    if proc.returncode != 0:
        raise AssertionError(f"{script} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    last = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert last, f"{script} printed no result:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
    return json.loads(last[-1])


@pytest.fixture
def scanners(hilbench_bench):
    """The bundled ``scanners`` bench, started in this process."""
    return hilbench_bench("scanners")


__all__ = ["fraction_within", "math", "need", "room_range", "run_client"]
