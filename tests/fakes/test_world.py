"""The world on its own (hilbench/fakes/world.py): stepping, collisions, poses between steps, casting against
bodies, scans skewed by a turning body, recording; and the rover's encoder noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilbench.fakes.mecanum_robot import Robot
from hilbench.fakes.scanners.sick_lms200 import SickLms200
from hilbench.fakes.scene import Pose, RangeModel, Scene
from hilbench.fakes.world import Body, Recorder, Shape, World, footprint_hits, read_record


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def room_world(*bodies: Body, clock: Clock | None = None) -> World:
    """A 6 m x 4 m room (walls x = +-3, y = +-2)."""
    return World(Scene.room(-3, -2, 3, 2), bodies, t0=100.0, clock=clock or Clock())


def run(world: World, clock: Clock, seconds: float, step: float = 0.005) -> None:
    for _ in range(round(seconds / step)):
        clock.t += step
        world.step()


def test_a_body_moves_in_its_own_frame_and_the_history_interpolates():
    clock = Clock()
    w = room_world(Body("r", Shape("box", (0.5, 0.4)), theta=math.pi / 2), clock=clock)
    w.set_velocity("r", 0.2, 0.0, 0.0)  # forward in the body's frame: +y in the world
    run(w, clock, 1.0)
    b = w.body("r")
    assert b.x == pytest.approx(0.0, abs=1e-9) and b.y == pytest.approx(0.2, abs=0.002)
    assert (b.vx, b.vy) == pytest.approx((0.0, 0.2), abs=1e-9)
    mid = w.pose_at("r", 100.5)
    assert mid.y == pytest.approx(0.1, abs=0.002)
    ahead = w.pose_at("r", clock.t + 0.01)  # past the last step: extrapolated with the velocity
    assert ahead.y == pytest.approx(b.y + 0.002, abs=1e-6)


def test_a_body_meeting_a_wall_stops_and_counts_one_collision():
    clock = Clock()
    w = room_world(Body("r", Shape("box", (0.5, 0.4)), x=2.5), clock=clock)
    w.set_velocity("r", 0.5)
    run(w, clock, 1.0)
    b = w.body("r")
    assert b.blocked and b.collisions == 1
    assert b.x == pytest.approx(2.75, abs=0.001)  # it stops where its front touches the wall x = 3
    w.set_velocity("r", -0.5)  # backing off is allowed
    run(w, clock, 0.2)
    assert not w.body("r").blocked and w.body("r").x < 2.7


def test_a_pause_against_the_wall_is_the_same_contact():
    """A step in which the wheels did not move (a board that lags one step, a stop) ends no contact: pushing on
    is still the one collision."""
    clock = Clock()
    w = room_world(Body("r", Shape("box", (0.5, 0.4)), x=2.5), clock=clock)
    w.set_velocity("r", 0.5)
    run(w, clock, 1.0)
    w.set_velocity("r", 0.0)
    run(w, clock, 0.1)
    assert w.body("r").blocked
    w.set_velocity("r", 0.5)
    run(w, clock, 0.5)
    b = w.body("r")
    assert b.blocked and b.collisions == 1 and b.x == pytest.approx(2.75, abs=0.001)


def test_bodies_collide_with_each_other_and_with_obstacles():
    clock = Clock()
    a = Body("a", Shape("circle", radius=0.2), x=-1.0)
    b = Body("b", Shape("box", (0.4, 0.4)), x=0.0)
    w = room_world(a, b, clock=clock)
    w.set_velocity("a", 1.0)
    run(w, clock, 1.0)
    assert a.blocked and a.x == pytest.approx(-0.4, abs=0.002)  # 0.2 + 0.2 from b's centre
    segs = np.asarray([[0.0, -1.0, 0.0, 1.0]])
    assert footprint_hits(Shape("box", (0.5, 0.4)), 0.2, 0.0, 0.0, segs, np.zeros((0, 3)))
    assert not footprint_hits(Shape("box", (0.5, 0.4)), 0.26, 0.0, 0.0, segs, np.zeros((0, 3)))
    assert footprint_hits(Shape("box", (0.5, 0.4)), 0.26, 0.0, math.pi / 2, np.zeros((0, 4)),
                          np.asarray([[0.26, 0.4, 0.21]]))  # turned: its long side reaches y = 0.25


def test_a_driver_s_motion_moves_the_body_exactly_however_irregular_the_steps_and_slip_loses_a_share():
    """A driver reports the motion its wheels made (a robot turning on a circle); the world applies it
    between its steps, long or short, so the body ends where the wheels took it."""
    clock = Clock()
    w = room_world(Body("r", Shape("circle", radius=0.1)), Body("s", Shape("circle", radius=0.1), y=1.0),
                   clock=clock)
    v, omega = 0.3, 0.5

    def wheels(t: float):
        dt = t - 100.0
        th = omega * dt
        return 1, v / omega * math.sin(th), v / omega * (1 - math.cos(th)), th, v, 0.0, omega

    w.drive("r", wheels)
    w.drive("s", wheels, slip=0.5)
    for dt in (0.003, 0.2, 0.01, 0.5, 0.05, 0.237):  # a busy machine steps irregularly
        clock.t += dt
        w.step()
    th = omega * (clock.t - 100.0)
    r = w.body("r")
    assert (r.x, r.y, r.theta) == pytest.approx((v / omega * math.sin(th), v / omega * (1 - math.cos(th)), th))
    s = w.body("s")
    assert s.theta == pytest.approx(th / 2, rel=0.05) and 0 < s.x < r.x  # slipping: less of the same motion
    assert (r.vx, r.vy, r.omega) == pytest.approx((v * math.cos(th), v * math.sin(th), omega))


def test_place_restarts_the_history_so_no_sensor_sees_a_slide():
    clock = Clock()
    w = room_world(Body("r", Shape("circle", radius=0.2)), clock=clock)
    run(w, clock, 0.1)
    w.place("r", 1.0, 1.0, 0.5)
    assert w.pose_at("r", clock.t - 0.05) == w.pose_at("r", clock.t)  # (x, y, theta) = the new pose
    assert w.pose_at("r", clock.t).x == 1.0


def test_casts_see_other_bodies_but_not_their_own():
    clock = Clock()
    w = room_world(Body("me", Shape("box", (0.5, 0.4))), Body("other", Shape("box", (0.5, 0.4)), x=2.0),
                   clock=clock)
    r, cos_inc, _ = w.cast(0.0, 0.0, np.asarray([0.0, math.pi]), clock.t, exclude="me")
    assert r[0] == pytest.approx(1.75) and cos_inc[0] == pytest.approx(1.0)  # other's near face at x = 1.75
    assert r[1] == pytest.approx(3.0)  # the wall behind, through its own footprint
    r, _, _ = w.cast(0.0, 0.0, np.asarray([0.0]), clock.t)
    assert r[0] == pytest.approx(0.25)  # not excluded: its own front face


def test_bodies_culled_by_angle_give_what_every_ray_against_every_body_gives():
    """:meth:`World.cast` tests each body only against the rays it may meet; the reference tests all pairs."""
    from hilbench.fakes.world import cast_rays

    rng = np.random.default_rng(7)
    clock = Clock()
    for trial in range(20):
        bodies = [Body(f"b{k}", Shape("box", tuple(rng.uniform(0.1, 0.8, 2))) if k % 2 else
                       Shape("circle", radius=float(rng.uniform(0.05, 0.4))),
                       *rng.uniform(-2.5, 2.5, 2), float(rng.uniform(-3, 3))) for k in range(8)]
        w = room_world(*bodies, clock=clock)
        n = 400
        spread = 0.3 if trial % 2 else 0.0  # rays from one origin, or each from its own (a moving caster)
        ox = rng.uniform(-spread, spread, n) if spread else 0.0
        oy = rng.uniform(-spread, spread, n) if spread else 0.0
        angles = rng.uniform(-np.pi, np.pi, n)
        got = w.cast(ox, oy, angles, clock.t, exclude="b0")
        segs, srefl, circ, crefl = w.body_geometry(clock.t, exclude="b0")
        sc = w.scene
        ref = cast_rays(ox, oy, angles, np.vstack([sc.segments, segs]), np.concatenate([sc.segment_reflectivity, srefl]),
                        np.vstack([sc.circles, circ]), np.concatenate([sc.circle_reflectivity, crefl]))
        for a, b in zip(got, ref, strict=True):
            assert np.allclose(a, b)


def test_a_scan_taken_while_turning_is_skewed():
    """Each beam of the LMS 200 leaves from where its body points at that beam's time."""
    clock = Clock()
    w = room_world(Body("r", Shape("circle", radius=0.1)), clock=clock)
    omega = 2.0  # rad/s: 0.013 s of scan turns the body by 1.5 degrees
    w.set_velocity("r", 0.0, 0.0, omega)
    run(w, clock, 0.5)
    model = RangeModel(0.0, 80.0, 0.0, 0.0)  # no noise: compare exactly
    lms = SickLms200("lms", w, Pose(0.1, 0.0, 0.0), model, t0=100.0, body="r")
    angles = lms.beam_angles()
    t_start = clock.t - 0.1
    times = lms.beam_times(t_start, angles)
    assert times[-1] - times[0] == pytest.approx(180 / 360 * 1 / 75, rel=1e-3)
    skewed, _, _ = lms.measure(angles, t_start, times)
    still, _, _ = lms.measure(angles, t_start)  # every beam at the scan's start
    # By hand: the body turns at omega from its pose at t_start; the mount is 0.1 m ahead of its centre.
    th = w.pose_at("r", t_start).theta + omega * (times - t_start)
    ox, oy = 0.1 * np.cos(th), 0.1 * np.sin(th)
    phi = th + np.radians(angles - 90.0)
    c, s = np.cos(phi), np.sin(phi)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (3 - ox) / c, (-3 - ox) / c)
        ty = np.where(s > 0, (2 - oy) / s, (-2 - oy) / s)
    assert np.allclose(skewed, np.minimum(tx, ty), atol=1e-6)
    assert np.max(np.abs(skewed - still)) > 0.02  # the skew is not noise


def test_the_recorder_writes_every_step_and_every_scan(tmp_path):
    clock = Clock()
    w = room_world(Body("r", Shape("circle", radius=0.1)), clock=clock)
    rec = Recorder(str(tmp_path / "rec.jsonl"), w)
    w.listeners.append(rec)
    w.set_velocity("r", 0.1)
    run(w, clock, 0.5)
    w.note_scan("lms", "r", 100.1, 100.1133)
    rec.close()
    got = read_record(str(tmp_path / "rec.jsonl"))
    assert got["header"]["bodies"] == {"r": {"kind": "circle", "radius": 0.1}}
    assert len(got["poses"]) == 100  # 200 Hz
    t, poses = got["poses"][-1]
    assert t == pytest.approx(100.5) and poses["r"][0] == pytest.approx(0.05, abs=0.001)
    assert got["scans"][0].device == "lms" and got["scans"][0].t_last == pytest.approx(100.1133)


def test_encoder_noise_makes_odometry_drift_and_none_keeps_it_exact():
    def drive(noise: float) -> Robot:
        r = Robot(10_000, 10_000, encoder_noise=noise, seed=3)
        r.push_setpoint(0, 300.0, 0.0, 0.0)
        r.advance(5e6)
        return r

    exact, noisy = drive(0.0), drive(20.0)
    assert exact.y == 0.0 and exact.theta == 0.0
    assert abs(noisy.y) > 1.0 or abs(noisy.theta) > 1e-3  # mm, rad: sideways and heading drift
    assert noisy.wheel_angle != exact.wheel_angle
    assert noisy.x == pytest.approx(exact.x, rel=0.02)
    assert exact.body_velocity() == pytest.approx((0.3, 0.0, 0.0))
    assert exact.measured == exact.motion  # what the encoders measured is what the wheels did
    assert noisy.measured != pytest.approx(noisy.motion, abs=1e-4)  # unless they count noise


def test_odometry_per_encoder_message_loses_no_delta_and_the_mailbox_does():
    """The FreeRTOS build's odometry reads one wheel period's delta per pose cycle (spec §2.4: 20 of 33.3 ms);
    the micro-ROS build's runs per encoder message (§2.2) and integrates them all, as the wheels measure."""
    def drive(every_delta: bool) -> Robot:
        r = Robot(33_333, 20_000, every_delta=every_delta)
        r.push_setpoint(0, 300.0, 0.0, 0.0)
        r.advance(3e6)
        return r

    mailbox, every = drive(False), drive(True)
    assert every.x == pytest.approx(every.measured[0] * 1000.0, rel=1e-4)
    assert mailbox.x == pytest.approx(0.6 * mailbox.measured[0] * 1000.0, rel=1e-4)
    assert mailbox.measured == every.measured == mailbox.motion
