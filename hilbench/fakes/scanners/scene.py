"""A 2D scene for emulated laser scanners: walls, boxes, circles and moving objects, and ray casting.

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

import numpy as np


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
        ``dense`` tests every pair instead (the reference the tests compare with)."""
        angles = np.asarray(angles, dtype=float)
        dx, dy = np.cos(angles), np.sin(angles)
        n = len(angles)
        best = np.full(n, np.inf)
        cos_inc = np.zeros(n)
        refl = np.zeros(n)
        segs, srefl, circ, crefl = self.geometry(t)
        if len(segs):
            hit_t, k = (_segments_dense if dense else _segments_culled)(ox, oy, angles, dx, dy, segs)
            hit = np.isfinite(hit_t)
            best = np.where(hit, hit_t, best)
            ex, ey = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
            elen = np.hypot(ex, ey)
            with np.errstate(divide="ignore", invalid="ignore"):
                nx, ny = -ey / elen, ex / elen
            cos_inc = np.where(hit, np.abs(dx * nx[k] + dy * ny[k]), cos_inc)
            refl = np.where(hit, srefl[k], refl)
        if len(circ):
            fx, fy = ox - circ[:, 0], oy - circ[:, 1]
            b = dx[:, None] * fx[None, :] + dy[:, None] * fy[None, :]
            c = (fx * fx + fy * fy - circ[:, 2] ** 2)[None, :]
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
        best = np.where(best <= max_range, best, np.inf)
        return best, np.clip(np.nan_to_num(cos_inc), 0.0, 1.0), refl


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
