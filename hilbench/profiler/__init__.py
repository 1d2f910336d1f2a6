"""The trace profiler: per-task timing, periodicity, jitter, histograms, Gantt charts, Perfetto export.

Feed a :class:`~hilbench.profiler.ingest.Profiler` the bytes a board sends (text stamps of either
dialect, binary stamp words, logs and run-time statistics reports, mixed),
then call :meth:`~hilbench.profiler.ingest.Profiler.analyse` for an
:class:`~hilbench.profiler.analysis.Analysis` (its settings:
:class:`~hilbench.profiler.settings.ProfilerSettings`). Definitions follow the
spec sheet ``stm32_board.md`` §5. See docs/instruments/trace.md.

The package imports none of its modules: its trace instrument plug-in
(:mod:`hilbench.profiler.instrument`) is loaded by every ``hilbench monitor``
that tells a raw capture's protocol from its bytes, and must not bring the
analysis (numpy) with it.
"""
