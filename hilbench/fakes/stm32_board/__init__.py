"""The STM32F767 mecanum rover board (FreeRTOS) as software: velocity frames in, trace stamps out.

- :mod:`presets`: calibration data from the thesis tables (task sets, periods, execution times).
- :mod:`kernel`: a FreeRTOS-like kernel in virtual time (the exact, discrete-event path).
- :mod:`fast_path`: the kernel's vectorised fast path (whole runs of periodic ticks with numpy).
- :mod:`firmware`: the firmware's tasks, output paths (V1/V2/V3/binary), recv_vel and the report.
- :mod:`sink`: record buffers, the 2048-byte output ring, UART DMA, the wire, fault knobs.
- :mod:`~hilbench.fakes.mecanum_robot` (a kit the CANopen board shares): setpoint queue, ramp, kinematics and odometry.
- :mod:`board`: :class:`Board`, offline and live (paced onto a serial line).
"""

from hilbench.fakes.stm32_board.board import Board
from hilbench.fakes.stm32_board.presets import OUTPUTS, BoardConfig, Preset, make_preset, preset_names

__all__ = ["OUTPUTS", "Board", "BoardConfig", "Preset", "make_preset", "preset_names"]
