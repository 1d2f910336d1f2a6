"""A bench's world: the profile's ``[world]`` table, checked, built and handed out as ``bench.world``.

Schema (every key optional)::

    [world]
    step_hz = 200                      # how often bodies move (and the truth is recorded), 20..2000
    walls = [ [[-3.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]] ]   # polylines, metres
    wall_reflectivity = 0.8
    boxes = [ { center = [1.0, 1.0], size = [0.4, 0.3], heading = 30.0, reflectivity = 0.5 } ]
    circles = [ { center = [-1.0, 0.5], radius = 0.1 } ]
    moving = [ { path = [[1.0, -1.0], [1.0, 1.0]], speed = 0.5, radius = 0.2 } ]    # or size = [w, h]

    [[world.bodies]]
    name = "rover"
    shape = "box"                      # "box" (size = [length along x, width]) or "circle" (radius)
    size = [0.46, 0.38]
    pose = { x = 0.0, y = 0.0, theta = 0.0 }   # metres, radians
    reflectivity = 0.6

The geometry keys are those of the scanners' older ``[scene]`` table, which
still loads (as the world's geometry; a profile gives it in one of the two).
A device sits on a body with ``body = "NAME"`` in its ``[[devices]]`` entry
(a core key, like ``endpoint``); a scanner's ``pose`` is then its mount pose
on the body. A device that drives its body (the rover boards) may have
``odometry = { slip = 0.0, encoder_noise = 0.0 }`` (:func:`check_odometry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.bench.checks import Checker
from hilbench.errors import UsageError

if TYPE_CHECKING:
    from hilbench.fakes.scene import Scene
    from hilbench.fakes.world import Body, Recorder, World

SCENE_KEYS = ("walls", "wall_reflectivity", "boxes", "circles", "moving")
WORLD_KEYS = (*SCENE_KEYS, "bodies", "step_hz")
BODY_KEYS = ("name", "shape", "size", "radius", "pose", "reflectivity")
ODOMETRY_KEYS = ("slip", "encoder_noise")
#: Largest scene accepted (edges), so a profile cannot make every beam cost seconds.
MAX_EDGES = 20_000
#: Most bodies a world takes (each steps every world step and is in every scanner's view).
MAX_BODIES = 64


@dataclass
class BodySpec:
    """A body of the profile's world."""

    name: str
    shape: str
    size: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    reflectivity: float = 0.8


@dataclass
class WorldSpec:
    """The checked ``[world]`` table: its scene (None: none given here) and bodies."""

    scene: Any = None
    bodies: list[BodySpec] = field(default_factory=list)
    step_hz: float = 200.0

    def body_names(self) -> list[str]:
        return [b.name for b in self.bodies]


def _point(c: Checker, value: Any, key: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2:
        c.fail(key, f"expected a point [x, y] in metres, got {value!r}")
    return c.number(value[0], f"{key}[0]", -1e4, 1e4), c.number(value[1], f"{key}[1]", -1e4, 1e4)


def _array(c: Checker, value: Any, key: str) -> list:
    if not isinstance(value, list):
        c.fail(key, "expected an array of tables")
    return value


def check_scene(c: Checker, raw: Any, name: str = "scene", extra: tuple[str, ...] = ()) -> Scene:
    """Scene geometry (``walls``, ``boxes``, ``circles``, ``moving``) of a table -> a
    :class:`~hilbench.fakes.scene.Scene` (one-line errors); ``extra``: other keys the table may have."""
    from hilbench.fakes.scene import Mover, Scene

    raw = c.table(raw, name)
    c.unknown(raw, name, (*SCENE_KEYS, *extra))
    walls = raw.get("walls", [])
    if not isinstance(walls, list):
        c.fail(f"{name}.walls", "expected an array of polylines ([[x, y], [x, y], ...])")
    lines = []
    for i, line in enumerate(walls):
        key = f"{name}.walls[{i}]"
        if not isinstance(line, list) or len(line) < 2:
            c.fail(key, "expected a polyline of at least two points [[x, y], [x, y], ...]")
        lines.append([_point(c, p, f"{key}[{j}]") for j, p in enumerate(line)])
    refl = c.number(raw.get("wall_reflectivity", 0.8), f"{name}.wall_reflectivity", 0.0, 1.0)
    boxes = []
    for i, box in enumerate(_array(c, raw.get("boxes", []), f"{name}.boxes")):
        key = f"{name}.boxes[{i}]"
        box = c.table(box, key)
        c.unknown(box, key, ("center", "size", "heading", "reflectivity"))
        if "center" not in box or "size" not in box:
            c.fail(key, "expected center = [x, y] and size = [w, h]")
        w, h = _point(c, box["size"], f"{key}.size")
        if w <= 0 or h <= 0:
            c.fail(f"{key}.size", f"expected positive sizes, got {box['size']!r}")
        boxes.append({"center": _point(c, box["center"], f"{key}.center"), "size": (w, h),
                      "heading": c.number(box.get("heading", 0.0), f"{key}.heading", -360, 360),
                      "reflectivity": c.number(box.get("reflectivity", 0.8), f"{key}.reflectivity", 0, 1)})
    circles = []
    for i, circ in enumerate(_array(c, raw.get("circles", []), f"{name}.circles")):
        key = f"{name}.circles[{i}]"
        circ = c.table(circ, key)
        c.unknown(circ, key, ("center", "radius", "reflectivity"))
        if "center" not in circ or "radius" not in circ:
            c.fail(key, "expected center = [x, y] and radius")
        circles.append({"center": _point(c, circ["center"], f"{key}.center"),
                        "radius": c.number(circ["radius"], f"{key}.radius", 1e-4, 1e3),
                        "reflectivity": c.number(circ.get("reflectivity", 0.8), f"{key}.reflectivity", 0, 1)})
    movers = []
    for i, mv in enumerate(_array(c, raw.get("moving", []), f"{name}.moving")):
        key = f"{name}.moving[{i}]"
        mv = c.table(mv, key)
        c.unknown(mv, key, ("path", "speed", "radius", "size", "reflectivity"))
        path = mv.get("path")
        if not isinstance(path, list) or not path:
            c.fail(f"{key}.path", "expected an array of points [[x, y], ...] (a closed loop)")
        pts = tuple(_point(c, p, f"{key}.path[{j}]") for j, p in enumerate(path))
        if ("radius" in mv) == ("size" in mv):
            c.fail(key, "expected exactly one of radius = R (a circle) or size = [w, h] (a box)")
        size = _point(c, mv["size"], f"{key}.size") if "size" in mv else None
        movers.append(Mover(pts, c.number(mv.get("speed", 0.5), f"{key}.speed", 0, 100),
                            radius=c.number(mv.get("radius", 0.0), f"{key}.radius", 0, 1e3), size=size,
                            reflectivity=c.number(mv.get("reflectivity", 0.8), f"{key}.reflectivity", 0, 1)))
    scene = Scene.build(walls=lines, boxes=boxes, circles=circles, movers=movers,
                        wall_reflectivity=[refl] * len(lines))
    if scene.edge_count > MAX_EDGES:
        c.fail(name, f"expected at most {MAX_EDGES} edges, got {scene.edge_count}")
    return scene


def check_world(c: Checker, raw: Any, name: str = "world") -> WorldSpec:
    """The ``[world]`` table -> a :class:`WorldSpec` (one-line errors naming the key)."""
    raw = c.table(raw, name)
    c.unknown(raw, name, WORLD_KEYS)
    geometry = {k: v for k, v in raw.items() if k in SCENE_KEYS}
    scene = check_scene(c, geometry, name) if geometry else None
    bodies: list[BodySpec] = []
    raw_bodies = _array(c, raw.get("bodies", []), f"{name}.bodies")
    if len(raw_bodies) > MAX_BODIES:
        c.fail(f"{name}.bodies", f"expected at most {MAX_BODIES} bodies, got {len(raw_bodies)}")
    for i, rb in enumerate(raw_bodies):
        key = f"{name}.bodies[{i}]"
        rb = c.table(rb, key)
        c.unknown(rb, key, BODY_KEYS)
        bname = c.string(rb.get("name"), f"{key}.name")
        if bname in (b.name for b in bodies):
            c.fail(f"{key}.name", f"body name {bname!r} is used twice")
        shape = c.choice(rb.get("shape", "box" if "size" in rb else "circle"), f"{key}.shape", ("box", "circle"))
        spec = BodySpec(bname, shape)
        if shape == "box":
            if "size" not in rb or "radius" in rb:
                c.fail(key, 'expected size = [length, width] (metres) for shape = "box"')
            w, h = _point(c, rb["size"], f"{key}.size")
            if not (0 < w <= 100 and 0 < h <= 100):
                c.fail(f"{key}.size", f"expected sizes 0..100 m, got {rb['size']!r}")
            spec.size = (w, h)
        else:
            if "radius" not in rb or "size" in rb:
                c.fail(key, 'expected radius = R (metres) for shape = "circle"')
            spec.radius = c.number(rb["radius"], f"{key}.radius", 1e-3, 100.0)
        spec.x, spec.y, spec.theta = check_pose(c, rb.get("pose", {}), f"{key}.pose")
        spec.reflectivity = c.number(rb.get("reflectivity", 0.8), f"{key}.reflectivity", 0.0, 1.0)
        bodies.append(spec)
    step_hz = c.number(raw.get("step_hz", 200.0), f"{name}.step_hz", 20.0, 2000.0)
    return WorldSpec(scene, bodies, step_hz)


def check_pose(c: Checker, raw: Any, key: str) -> tuple[float, float, float]:
    """``{x, y, theta}`` (metres, radians; or ``heading`` in degrees) -> (x, y, theta)."""
    raw = c.table(raw, key)
    c.unknown(raw, key, ("x", "y", "theta", "heading"))
    if "theta" in raw and "heading" in raw:
        c.fail(key, "expected theta (radians) or heading (degrees), not both")
    theta = c.number(raw.get("theta", 0.0), f"{key}.theta", -4 * math.pi, 4 * math.pi)
    if "heading" in raw:
        theta = math.radians(c.number(raw["heading"], f"{key}.heading", -360.0, 360.0))
    return (c.number(raw.get("x", 0.0), f"{key}.x", -1e4, 1e4), c.number(raw.get("y", 0.0), f"{key}.y", -1e4, 1e4),
            theta)


def check_odometry(c: Checker, raw: Any, key: str) -> dict[str, float]:
    """A driving device's ``odometry`` table: ``slip`` (share of the wheels' motion the body loses, 0..0.9)
    and ``encoder_noise`` (standard deviation in encoder counts per wheel per control cycle, 0..1000)."""
    raw = c.table(raw, key)
    c.unknown(raw, key, ODOMETRY_KEYS)
    return {"slip": c.number(raw.get("slip", 0.0), f"{key}.slip", 0.0, 0.9),
            "encoder_noise": c.number(raw.get("encoder_noise", 0.0), f"{key}.encoder_noise", 0.0, 1000.0)}


def check_body(c: Checker, value: Any, key: str, world: WorldSpec | None) -> str:
    """A device's ``body`` key: the name of a body of the profile's world."""
    names = world.body_names() if world is not None else []
    if not isinstance(value, str) or value not in names:
        known = ", ".join(names) if names else 'none: add [[world.bodies]] with name = "..."'
        c.fail(key, f"expected the name of a world body ({known}), got {value!r}")
    return value


def build_world(profile, t: float, clock: Any = None) -> World:
    """The world of a checked profile at bench time ``t``: its geometry (``[world]``, or the older
    ``[scene]``) and bodies, on the bench's ``clock`` (a :class:`~hilbench.transports.clock.WallClock`,
    the wall clock if None; a virtual clock's loop steps the world)."""
    from hilbench.fakes.world import Body, Shape, World

    spec: WorldSpec = profile.world or WorldSpec()
    scene = spec.scene or profile.tables.get("scene")  # (None: the world's empty one, made when asked for)
    bodies = [Body(b.name, Shape(b.shape, b.size, b.radius), b.x, b.y, b.theta, reflectivity=b.reflectivity)
              for b in spec.bodies]
    if clock is None:
        return World(scene, bodies, t0=t, step=1.0 / spec.step_hz)
    loop = getattr(clock, "loop", None) if clock.virtual else None
    return World(scene, bodies, t0=t, step=1.0 / spec.step_hz, clock=clock.now, wall=clock.wall,
                 timer=loop.call_at if loop is not None else None)


class BodyView:
    """A body of a running bench, as tests see it: :attr:`pose` now (x, y, theta), :attr:`velocity`."""

    def __init__(self, world: World, body: Body) -> None:
        self._world = world
        self.body = body
        self.name = body.name

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x m, y m, theta rad) at the bench clock now (interpolated from the world's steps)."""
        p = self._world.pose_at(self.name, self._world.clock())
        return p.x, p.y, p.theta

    @property
    def velocity(self) -> tuple[float, float, float]:
        """(vx, vy m/s, omega rad/s), world frame, as of the last world step."""
        return self.body.vx, self.body.vy, self.body.omega

    @property
    def blocked(self) -> bool:
        """Whether the body's last move was refused (it met a wall, an obstacle or another body)."""
        return self.body.blocked

    def __repr__(self) -> str:
        x, y, th = self.pose
        return f"Body({self.name!r}, x={x:.3f}, y={y:.3f}, theta={th:.3f})"


class BenchWorld:
    """``bench.world``: the bench's world (the truth): bodies, placing them, snapshots and recorders."""

    def __init__(self, bench, world: World) -> None:
        self.bench = bench
        self.world = world
        self._recorders: list[Recorder] = []

    def body(self, name: str) -> BodyView:
        """A body by name (KeyError naming the bodies)."""
        return BodyView(self.world, self.world.body(name))

    @property
    def bodies(self) -> list[str]:
        return list(self.world.bodies)

    def place(self, name: str, x: float, y: float, theta: float = 0.0) -> None:
        """Put body ``name`` at (x, y, theta) now (m, m, rad)."""
        self.world.place(name, x, y, theta)

    def set_velocity(self, name: str, vx: float = 0.0, vy: float = 0.0, omega: float = 0.0) -> None:
        """Move a body nothing drives at a body-frame velocity (m/s, rad/s) from the next step on."""
        self.world.set_velocity(name, vx, vy, omega)

    def set_slip(self, name: str, slip: float) -> None:
        """Let driven body ``name`` lose ``slip`` (0..0.9) of its wheels' motion from the next step on (the
        profile's ``odometry.slip``, changed while the bench runs): its odometry drifts from the truth while
        slip is on, and stops drifting when it is 0 again."""
        if not 0.0 <= slip <= 0.9:
            raise ValueError(f"slip: expected a number 0.0..0.9, got {slip!r}")
        b = self.world.body(name)
        with self.world.lock:
            b.slip = float(slip)

    def record(self, path: str) -> Recorder:
        """Record every body's pose at every world step and every scan's first and last ray time into ``path``
        (JSON lines: :func:`hilbench.fakes.world.read_record` reads it back) until ``close()`` or the bench
        stops."""
        from hilbench.fakes.world import Recorder

        rec = Recorder(path, self.world, {"bench": self.bench.profile.name, "devices": self.devices()})
        self._recorders.append(rec)
        self.world.listeners.append(rec)
        return rec

    def stop_recording(self, recorder: Recorder) -> None:
        """End a record: the file is complete at its path from here on."""
        if recorder in self.world.listeners:
            self.world.listeners.remove(recorder)
        if recorder in self._recorders:
            self._recorders.remove(recorder)
        recorder.close()

    def close(self) -> None:
        """The bench stops: end every record still running."""
        for recorder in list(self._recorders):
            self.stop_recording(recorder)

    def devices(self) -> dict[str, dict[str, Any]]:
        """Each device's body (None: fixed in the world), its mount pose and where it is now."""
        out = {}
        now = self.world.clock()
        for spec in self.bench.profile.devices:
            dev = self.bench.devices.get(spec.name)
            mount = _mount(spec, dev)
            entry: dict[str, Any] = {"body": spec.body, "mount": mount}
            if spec.body is not None:
                from hilbench.fakes.world import Pose2

                p = self.world.pose_at(spec.body, now).compose(Pose2(mount["x"], mount["y"], mount["theta"]))
                entry["pose"] = {"x": p.x, "y": p.y, "theta": p.theta}
            else:
                entry["pose"] = dict(mount)
            out[spec.name] = entry
        return out

    def snapshot(self, *, geometry: bool = False, scans: bool = False) -> dict[str, Any]:
        """The truth now: ``time`` (bench clock, s), ``unix_time``, ``bodies`` ({NAME: {x, y, theta, vx, vy,
        omega, shape, ...}}), ``moving``, ``devices`` ({NAME: {body, mount, pose}}); ``geometry``: the static
        scene too, ``scans``: the points each scanner's recent beams hit."""
        out = self.world.snapshot()
        out["devices"] = self.devices()
        if geometry:
            out["geometry"] = self.world.geometry()
        if scans:
            out["scans"] = {name: dev.points() for name, dev in self.bench.devices.items() if hasattr(dev, "points")}
        return out

    def since(self, t: float) -> dict[str, Any]:
        """What happened after bench time ``t``: every step's poses and every scan (for remote recorders)."""
        w = self.world
        with w.lock:
            rows: dict[float, dict[str, list[float]]] = {}
            for name, b in w.bodies.items():
                for h in b.history:
                    if h[0] > t:
                        rows.setdefault(h[0], {})[name] = [round(h[1], 6), round(h[2], 6), round(h[3], 6)]
            poses = [{"t": ts, "bodies": rows[ts]} for ts in sorted(rows)]
            scans = [{"device": s.device, "body": s.body, "t_first": s.t_first, "t_last": s.t_last}
                     for s in w.scans if s.t_last > t]
        return {"time": w.clock(), "poses": poses, "scans": scans}


def _mount(spec, device) -> dict[str, float]:
    pose = getattr(device, "pose", None)
    if pose is not None and hasattr(pose, "heading"):  # a scanner's own pose
        return {"x": pose.x, "y": pose.y, "theta": math.radians(pose.heading)}
    if spec.mount is not None:  # any other device's core ``pose``
        return dict(zip(("x", "y", "theta"), spec.mount, strict=True))
    return {"x": 0.0, "y": 0.0, "theta": 0.0}


def control(bench, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
    """The bench's ``world`` commands: ``world`` (the snapshot; ``geometry``, ``scans``: true adds them;
    ``since``: T adds the steps and scans after bench time T), ``world_place`` (body, x, y, theta),
    ``world_slip`` (body, slip: :meth:`BenchWorld.set_slip`)."""
    world = bench.world
    if cmd == "world":
        since = req.get("since")
        if since is not None and (isinstance(since, bool) or not isinstance(since, int | float)):
            raise UsageError(f"since: expected a bench time in seconds, got {since!r:.40}")
        out = world.snapshot(geometry=req.get("geometry") is True, scans=req.get("scans") is True)
        if since is not None:
            out["history"] = world.since(float(since))
        return out
    if cmd == "world_place":
        name = req.get("body")
        if name not in world.world.bodies:
            raise UsageError(f"body: expected one of {', '.join(world.bodies) or 'none'}, got {name!r:.40}")
        vals = []
        for k in ("x", "y", "theta"):
            v = req.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or abs(v) > 1e4:
                raise UsageError(f"{k}: expected a number (metres, radians), got {v!r:.40}")
            vals.append(float(v))
        world.place(name, *vals)
        return {"body": name, "pose": dict(zip(("x", "y", "theta"), vals, strict=True))}
    if cmd == "world_slip":
        name = req.get("body")
        if name not in world.world.bodies:
            raise UsageError(f"body: expected one of {', '.join(world.bodies) or 'none'}, got {name!r:.40}")
        v = req.get("slip")
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0.0 <= v <= 0.9:
            raise UsageError(f"slip: expected a number 0.0..0.9, got {v!r:.40}")
        world.set_slip(name, float(v))
        return {"body": name, "slip": float(v)}
    raise UsageError(f"unknown command {cmd!r}")


def refuse_second_driver(world: World, body: str, device: str) -> None:
    """A body is driven by one device: a second one is a profile mistake (one line)."""
    if world.body(body).driver is not None:
        raise UsageError(f"body {body!r} is driven by two devices (the second: {device!r}); give each its own body")


__all__ = ["BenchWorld", "BodySpec", "BodyView", "MAX_EDGES", "SCENE_KEYS", "WORLD_KEYS", "WorldSpec",
           "build_world", "check_body", "check_odometry", "check_pose", "check_scene", "check_world", "control",
           "refuse_second_driver"]
