"""Fixtures of the real-client tests: a monitor on every endpoint of a bench."""

from __future__ import annotations

import pytest

from hilbench.monitor import Monitor
from hilbench.transports.sources.base import MediumSource


@pytest.fixture
def watch():
    """``watch(bench)``: a monitor on every endpoint of a running bench; stopped after the test.

    Yields the starter."""
    monitors: list[Monitor] = []

    def start(bench) -> dict[str, Monitor]:
        """``bench``: an in-process bench (its media), or a ``hilbench_emulator`` manifest (its TCP taps)."""
        from hilbench.transports.sources import open_source

        out = {}
        if isinstance(bench, dict):
            sources = {e["name"]: open_source(f"{bench['manifest_path']}#{e['name']}") for e in bench["endpoints"]}
        else:
            sources = {name: MediumSource(ep.medium) for name, ep in bench.endpoints.items()}
        for name, source in sources.items():
            mon = Monitor(source).start()
            monitors.append(mon)
            out[name] = mon
        return out

    yield start
    for mon in monitors:
        mon.stop()
