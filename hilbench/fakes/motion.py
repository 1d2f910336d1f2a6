"""Servo motion as a function of time: velocity- and acceleration-limited motion profiles.

A motion profile is a short list of constant-acceleration segments computed
when a goal changes; the servo's present position, velocity and acceleration
are evaluated from it at the moment a host reads them. No thread ticks the
simulation, so an idle bench costs nothing and every read is exact. A kit:
the Dynamixel servos and the servos built from control tables
(:mod:`~hilbench.fakes.control_table_servo`, :mod:`~hilbench.fakes.table_servo`)
move by it.
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Segment(NamedTuple):
    t0: float  # start time
    p0: float  # position at t0 (pulses)
    v0: float  # velocity at t0 (pulses/s)
    a: float  # constant acceleration (pulses/s^2)
    duration: float  # seconds; math.inf for the last, open-ended segment


class State(NamedTuple):
    position: float
    velocity: float
    acceleration: float
    moving: bool


class MotionProfile:
    """Piecewise constant-acceleration motion, starting at rest at ``position``."""

    def __init__(self, t: float, position: float) -> None:
        self.segments: list[Segment] = [Segment(t, position, 0.0, 0.0, math.inf)]
        self.target: float = position

    def at(self, t: float) -> State:
        """Position, velocity and acceleration at time ``t``."""
        segments = self.segments
        if len(segments) == 1:  # at rest, or running at a constant speed (most reads)
            seg = segments[0]
            dt = t - seg.t0
            if dt < 0.0:
                dt = 0.0
            return State(seg.p0 + seg.v0 * dt + 0.5 * seg.a * dt * dt, seg.v0 + seg.a * dt, seg.a,
                         seg.duration != math.inf or seg.v0 != 0.0)
        for seg in segments:
            dt = t - seg.t0
            if dt < seg.duration:
                dt = max(dt, 0.0)
                return State(seg.p0 + seg.v0 * dt + 0.5 * seg.a * dt * dt, seg.v0 + seg.a * dt, seg.a,
                             seg.duration != math.inf or seg.v0 != 0.0)
        seg = self.segments[-1]  # unreachable: the last segment is open-ended
        return State(seg.p0, seg.v0, 0.0, False)

    def position_velocity(self, t: float) -> tuple[float, float]:
        """``at(t)``'s position and velocity (the same arithmetic, without building a State)."""
        segments = self.segments
        if len(segments) == 1:
            seg = segments[0]
            dt = t - seg.t0
            if dt < 0.0:
                dt = 0.0
            return seg.p0 + seg.v0 * dt + 0.5 * seg.a * dt * dt, seg.v0 + seg.a * dt
        s = self.at(t)
        return s.position, s.velocity

    def rests_at(self, t: float, position: float) -> bool:
        """Whether the horn is at rest at ``position`` from ``t`` on (planning a move there would change nothing)."""
        seg = self.segments[-1]
        return t >= seg.t0 and seg.p0 == position and seg.v0 == 0.0 and seg.a == 0.0 and self.target == position

    def end_time(self) -> float:
        """When the motion settles (the start of the final, open-ended segment)."""
        return self.segments[-1].t0

    def stop(self, t: float) -> None:
        """Freeze at the present position (torque off, shutdown)."""
        p = self.at(t).position
        self.segments = [Segment(t, p, 0.0, 0.0, math.inf)]
        self.target = p

    def move_to(self, t: float, target: float, vmax: float, amax: float) -> None:
        """Head for ``target`` from the present state, within ``vmax`` and ``amax`` (both > 0)."""
        s = self.at(t)
        self.target = target
        segs: list[Segment] = []
        p, v, now = s.position, s.velocity, t
        # Moving away from the target, or too fast to stop before it: brake to rest first.
        direction = 1.0 if target >= p else -1.0
        stop_dist = v * v / (2 * amax)
        if v * direction < 0 or stop_dist > abs(target - p):
            dur = abs(v) / amax
            a = -amax if v > 0 else amax
            segs.append(Segment(now, p, v, a, dur))
            p += v * dur + 0.5 * a * dur * dur
            now += dur
            v = 0.0
            direction = 1.0 if target >= p else -1.0
        dist = abs(target - p)
        v = min(abs(v), vmax)  # speed along the direction of travel
        d_acc = (vmax * vmax - v * v) / (2 * amax)
        d_dec = vmax * vmax / (2 * amax)
        if d_acc + d_dec <= dist:
            peak = vmax
            cruise = (dist - d_acc - d_dec) / vmax
        else:
            peak = math.sqrt(max((2 * amax * dist + v * v) / 2, 0.0))
            cruise = 0.0
        t_acc = (peak - v) / amax
        t_dec = peak / amax
        for dur, acc, vel in ((t_acc, amax, v), (cruise, 0.0, peak), (t_dec, -amax, peak)):
            if dur > 1e-9:
                segs.append(Segment(now, p, vel * direction, acc * direction, dur))
                p += direction * (vel * dur + 0.5 * acc * dur * dur)
                now += dur
        segs.append(Segment(now, target, 0.0, 0.0, math.inf))
        self.segments = segs

    def run_at(self, t: float, velocity: float, amax: float) -> None:
        """Velocity mode: ramp to ``velocity`` (pulses/s, signed) and keep it."""
        s = self.at(t)
        dv = velocity - s.velocity
        dur = abs(dv) / amax
        segs = []
        p = s.position
        if dur > 1e-9:
            a = amax if dv > 0 else -amax
            segs.append(Segment(t, p, s.velocity, a, dur))
            p += s.velocity * dur + 0.5 * a * dur * dur
        segs.append(Segment(t + dur, p, velocity, 0.0, math.inf))
        self.segments = segs
        self.target = math.copysign(math.inf, velocity) if velocity else p
