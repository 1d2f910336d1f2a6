"""What every emulated scanner shares: a place in the scene, a range model, a clock and fault knobs.

A scanner measures the scene from its pose: beam angles in the sensor's own
convention are turned into world directions by the model (clockwise for the
RPLIDAR, right-to-left for the LMS 200, counter-clockwise steps for SCIP
units), cast against the scene at the time each beam is taken, and passed
through the model's :class:`~hilbench.fakes.scene.RangeModel`.
Every measurement is kept with its true time (:attr:`Scanner.truth`) so
tests can compare what a client decoded with what the emulator meant.

A scanner sits in a :class:`~hilbench.fakes.world.World` (a bare scene is
put into a world of its own): fixed in it (``pose`` is then its world pose),
or mounted on a body (``body``; ``pose`` is then the mount pose in the
body's frame). A mounted scanner casts each ray from where its body was at
that ray's time, so a scan taken while the body turns is skewed as a real
one is; every body's footprint but its own is in its view.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hilbench.fakes.scene import Pose, RangeModel, Scene
from hilbench.fakes.world import World
from hilbench.transports.clock import WALL


@dataclass(frozen=True)
class TruthScan:
    """One scan as emulated: start time (monotonic s), sensor-convention angles (deg), true ranges (m), measured
    ranges (m), and the time of its last ray."""

    t: float
    angles: np.ndarray
    ranges: np.ndarray
    measured: np.ndarray
    t_last: float = 0.0


class Scanner:
    """Base class of emulated scanners on a medium (subclasses implement ``on_bytes``)."""

    #: How many recent scans :attr:`truth` keeps.
    TRUTH_SCANS = 64
    #: :attr:`requests` keeps at most this many names (the older half is dropped when it is full).
    MAX_REQUESTS = 256

    #: World hit points of this many recent measurements are kept (:meth:`points`, for views).
    POINT_BATCHES = 48

    def __init__(self, name: str, scene: Scene | World, pose: Pose, model: RangeModel, *, t0: float | None = None,
                 body: str | None = None) -> None:
        self.name = name
        self.t0 = WALL.now() if t0 is None else t0
        self.world = scene if isinstance(scene, World) else World(scene, t0=self.t0)
        self.scene = self.world.scene
        if body is not None:
            self.world.body(body)  # (KeyError naming the bodies)
        self.body = body
        self.pose = pose
        self.model = model
        self._points: collections.deque[tuple[Any, ...]] = collections.deque(maxlen=self.POINT_BATCHES)
        self.port = None
        self.truth: collections.deque[TruthScan] = collections.deque(maxlen=self.TRUTH_SCANS)
        self.counters: dict[str, int] = collections.Counter()
        self.requests: list[str] = []  # names of the latest requests, oldest first (for status reports)

    def attach(self, medium) -> None:
        """Join a medium as ``<name>-device`` (the host port keeps the endpoint's name, so taps and
        trackers tell the two directions apart); the device port transmits on the medium's clock."""
        self.port = medium.add_device(_Party(self, f"{self.name}-device"))

    def now(self) -> float:
        """The medium's time (its bench's clock; the wall clock before the scanner is attached)."""
        return self.port.now() if self.port is not None else WALL.now()

    def directions(self, sensor_deg: np.ndarray, heading: np.ndarray | float) -> np.ndarray:
        """World directions (rad) of beams at sensor-convention angles when the sensor's straight-ahead
        points at ``heading`` (rad, one or one per beam; overridden per convention)."""
        raise NotImplementedError

    def world_angles(self, sensor_deg: np.ndarray) -> np.ndarray:
        """World directions (rad) of beams at sensor-convention angles from the (fixed) mounting pose."""
        return self.directions(np.asarray(sensor_deg, float), math.radians(self.pose.heading))

    def origins(self, sensor_deg: np.ndarray, times: np.ndarray) -> tuple[Any, Any, np.ndarray]:
        """Where each beam starts and which world direction it takes (x, y: arrays, or numbers for a scanner
        fixed in the world; directions in rad) when beam k is taken at ``times[k]``."""
        p = self.pose
        if self.body is None:  # (scalars: the world's caster then takes the cached path for a fixed origin)
            return p.x, p.y, self.world_angles(sensor_deg)
        bx, by, bth = self.world.poses_at(self.body, times)
        c, s = np.cos(bth), np.sin(bth)
        return (bx + c * p.x - s * p.y, by + s * p.x + c * p.y,
                self.directions(sensor_deg, bth + math.radians(p.heading)))

    def measure(self, sensor_deg: np.ndarray, t: float,
                times: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """True ranges (m, inf: nothing), measured ranges (m, 0: no return) and power for beams taken at
        ``times`` (one per beam; default: all at ``t``); other bodies and movers are where they are at ``t``."""
        sensor_deg = np.asarray(sensor_deg, float)
        times = np.full(len(sensor_deg), t) if times is None else np.asarray(times, float)
        ox, oy, dirs = self.origins(sensor_deg, times)
        rng, cos_inc, refl = self.world.cast(ox, oy, dirs, t, max_range=self.model.max_range, exclude=self.body)
        self._points.append((ox, oy, dirs, rng))  # (turned into points only when a view asks)
        meas, power = self.model.measure(rng, cos_inc, refl)
        return rng, meas, power

    def points(self, limit: int = 2000) -> list[list[float]]:
        """World points (x, y) the most recent beams hit (truth, newest last; for top-down views)."""
        xs, ys = [], []
        for ox, oy, dirs, rng in list(self._points):
            hit = np.isfinite(rng)
            xs.append((ox[hit] if np.ndim(ox) else ox) + rng[hit] * np.cos(dirs[hit]))
            ys.append((oy[hit] if np.ndim(oy) else oy) + rng[hit] * np.sin(dirs[hit]))
        if not xs:
            return []
        return np.stack([np.concatenate(xs)[-limit:], np.concatenate(ys)[-limit:]], axis=1).round(4).tolist()

    def truth_range(self, sensor_deg: float, t: float | None = None) -> float:
        """The true range (m) of one beam at a sensor angle (for tests computing the truth by hand)."""
        t = self.now() if t is None else t
        ox, oy, dirs = self.origins(np.asarray([sensor_deg], float), np.asarray([t]))
        r, _, _ = self.world.cast(ox, oy, dirs, t, exclude=self.body)
        return float(r[0])

    def note_request(self, name: str) -> None:
        """Keep the name of a request the unit heard (bounded: see :attr:`MAX_REQUESTS`)."""
        self.requests.append(name)
        if len(self.requests) > self.MAX_REQUESTS:
            del self.requests[:self.MAX_REQUESTS // 2]

    def remember(self, t: float, angles: np.ndarray, ranges: np.ndarray, measured: np.ndarray,
                 t_last: float | None = None) -> None:
        """Keep a finished scan (first ray at ``t``, last at ``t_last``) and tell the world's recorders."""
        self.truth.append(TruthScan(t, np.asarray(angles), np.asarray(ranges), np.asarray(measured),
                                    t if t_last is None else t_last))
        self.world.note_scan(self.name, self.body, t, t if t_last is None else t_last)

    def on_port_event(self, event, t: float) -> None:  # noqa: D401 (modem lines: most scanners ignore them)
        """Modem lines, BREAK or settings from the host (ignored unless a model cares)."""


class _Party:
    """A scanner as a party on a medium, under its own name."""

    def __init__(self, scanner: Scanner, name: str) -> None:
        self.scanner = scanner
        self.name = name

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        self.scanner.on_bytes(data, t, baud)

    def on_port_event(self, event, t: float) -> None:
        self.scanner.on_port_event(event, t)


__all__ = ["Scanner", "TruthScan"]
