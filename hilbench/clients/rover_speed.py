"""How fast the mecanum rover can go: what a velocity command (Vel2d or the CAN setpoint) asks of its wheels.

The board passes any setpoint on; its wheels turn at most 105 rpm (the motor's measured limit), so a faster
command saturates them (the duty cycle is clamped at 100 %): the rover goes slower than asked, and a command
that mixes forward and turning motion also changes direction. Host tools send such commands as given, as a ROS
driver would, and warn (:func:`beyond_top_speed`).
"""

from __future__ import annotations

import math

#: The rover's wheels (spec stm32_board §2.5, held equal to the emulated robot's by a test): radius (m),
#: lever arm L = (length + width) / 2 (m), and the most a wheel turns (105 rpm, in rad/s).
WHEEL_RADIUS = 0.050
LEVER_ARM = 0.3125
WHEEL_MAX = 105 * 2 * math.pi / 60


def wheel_speed(vx: float, vy: float, omega: float) -> float:
    """The fastest wheel's speed (rad/s) that a velocity (m/s, m/s, rad/s) needs."""
    return (abs(vx) + abs(vy) + LEVER_ARM * abs(omega)) / WHEEL_RADIUS


def beyond_top_speed(vx: float, vy: float, omega: float) -> str | None:
    """A one-line warning when the rover cannot follow the velocity (a wheel beyond 105 rpm), else None."""
    need = wheel_speed(vx, vy, omega)
    if need <= WHEEL_MAX * (1 + 1e-9):
        return None
    return (f"x {vx:g} m/s, y {vy:g} m/s, z {omega:g} rad/s needs a wheel at {need:.2f} rad/s; the rover's wheels "
            f"turn at most {WHEEL_MAX:.2f} rad/s (105 rpm: |x| + |y| + {LEVER_ARM:g} m x |z| <= "
            f"{WHEEL_MAX * WHEEL_RADIUS:.2f} m/s): the board saturates them")


__all__ = ["LEVER_ARM", "WHEEL_MAX", "WHEEL_RADIUS", "beyond_top_speed", "wheel_speed"]
