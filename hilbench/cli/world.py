"""``hilbench world``: the truth of a running bench's world, seen from above, as JSON, a picture or a record.

- ``hilbench world MANIFEST``: a live top-down view in the terminal (walls,
  obstacles, moving objects, every body with its heading, the points each
  scanner's beams hit), with each body's pose and velocity below;
- ``--json``: one document (``time``, ``unix_time``, ``bodies``, ``moving``,
  ``devices``) and exit;
- ``--png FILE``: one picture (matplotlib: ``pip install hilbench[plot]``),
  replacing FILE in one step;
- ``--record FILE``: every body's pose at every world step (200 Hz by
  default) and every scan's first and last ray time, as JSON lines (the
  format of :class:`hilbench.fakes.world.Recorder`), until Ctrl-C, SIGTERM or
  ``--duration``; a recording as ``record`` makes one
  (:func:`hilbench.cli.outputs.start_recording`): it never replaces an
  existing file without ``--force``, streams into ``FILE``'s ``.partial`` file
  flushed every half second, and is renamed into place when it ends.

Neither may be the manifest read (:func:`hilbench.cli.outputs.check_outputs`).

Everything comes through the bench's control channel (its ``world`` command).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from typing import Any

from hilbench.cli.common import CliError
from hilbench.rules import SECONDS

#: How often the live view and the recorder ask the bench (s).
LIVE_PERIOD = 0.2
RECORD_PERIOD = 0.25


def _client(args: argparse.Namespace):
    from hilbench.bench.control import ControlClient

    if args.control:
        return ControlClient(args.control)
    if args.manifest:
        return ControlClient.from_manifest(args.manifest)
    raise CliError("tell me where the bench is: MANIFEST (from hilbench emulate) or --control HOST:PORT")


def _clean(reply: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in reply.items() if k != "ok"}


def cmd_world(args: argparse.Namespace) -> int:
    from hilbench.cli.outputs import check_outputs, picture_format

    check_outputs([("--png", args.png), ("--record", args.record)], inputs=[args.manifest],
                  recordings=("--record",), force=args.force)
    if args.png:
        picture_format("--png", args.png, "the world")
    client = _client(args)
    if args.json:
        print(json.dumps(_clean(client.world())))
        return 0
    if args.png:
        _png(client.world(geometry=True, scans=True), args.png)
        print(f"wrote {args.png}")
        return 0
    duration = args.duration or None
    if args.record:
        return _record(client, args.record, duration, force=args.force)
    return _live(client, duration)


# ---------------------------------------------------------------------- record


def _record(client, path: str, duration: float | None, *, force: bool = False) -> int:
    from hilbench.cli.common import terminate_on_sigterm
    from hilbench.cli.outputs import start_recording
    from hilbench.fakes.world import RecordLines

    first = client.world()
    t = first["time"]
    end = None if duration is None else time.monotonic() + duration
    poses = scans = 0
    terminate_on_sigterm()  # SIGTERM ends the record as Ctrl-C does: renamed into place
    with start_recording(path, RecordLines, force=force) as rec:
        rec.chunk({"type": "header", "time": t, "unix_time": first["unix_time"],
                   "bodies": {n: b["shape"] for n, b in first["bodies"].items()}, "devices": first["devices"]})
        try:
            while end is None or time.monotonic() < end:
                time.sleep(RECORD_PERIOD)
                hist = client.world(since=t)["history"]
                for row in hist["poses"]:
                    rec.chunk({"type": "pose", **row})
                    t = max(t, row["t"])
                    poses += 1
                for s in hist["scans"]:
                    rec.chunk({"type": "scan", **s})
                    scans += 1
                rec.flush()
        except KeyboardInterrupt:
            pass
    print(f"recorded {poses} poses and {scans} scans into {path}")
    return 0


# ---------------------------------------------------------------------- pictures


def _png(doc: dict[str, Any], path: str) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Circle, Polygon
    except ImportError:
        raise CliError("--png needs matplotlib (pip install 'hilbench[plot]')") from None
    fig, ax = plt.subplots(figsize=(8, 6))
    geo = doc.get("geometry", {})
    for x0, y0, x1, y1 in geo.get("segments", []):
        ax.plot([x0, x1], [y0, y1], color="black", lw=1.5)
    for x, y, r in geo.get("circles", []):
        ax.add_patch(Circle((x, y), r, fill=False, color="black"))
    for m in doc.get("moving", []):
        if "radius" in m:
            ax.add_patch(Circle((m["x"], m["y"]), m["radius"], color="tab:orange", alpha=0.6))
        else:
            w, h = m["size"]
            ax.add_patch(Polygon(_corners(m["x"], m["y"], 0.0, w, h), color="tab:orange", alpha=0.6))
    colours = ["tab:blue", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink"]
    for i, (name, b) in enumerate(doc.get("bodies", {}).items()):
        col = colours[i % len(colours)]
        shape = b["shape"]
        if shape["kind"] == "box":
            ax.add_patch(Polygon(_corners(b["x"], b["y"], b["theta"], *shape["size"]), color=col, alpha=0.5))
            reach = shape["size"][0] / 2
        else:
            ax.add_patch(Circle((b["x"], b["y"]), shape["radius"], color=col, alpha=0.5))
            reach = shape["radius"]
        ax.arrow(b["x"], b["y"], reach * math.cos(b["theta"]), reach * math.sin(b["theta"]), color=col,
                 width=0.01, length_includes_head=True)
        ax.annotate(name, (b["x"], b["y"]), ha="center", va="center", fontsize=9)
    for name, pts in doc.get("scans", {}).items():
        if pts:
            xs, ys = zip(*pts, strict=True)
            ax.scatter(xs, ys, s=2, label=name)
    if any(doc.get("scans", {}).values()):
        ax.legend(loc="upper right", fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"world at t = {doc['time']:.3f} s")
    from hilbench.cli.outputs import output_file, picture_format

    try:
        with output_file(path, "wb") as f:  # a full disk or a kill leaves an old picture whole
            fig.savefig(f, format=picture_format("--png", path, "the world"), dpi=100, bbox_inches="tight")
    finally:
        plt.close(fig)


def _corners(x: float, y: float, theta: float, w: float, h: float) -> list[tuple[float, float]]:
    c, s = math.cos(theta), math.sin(theta)
    return [(x + c * u - s * v, y + s * u + c * v) for u, v in ((-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2),
                                                             (-w / 2, h / 2))]


def render_text(doc: dict[str, Any], width: int = 78, height: int = 26) -> list[str]:
    """A top-down character picture of a world document (with ``geometry`` and ``scans``): ``#`` walls and
    obstacles, ``o`` moving objects, ``.`` scan hits, each body as its first letter (its front as ``*``)."""
    geo = doc.get("geometry", {})
    xs, ys = [], []
    for x0, y0, x1, y1 in geo.get("segments", []):
        xs += [x0, x1]
        ys += [y0, y1]
    for b in doc.get("bodies", {}).values():
        xs.append(b["x"])
        ys.append(b["y"])
    if not xs:
        xs, ys = [-1.0, 1.0], [-1.0, 1.0]
    x0, x1, y0, y1 = min(xs) - 0.2, max(xs) + 0.2, min(ys) - 0.2, max(ys) + 0.2
    # Terminal cells are about twice as tall as wide: keep the picture's aspect.
    scale = min((width - 1) / max(x1 - x0, 1e-6), 2 * (height - 1) / max(y1 - y0, 1e-6))
    cols, rows = int((x1 - x0) * scale) + 1, int((y1 - y0) * scale / 2) + 1
    grid = [[" "] * cols for _ in range(rows)]

    def put(x: float, y: float, ch: str, over: bool = True) -> None:
        c, r = int(round((x - x0) * scale)), int(round((y1 - y) * scale / 2))
        if 0 <= r < rows and 0 <= c < cols and (over or grid[r][c] == " "):
            grid[r][c] = ch

    def line(ax: float, ay: float, bx: float, by: float, ch: str) -> None:
        n = max(2, int(math.hypot(bx - ax, by - ay) * scale) + 1)
        for k in range(n + 1):
            put(ax + (bx - ax) * k / n, ay + (by - ay) * k / n, ch)

    def ring(cx: float, cy: float, r: float, ch: str) -> None:
        n = max(8, int(2 * math.pi * r * scale) + 1)
        for k in range(n):
            put(cx + r * math.cos(2 * math.pi * k / n), cy + r * math.sin(2 * math.pi * k / n), ch)

    for pts in doc.get("scans", {}).values():
        for px, py in pts:
            put(px, py, ".")
    for sx0, sy0, sx1, sy1 in geo.get("segments", []):
        line(sx0, sy0, sx1, sy1, "#")
    for cx, cy, r in geo.get("circles", []):
        ring(cx, cy, r, "#")
    for m in doc.get("moving", []):
        if "radius" in m:
            ring(m["x"], m["y"], m["radius"], "o")
        put(m["x"], m["y"], "o")
    for name, b in doc.get("bodies", {}).items():
        shape = b["shape"]
        letter = name[:1].upper() if len(doc["bodies"]) == len({n[:1] for n in doc["bodies"]}) else name[-1:]
        if shape["kind"] == "box":
            pts = _corners(b["x"], b["y"], b["theta"], *shape["size"])
            for k in range(4):
                line(*pts[k], *pts[(k + 1) % 4], letter)
            reach = shape["size"][0] / 2
        else:
            ring(b["x"], b["y"], shape["radius"], letter)
            reach = shape["radius"]
        put(b["x"], b["y"], letter)
        put(b["x"] + reach * math.cos(b["theta"]), b["y"] + reach * math.sin(b["theta"]), "*")
    return ["".join(r).rstrip() for r in grid]


def _live(client, duration: float | None) -> int:
    from rich.console import Group
    from rich.live import Live
    from rich.table import Table
    from rich.text import Text

    geometry = client.world(geometry=True)["geometry"]
    end = None if duration is None else time.monotonic() + duration

    def frame():
        doc = client.world(scans=True)
        doc["geometry"] = geometry
        table = Table("body", "x m", "y m", "theta °", "vx m/s", "vy m/s", "omega °/s", "", box=None)
        for name, b in doc["bodies"].items():
            table.add_row(name, f"{b['x']:.3f}", f"{b['y']:.3f}", f"{math.degrees(b['theta']):.1f}",
                          f"{b['vx']:.3f}", f"{b['vy']:.3f}", f"{math.degrees(b['omega']):.1f}",
                          "blocked" if b.get("blocked") else "")
        pic = Text("\n".join(render_text(doc)))
        return Group(Text(f"world at t = {doc['time']:.3f} s (Ctrl-C ends)"), pic, table)

    try:
        with Live(frame(), refresh_per_second=1 / LIVE_PERIOD, transient=False) as live:
            while end is None or time.monotonic() < end:
                time.sleep(LIVE_PERIOD)
                live.update(frame())
    except KeyboardInterrupt:
        pass
    return 0


ORDER = 55
VERBS = {"world": "the truth of a running bench's world: live view from above, JSON, picture or record"}


def register(sub: argparse._SubParsersAction) -> None:
    w = sub.add_parser("world", help=VERBS["world"],
                       description="Show a running bench's world (its bodies, obstacles, moving objects and what "
                                   "its scanners see) from above, live; or print it once as JSON, draw it as a "
                                   "PNG, or record every body's pose and every scan's ray times.")
    w.add_argument("manifest", nargs="?", metavar="MANIFEST", help="the manifest hilbench emulate wrote")
    w.add_argument("--control", metavar="HOST:PORT", help="the control address instead of a manifest")
    what = w.add_mutually_exclusive_group()
    what.add_argument("--json", action="store_true", help="print one JSON document (time, unix_time, bodies, "
                                                          "moving, devices) and exit")
    what.add_argument("--png", metavar="FILE", help="draw the world into a PNG file (needs matplotlib)")
    what.add_argument("--record", metavar="FILE", help="record every body's pose at every world step and every "
                                                       "scan's first and last ray time (JSON lines)")
    w.add_argument("--force", action="store_true", help="--record: record even over an existing non-empty file "
                                                        "(replaced when the recording ends)")
    w.add_argument("--duration", type=SECONDS, metavar="S", default=0.0,
                   help="live view / record: stop after S seconds (0: at Ctrl-C)")
    w.set_defaults(func=cmd_world)
