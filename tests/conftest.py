"""Shared test helpers: where the shared captures live."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$HILBENCH_SHARED_DATA`` or ``../shared/data`` beside the repository."""
    env = os.environ.get("HILBENCH_SHARED_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def wolfgang_capture() -> bytes:
    """The raw Wolfgang bus capture (see shared/data/README.md)."""
    path = shared_data_dir() / "dynamixel" / "wolfgang_trace.bin"
    if not path.exists():
        pytest.skip(f"shared capture not found at {path} (set HILBENCH_SHARED_DATA)")
    return path.read_bytes()


@pytest.fixture
def patient_sdk(monkeypatch):
    """Official SDK reply timeouts of ~200 ms instead of ~35 ms (spec §7.2: LATENCY_TIMER is read at call time).

    For tests about bytes and state, not timing, that run the SDK next to other busy threads or
    processes on a loaded 2-core machine.
    """
    import dynamixel_sdk.port_handler as port_handler

    monkeypatch.setattr(port_handler, "LATENCY_TIMER", 100)
