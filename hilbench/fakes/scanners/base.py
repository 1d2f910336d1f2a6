"""What every emulated scanner shares: a place in the scene, a range model, a clock and fault knobs.

A scanner measures the scene from its pose: beam angles in the sensor's own
convention are turned into world directions by the model (clockwise for the
RPLIDAR, right-to-left for the LMS 200, counter-clockwise steps for SCIP
units), cast against the scene at the time each beam is taken, and passed
through the model's :class:`~hilbench.fakes.scanners.scene.RangeModel`.
Every measurement is kept with its true time (:attr:`Scanner.truth`) so
tests can compare what a client decoded with what the emulator meant.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np

from hilbench.fakes.scanners.scene import Pose, RangeModel, Scene
from hilbench.transports.clock import WALL


@dataclass(frozen=True)
class TruthScan:
    """One scan as emulated: start time (monotonic s), sensor-convention angles (deg), true ranges (m)."""

    t: float
    angles: np.ndarray
    ranges: np.ndarray
    measured: np.ndarray


class Scanner:
    """Base class of emulated scanners on a medium (subclasses implement ``on_bytes``)."""

    #: How many recent scans :attr:`truth` keeps.
    TRUTH_SCANS = 64
    #: :attr:`requests` keeps at most this many names (the older half is dropped when it is full).
    MAX_REQUESTS = 256

    def __init__(self, name: str, scene: Scene, pose: Pose, model: RangeModel, *, t0: float | None = None) -> None:
        self.name = name
        self.scene = scene
        self.pose = pose
        self.model = model
        self.t0 = WALL.now() if t0 is None else t0
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

    def world_angles(self, sensor_deg: np.ndarray) -> np.ndarray:
        """World directions (rad) of beams at sensor-convention angles (overridden per convention)."""
        raise NotImplementedError

    def measure(self, sensor_deg: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """True ranges (m, inf: nothing), measured ranges (m, 0: no return) and power for beams at ``t``."""
        p = self.pose
        rng, cos_inc, refl = self.scene.cast(p.x, p.y, self.world_angles(np.asarray(sensor_deg, float)),
                                             t=t - self.t0, max_range=self.model.max_range)
        meas, power = self.model.measure(rng, cos_inc, refl)
        return rng, meas, power

    def truth_range(self, sensor_deg: float, t: float | None = None) -> float:
        """The true range (m) of one beam at a sensor angle (for tests computing the truth by hand)."""
        t = self.now() if t is None else t
        p = self.pose
        r, _, _ = self.scene.cast(p.x, p.y, self.world_angles(np.asarray([sensor_deg], float)), t=t - self.t0)
        return float(r[0])

    def note_request(self, name: str) -> None:
        """Keep the name of a request the unit heard (bounded: see :attr:`MAX_REQUESTS`)."""
        self.requests.append(name)
        if len(self.requests) > self.MAX_REQUESTS:
            del self.requests[:self.MAX_REQUESTS // 2]

    def remember(self, t: float, angles: np.ndarray, ranges: np.ndarray, measured: np.ndarray) -> None:
        self.truth.append(TruthScan(t, np.asarray(angles), np.asarray(ranges), np.asarray(measured)))

    def on_line(self, event, t: float) -> None:  # noqa: D401 (modem lines: most scanners ignore them)
        """Modem lines, BREAK or settings from the host (ignored unless a model cares)."""


class _Party:
    """A scanner as a party on a medium, under its own name."""

    def __init__(self, scanner: Scanner, name: str) -> None:
        self.scanner = scanner
        self.name = name

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        self.scanner.on_bytes(data, t, baud)

    def on_line(self, event, t: float) -> None:
        self.scanner.on_line(event, t)


__all__ = ["Scanner", "TruthScan"]
