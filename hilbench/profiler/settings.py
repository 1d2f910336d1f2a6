"""What the profiler is told about a trace: task names, nominal periods, deadlines, windows.

Every field has a default that works on an unknown stream; the spec sheet's
definitions (stm32_board.md §5) name where each one enters the statistics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

#: Names the FreeRTOS kernel itself creates: always tasks (§5.1).
KERNEL_TASKS = frozenset({"IDLE", "Tmr Svc"})
#: vTaskGetRunTimeStats counts TIM13 updates: 108 MHz / 10001 (§2.1), so one unit is 10001/108 µs.
RUNTIME_UNIT_US = 10001 / 108
#: Default reorder window (µs of stream time): V1 flushes buffered hook stamps late (§3.5).
REORDER_US = 500_000
#: A text window whose first stamp is this far from 0 suggests a record-buffer overrun (§5.6).
OVERRUN_SUSPECT_US = 10_000


@dataclass(frozen=True)
class ProfilerSettings:
    """Settings of one analysis (all times in µs).

    - ``tasks``: the hook-produced (task) names. ``None`` takes them from the
      run-time statistics report in the stream plus :data:`KERNEL_TASKS`, or,
      without a report, infers them (a name whose slices mostly lie inside
      another name's slices is a function). Every other name is a function.
    - ``periods``: nominal period T per name; enables jobs merging, release
      latency, missed activations, deadline misses and overruns.
    - ``merge_gaps``: slices of a task closer than this merge into one job
      (default T/2 when T is set, no merging otherwise).
    - ``deadlines`` (default T) and ``budgets`` (default T): for deadline
      misses (response R > D) and overruns (execution C > B).
    - ``window``: analyse only stamps with ``a <= t <= b``.
    - ``denominator``: ``"span"`` (t_last - t_first), ``"profiled"`` (the
      report's ``profiled for`` / ``output took`` value when present) or a
      number of µs.
    """

    tasks: frozenset[str] | None = None
    periods: dict[str, float] = field(default_factory=dict)
    merge_gaps: dict[str, float] = field(default_factory=dict)
    deadlines: dict[str, float] = field(default_factory=dict)
    budgets: dict[str, float] = field(default_factory=dict)
    window: tuple[float, float] | None = None
    denominator: str | float = "span"
    reorder_us: float = REORDER_US
    hist_tick_us: float = 1.0
    linear_bins: int = 20
    runtime_unit_us: float = RUNTIME_UNIT_US
    max_stamps: int = 20_000_000
    overrun_suspect_us: float = OVERRUN_SUSPECT_US
    #: The source joined a running stream (a live port): its first window may start anywhere.
    joined_mid_stream: bool = False
    #: How many first offenders (deadline misses, overruns) to list per name.
    offenders: int = 5

    def with_(self, **changes) -> ProfilerSettings:
        """A copy with some fields changed."""
        return replace(self, **changes)

    def merge_gap(self, name: str) -> float | None:
        gap = self.merge_gaps.get(name)
        if gap is not None:
            return gap
        period = self.periods.get(name)
        return period / 2 if period else None
