"""Fixtures of the real-client tests: a monitor on every endpoint of a bench."""

from __future__ import annotations

import pytest

from hilbench.monitor import Monitor
from hilbench.transports.sources.base import MediumSource


@pytest.fixture
def watch():
    """``watch(bench)``: a monitor on every endpoint of a running bench; stopped after the test."""
    monitors: list[Monitor] = []

    def start(bench) -> dict[str, Monitor]:
        out = {}
        for name, ep in bench.endpoints.items():
            mon = Monitor(MediumSource(ep.medium)).start()
            monitors.append(mon)
            out[name] = mon
        return out

    yield start
    for mon in monitors:
        mon.stop()
