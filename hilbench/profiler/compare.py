"""Comparing two runs per name, as the thesis compares caches on and off (spec sheet §4.1-§4.2).

The thesis reports the change of each name's summed time between runs in
percent of the first run: (other - base) / base x 100, e.g. FreeRTOS
odometry 22,373 -> 6,256 µs is -72.04 % with caches. The mean and the count
change the same way, and the run lengths (sum of all totals) as a difference.
Either run may be an :class:`~hilbench.profiler.analysis.Analysis` or the
``--json`` document of an earlier run, so a baseline can be kept in a file.
"""

from __future__ import annotations

import json
from pathlib import Path


def summary_of(run) -> dict[str, dict]:
    """The per-name figures of an Analysis, a ``--json`` document, or a ``{"tasks": ...}``-like dict."""
    if hasattr(run, "tasks") and not isinstance(run, dict):
        return run.tasks
    if isinstance(run, dict) and isinstance(run.get("tasks"), dict):
        return run["tasks"]
    raise ValueError("not a profiler summary: expected a 'tasks' mapping")


def load_summary(path: str | Path) -> dict:
    """A ``--json`` document saved by ``hilbench trace --json``; ValueError (one line) otherwise."""
    try:
        doc = json.loads(Path(path).read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        why = f"{exc.msg} at line {exc.lineno}" if isinstance(exc, json.JSONDecodeError) else "not text"
        raise ValueError(f"{path}: not JSON ({why})") from None
    try:
        tasks = summary_of(doc)
    except ValueError:
        tasks = None
    if tasks is None or not all(isinstance(v, dict) for v in tasks.values()):
        raise ValueError(f"{path}: not a `hilbench trace --json` document (no 'tasks' table of figures)")
    return doc


def _change(base, other) -> float | None:
    if base is None or other is None or base == 0:
        return None
    return (other - base) / base * 100


def _diff(base, other):
    return None if base is None or other is None else other - base


def compare(base, other, *, aliases: dict[str, str] | None = None) -> dict:
    """Per-name change from ``base`` to ``other``.

    ``aliases`` maps names of ``other`` to names of ``base`` where the two runs
    name the same work differently (e.g. micro-ROS ``odom`` vs FreeRTOS
    ``odometry``). Names found in only one run are listed with the other side
    None.
    """
    a = summary_of(base)
    b = {(aliases or {}).get(k, k): v for k, v in summary_of(other).items()}
    rows: dict[str, dict] = {}
    for name in list(a) + [n for n in b if n not in a]:
        x, y = a.get(name, {}), b.get(name, {})
        row = {"kind": x.get("kind") or y.get("kind")}
        for key in ("total_us", "mean_us", "count", "max_us", "freq_hz"):
            xv, yv = x.get(key), y.get(key)
            short = key.removesuffix("_us")
            row[f"base_{short}"] = xv
            row[f"other_{short}"] = yv
            row[f"diff_{short}"] = _diff(xv, yv)
            row[f"change_{short}_pct"] = _change(xv, yv)
        xs, ys = x.get("share"), y.get("share")
        row["base_share"], row["other_share"], row["diff_share_pp"] = xs, ys, _diff(xs, ys)
        rows[name] = row
    sa = sum(v.get("total_us") or 0 for v in a.values())
    sb = sum(v.get("total_us") or 0 for v in b.values())
    return {"tasks": rows, "base_sum_us": sa, "other_sum_us": sb, "diff_sum_us": sb - sa}
