"""The live dashboard: one rich screen over a monitor, refreshed at most 10 times a second.

The frame is generic: the screen's content comes from the view set of the
tracker's instrument (:class:`ViewSet`, e.g. the Dynamixel bus's device
overview, model overview, device details and error log), so a scanner, CAN
or UDP instrument brings views of its own. The screen is redrawn on a timer,
never per packet, so its cost does not grow with the data rate; between
frames the loop only waits for keys. Keys (real terminal, cbreak mode):

=================  ===========================================
``1`` ... ``9``    the view set's views, in order (also its letters)
Tab / Shift-Tab    next / previous view
Left / Right       previous / next selection (the view set decides)
Up / Down, PgUp    scroll the list of the current view
``q``              quit
=================  ===========================================

When stdin is not a terminal the dashboard has no keys; ``view``,
``device`` and ``model`` (the ``--view``/``--device`` options) choose what it
shows.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from rich.console import Group
from rich.live import Live
from rich.text import Text

from hilbench import registry
from hilbench.console import Console
from hilbench.dashboard.keys import KeyReader

#: The refresh cap (frames per second).
MAX_FPS = 10
#: Keys every view set has: scrolling and quitting.
SCROLL_KEYS = {"down": 1, "j": 1, "up": -1, "k": -1, "pgdn": 10, "space": 10, "pgup": -10}


class ViewSet(Protocol):
    """An instrument's screens (its :meth:`~hilbench.monitor.instrument.Instrument.views`)."""

    #: View names; keys 1..n select them in this order.
    views: tuple[str, ...]
    #: View name -> title.
    titles: dict[str, str]
    #: Extra keys -> view name (``{"d": "devices", "enter": "details"}``).
    letters: dict[str, str]

    def render(self, dash: Dashboard, width: int, height: int) -> Group:
        """The whole screen for the dashboard's state, exactly ``height`` lines (called under the lock)."""

    def navigate(self, dash: Dashboard, key: str) -> bool:
        """Handle a selection key (left/right, ...) under the lock; False if it is not one of its keys."""


class Dashboard:
    """Renders a tracker's state; :meth:`run` shows it live until quit (or until ``stop()`` is true).

    ``tracker`` is a tracker, or a :class:`~hilbench.monitor.live.Monitor` whose
    tracker may appear later (while it tells the protocol, the screen says it
    waits). ``views`` defaults to the view set of the tracker's instrument.
    ``lock`` is the lock the tracker is fed under (a monitor's own by default),
    ``clock`` returns the time "now" (for ages; default: the newest data's time),
    ``status`` returns a short word for the footer ("live", "replay", "ended").
    """

    def __init__(
        self,
        tracker: Any,
        *,
        views: ViewSet | None = None,
        lock: threading.Lock | None = None,
        source: str = "",
        view: str | None = None,
        device: Any = None,
        model: str | None = None,
        clock: Callable[[], float | None] | None = None,
        status: Callable[[], str] | None = None,
    ) -> None:
        is_monitor = hasattr(tracker, "instrument") and hasattr(tracker, "ended")
        self.monitor = tracker if is_monitor else None
        self._tracker = None if is_monitor else tracker
        self.lock = lock or (tracker.lock if is_monitor else threading.Lock())
        self._views = views
        self.source = source
        self.view = view
        self.device = device
        self.model = model
        self.scroll = 0
        self.clock = clock
        self.status = status or (lambda: "live")
        self.frames = 0
        vs = self.views
        if vs is not None and view is not None and view not in vs.views:
            raise ValueError(f"view must be one of {', '.join(vs.views)}")

    @property
    def tracker(self) -> Any:
        """The tracker shown (None while a monitor still tells the protocol)."""
        return self.monitor.tracker if self.monitor is not None else self._tracker

    @property
    def views(self) -> ViewSet | None:
        """The view set (of the tracker's instrument unless one was given)."""
        if self._views is None and self.tracker is not None:
            inst = registry.instrument_for(getattr(self.tracker, "protocol", ""))
            self._views = inst.views() if inst is not None else None
        return self._views

    def now(self) -> float | None:
        """The time the screen shows ages against."""
        now = self.clock() if self.clock else None
        if now is None and self.tracker is not None:
            now = self.tracker.t_last
        return now

    # ------------------------------------------------------------------ rendering

    def render(self, width: int = 80, height: int = 24) -> Group:
        """The current screen, ``height`` lines of at most ``width`` columns (taken under the lock)."""
        with self.lock:
            vs = self.views
            if vs is None:
                what = "waiting for traffic to tell what it carries" if self.tracker is None else \
                    "no dashboard views for this protocol"
                lines = [Text(f" hilbench monitor  {self.source}", style="bold"), Text(f" {what} [{self.status()}]")]
                return Group(*lines, *[Text("")] * max(0, height - len(lines)))
            if self.view is None or self.view not in vs.views:
                self.view = vs.views[0]
            return vs.render(self, width, height)

    # ------------------------------------------------------------------ keys

    def handle_key(self, key: str) -> bool:
        """Apply one key; False means quit."""
        if key in ("q", "Q", "eof"):
            return False
        vs = self.views
        if vs is None:
            return True
        views = {str(n + 1): name for n, name in enumerate(vs.views[:9])} | vs.letters
        if key in views:
            if self.view != views[key]:
                self.scroll = 0
            self.view = views[key]
        elif key in ("tab", "backtab"):
            step = 1 if key == "tab" else -1
            cur = vs.views.index(self.view) if self.view in vs.views else 0
            self.view = vs.views[(cur + step) % len(vs.views)]
            self.scroll = 0
        elif key in SCROLL_KEYS:
            self.scroll = max(0, self.scroll + SCROLL_KEYS[key])
        elif key == "home":
            self.scroll = 0
        else:
            with self.lock:
                if vs.navigate(self, key):
                    self.scroll = 0
        return True

    # ------------------------------------------------------------------ running

    def run(
        self,
        *,
        console: Console | None = None,
        stop: Callable[[], bool] | None = None,
        screen_mode: bool | None = None,
        fps: float = MAX_FPS,
        keys: KeyReader | None = None,
    ) -> None:
        """Show the dashboard until ``q`` (or ``stop()`` returns True); at most ``fps`` frames a second.

        In a terminal the screen uses the alternate buffer (restored on exit);
        otherwise only the final frame is printed.
        """
        console = console or Console()
        fps = min(fps, MAX_FPS)
        period = 1.0 / fps
        interactive = console.is_terminal
        if screen_mode is None:
            screen_mode = interactive
        reader = keys or KeyReader()

        def draw() -> Group:
            self.frames += 1
            size = console.size
            return self.render(max(40, size.width), max(12, size.height - (0 if screen_mode else 1)))

        with reader, Live(console=console, screen=screen_mode, auto_refresh=False, transient=False,
                          redirect_stdout=False, redirect_stderr=False) as live:
            live.update(draw(), refresh=True)
            last = time.monotonic()
            while True:
                if stop is not None and stop():
                    break
                wait = max(0.0, last + period - time.monotonic())
                pressed = reader.read(wait) if reader.active else []
                if not reader.active and wait:
                    time.sleep(wait)
                quit_ = False
                for key in pressed:
                    if not self.handle_key(key):
                        quit_ = True
                if quit_:
                    break
                if time.monotonic() >= last + period:  # keys wait for the next frame: the cap holds
                    live.update(draw(), refresh=True)
                    last = time.monotonic()
            live.update(draw(), refresh=True)
