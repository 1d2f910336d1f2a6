"""The spec sheet's trace vectors (stm32_board.md §4.4, §6.4, §6.5) and a helper to profile bytes."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hilbench.profiler.ingest import Profiler
from hilbench.profiler.settings import ProfilerSettings
from tests.stm32_vectors import LISTING_34, LISTING_35, LISTING_38, LISTING_39, REPORT_65, TRACE_64, lines

# §6.4 settings: tasks {IDLE, wheel_ctrl, tsink}, function pid; wheel_ctrl T = 1000, merge_gap 500, D = 25.
SETTINGS_64 = ProfilerSettings(tasks=frozenset({"IDLE", "wheel_ctrl", "tsink"}), periods={"wheel_ctrl": 1000},
                              merge_gaps={"wheel_ctrl": 500}, deadlines={"wheel_ctrl": 25})
def profile(data: bytes, settings: ProfilerSettings | None = None, chunk: int | None = None):
    p = Profiler(settings)
    step = chunk or max(1, len(data))
    for i in range(0, len(data), step):
        p.feed(data[i : i + step])
    p.finish()
    return p.analyse(), p


@pytest.fixture(scope="session")
def spec():
    return SimpleNamespace(lines=lines, LISTING_34=LISTING_34, LISTING_35=LISTING_35, LISTING_38=LISTING_38,
                           LISTING_39=LISTING_39, TRACE_64=TRACE_64, SETTINGS_64=SETTINGS_64, REPORT_65=REPORT_65,
                           profile=profile)
