"""A live view while a stream runs: rates, per-task figures of the last second, a text Gantt of the last
few milliseconds, and the quality counters; refreshed at most 10 times a second.

The view analyses only the recent part of the timeline (``stats_us``), so a
refresh costs the same after an hour as after a second. The caller feeds the
profiler and calls :meth:`LiveView.tick` as often as it likes; the view
decides when to redraw.
"""

from __future__ import annotations

import time

from rich.console import Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from hilbench.console import Console
from hilbench.profiler.gantt import text_gantt
from hilbench.profiler.ingest import Profiler

MAX_RATE_HZ = 10.0


class LiveView:
    """See the module docstring. Use as a context manager around the read loop."""

    def __init__(self, profiler: Profiler, console: Console | None = None, *, source: str = "",
                 stats_us: float = 1_000_000, gantt_us: float = 20_000, max_rate_hz: float = MAX_RATE_HZ,
                 width: int = 64) -> None:
        self.profiler = profiler
        self.console = console or Console()
        self.source = source
        self.stats_us = stats_us
        self.gantt_us = gantt_us
        self.min_interval = 1.0 / min(max_rate_hz, MAX_RATE_HZ)
        self.width = width
        self.frames = 0
        self.started = time.monotonic()
        self._last = 0.0
        self._rate_mark = (self.started, 0, 0)  # (time, stamps, bytes) at the last rate sample
        self._rates = (0.0, 0.0)
        self._live: Live | None = None

    def __enter__(self) -> LiveView:
        self._live = Live(console=self.console, auto_refresh=False, transient=False)
        self._live.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None

    def tick(self, force: bool = False) -> bool:
        """Redraw if the last frame is at least 1/10 s old (or ``force``); return whether it drew."""
        now = time.monotonic()
        if not force and now - self._last < self.min_interval:
            return False
        self._last = now
        self.frames += 1
        if self._live is not None:
            self._live.update(self.render(), refresh=True)
        return True

    def _sample_rates(self) -> tuple[float, float]:
        now = time.monotonic()
        t0, s0, b0 = self._rate_mark
        stamps = self.profiler.timeline.count + self.profiler.timeline.discarded
        nbytes = self.profiler.decoder.bytes_in
        if now - t0 >= 0.5:
            self._rates = ((stamps - s0) / (now - t0), (nbytes - b0) / (now - t0))
            self._rate_mark = (now, stamps, nbytes)
        return self._rates

    def render(self) -> Group:
        p = self.profiler
        stamps_s, bytes_s = self._sample_rates()
        q_total = p.timeline.count + p.timeline.discarded
        head = Text(f"{self.source}  ", style="bold")
        head.append(f"{time.monotonic() - self.started:6.1f} s  {q_total:,} stamps  {stamps_s:,.0f} stamps/s  "
                    f"{bytes_s / 1000:,.1f} kB/s  windows {len(p.timeline.segments)}  reports {len(p.reports)}")
        parts: list = [head]
        if p.timeline.count:
            a = p.analyse(last_us=self.stats_us)
            t = Table(title=f"last {self.stats_us / 1e6:g} s of the stream", title_justify="left",
                      header_style="bold", pad_edge=False)
            for col in ("name", "rate Hz", "mean µs", "max µs", "share %", "jitter µs"):
                t.add_column(col, justify="left" if col == "name" else "right", no_wrap=True)
            for name, s in a.tasks.items():
                t.add_row(name, _f(s["freq_hz"], 1), _f(s["mean_us"], 2), _f(s["max_us"], 0), _f(s["share"], 2),
                          _f(s["jitter_us"], 0), style=None if s["kind"] == "task" else "cyan")
            parts.append(t)
            g = p.analyse(last_us=self.gantt_us)
            if len(g.t):
                parts.append(Text(f"last {self.gantt_us / 1000:g} ms", style="bold"))
                parts.append(Text("\n".join(text_gantt(g, width=self.width))))
            q = a.quality
            qt = Text(f"drops {q['drops']}  est. drops {q['estimated_drops']}  orphans "
                      f"{q['orphan_ends']}/{q['orphan_begins']}  double begins {q['double_begins']}  out of order "
                      f"{q['out_of_order']}  parse errors {q['parse_errors']}  wraps {q['wraps']}")
            if q["untrustworthy"]:
                qt.stylize("red")
            parts.append(qt)
        else:
            parts.append(Text("waiting for stamps ..."))
        return Group(*parts)


def _f(x, digits: int) -> str:
    if x is None:
        return "-"
    return f"{x:,.{digits}f}"
