"""The live dashboard: one rich screen over a monitor, refreshed at most 10 times a second.

The screen is redrawn on a timer, never per packet, so its cost does not
grow with the bus's data rate; between frames the loop only waits for keys.
Keys (real terminal, cbreak mode):

=================  ===========================================
``1`` ``d``        device overview (start screen)
``2`` ``m``        model overview
``3`` ``i`` Enter  device details
``4`` ``e``        error log
Tab / Shift-Tab    next / previous view
Left / Right       previous / next device (model in view 2)
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

from rich.console import Console, Group
from rich.live import Live

from hilbench.dashboard.keys import KeyReader
from hilbench.dashboard.views import VIEWS, Frame, screen
from hilbench.monitor.tracker import BusTracker

#: The refresh cap (frames per second).
MAX_FPS = 10


class Dashboard:
    """Renders a tracker's state; :meth:`run` shows it live until quit (or until ``stop()`` is true).

    ``lock`` is the lock the tracker is fed under (a :class:`~hilbench.monitor.live.Monitor`'s),
    ``clock`` returns the bus time "now" (for ages; default: the newest data's time),
    ``status`` returns a short word for the footer ("live", "replay", "ended").
    """

    def __init__(
        self,
        tracker: BusTracker,
        *,
        lock: threading.Lock | None = None,
        source: str = "",
        view: str = "devices",
        device: int | None = None,
        model: str | None = None,
        clock: Callable[[], float | None] | None = None,
        status: Callable[[], str] | None = None,
    ) -> None:
        if view not in VIEWS:
            raise ValueError(f"view must be one of {', '.join(VIEWS)}")
        self.tracker = tracker
        self.lock = lock or threading.Lock()
        self.source = source
        self.view = view
        self.device = device
        self.model = model
        self.scroll = 0
        self.clock = clock
        self.status = status or (lambda: "live")
        self.frames = 0

    # ------------------------------------------------------------------ rendering

    def frame(self, width: int = 80) -> Frame:
        tr = self.tracker
        now = self.clock() if self.clock else None
        if now is None:
            now = tr.t_last
        return Frame(tr, now, self.source, self.status(), self.view, self.device, self.model, self.scroll, width,
                     tr.models())

    def render(self, width: int = 80, height: int = 24) -> Group:
        """The current screen, ``height`` lines of at most ``width`` columns (taken under the lock)."""
        with self.lock:
            fr = self.frame(width)
            if self.device is None or self.device not in self.tracker.devices:
                ids = sorted(self.tracker.devices)
                self.device = fr.device = ids[0] if ids else None
            return screen(fr, height)

    # ------------------------------------------------------------------ keys

    def handle_key(self, key: str) -> bool:
        """Apply one key; False means quit."""
        if key in ("q", "Q", "eof"):
            return False
        views = {"1": "devices", "d": "devices", "2": "models", "m": "models", "3": "details", "i": "details",
                 "enter": "details", "4": "log", "e": "log"}
        if key in views:
            if self.view != views[key]:
                self.scroll = 0
            self.view = views[key]
        elif key in ("tab", "backtab"):
            step = 1 if key == "tab" else -1
            self.view = VIEWS[(VIEWS.index(self.view) + step) % len(VIEWS)]
            self.scroll = 0
        elif key in ("left", "right", ",", ".", "p", "n"):
            step = 1 if key in ("right", ".", "n") else -1
            with self.lock:
                if self.view == "models":
                    names = list(self.tracker.models())
                    if names:
                        cur = names.index(self.model) if self.model in names else 0
                        self.model = names[(cur + step) % len(names)]
                else:
                    ids = sorted(self.tracker.devices)
                    if ids:
                        cur = ids.index(self.device) if self.device in ids else 0
                        self.device = ids[(cur + step) % len(ids)]
                        if self.view == "devices":
                            self.view = "details"
            self.scroll = 0
        elif key in ("down", "j"):
            self.scroll += 1
        elif key in ("up", "k"):
            self.scroll = max(0, self.scroll - 1)
        elif key in ("pgdn", "space"):
            self.scroll += 10
        elif key == "pgup":
            self.scroll = max(0, self.scroll - 10)
        elif key == "home":
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
