"""The static and scripted geometry of a bench's world: walls, boxes, circles and moving objects, and ray
casting (the world adds its bodies; every laser scanner casts its beams here).

Geometry is in metres in a world frame (x right, y up, angles counter-clockwise
from +x). Walls are polylines, boxes and circles are static obstacles, movers
follow a closed path at a constant speed (a walking person, a robot), so their
position is a pure function of time and every scanner sharing the scene sees
the same thing. Every element carries a reflectivity (0..1) for the scanners'
quality/intensity model.

:meth:`Scene.cast` is vectorised with numpy: all beams against all edges at
once (beams x edges), then circles in closed form (spec §5.2). 1081 beams
against a few hundred edges is well below a millisecond.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from hilbench.lazy_module import LazyModule

if TYPE_CHECKING:
    import numpy as np
else:  # (numpy comes with the first array: a bench without walls or bodies starts without it)
    np = LazyModule("numpy", globals(), "np")


@dataclass(frozen=True)
class Mover:
    """A circle (``radius``) or box (``size`` w, h) moving along a closed ``path`` at ``speed`` m/s."""

    path: tuple[tuple[float, float], ...]
    speed: float
    radius: float = 0.0
    size: tuple[float, float] | None = None
    reflectivity: float = 0.8

    def position(self, t: float) -> tuple[float, float]:
        """Where it is ``t`` seconds after the scene's start (the path loops back to its first point)."""
        pts = np.asarray(self.path + (self.path[0],), dtype=float)
        seg = np.diff(pts, axis=0)
        lengths = np.hypot(seg[:, 0], seg[:, 1])
        total = float(lengths.sum())
        if total <= 0 or self.speed <= 0:
            return float(pts[0, 0]), float(pts[0, 1])
        s = (self.speed * t) % total
        k = int(np.searchsorted(np.cumsum(lengths), s, side="right"))
        k = min(k, len(lengths) - 1)
        before = float(lengths[:k].sum())
        frac = (s - before) / lengths[k] if lengths[k] > 0 else 0.0
        p = pts[k] + seg[k] * frac
        return float(p[0]), float(p[1])


def _box_segments(cx: float, cy: float, w: float, h: float, heading_deg: float) -> list[tuple[float, ...]]:
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    corners = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    pts = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in corners]
    return [(*pts[k], *pts[(k + 1) % 4]) for k in range(4)]


@dataclass
class Scene:
    """Static segments and circles plus movers; see the module docstring."""

    segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    segment_reflectivity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    circles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    circle_reflectivity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    movers: tuple[Mover, ...] = ()
    #: Visibility maps of the static segments by origin (a scanner's pose rarely moves): see :meth:`cast`.
    _visibility: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def build(
        cls,
        walls: list[list[tuple[float, float]]] = (),
        boxes: list[dict] = (),
        circles: list[dict] = (),
        movers: list[Mover] = (),
        wall_reflectivity: list[float] | None = None,
    ) -> Scene:
        """A scene from polylines (walls), box and circle dicts (``center``, ``size``/``radius``,
        ``heading`` degrees, ``reflectivity``) and movers."""
        segs, refl = [], []
        for i, line in enumerate(walls):
            r = wall_reflectivity[i] if wall_reflectivity else 0.8
            for a, b in zip(line[:-1], line[1:], strict=False):
                segs.append((a[0], a[1], b[0], b[1]))
                refl.append(r)
        for box in boxes:
            for s in _box_segments(box["center"][0], box["center"][1], box["size"][0], box["size"][1],
                                   box.get("heading", 0.0)):
                segs.append(s)
                refl.append(box.get("reflectivity", 0.8))
        circ = [(c["center"][0], c["center"][1], c["radius"]) for c in circles]
        crefl = [c.get("reflectivity", 0.8) for c in circles]
        return cls(np.asarray(segs, float).reshape(-1, 4), np.asarray(refl, float),
                   np.asarray(circ, float).reshape(-1, 3), np.asarray(crefl, float), tuple(movers))

    @classmethod
    def room(cls, xmin: float, ymin: float, xmax: float, ymax: float) -> Scene:
        """An empty rectangular room whose inner walls are the four lines."""
        return cls.build(walls=[[(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax), (xmin, ymin)]])

    # ------------------------------------------------------------------ time

    def geometry(self, t: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Segments, their reflectivity, circles and theirs, with movers where they are at time ``t``."""
        if not self.movers:
            return self.segments, self.segment_reflectivity, self.circles, self.circle_reflectivity
        segs, refl = [self.segments], [self.segment_reflectivity]
        circ, crefl = [self.circles], [self.circle_reflectivity]
        for m in self.movers:
            x, y = m.position(t)
            if m.size is not None:
                s = np.asarray(_box_segments(x, y, m.size[0], m.size[1], 0.0))
                segs.append(s)
                refl.append(np.full(len(s), m.reflectivity))
            else:
                circ.append(np.asarray([[x, y, m.radius]]))
                crefl.append(np.asarray([m.reflectivity]))
        return np.vstack(segs), np.concatenate(refl), np.vstack(circ), np.concatenate(crefl)

    def _static_hits(self, ox: float, oy: float, angles, dx, dy) -> tuple[np.ndarray, np.ndarray]:
        segs = self.segments
        if not len(segs):
            return np.full(len(angles), np.inf), np.zeros(len(angles), np.int64)
        key = (float(ox), float(oy))
        vis = self._visibility.get(key)
        if vis is None and len(segs) <= VISIBILITY_MAX_EDGES:
            if key in self._seen_origins:
                vis = _visibility_map(ox, oy, segs)
                if len(self._visibility) >= VISIBILITY_CACHE:
                    self._visibility.pop(next(iter(self._visibility)))
                self._visibility[key] = vis
            else:
                self._seen_origins.add(key)  # build the map on the second cast from this origin
                if len(self._seen_origins) > 4 * VISIBILITY_CACHE:
                    self._seen_origins.clear()
        if vis is None:
            return _segments_culled(ox, oy, angles, dx, dy, segs)
        return _segments_visible(ox, oy, angles, dx, dy, segs, vis)

    def _normals(self, segs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit normals of ``segs`` (the static ones computed once)."""
        static = segs is self.segments
        if static and "_static_normals" in self.__dict__:
            return self.__dict__["_static_normals"]
        ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
        elen = np.hypot(ex, ey)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = (-ey / elen, ex / elen)
        if static:
            self.__dict__["_static_normals"] = out
        return out

    @property
    def _seen_origins(self) -> set:
        seen = self.__dict__.get("_seen")
        if seen is None:
            seen = self.__dict__["_seen"] = set()
        return seen

    @property
    def edge_count(self) -> int:
        return len(self.segments) + sum(4 if m.size else 0 for m in self.movers)

    # ------------------------------------------------------------------ ray casting

    def cast(self, ox: float, oy: float, angles: np.ndarray, t: float = 0.0,
             max_range: float = math.inf, *, dense: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ranges (m; ``inf`` where nothing is hit within ``max_range``), cos(incidence) and reflectivity
        of beams from (ox, oy) in world directions ``angles`` (radians, counter-clockwise from +x).

        Each edge is tested only against the beams inside the angle it subtends
        from the origin (sorted beams, two binary searches per edge), so the work
        grows with beams x edges *seen per beam*, not beams x all edges;
        ``dense`` tests every pair instead (the reference the tests compare with).

        For the static segments seen from an origin used before (a scanner whose
        pose does not move) a visibility map is kept: the angles at which the
        nearest edge can change (edge ends and crossings) cut the circle into
        intervals with one nearest edge each, so a beam costs one binary search
        and one intersection. It is exact: a beam whose intersection with its
        interval's edge fails falls back to the culled caster."""
        angles = np.asarray(angles, dtype=float)
        dx, dy = np.cos(angles), np.sin(angles)
        n = len(angles)
        best = np.full(n, np.inf)
        cos_inc = np.zeros(n)
        refl = np.zeros(n)
        segs, srefl, circ, crefl = self.geometry(t)
        if len(segs):
            if dense:
                hit_t, k = _segments_dense(ox, oy, angles, dx, dy, segs)
            else:
                hit_t, k = self._static_hits(ox, oy, angles, dx, dy)
                n_static = len(self.segments)
                if len(segs) > n_static:  # moving boxes: few edges, cast every time
                    mt, mk = _segments_culled(ox, oy, angles, dx, dy, segs[n_static:])
                    closer = mt < hit_t
                    hit_t = np.where(closer, mt, hit_t)
                    k = np.where(closer, mk + n_static, k)
            hit = hit_t < np.inf
            best = hit_t  # inf where nothing was hit
            nx, ny = self._normals(segs)
            cos_inc = np.abs(dx * nx[k] + dy * ny[k])
            cos_inc[~hit] = 0.0
            refl = srefl[k]
            refl[~hit] = 0.0
        if len(circ):
            best, cos_inc, refl = hit_circles(ox, oy, dx, dy, circ, crefl, best, cos_inc, refl)
        if max_range < math.inf:
            best = np.where(best <= max_range, best, np.inf)
        np.clip(cos_inc, 0.0, 1.0, out=cos_inc)  # (a zero-length edge has no normal: NaN clips to NaN)
        cos_inc[np.isnan(cos_inc)] = 0.0
        return best, cos_inc, refl


def hit_circles(ox, oy, dx: np.ndarray, dy: np.ndarray, circ: np.ndarray, crefl: np.ndarray, best: np.ndarray,
                cos_inc: np.ndarray, refl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Beams (directions ``dx``, ``dy``; from one origin, or one origin per beam as arrays) against circles
    ``circ`` (rows x, y, r) in closed form: where a circle is nearer than ``best``, its range, cos(incidence)
    and reflectivity replace the beam's. The scene's caster and the world's share it."""
    n = len(dx)
    ox, oy = np.asarray(ox, dtype=float), np.asarray(oy, dtype=float)
    fx, fy = ox[..., None] - circ[:, 0], oy[..., None] - circ[:, 1]  # (m,) from one origin, (n, m) per beam
    b = dx[:, None] * fx + dy[:, None] * fy
    c = fx * fx + fy * fy - circ[:, 2] ** 2
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        root = np.sqrt(disc)
    t1, t2 = -b - root, -b + root
    tc = np.where(t1 > 1e-9, t1, np.where(t2 > 1e-9, t2, np.inf))
    tc = np.where(disc >= 0, tc, np.inf)
    k = np.argmin(tc, axis=1)
    rng = tc[np.arange(n), k]
    closer = rng < best
    if closer.any():
        hit_r = np.where(closer, rng, 0.0)  # no inf * 0 for beams that miss every circle
        px = ox + dx * hit_r - circ[k, 0]
        py = oy + dy * hit_r - circ[k, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            ci = np.abs(dx * px + dy * py) / circ[k, 2]
        best = np.where(closer, rng, best)
        cos_inc = np.where(closer, ci, cos_inc)
        refl = np.where(closer, crefl[k], refl)
    return best, cos_inc, refl


def _segments_dense(ox, oy, angles, dx, dy, segs):
    """Nearest segment hit of every beam, testing all beam-edge pairs: (range or inf, edge index)."""
    n = len(angles)
    ax, ay = segs[:, 0] - ox, segs[:, 1] - oy
    ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    den = dx[:, None] * ey[None, :] - dy[:, None] * ex[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / den
        tt = (ax * ey - ay * ex)[None, :] * inv
        ss = (ax[None, :] * dy[:, None] - ay[None, :] * dx[:, None]) * inv
    ok = (np.abs(den) > 1e-12) & (tt > 1e-9) & (ss >= 0.0) & (ss <= 1.0)
    tt = np.where(ok, tt, np.inf)
    k = np.argmin(tt, axis=1)
    return tt[np.arange(n), k], k


_TWO_PI = 2 * math.pi
#: Scenes with more static edges than this are not given visibility maps (their crossings cost E^2).
VISIBILITY_MAX_EDGES = 1500
#: Visibility maps kept per scene (one per scanner origin).
VISIBILITY_CACHE = 16


def _visibility_map(ox: float, oy: float, segs: np.ndarray) -> tuple[np.ndarray, ...]:
    """Interval bounds (sorted angles in [0, 2 pi]), the nearest edge of each interval (-1: none), and
    that edge's geometry relative to the origin per interval (so a cast gathers from short arrays)."""
    ends = np.concatenate([np.arctan2(segs[:, 1] - oy, segs[:, 0] - ox), np.arctan2(segs[:, 3] - oy,
                                                                                      segs[:, 2] - ox)])
    # Where two edges cross, the nearer one can change: those angles bound intervals too.
    ax, ay = segs[:, 0], segs[:, 1]
    ex, ey = segs[:, 2] - ax, segs[:, 3] - ay
    den = ex[:, None] * ey[None, :] - ey[:, None] * ex[None, :]
    wx, wy = ax[None, :] - ax[:, None], ay[None, :] - ay[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (wx * ey[None, :] - wy * ex[None, :]) / den
        v = (wx * ey[:, None] - wy * ex[:, None]) / den
    cross = (np.abs(den) > 1e-12) & (u > 0) & (u < 1) & (v > 0) & (v < 1)
    i, _j = np.nonzero(cross)
    px, py = ax[i] + u[cross] * ex[i], ay[i] + u[cross] * ey[i]
    crit = np.mod(np.concatenate([ends, np.arctan2(py - oy, px - ox)]), _TWO_PI)
    crit = np.unique(np.concatenate([crit, [0.0, _TWO_PI]]))
    mids = (crit[:-1] + crit[1:]) / 2
    t, k = _segments_culled(ox, oy, mids, np.cos(mids), np.sin(mids), segs)
    edge = np.where(np.isfinite(t), k, -1)
    kk = np.maximum(edge, 0)
    rax, ray = segs[kk, 0] - ox, segs[kk, 1] - oy
    rex, rey = segs[kk, 2] - segs[kk, 0], segs[kk, 3] - segs[kk, 1]
    return crit, edge, rax, ray, rex, rey, rax * rey - ray * rex


def _segments_visible(ox, oy, angles, dx, dy, segs, vis) -> tuple[np.ndarray, np.ndarray]:
    """Nearest static hits through a visibility map; beams it cannot settle go to the culled caster."""
    crit, edge_of, rax, ray, rex, rey, num = vis
    theta = np.mod(angles, _TWO_PI)
    idx = np.searchsorted(crit, theta, side="right") - 1
    np.clip(idx, 0, len(edge_of) - 1, out=idx)
    k = edge_of[idx]
    ax, ay, ex, ey = rax[idx], ray[idx], rex[idx], rey[idx]
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / den
        tt = num[idx] * inv
        ss = (ax * dy - ay * dx) * inv
    ok = (k >= 0) & (tt > 1e-9) & (ss >= -1e-9) & (ss <= 1.0 + 1e-9) & (np.abs(den) > 1e-12)
    # On an interval bound the neighbour's edge may be the one hit: settle those beams the slow way.
    lo, hi = crit[idx], crit[np.minimum(idx + 1, len(crit) - 1)]
    unsure = ((k >= 0) & ~ok) | (theta - lo < 1e-9) | (hi - theta < 1e-9)
    best = np.where(ok, tt, np.inf)
    which = np.maximum(k, 0)
    if unsure.any():
        sub = np.nonzero(unsure)[0]
        st, sk = _segments_culled(ox, oy, angles[sub], dx[sub], dy[sub], segs)
        best[sub] = st
        which[sub] = sk
    return best, which


def _segments_culled(ox, oy, angles, dx, dy, segs):
    """As :func:`_segments_dense`, testing each edge only against the beams within the angle it subtends."""
    n = len(angles)
    theta = np.mod(angles, _TWO_PI)
    order = np.argsort(theta, kind="stable")
    ts = theta[order]
    ax, ay = segs[:, 0] - ox, segs[:, 1] - oy
    bx, by = segs[:, 2] - ox, segs[:, 3] - oy
    pa, pb = np.arctan2(ay, ax), np.arctan2(by, bx)
    width = np.mod(pb - pa + math.pi, _TWO_PI) - math.pi
    lo = np.where(width >= 0, pa, pb)
    width = np.abs(width)
    eps = 1e-9
    lo = np.mod(lo - eps, _TWO_PI)
    hi = lo + width + 2 * eps
    # Up to two index ranges per edge (the second when the interval wraps past 2 pi).
    s1 = np.searchsorted(ts, lo, side="left")
    e1 = np.searchsorted(ts, np.minimum(hi, _TWO_PI), side="right")
    wrap = hi > _TWO_PI
    e2 = np.where(wrap, np.searchsorted(ts, hi - _TWO_PI, side="right"), 0)
    starts = np.concatenate([s1, np.zeros(len(segs), np.int64)])
    ends = np.concatenate([e1, e2])
    edge_of = np.concatenate([np.arange(len(segs)), np.arange(len(segs))])
    counts = np.maximum(ends - starts, 0)
    total = int(counts.sum())
    best = np.full(n, np.inf)
    which = np.zeros(n, np.int64)
    if total == 0:
        return best, which
    edge = np.repeat(edge_of, counts)
    offs = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    beam = order[np.repeat(starts, counts) + offs]
    ex, ey = segs[edge, 2] - segs[edge, 0], segs[edge, 3] - segs[edge, 1]
    ddx, ddy = dx[beam], dy[beam]
    den = ddx * ey - ddy * ex
    eax, eay = ax[edge], ay[edge]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / den
        tt = (eax * ey - eay * ex) * inv
        ss = (eax * ddy - eay * ddx) * inv
    ok = (np.abs(den) > 1e-12) & (tt > 1e-9) & (ss >= -1e-12) & (ss <= 1.0 + 1e-12)
    if not ok.any():
        return best, which
    beam, edge, tt = beam[ok], edge[ok], tt[ok]
    np.minimum.at(best, beam, tt)
    won = tt == best[beam]
    which[beam[won]] = edge[won]
    return best, which


@dataclass(frozen=True)
class Pose:
    """A scanner's mounting pose in the scene: position (m) and heading (degrees, counter-clockwise from +x)."""

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0


@dataclass
class RangeModel:
    """Per-model measurement model: range limits, noise, dropouts and returned power (spec §5.3-5.5).

    ``sigma`` is max(``sigma0``, ``sigma_k`` * r) in metres; ``dropout`` is the
    probability that a valid return is lost; grazing beams (cos < ``grazing``)
    and weak returns drop out too. Seeded per device so a test replays the same scans.
    """

    min_range: float = 0.15
    max_range: float = 12.0
    sigma0: float = 0.0005
    sigma_k: float = 0.005
    dropout: float = 0.0
    grazing: float = 0.05
    seed: int = 0

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    def sigma(self, r: np.ndarray) -> np.ndarray:
        return np.maximum(self.sigma0, self.sigma_k * r)

    def measure(self, ranges: np.ndarray, cos_inc: np.ndarray,
                refl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Noisy ranges (m; 0 = no return) and returned power 0..1 for true ``ranges`` (inf: no hit)."""
        r = np.asarray(ranges, dtype=float)
        valid = np.isfinite(r) & (r >= self.min_range) & (r <= self.max_range) & (cos_inc >= self.grazing)
        if self.dropout:
            valid &= self.rng.random(len(r)) >= self.dropout
        rr = np.where(valid, r, 0.0)
        noisy = rr + self.rng.standard_normal(len(r)) * self.sigma(rr)
        noisy = np.where(valid, np.clip(noisy, self.min_range, self.max_range), 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            power = np.where(valid, refl * cos_inc / np.maximum(rr, 0.5) ** 2 * 0.25, 0.0)
        return noisy, np.clip(power, 0.0, 1.0)


__all__ = ["Mover", "Pose", "RangeModel", "Scene"]
