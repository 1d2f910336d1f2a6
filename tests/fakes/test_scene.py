"""The scene and its ray caster: the room by hand, culled casting against every pair, movers, the model."""

from __future__ import annotations

import numpy as np

from hilbench.bench.profile import load_profile
from hilbench.fakes.scene import Mover, RangeModel, Scene
from tests.fakes.scanners.conftest import room_range


def test_room_matches_the_hand_computed_truth():
    scene = load_profile("scanners").tables["scene"]
    phi = np.linspace(-np.pi, np.pi, 3601)
    r, cos_inc, refl = scene.cast(0.5, 0.3, phi)
    assert np.allclose(r, room_range(phi))
    assert np.all((cos_inc > 0) & (cos_inc <= 1)) and np.all(refl == 0.8)
    assert np.allclose(scene.cast(0.5, 0.3, np.radians([0, 90, 180, 270]))[0], [2.5, 1.7, 3.5, 2.3])


def test_culled_and_visibility_casting_agree_with_every_pair():
    rng = np.random.default_rng(5)
    for trial in range(20):
        segs = rng.uniform(-4, 4, (80, 4))  # crossing segments: the visibility map must cut at crossings
        movers = (Mover(((0.0, 0.0), (1.0, 1.0)), 0.4, size=(0.3, 0.2)),) if trial % 2 else ()
        scene = Scene(segs, np.ones(80), np.array([[0.7, -0.4, 0.3]]), np.ones(1), movers=movers)
        ox, oy = rng.uniform(-1, 1, 2)
        for rep in range(3):  # the first cast from an origin is culled, later ones use its visibility map
            beams = rng.uniform(-7, 7, 700)
            fast = scene.cast(ox, oy, beams, t=rep * 0.5)
            slow = scene.cast(ox, oy, beams, t=rep * 0.5, dense=True)
            for a, b in zip(fast, slow, strict=True):
                assert np.allclose(a, b)
        assert (float(ox), float(oy)) in scene._visibility


def test_movers_boxes_circles_and_max_range():
    scene = Scene.build(walls=[[(-3, -2), (3, -2), (3, 2), (-3, 2), (-3, -2)]],
                        boxes=[{"center": (2.0, 0.0), "size": (0.2, 0.4)}],
                        circles=[{"center": (0.0, 1.0), "radius": 0.25}],
                        movers=[Mover(((-1.0, -1.0), (-1.0, 1.0)), 1.0, radius=0.1)])
    r = scene.cast(0.0, 0.0, np.radians([0, 90, 180]), t=1.0)[0]
    assert np.allclose(r, [1.9, 0.75, 0.9])  # box face, circle, the mover at (-1, 0) after 1 s
    r2 = scene.cast(0.0, 0.0, np.radians([180]), t=0.0)[0]
    assert np.isclose(r2[0], 3.0)  # at t = 0 the mover is at (-1, -1): the wall behind
    assert np.isinf(scene.cast(0.0, 0.0, np.radians([0]), max_range=1.0)[0][0])


def test_range_model_noise_dropouts_and_limits():
    model = RangeModel(min_range=0.15, max_range=12.0, sigma0=0.001, sigma_k=0.01, seed=3)
    r = np.full(20000, 4.0)
    meas, power = model.measure(r, np.ones_like(r), np.full_like(r, 0.8))
    assert abs(np.std(meas) - 0.04) < 0.003 and abs(np.mean(meas) - 4.0) < 0.002
    near, _ = model.measure(np.array([0.1, np.inf, 13.0]), np.ones(3), np.ones(3))
    assert np.all(near == 0)  # too close, nothing hit, beyond max range: no return, not a small number
    drop = RangeModel(dropout=0.25, seed=1)
    m, _ = drop.measure(np.full(20000, 2.0), np.ones(20000), np.ones(20000))
    assert abs(np.mean(m == 0) - 0.25) < 0.02
    again, _ = RangeModel(min_range=0.15, max_range=12.0, sigma0=0.001, sigma_k=0.01, seed=3).measure(
        r, np.ones_like(r), np.full_like(r, 0.8))
    assert np.array_equal(meas, again)  # seeded: a failing test replays the same scans
