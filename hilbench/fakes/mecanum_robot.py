"""The mecanum rover's motion model as its firmware runs it (spec §2.4, §2.5): setpoint queue, ramp, kinematics,
odometry.

A kit: the STM32 rover board (:mod:`hilbench.fakes.stm32_board`) and its CANopen firmware
(:mod:`hilbench.fakes.canopen.rover`) both drive their wheels with it.

The firmware's control tasks exchange data through queues with timeout 0, so
the data never changes when a task runs; only how often. This model therefore
advances by pose cycles (one pose_control and one odometry job each) computed
from time, independent of the scheduler, and integrates long steady stretches
with numpy:

- ``vel_sp_queue`` (depth 10): recv_vel pushes scaled setpoints; a full queue
  drops the new one. pose_control takes at most one per cycle.
- The ramp moves the command toward the setpoint by at most 3 % of the
  maximum rim speed per cycle (16.4934 mm/s for vx, vy; 0.052779 rad/s for ω).
- Inverse kinematics gives wheel setpoints (rad/s, order fr, fl, bl, br);
  wheel_ctrl holds the last one and drives the duty cycle; the branch head's
  PIDs pass setpoints through, so the wheels turn at the setpoint (open loop).
- Odometry reads the encoder mailbox once per pose cycle, which holds the
  delta of one wheel period only (hal_fetch overwrites it at the wheel rate):
  the FreeRTOS firmware integrates wheel_period / pose_period of the true
  motion, and this model reproduces that. The micro-ROS build runs its
  odometry callback per encoder message (spec §2.2), so it integrates every
  delta (``every_delta=True``), as the CAN firmware does (equal periods).
- What the wheels measure (:attr:`Robot.measured`: every encoder delta
  integrated) is the true motion of the wheels: the world body moves by it
  (less slip), so without slip, noise or a collision it is the truth.
- Encoders may be noisy (``encoder_noise``: standard deviation in counts of
  each wheel's delta per pose cycle while it turns): odometry and the
  encoder counts then drift from what the wheels did.

What the wheels *do* is the truth a world body is driven with
(:mod:`hilbench.fakes.world`): :meth:`Robot.motion_at` integrates their
motion exactly (constant wheel speeds between pose cycles: one SE(2)
exponential per stretch), whatever the firmware's odometry makes of it. A body that meets a wall stops; the wheels and the odometry
run on.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from hilbench.fakes.world import compose, twist_motion

WHEEL_RADIUS = 50.0  # mm
L_W_HALF = (325.0 + 300.0) / 2  # mm
WHEEL_MAX_RPM = 105.0
WHEEL_MAX = WHEEL_MAX_RPM * 2 * math.pi / 60  # rad/s: 10.995574
RIM_MAX = WHEEL_MAX * WHEEL_RADIUS  # mm/s: 549.78
RAMP_LINEAR = 0.03 * RIM_MAX  # mm/s per pose cycle: 16.4934
RAMP_ANGULAR = 0.03 * RIM_MAX / L_W_HALF  # rad/s per pose cycle: 0.052779
QUEUE_DEPTH = 10
INC2RAD = 2 * math.pi / 3072


def inverse_kinematics(vx: float, vy: float, wz: float) -> tuple[float, float, float, float]:
    """Robot velocity (mm/s, mm/s, rad/s) to wheel speeds (rad/s): fr, fl, bl, br."""
    r, lw = WHEEL_RADIUS, L_W_HALF
    return ((vx + vy + lw * wz) / r, (vx - vy - lw * wz) / r, (vx + vy - lw * wz) / r, (vx - vy + lw * wz) / r)


def forward_kinematics(fr: float, fl: float, bl: float, br: float) -> tuple[float, float, float]:
    """Wheel values (rad or rad/s) to robot displacement (mm, mm, rad) or velocity."""
    r, lw = WHEEL_RADIUS, L_W_HALF
    return (r / 4 * (fr + fl + bl + br), r / 4 * (fr - fl + bl - br), r / (4 * lw) * (fr - fl - bl + br))


def duty_cycle(wheel: float) -> float:
    """Duty cycle in % for a wheel speed, clamped to ±100."""
    return max(-100.0, min(100.0, wheel / WHEEL_MAX * 100.0))


def _wrap(theta: float) -> float:
    return math.atan2(math.sin(theta), math.cos(theta))


@dataclass
class RobotState:
    """A snapshot: setpoint and ramped command (mm/s, mm/s, rad/s), wheels (rad/s), duty (%), pose (mm, rad)."""

    t_us: float
    setpoint: tuple[float, float, float]
    command: tuple[float, float, float]
    wheels: tuple[float, float, float, float]
    duty: tuple[float, float, float, float]
    pose: tuple[float, float, float]
    pose_cycles: int
    queued: int


class Robot:
    """Pose cycles at ``pose_period_us`` starting at ``first_cycle_us``; see the module docstring."""

    def __init__(self, pose_period_us: float, wheel_period_us: float, first_cycle_us: float = 0.0, *,
                 encoder_noise: float = 0.0, seed: int = 0, every_delta: bool = False) -> None:
        self.pose_period = pose_period_us
        self.encoder_noise = encoder_noise
        self.rng = np.random.default_rng(seed)
        self.wheel_period = wheel_period_us
        #: How much wheel motion the odometry integrates per pose cycle (us): one wheel period's delta (the
        #: FreeRTOS mailbox) or, with ``every_delta`` (odometry per encoder message), the whole pose period.
        self.odometry_span = pose_period_us if every_delta else wheel_period_us
        self.next_cycle = first_cycle_us
        self.cycles = 0
        self.queue: deque[tuple[float, tuple[float, float, float]]] = deque()
        self.setpoint = (0.0, 0.0, 0.0)
        self.command = (0.0, 0.0, 0.0)
        self.x = self.y = self.theta = 0.0
        self.dropped = 0
        #: How far each wheel (fr, fl, bl, br) has turned in total (rad): what its encoder counts.
        self.wheel_angle = [0.0, 0.0, 0.0, 0.0]
        #: What the wheels did up to ``next_cycle`` (m, m, rad in the start frame): the true motion.
        self.motion = (0.0, 0.0, 0.0)
        #: What the encoders measured up to ``next_cycle`` (m, m, rad in the start frame): every delta
        #: integrated; equal to :attr:`motion` without encoder noise.
        self.measured = (0.0, 0.0, 0.0)

    def push_setpoint(self, t_us: float, vx: float, vy: float, wz: float) -> bool:
        """recv_vel's ``xQueueSend(vel_sp_queue, timeout 0)``: False when the queue was full."""
        self.advance(t_us)
        if len(self.queue) >= QUEUE_DEPTH:
            self.dropped += 1
            return False
        self.queue.append((t_us, (vx, vy, wz)))
        return True

    def body_velocity(self) -> tuple[float, float, float]:
        """What the wheels do now: the body-frame velocity (m/s, m/s, rad/s) their speeds make."""
        vx, vy, wz = forward_kinematics(*self.wheels)
        return vx / 1000.0, vy / 1000.0, wz

    def motion_at(self, t_us: float) -> tuple[float, float, float]:
        """What the wheels did from the start to ``t_us`` (m, m, rad in the start frame), after
        :meth:`advance` to ``t_us``: the motion up to the next cycle, less the part of this cycle still to come."""
        return self._back_to(self.motion, t_us)

    def measured_at(self, t_us: float) -> tuple[float, float, float]:
        """What the encoders measured from the start to ``t_us`` (m, m, rad in the start frame), after
        :meth:`advance` to ``t_us``: with slip and encoder noise off, the truth of a body that met nothing."""
        return self._back_to(self.measured, t_us)

    def _back_to(self, at_next_cycle: tuple[float, float, float], t_us: float) -> tuple[float, float, float]:
        ahead = (self.next_cycle - t_us) * 1e-6
        if ahead <= 0:
            return at_next_cycle
        vx, vy, w = self.body_velocity()
        return compose(at_next_cycle, twist_motion(-vx, -vy, -w, ahead))

    @property
    def wheels(self) -> tuple[float, float, float, float]:
        w = inverse_kinematics(*self.command)
        return tuple(max(-WHEEL_MAX, min(WHEEL_MAX, v)) for v in w)  # type: ignore[return-value]

    def state(self, t_us: float) -> RobotState:
        self.advance(t_us)
        wheels = self.wheels
        return RobotState(t_us, self.setpoint, self.command, wheels, tuple(duty_cycle(w) for w in wheels),
                          (self.x, self.y, self.theta), self.cycles, len(self.queue))  # type: ignore[arg-type]

    def advance(self, t_us: float) -> None:
        """Run every pose cycle released by ``t_us``."""
        while self.next_cycle <= t_us:
            if self.queue or self.command != self.setpoint:
                self._cycle()
                continue
            # Steady: no setpoint waiting and the ramp has converged; integrate the rest in bulk.
            n = int((t_us - self.next_cycle) // self.pose_period) + 1
            self._steady(n)

    def _cycle(self) -> None:
        if self.queue and self.queue[0][0] <= self.next_cycle:
            self.setpoint = self.queue.popleft()[1]
        cmd = list(self.command)
        for i, step in enumerate((RAMP_LINEAR, RAMP_LINEAR, RAMP_ANGULAR)):
            diff = self.setpoint[i] - cmd[i]
            cmd[i] = self.setpoint[i] if abs(diff) <= step else cmd[i] + math.copysign(step, diff)
        self.command = (cmd[0], cmd[1], cmd[2])
        self._odometry(1)
        self.cycles += 1
        self.next_cycle += self.pose_period

    def _steady(self, n: int) -> None:
        self._odometry(n)
        self.cycles += n
        self.next_cycle += n * self.pose_period

    def _odometry(self, n: int) -> None:
        wheels = self.wheels
        if any(wheels):
            vx, vy, w = self.body_velocity()
            step = twist_motion(vx, vy, w, self.pose_period * 1e-6 * n)
            self.motion = compose(self.motion, step)
            if not self.encoder_noise:
                self.measured = compose(self.measured, step)
        if self.encoder_noise and any(wheels):
            for _ in range(n):  # each reading its own noise
                self._odometry_noisy(wheels)
            return
        turned = self.pose_period * 1e-6 * n  # the wheels turn for the whole pose period(s)
        self.wheel_angle = [a + w * turned for a, w in zip(self.wheel_angle, wheels, strict=True)]
        # One wheel period's encoder delta per pose cycle (the mailbox semantics of the firmware), or all of them.
        dt = self.odometry_span * 1e-6
        dx, dy, dth = forward_kinematics(*(w * dt for w in wheels))
        if dx == 0 and dy == 0 and dth == 0:
            return
        if n == 1:
            self._integrate(dx, dy, dth)
            return
        mids = self.theta + dth * (np.arange(n) + 0.5)
        self.x += float(np.sum(dx * np.cos(mids) - dy * np.sin(mids)))
        self.y += float(np.sum(dx * np.sin(mids) + dy * np.cos(mids)))
        self.theta = _wrap(self.theta + n * dth)

    def _odometry_noisy(self, wheels: tuple[float, ...]) -> None:
        """One pose cycle whose encoder deltas carry noise (counts, while a wheel turns)."""
        noise = self.rng.standard_normal(4) * self.encoder_noise * INC2RAD
        turned = self.pose_period * 1e-6
        measured = [w * turned + (e if w else 0.0) for w, e in zip(wheels, noise, strict=True)]
        self.wheel_angle = [a + m for a, m in zip(self.wheel_angle, measured, strict=True)]
        mx, my, mth = forward_kinematics(*(m / turned for m in measured))  # (mm/s, rad/s over the cycle)
        self.measured = compose(self.measured, twist_motion(mx / 1000.0, my / 1000.0, mth, turned))
        frac = self.odometry_span / self.pose_period
        self._integrate(*forward_kinematics(*(m * frac for m in measured)))

    def _integrate(self, dx: float, dy: float, dth: float) -> None:
        mid = self.theta + dth / 2
        self.x += dx * math.cos(mid) - dy * math.sin(mid)
        self.y += dx * math.sin(mid) + dy * math.cos(mid)
        self.theta = _wrap(self.theta + dth)
