"""The trace profiler: per-task timing, periodicity, jitter, histograms, Gantt charts, Perfetto export.

Feed a :class:`Profiler` the bytes a board sends (text stamps of either
dialect, binary stamp words, logs and run-time statistics reports, mixed),
then call :meth:`Profiler.analyse` for an :class:`Analysis`. Definitions
follow the spec sheet ``stm32_board.md`` §5. See docs/instruments/trace.md.
"""

from hilbench.profiler.analysis import Analysis, analyse
from hilbench.profiler.ingest import Profiler, profile_bytes
from hilbench.profiler.settings import KERNEL_TASKS, ProfileSettings

__all__ = ["KERNEL_TASKS", "Analysis", "ProfileSettings", "Profiler", "analyse", "profile_bytes"]
