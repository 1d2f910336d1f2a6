"""The rover board's Vel2d receiver (idle-line framing, then the CRC check) as a fuzz target
(:mod:`hilbench.fuzzing`), with the board's UART at its fastest and a host's stream of velocity frames to
mutate. Registered in ``pyproject.toml`` (``hilbench.fuzz_targets``)."""

from __future__ import annotations

import random

from hilbench.fuzzing import FuzzTarget
from hilbench.protocols import vel2d

#: The rover board's UART at its fastest, 12.5 Mbit/s (STM32F767 USART at 108 MHz / 8), 8N1.
BOARD_LINE = 12_500_000 / 10


def vel2d_traffic(rng: random.Random, size: int) -> bytes:
    """Velocity frames back to back, as a host streaming commands sends them."""
    frames = []
    while len(frames) * vel2d.FRAME_SIZE < size:
        frames.append(vel2d.build(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-3, 3)))
    return b"".join(frames)


class _Vel2dReader:
    """The board's receiver: idle-line framing on a continuous line, then the CRC check."""

    def __init__(self, baud: int = 12_500_000) -> None:
        self.framer = vel2d.IdleLineFramer(baud)
        self.t = 0.0
        self.ok = 0
        self.bad = 0

    def _check(self, chunks) -> None:
        for raw, _ in chunks:
            if isinstance(vel2d.decode(raw), vel2d.Velocity):
                self.ok += 1
            else:
                self.bad += len(raw)

    def feed(self, data: bytes) -> None:
        self._check(self.framer.feed(data, self.t))
        self.t += len(data) * self.framer.char_time

    def finish(self) -> None:
        self._check(self.framer.flush())

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.bad


VEL2D = FuzzTarget("vel2d", "Vel2d velocity frames (idle-line framing, CRC-32/MPEG-2)", _Vel2dReader,
                      BOARD_LINE, "12.5 Mbit/s UART", vel2d_traffic)


__all__ = ["BOARD_LINE", "VEL2D", "vel2d_traffic"]
