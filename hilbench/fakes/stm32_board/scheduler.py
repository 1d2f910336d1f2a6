"""Deprecated alias: the scheduler is now :mod:`~hilbench.fakes.stm32_board.kernel` (the exact path)
and :mod:`~hilbench.fakes.stm32_board.fast_path` (the vectorised fast path); import from those.
"""

from __future__ import annotations

import warnings

from hilbench.fakes.stm32_board.fast_path import fast_run
from hilbench.fakes.stm32_board.kernel import (
    CALL,
    DELAY,
    DELAY_UNTIL,
    FSTAMP,
    NOTIFY,
    RUN,
    WAIT,
    YIELD,
    Durations,
    Kernel,
    Periodic,
    ReadyList,
    Task,
    TaskGen,
)

__all__ = ["CALL", "DELAY", "DELAY_UNTIL", "FSTAMP", "NOTIFY", "RUN", "WAIT", "YIELD", "Durations", "Kernel",
           "Periodic", "ReadyList", "Task", "TaskGen", "fast_run"]

warnings.warn("hilbench.fakes.stm32_board.scheduler is deprecated: import from hilbench.fakes.stm32_board.kernel "
              "(Kernel, Task, Durations, Periodic, ReadyList, the actions) and "
              "hilbench.fakes.stm32_board.fast_path (fast_run)", DeprecationWarning, stacklevel=2)
