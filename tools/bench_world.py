#!/usr/bin/env python3
"""World benchmarks; prints one JSON object per figure (see DESIGN.md §10).

1. World steps per second with 2 and 10 bodies, each driven by the rover
   firmware's motion model (a :class:`~hilbench.fakes.mecanum_robot.Robot`
   turning on a circle) and carrying a SICK LMS 200 (181 beams at 75 Hz, each
   ray from its body's pose at its time), in an arena with obstacles and a
   moving object, stepped at 200 Hz in simulated time as fast as this machine
   allows. Reference: the 200 steps/s real time needs; ``ratio`` = how many
   times faster than real time the whole world (steps and scans) runs;
   ``cpu_ratio`` divides by this process's CPU time instead (steadier on a
   shared machine).
2. The cost a moving body adds to a scan (one LMS 200 scan, 181 beams):
   a scanner fixed in a static scene (the reference: cached visibility map),
   the same with one body moving in its view (its pose at the scan's time,
   its footprint against the beams it subtends), with 10 bodies standing and
   10 bodies moving in view, and a scanner on a moving body (each beam from
   its own origin). ``ratio`` = that scan's time / the static scan's (CPU
   time of the measuring thread, median of 195 scans).

Usage: tools/bench_world.py [--seconds S]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from benchlib import emit

from hilbench.fakes.mecanum_robot import Robot
from hilbench.fakes.scanners.sick_lms200 import SickLms200
from hilbench.fakes.scene import Mover, Pose, RangeModel, Scene
from hilbench.fakes.world import Body, Shape, World

STEP = 0.005
LMS_PERIOD = 1 / 75


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def arena(clock: Clock) -> World:
    scene = Scene.build(walls=[[(-8, -6), (8, -6), (8, 6), (-8, 6), (-8, -6)]],
                        boxes=[{"center": (0.0, 5.0), "size": (1.0, 0.4)}, {"center": (6.0, -4.0), "size": (0.4, 0.4)}],
                        circles=[{"center": (-6.0, 5.0), "radius": 0.25}],
                        movers=[Mover(((-6.0, -5.3), (6.0, -5.3)), 0.4, radius=0.2)])
    return World(scene, t0=0.0, clock=clock)


def driven(world: World, n: int) -> list[tuple[SickLms200, Robot]]:
    """``n`` rovers on a grid, each turning on a 0.5 m circle (its own Robot), each with an LMS 200."""
    units = []
    for k in range(n):
        name = f"r{k}"
        world.add_body(Body(name, Shape("box", (0.5, 0.4)), x=-6.0 + 3.0 * (k % 5), y=-2.5 + 3.0 * (k // 5)))
        robot = Robot(10_000, 10_000)
        robot.push_setpoint(0.0, 200.0, 0.0, 0.4)

        def motion(t: float, robot: Robot = robot) -> tuple:
            robot.advance(t * 1e6)
            return (1, *robot.motion_at(t * 1e6), *robot.body_velocity())

        world.drive(name, motion)
        lms = SickLms200(f"{name}-lms", world, Pose(0.15, 0.0, 0.0), RangeModel(0.0, 80.0, 0.005, 0.0), t0=0.0,
                         body=name)
        lms.resolution = 100
        units.append((lms, robot))
    return units


def steps_per_second(n: int, seconds: float) -> tuple[float, float]:
    """(world steps per wall second, simulated seconds per wall second and per CPU second of this process) with
    ``n`` driven, scanning bodies."""
    clock = Clock()
    world = arena(clock)
    units = driven(world, n)
    angles = units[0][0].beam_angles()
    next_scan = LMS_PERIOD
    steps = 0
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    while clock.t < seconds:
        clock.t += STEP
        world.step()
        steps += 1
        while next_scan <= clock.t:  # every scanner's scans that ended by now
            start = next_scan - LMS_PERIOD
            for lms, _robot in units:
                times = lms.beam_times(start, angles)
                lms.measure(angles, start + LMS_PERIOD / 2, times)
            next_scan += LMS_PERIOD
    wall, cpu = time.perf_counter() - t_wall, time.process_time() - t_cpu
    return steps / wall, seconds / wall, seconds / cpu


def scan_cost(repeat: int) -> dict[str, float]:
    """Median CPU seconds per LMS 200 scan (181 beams): static; one body moving in view; 10 bodies standing, 10
    moving in view; from a moving body."""
    out = {}
    for case in ("static", "mover", "bodies", "movers", "moving"):
        clock = Clock()
        world = arena(clock)
        if case == "mover":  # 2 m ahead of the scanner (at (0, -1), looking east), driving on a circle
            world.add_body(Body("b0", Shape("box", (0.5, 0.4)), x=2.0, y=-1.0))
            world.set_velocity("b0", 0.3, 0.0, 0.2)
        if case in ("bodies", "movers"):
            for k in range(10):
                world.add_body(Body(f"b{k}", Shape("box", (0.5, 0.4)), x=-6.0 + 3.0 * (k % 5), y=3.0 + (k // 5)))
                if case == "movers":
                    world.set_velocity(f"b{k}", 0.3, 0.0, 0.2)
        body = None
        if case == "moving":
            body = "me"
            world.add_body(Body("me", Shape("box", (0.5, 0.4)), x=0.0, y=-1.0))
            world.set_velocity("me", 0.3, 0.0, 0.5)
        lms = SickLms200("lms", world, Pose(0.15 if body else 0.0, 0.0 if body else -1.0, 0.0),
                         RangeModel(0.0, 80.0, 0.005, 0.0), t0=0.0, body=body)
        lms.resolution = 100
        angles = lms.beam_angles()
        times = []
        for i in range(repeat):
            clock.t += LMS_PERIOD
            world.step()
            start = clock.t - LMS_PERIOD
            beam_t = lms.beam_times(start, angles) if body else None
            t0 = time.thread_time()  # (CPU time of this thread: what the scan costs, not what neighbours took)
            lms.measure(angles, start + LMS_PERIOD / 2, beam_t)
            if i >= 5:  # (after the visibility map exists)
                times.append(time.thread_time() - t0)
        out[case] = statistics.median(times)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per world (default 10)")
    args = ap.parse_args()
    for n in (2, 10):
        steps, speed, cpu_speed = steps_per_second(n, args.seconds)
        emit(f"world_steps_{n}_bodies", steps, "steps/s", 1 / STEP, steps * STEP, bodies=n, scanners=n,
             beams_per_scan=181, scan_hz=75, realtime_factor=round(speed, 2), cpu_ratio=round(cpu_speed, 2))
    cost = scan_cost(200)
    emit("scan_static_scene", cost["static"] * 1e6, "us", cost["static"] * 1e6, 1.0, beams=181)
    emit("scan_with_a_moving_body_in_view", cost["mover"] * 1e6, "us", cost["static"] * 1e6,
         cost["mover"] / cost["static"], beams=181, note="fixed scanner; one body driving across its view")
    emit("scan_with_10_bodies_in_view", cost["bodies"] * 1e6, "us", cost["static"] * 1e6,
         cost["bodies"] / cost["static"], beams=181)
    emit("scan_with_10_moving_bodies_in_view", cost["movers"] * 1e6, "us", cost["static"] * 1e6,
         cost["movers"] / cost["static"], beams=181)
    emit("scan_from_moving_body", cost["moving"] * 1e6, "us", cost["static"] * 1e6,
         cost["moving"] / cost["static"], beams=181, note="each beam from its own origin (body turning)")
    assert math.isfinite(cost["moving"])


if __name__ == "__main__":
    main()
