"""One world per bench: static geometry, objects moving on paths and named rigid bodies that devices move.

The world is the truth every device shares (DESIGN.md §12). It holds:

- the **scene** (:class:`~hilbench.fakes.scene.Scene`): walls, boxes
  and circles that never move, and movers on closed paths whose position is a
  pure function of time;
- **bodies** (:class:`Body`): named rigid bodies with a footprint (a box
  ``w`` x ``h`` or a circle), a pose (x, y in metres, theta in radians
  counter-clockwise from +x) and a velocity. A body may have a **driver**, a
  callable giving its body-frame velocity at a time (the rover board's
  firmware motion model); the world integrates it.

:meth:`World.step` advances every body to a time: it asks each driver for
its velocity, integrates the pose over the step and refuses a move that makes
the footprint meet the scene or another body (the body stops; what drives
it does not know: a rover's wheels keep turning). Each step is kept in a
bounded history, so a sensor can ask where a body was at any recent time
(:meth:`World.pose_at`, interpolated; a time past the last step is
extrapolated with the body's velocity, a few milliseconds at most).

Sensors observe the world at their own sample times: :meth:`World.cast`
casts rays against the scene and every body's footprint (except the
caster's own body), each ray from its own origin when the caster moves.

Time is the bench clock: ``clock`` (the wall clock's ``now``, ``time.monotonic``,
unless the bench gives another); the scene's movers run on time since
``World.t0``. A world steps in a thread of its own, or, on a bench in virtual
time, as timers of the bench's loop (``timer``), so its bodies move in the
bench's virtual time, in step with every other device.
"""

from __future__ import annotations

import collections
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.fakes.scene import Scene, hit_circles
from hilbench.lazy_module import LazyModule
from hilbench.transports.clock import WALL

if TYPE_CHECKING:
    import numpy as np
else:  # (numpy comes with the first array: a bench without walls or bodies starts without it)
    np = LazyModule("numpy", globals(), "np")

#: Default world step (s): 200 Hz, so every body's pose is known at least every 5 ms.
STEP = 0.005
#: Seconds of step history kept per world (what sensors and recorders may ask about).
HISTORY_S = 10.0
#: Scans remembered for recorders polling the world (first and last ray times).
SCAN_HISTORY = 4096
#: Rays cast at once when each has its own origin (bounds the rays x edges arrays).
RAY_CHUNK = 256

Driver = Callable[[float], tuple[Any, float, float, float, float, float, float]]


@dataclass(frozen=True)
class Shape:
    """A footprint: ``kind`` "box" (``size`` = w along the body's x, h along its y) or "circle" (``radius``)."""

    kind: str = "circle"
    size: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0

    def describe(self) -> dict[str, Any]:
        if self.kind == "box":
            return {"kind": "box", "size": list(self.size)}
        return {"kind": "circle", "radius": self.radius}

    @property
    def extent(self) -> float:
        """Radius of a circle around the footprint (for quick rejection)."""
        return self.radius if self.kind == "circle" else math.hypot(*self.size) / 2


@dataclass(frozen=True)
class Pose2:
    """A pose in the world: x, y (m), theta (rad, counter-clockwise from +x)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def compose(self, mount: Pose2) -> Pose2:
        """The pose of something mounted at ``mount`` (in this pose's frame) in the world."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2(self.x + c * mount.x - s * mount.y, self.y + s * mount.x + c * mount.y,
                     _wrap(self.theta + mount.theta))


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def twist_motion(vx: float, vy: float, w: float, dt: float) -> tuple[float, float, float]:
    """The motion (dx, dy, dtheta; frame at its start) of a constant body-frame twist over ``dt`` (exact)."""
    th = w * dt
    if abs(th) < 1e-9:
        return vx * dt, vy * dt, th
    s, c = math.sin(th), math.cos(th)
    return (vx * s - vy * (1 - c)) / w, (vx * (1 - c) + vy * s) / w, th


def compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Pose ``b`` (in ``a``'s frame) after pose ``a``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


def relative(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """Pose ``b`` seen from pose ``a`` (``compose(a, relative(a, b)) == b``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return c * dx + s * dy, -s * dx + c * dy, b[2] - a[2]


@dataclass
class Body:
    """A named rigid body: footprint, pose, velocity (world frame: vx, vy m/s, omega rad/s) and its driver."""

    name: str
    shape: Shape
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    omega: float = 0.0
    reflectivity: float = 0.8
    #: What moves it: ``driver(t)`` -> (epoch, x, y, theta, vx, vy, omega): the motion its wheels made up to
    #: ``t`` (in the frame they started in; a new epoch starts from zero) and its body-frame velocity now.
    #: None: the body moves at :attr:`command`.
    driver: Driver | None = None
    #: Share of the driver's motion the body loses (wheels slipping on the floor), 0..1.
    slip: float = 0.0
    #: Body-frame velocity of a body without driver (``World.set_velocity``).
    command: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Whether the last step's move was refused (the footprint would have met something).
    blocked: bool = False
    collisions: int = 0
    #: (t, x, y, theta, vx, vy, omega) per step, oldest first.
    history: collections.deque = field(default_factory=lambda: collections.deque(maxlen=int(HISTORY_S / STEP)))
    _motion: tuple[Any, float, float, float] | None = None  # the driver's last reading (epoch, x, y, theta)

    @property
    def pose(self) -> Pose2:
        return Pose2(self.x, self.y, self.theta)

    def describe(self) -> dict[str, Any]:
        # (+ 0.0: a body facing west has vx = -0.0 at rest, which reads as motion in JSON)
        return {"x": self.x, "y": self.y, "theta": self.theta, "vx": self.vx + 0.0, "vy": self.vy + 0.0,
                "omega": self.omega + 0.0,
                "shape": self.shape.describe(), "blocked": self.blocked, "collisions": self.collisions}

    # ------------------------------------------------------------------ geometry

    def segments(self, x: float | None = None, y: float | None = None, theta: float | None = None) -> np.ndarray:
        """Box edges at a pose (default: now) as (4, 4) x0 y0 x1 y1; empty for a circle."""
        if self.shape.kind != "box":
            return np.zeros((0, 4))
        x = self.x if x is None else x
        y = self.y if y is None else y
        theta = self.theta if theta is None else theta
        c, s = math.cos(theta), math.sin(theta)
        w, h = self.shape.size[0] / 2, self.shape.size[1] / 2
        pts = [(x + c * u - s * v, y + s * u + c * v) for u, v in ((-w, -h), (w, -h), (w, h), (-w, h))]
        return np.asarray([(*pts[k], *pts[(k + 1) % 4]) for k in range(4)])

    def pose_at(self, t: float) -> tuple[float, float, float]:
        """(x, y, theta) at time ``t`` from the step history (newest first: a sensor asks about recent times);
        past the last step extrapolated with the velocity. Call under the world's lock."""
        hist = self.history
        n = len(hist)
        for i in range(n - 1, -1, -1):
            h = hist[i]
            if h[0] <= t:
                if i == n - 1:
                    dt = t - h[0]
                    return h[1] + h[4] * dt, h[2] + h[5] * dt, h[3] + h[6] * dt
                nxt = hist[i + 1]
                f = (t - h[0]) / (nxt[0] - h[0]) if nxt[0] > h[0] else 0.0
                dth = math.atan2(math.sin(nxt[3] - h[3]), math.cos(nxt[3] - h[3]))
                return h[1] + f * (nxt[1] - h[1]), h[2] + f * (nxt[2] - h[2]), h[3] + f * dth
        h = hist[0]
        return h[1], h[2], h[3]


@dataclass(frozen=True)
class ScanRecord:
    """One scan as taken: the device, its body (or None), the true time of its first and last ray."""

    device: str
    body: str | None
    t_first: float
    t_last: float


class World:
    """The bench's world; see the module docstring. ``clock`` is the bench clock (seconds), ``wall`` maps its
    times to Unix time, and ``timer`` (``call_at(t, fn)`` of the bench's virtual loop), when given, runs the
    steps instead of a thread of the world's own."""

    def __init__(self, scene: Scene | None = None, bodies: list[Body] | tuple[Body, ...] = (), *,
                 t0: float | None = None, step: float = STEP, clock: Callable[[], float] = WALL.now,
                 wall: Callable[[float], float] = WALL.wall,
                 timer: Callable[[float, Callable[[], None]], None] | None = None) -> None:
        self._scene = scene  # (None: an empty one, made when first asked for; its arrays need numpy)
        self.bodies: dict[str, Body] = {}
        self.clock = clock
        self.wall = wall
        self.timer = timer
        self._timed = False  # stepping as timers (see start)
        self._run_id = 0  # which start() the queued timer belongs to (one left from before a restart ends)
        self.t0 = clock() if t0 is None else t0
        self.step_s = step
        self.t = self.t0  # time of the last step
        self.steps = 0
        self.lock = threading.RLock()
        self.scans: collections.deque[ScanRecord] = collections.deque(maxlen=SCAN_HISTORY)
        self.listeners: list[Any] = []  # objects with on_step(world, t) and on_scan(record)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        for b in bodies:
            self.add_body(b)

    @property
    def scene(self) -> Scene:
        """The static geometry and the movers (an empty scene if the world was given none)."""
        if self._scene is None:
            self._scene = Scene()
        return self._scene

    @scene.setter
    def scene(self, scene: Scene) -> None:
        self._scene = scene

    # ------------------------------------------------------------------ bodies

    def add_body(self, body: Body) -> Body:
        if body.name in self.bodies:
            raise ValueError(f"body {body.name!r} exists already")
        with self.lock:
            self.bodies[body.name] = body
            body.history.append((self.t, body.x, body.y, body.theta, 0.0, 0.0, 0.0))
        return body

    def body(self, name: str) -> Body:
        """A body by name; KeyError naming the bodies."""
        try:
            return self.bodies[name]
        except KeyError:
            raise KeyError(f"no body named {name!r} (bodies: {', '.join(self.bodies) or 'none'})") from None

    def drive(self, name: str, driver: Driver | None, slip: float = 0.0) -> None:
        """Let ``driver`` (see :attr:`Body.driver`) move body ``name``, losing ``slip`` of its motion."""
        b = self.body(name)
        with self.lock:
            b.driver, b.slip, b._motion = driver, float(slip), None

    def set_velocity(self, name: str, vx: float = 0.0, vy: float = 0.0, omega: float = 0.0) -> None:
        """The body-frame velocity of a body nothing drives (from the next step on)."""
        self.body(name).command = (float(vx), float(vy), float(omega))

    def place(self, name: str, x: float, y: float, theta: float = 0.0) -> None:
        """Put a body at a pose now (a test setting up a scene); its history restarts there, so no sensor
        sees it slide from where it was."""
        b = self.body(name)
        with self.lock:
            t = max(self.clock(), self.t)
            b.x, b.y, b.theta = float(x), float(y), _wrap(float(theta))
            b.blocked = False
            b.history.clear()
            b.history.append((t, b.x, b.y, b.theta, b.vx, b.vy, b.omega))

    # ------------------------------------------------------------------ stepping

    def step(self, t: float | None = None) -> None:
        """Advance every body to time ``t`` (default: the clock now)."""
        t = self.clock() if t is None else t
        # Drivers first, outside the world's lock (each takes its own device's lock).
        readings = {name: b.driver(t) for name, b in self.bodies.items() if b.driver is not None}
        with self.lock:
            dt = t - self.t
            if dt <= 0:
                return
            if self.bodies:  # (a world without bodies moves nothing: no arrays, no numpy)
                mover_segs, _, mover_circ, _ = self._movers(t)
            for name, b in self.bodies.items():
                m = readings.get(name)
                if m is None or b.driver is None:
                    delta, bv = twist_motion(*b.command, dt), b.command
                else:
                    epoch, mx, my, mth, bvx, bvy, bw = m
                    last = b._motion
                    # (a driver's motion counts from its start, where the body stood; a new epoch from zero)
                    base = (0.0, 0.0, 0.0) if last is None or last[0] != epoch else last[1:]
                    b._motion = (epoch, mx, my, mth)
                    keep = 1.0 - b.slip
                    dx, dy, dth = relative(base, (mx, my, mth))
                    delta, bv = (dx * keep, dy * keep, dth * keep), (bvx * keep, bvy * keep, bw * keep)
                self._move(b, delta, mover_segs, mover_circ)
                if b.blocked:
                    bv = (0.0, 0.0, 0.0)  # the truth stands; what drives it may not know
                c, s = math.cos(b.theta), math.sin(b.theta)
                b.vx, b.vy, b.omega = c * bv[0] - s * bv[1], s * bv[0] + c * bv[1], bv[2]
                b.history.append((t, b.x, b.y, b.theta, b.vx, b.vy, b.omega))
            self.t = t
            self.steps += 1
        for listener in list(self.listeners):
            listener.on_step(self, t)

    def _move(self, b: Body, delta: tuple[float, float, float], mover_segs: np.ndarray,
              mover_circ: np.ndarray) -> None:
        """Move ``b`` by ``delta`` (its own frame); where its footprint would meet something it does not meet
        now, only as far as it fits (it stops there: blocked)."""
        if not any(delta):  # a step without wheel motion (a lagging board, a stop) ends no contact:
            return          # the body is still where it touched, and pushing on is the same collision
        here = (b.x, b.y, b.theta)
        nx, ny, nth = compose(here, delta)
        if self.collides(b, nx, ny, nth, mover_segs, mover_circ) and \
                not self.collides(b, *here, mover_segs, mover_circ):
            # It stops where it touches: the largest share of the move that fits (bisected to 1/1024).
            lo, hi = 0.0, 1.0
            for _ in range(10):
                mid = (lo + hi) / 2
                if self.collides(b, *compose(here, tuple(d * mid for d in delta)), mover_segs, mover_circ):
                    hi = mid
                else:
                    lo = mid
            nx, ny, nth = compose(here, tuple(d * lo for d in delta))
            if not b.blocked:
                b.collisions += 1
            b.blocked = True
        else:
            b.blocked = False
        b.x, b.y, b.theta = nx, ny, _wrap(nth)

    def _movers(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The movers' edges and circles (and reflectivities) at time ``t``."""
        sc = self.scene
        if not sc.movers:
            return np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)), np.zeros(0)
        segs, refl, circ, crefl = sc.geometry(t - self.t0)
        return segs[len(sc.segments):], refl[len(sc.segments):], circ[len(sc.circles):], crefl[len(sc.circles):]

    def collides(self, b: Body, x: float, y: float, theta: float, mover_segs: np.ndarray | None = None,
                 mover_circ: np.ndarray | None = None) -> bool:
        """Whether body ``b``'s footprint at a pose meets the scene, a mover or another body."""
        if mover_segs is None or mover_circ is None:
            mover_segs, _, mover_circ, _ = self._movers(self.t)
        segs = [self.scene.segments, mover_segs]
        circ = [self.scene.circles, mover_circ]
        reach = b.shape.extent
        for other in self.bodies.values():
            if other is b or math.hypot(other.x - x, other.y - y) > reach + other.shape.extent:
                continue
            if other.shape.kind == "box":
                segs.append(other.segments())
            else:
                circ.append(np.asarray([[other.x, other.y, other.shape.radius]]))
        return footprint_hits(b.shape, x, y, theta, np.vstack(segs), np.vstack(circ))

    def start(self) -> None:
        """Step every ``step_s`` seconds of the clock: in a thread of its own, or as ``timer``'s timers (a
        virtual bench's loop: each step exactly at its time)."""
        if self._thread is not None or self._timed:
            return
        self._stop.clear()
        self.t = max(self.t, self.clock())
        for b in self.bodies.values():
            b.history.append((self.t, b.x, b.y, b.theta, b.vx, b.vy, b.omega))
        if self.timer is not None:
            self._timed = True
            self._run_id += 1
            run, start = self._run_id, self.t
            self.timer(start + self.step_s, lambda: self._tick(run, start, 1))
            return
        self._thread = threading.Thread(target=self._run, name="hilbench-world", daemon=True)
        self._thread.start()

    def _tick(self, run: int, start: float, k: int) -> None:
        """Step ``k`` (at ``start + k * step_s``, counted from the start so steps never drift), then queue
        the next one."""
        if self._stop.is_set() or run != self._run_id:
            return
        t = start + k * self.step_s
        try:
            self.step(t)
        except Exception:  # noqa: BLE001 (a driver that fails must not stop the world)
            import logging

            logging.getLogger(__name__).exception("world step failed")
        if self.timer is not None:
            self.timer(start + (k + 1) * self.step_s, lambda: self._tick(run, start, k + 1))

    def stop(self) -> None:
        self._stop.set()
        self._timed = False
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        for listener in list(self.listeners):
            close = getattr(listener, "close", None)
            if close is not None:
                close()

    def _run(self) -> None:
        nxt = self.clock()
        while not self._stop.is_set():
            try:
                self.step()
            except Exception:  # noqa: BLE001 (a driver that fails must not stop the world)
                import logging

                logging.getLogger(__name__).exception("world step failed")
            nxt += self.step_s
            now = self.clock()
            if nxt < now - 10 * self.step_s:
                nxt = now  # far behind (a stalled machine): do not race to catch up
            self._stop.wait(max(0.0, nxt - now))

    # ------------------------------------------------------------------ truth

    def pose_at(self, name: str, t: float) -> Pose2:
        """Where body ``name`` was (or will be, extrapolated from its velocity) at time ``t``."""
        x, y, th = self.poses_at(name, np.asarray([t], float))
        return Pose2(float(x[0]), float(y[0]), float(th[0]))

    def poses_at(self, name: str, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body ``name``'s poses at many times (arrays x, y, theta), interpolated between steps."""
        b = self.body(name)
        times = np.asarray(times, float)
        with self.lock:
            hist = b.history
            first = times.min()
            k = len(hist) - 1
            while k > 0 and hist[k][0] > first:  # the steps the times need (recent ones: few)
                k -= 1
            h = np.asarray([hist[i] for i in range(k, len(hist))], float)
        ht = h[:, 0]
        if len(h) == 1 or np.all(times >= ht[-1]):
            last = h[-1]
            dt = np.maximum(times - last[0], 0.0)
            return last[1] + last[4] * dt, last[2] + last[5] * dt, last[3] + last[6] * dt
        # Headings unwrapped step to step (each step turns less than half a turn).
        dth = np.diff(h[:, 3])
        dth = (dth + math.pi) % (2 * math.pi) - math.pi
        th_unwrapped = h[0, 3] + np.concatenate([[0.0], np.cumsum(dth)])
        x = np.interp(times, ht, h[:, 1])
        y = np.interp(times, ht, h[:, 2])
        th = np.interp(times, ht, th_unwrapped)
        late = times > ht[-1]
        if late.any():
            dt = times[late] - ht[-1]
            x[late] = h[-1, 1] + h[-1, 4] * dt
            y[late] = h[-1, 2] + h[-1, 5] * dt
            th[late] = th_unwrapped[-1] + h[-1, 6] * dt
        return x, y, th

    def note_scan(self, device: str, body: str | None, t_first: float, t_last: float) -> None:
        """A sensor took a scan whose rays ran from ``t_first`` to ``t_last`` (recorders hear of it)."""
        rec = ScanRecord(device, body, float(t_first), float(t_last))
        with self.lock:
            self.scans.append(rec)
        for listener in list(self.listeners):
            listener.on_scan(rec)

    def snapshot(self) -> dict[str, Any]:
        """The truth now, JSON-able: ``time``, ``unix_time``, ``bodies`` and the movers' positions."""
        with self.lock:
            now = self.clock()
            bodies = {}
            for name, b in self.bodies.items():
                d = b.describe()
                x, y, th = self.poses_at(name, np.asarray([now]))
                d.update(x=float(x[0]), y=float(y[0]), theta=_wrap(float(th[0])))
                bodies[name] = d
            moving = []
            for m in self.scene.movers:
                mx, my = m.position(now - self.t0)
                moving.append({"x": mx, "y": my, **({"size": list(m.size)} if m.size else {"radius": m.radius})})
        return {"time": now, "unix_time": self.wall(now), "steps": self.steps, "bodies": bodies, "moving": moving}

    def geometry(self) -> dict[str, Any]:
        """The static scene: segments [[x0, y0, x1, y1], ...] and circles [[x, y, r], ...]."""
        return {"segments": self.scene.segments.round(6).tolist(), "circles": self.scene.circles.round(6).tolist()}

    # ------------------------------------------------------------------ sensing

    def cast(self, ox: np.ndarray | float, oy: np.ndarray | float, angles: np.ndarray, t: float,
             max_range: float = math.inf, exclude: str | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ranges (m, inf: nothing), cos(incidence) and reflectivity of rays in world directions ``angles``
        from (``ox``, ``oy``) (one origin, or one per ray), against the scene (movers where they are at
        ``t``) and every body's footprint at ``t`` but ``exclude``'s."""
        angles = np.asarray(angles, float)
        per_ray = np.ndim(ox) > 0
        if per_ray:
            ox, oy = np.asarray(ox, float), np.asarray(oy, float)
            if np.ptp(ox) == 0 and np.ptp(oy) == 0:  # a caster standing still: the scene's cached path
                ox, oy, per_ray = float(ox[0]), float(oy[0]), False
        if per_ray:
            segs, srefl, circ, crefl = self.scene.geometry(t - self.t0)
            rng, cos_inc, refl = cast_rays(ox, oy, angles, segs, srefl, circ, crefl)
        else:
            rng, cos_inc, refl = self.scene.cast(float(ox), float(oy), angles, t=t - self.t0)
        if self.bodies:
            rng, cos_inc, refl = self._cast_bodies(ox, oy, angles, t, exclude, rng.copy(), cos_inc.copy(),
                                                   refl.copy())
        if max_range < math.inf:
            rng = np.where(rng <= max_range, rng, np.inf)
        return rng, cos_inc, refl

    def _cast_bodies(self, ox, oy, angles: np.ndarray, t: float, exclude: str | None, rng: np.ndarray,
                     cos_inc: np.ndarray, refl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Nearer hits on other bodies' footprints merged into (rng, cos_inc, refl). Only the rays inside the
        angle some body subtends from the rays' origins (its extent's circle seen from their mean, widened by
        how far they spread) are cast, in one pass against every body."""
        with self.lock:
            poses = {name: b.pose_at(t) for name, b in self.bodies.items() if name != exclude}
        if not poses:
            return rng, cos_inc, refl
        per_ray = np.ndim(ox) > 0
        if per_ray:
            mx, my = float(np.mean(ox)), float(np.mean(oy))
            spread = float(np.max(np.hypot(ox - mx, oy - my)))
        else:
            mx, my, spread = float(ox), float(oy), 0.0
        segs, srefl, circ, crefl = [], [], [], []
        wanted = np.zeros(len(angles), bool)
        for name, (x, y, th) in poses.items():
            b = self.bodies[name]
            ext = b.shape.extent
            d = math.hypot(x - mx, y - my)
            if d <= ext + spread + 1e-9:
                wanted[:] = True
            else:
                half = math.asin(min(1.0, ext / (d - spread))) + math.asin(min(1.0, spread / d)) + 1e-9
                diff = np.mod(angles - math.atan2(y - my, x - mx) + math.pi, 2 * math.pi) - math.pi
                near = np.abs(diff) <= half
                if not near.any():
                    continue
                wanted |= near
            if b.shape.kind == "box":
                segs.append(b.segments(x, y, th))
                srefl.extend([b.reflectivity] * 4)
            else:
                circ.append((x, y, b.shape.radius))
                crefl.append(b.reflectivity)
        sel = np.nonzero(wanted)[0]
        if not len(sel):
            return rng, cos_inc, refl
        r2, c2, f2 = cast_rays(ox[sel] if per_ray else ox, oy[sel] if per_ray else oy, angles[sel],
                               np.vstack(segs) if segs else np.zeros((0, 4)), np.asarray(srefl, float),
                               np.asarray(circ, float).reshape(-1, 3), np.asarray(crefl, float))
        closer = r2 < rng[sel]
        hit = sel[closer]
        rng[hit], cos_inc[hit], refl[hit] = r2[closer], c2[closer], f2[closer]
        return rng, cos_inc, refl

    def body_geometry(self, t: float, exclude: str | None = None):
        """Every body's footprint at ``t`` but ``exclude``'s: segments, their reflectivity, circles, theirs
        (what :meth:`cast` tests rays against, body by body)."""
        if not self.bodies:
            return np.zeros((0, 4)), np.zeros(0), np.zeros((0, 3)), np.zeros(0)
        segs, srefl, circ, crefl = [], [], [], []
        with self.lock:
            poses = {name: b.pose_at(t) for name, b in self.bodies.items() if name != exclude}
        for name, (x, y, th) in poses.items():
            b = self.bodies[name]
            if b.shape.kind == "box":
                s = b.segments(x, y, th)
                segs.append(s)
                srefl.extend([b.reflectivity] * len(s))
            else:
                circ.append((x, y, b.shape.radius))
                crefl.append(b.reflectivity)
        return (np.vstack(segs) if segs else np.zeros((0, 4)), np.asarray(srefl, float),
                np.asarray(circ, float).reshape(-1, 3), np.asarray(crefl, float))


def cast_rays(ox, oy, angles: np.ndarray, segs: np.ndarray, srefl: np.ndarray, circ: np.ndarray,
              crefl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hits of rays (one origin, or one per ray) against segments and circles, testing every pair
    (in chunks of :data:`RAY_CHUNK` rays): ranges (inf: none), cos(incidence), reflectivity."""
    n = len(angles)
    rng, cos_inc, refl = np.full(n, np.inf), np.zeros(n), np.zeros(n)
    if n == 0 or (not len(segs) and not len(circ)):
        return rng, cos_inc, refl
    per_ray = np.ndim(ox) > 0
    for a in range(0, n, RAY_CHUNK):
        b = min(n, a + RAY_CHUNK)
        sl = slice(a, b)
        cx = ox[sl] if per_ray else np.full(b - a, float(ox))
        cy = oy[sl] if per_ray else np.full(b - a, float(oy))
        r, c, f = _cast_chunk(cx, cy, angles[sl], segs, srefl, circ, crefl)
        rng[sl], cos_inc[sl], refl[sl] = r, c, f
    return rng, cos_inc, refl


def _cast_chunk(ox: np.ndarray, oy: np.ndarray, angles: np.ndarray, segs, srefl, circ, crefl):
    n = len(angles)
    dx, dy = np.cos(angles), np.sin(angles)
    best = np.full(n, np.inf)
    cos_inc = np.zeros(n)
    refl = np.zeros(n)
    if len(segs):
        ax, ay = segs[None, :, 0] - ox[:, None], segs[None, :, 1] - oy[:, None]
        ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
        den = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / den
            tt = (ax * ey[None, :] - ay * ex[None, :]) * inv
            ss = (ax * dy[:, None] - ay * dx[:, None]) * inv
        ok = (np.abs(den) > 1e-12) & (tt > 1e-9) & (ss >= 0.0) & (ss <= 1.0)
        tt = np.where(ok, tt, np.inf)
        k = np.argmin(tt, axis=1)
        best = tt[np.arange(n), k]
        hit = best < np.inf
        elen = np.hypot(ex, ey)
        with np.errstate(divide="ignore", invalid="ignore"):
            nx, ny = -ey / elen, ex / elen
        cos_inc = np.where(hit, np.abs(dx * nx[k] + dy * ny[k]), 0.0)
        refl = np.where(hit, srefl[k], 0.0)
    if len(circ):
        best, cos_inc, refl = hit_circles(ox, oy, dx, dy, circ, crefl, best, cos_inc, refl)
    np.clip(cos_inc, 0.0, 1.0, out=cos_inc)
    cos_inc[np.isnan(cos_inc)] = 0.0
    return best, cos_inc, refl


# ---------------------------------------------------------------------- collisions


def footprint_hits(shape: Shape, x: float, y: float, theta: float, segs: np.ndarray, circ: np.ndarray) -> bool:
    """Whether a footprint at a pose meets any segment (N, 4) or circle (M, 3)."""
    ext = shape.extent
    if len(segs):
        # Near segments only: distance from the centre to the segment below the footprint's extent.
        d = _point_segment_distance(x, y, segs)
        near = segs[d <= ext + 1e-9]
        if len(near):
            if shape.kind == "circle":
                return True  # (the extent is the radius)
            if _segments_hit_box(near, x, y, theta, shape.size):
                return True
    if len(circ):
        cx, cy, r = circ[:, 0], circ[:, 1], circ[:, 2]
        if shape.kind == "circle":
            if np.any(np.hypot(cx - x, cy - y) < r + shape.radius):
                return True
        else:
            c, s = math.cos(theta), math.sin(theta)
            u = c * (cx - x) + s * (cy - y)
            v = -s * (cx - x) + c * (cy - y)
            hw, hh = shape.size[0] / 2, shape.size[1] / 2
            du = np.abs(u) - hw
            dv = np.abs(v) - hh
            dist = np.hypot(np.maximum(du, 0), np.maximum(dv, 0))
            if np.any(dist < r):
                return True
    return False


def _point_segment_distance(px: float, py: float, segs: np.ndarray) -> np.ndarray:
    ax, ay = segs[:, 0], segs[:, 1]
    ex, ey = segs[:, 2] - ax, segs[:, 3] - ay
    ll = ex * ex + ey * ey
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(ll > 0, ((px - ax) * ex + (py - ay) * ey) / ll, 0.0)
    u = np.clip(u, 0.0, 1.0)
    return np.hypot(ax + u * ex - px, ay + u * ey - py)


def _segments_hit_box(segs: np.ndarray, x: float, y: float, theta: float, size: tuple[float, float]) -> bool:
    """Liang-Barsky: does any segment pass through the box (centre x, y, heading theta, size w x h)?"""
    c, s = math.cos(theta), math.sin(theta)
    x0, y0 = segs[:, 0] - x, segs[:, 1] - y
    x1, y1 = segs[:, 2] - x, segs[:, 3] - y
    u0, v0 = c * x0 + s * y0, -s * x0 + c * y0
    u1, v1 = c * x1 + s * y1, -s * x1 + c * y1
    hw, hh = size[0] / 2, size[1] / 2
    du, dv = u1 - u0, v1 - v0
    lo = np.zeros(len(segs))
    hi = np.ones(len(segs))
    ok = np.ones(len(segs), bool)
    for p, q in ((-du, u0 + hw), (du, hw - u0), (-dv, v0 + hh), (dv, hh - v0)):
        parallel = np.abs(p) < 1e-15
        ok &= ~(parallel & (q < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(parallel, 0.0, q / np.where(parallel, 1.0, p))
        lo = np.where(~parallel & (p < 0), np.maximum(lo, r), lo)
        hi = np.where(~parallel & (p > 0), np.minimum(hi, r), hi)
    return bool(np.any(ok & (lo <= hi)))


# ---------------------------------------------------------------------- recording


class RecordLines:
    """The writer of a world record (one JSON object per line) for
    :class:`~hilbench.transports.recording_file.Recording`, which flushes and renames it."""

    def __init__(self, path: str) -> None:
        import json

        self._dumps = json.dumps
        self.fh = open(path, "w", buffering=1 << 16, encoding="utf-8")  # noqa: SIM115 (closed by close())
        self.bytes = 0
        self.records = 0

    def chunk(self, obj: dict[str, Any]) -> None:
        line = self._dumps(obj, separators=(",", ":")) + "\n"
        self.fh.write(line)
        self.bytes += len(line)
        self.records += 1

    def flush(self) -> None:
        self.fh.flush()

    def close(self) -> None:
        self.fh.close()


class Recorder:
    """Writes the truth as JSON lines: a header, every body's pose at every world step (``"pose"``) and every
    scan's first and last ray time (``"scan"``). Attach with :meth:`World.listeners` (``world.record(path)``).

    A recording as ``hilbench record`` makes one (:class:`~hilbench.transports.recording_file.Recording`): it
    streams into ``path``'s ``.partial`` file, flushed at least every half second (a kill loses at most that),
    and :meth:`close` renames it to ``path`` in one step; an old file there stays whole until then."""

    def __init__(self, path: str, world: World, header: dict[str, Any] | None = None) -> None:
        from hilbench.transports.recording_file import Recording

        self.path = str(path)
        # (force: the caller's path is replaced when the record ends)
        self._recording: Recording | None = Recording(self.path, RecordLines, force=True)
        self.lock = threading.Lock()
        self.poses = 0
        self.scan_count = 0
        now = world.clock()
        self.write({"type": "header", "time": now, "unix_time": world.wall(now), "step_s": world.step_s,
                    "bodies": {n: b.shape.describe() for n, b in world.bodies.items()}, **(header or {})})

    def write(self, obj: dict[str, Any]) -> None:
        with self.lock:
            if self._recording is not None:
                self._recording.chunk(obj)

    def on_step(self, world: World, t: float) -> None:
        self.poses += 1
        self.write({"type": "pose", "t": t, "bodies": {n: [round(b.x, 6), round(b.y, 6), round(b.theta, 6)]
                                                       for n, b in world.bodies.items()}})

    def on_scan(self, rec: ScanRecord) -> None:
        self.scan_count += 1
        self.write({"type": "scan", "device": rec.device, "body": rec.body, "t_first": rec.t_first,
                    "t_last": rec.t_last})

    def close(self) -> None:
        """End the record: flushed, and renamed to ``path`` in one step."""
        with self.lock:
            if self._recording is not None:
                self._recording.close()
                self._recording = None


def read_record(path: str) -> dict[str, Any]:
    """A record file as ``{"header": {...}, "poses": [(t, {name: (x, y, theta)})], "scans": [ScanRecord]}``."""
    import json

    out: dict[str, Any] = {"header": {}, "poses": [], "scans": []}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                obj = json.loads(line)
            except ValueError:
                continue  # a line cut short by a killed recorder
            kind = obj.get("type")
            if kind == "header":
                out["header"] = obj
            elif kind == "pose":
                out["poses"].append((obj["t"], {n: tuple(v) for n, v in obj["bodies"].items()}))
            elif kind == "scan":
                out["scans"].append(ScanRecord(obj["device"], obj.get("body"), obj["t_first"], obj["t_last"]))
    return out


__all__ = ["Body", "Driver", "Pose2", "RecordLines", "Recorder", "STEP", "ScanRecord", "Shape", "World", "cast_rays", "compose",
           "footprint_hits", "read_record", "relative", "twist_motion"]
