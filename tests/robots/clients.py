"""Helpers of the real-client tests: run a robot's own software in a process of its own."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def need(module: str, what: str) -> None:
    """Skip unless ``module`` imports (the robots' software comes from `make install-robots`)."""
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{what} is not installed (make install-robots installs it)")


def run_client(script: str, *args: str, run=None, bench=None, timeout: float = 120) -> dict:
    """Run a client script with this interpreter; its last stdout line is JSON.

    With ``run`` (the ``hilbench_run`` fixture) and ``bench``, the client runs under ``hilbench run``:
    its output flushes wait for the bench instead of discarding bytes, as on a USB adapter.
    """
    argv = [sys.executable, str(HERE / script), *args]
    if run is not None:
        argv = run.command(bench, *argv)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, env=env)
    assert proc.returncode == 0, f"{script} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])
