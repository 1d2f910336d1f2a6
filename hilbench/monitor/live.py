"""A monitor: a byte source feeding a tracker in a background thread.

:class:`Monitor` reads a :class:`~hilbench.transports.sources.Source` chunk by
chunk, feeds the :class:`~hilbench.monitor.tracker.BusTracker` under a lock
(the dashboard reads the tracker under the same lock), optionally records
every chunk to a capture file, and keeps the tracker's clock running while a
live bus is quiet (reply timeouts, the silence rule, idle flushes of partial
packets).

::

    from hilbench.monitor import Monitor
    from hilbench.transports.sources import open_source

    with Monitor(open_source("capture.hbcap")) as mon:
        mon.wait()                       # the source ended
        print(mon.summary()["devices"])
"""

from __future__ import annotations

import threading
import time
from typing import Any

from hilbench.monitor.summary import summary
from hilbench.monitor.tracker import BusTracker
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.sources import Source

#: A live line silent this long ends a partial packet (it was cut off).
IDLE_FLUSH = 0.05
#: How often a quiet live source wakes the monitor up.
IDLE_TICK = 0.05
#: How far behind the wall clock a quiet live source's time is assumed to be. Bytes reach the
#: monitor later than they were stamped when the machine is busy (a bench's line thread, a TCP tap);
#: a reply still on its way must not be declared missed by the clock alone.
TICK_LAG = 0.5


class Monitor:
    """Feeds ``source`` into ``tracker`` (default: a new tracker for the source's baud and times)."""

    def __init__(
        self,
        source: Source,
        *,
        tracker: BusTracker | None = None,
        record: CaptureWriter | None = None,
        **tracker_options: Any,
    ) -> None:
        self.source = source
        if tracker is None:
            tracker = BusTracker(
                baud=source.baud, timestamps=source.timestamps != "none", **tracker_options
            )
        self.tracker = tracker
        self.recorder = record
        self.lock = threading.Lock()
        self.ended = threading.Event()
        self.error: BaseException | None = None
        self.chunks = 0
        self._thread: threading.Thread | None = None
        self._stopping = False

    # ------------------------------------------------------------------ running

    def start(self) -> Monitor:
        """Start reading in a background thread; returns self."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="monitor", daemon=True)
            self._thread.start()
        return self

    def run(self) -> None:
        """Read the source in this thread until it ends (or :meth:`stop`)."""
        self._run()

    def _run(self) -> None:
        tracker, lock, source, rec = self.tracker, self.lock, self.source, self.recorder
        idle = IDLE_TICK if source.live or source.clock() is not None or getattr(source, "speed", None) else None
        last_data = time.monotonic()
        try:
            for chunk in source.chunks(idle):
                if chunk is None:
                    now = source.clock()
                    with lock:
                        if now is not None:
                            if source.live:
                                now -= TICK_LAG
                            if time.monotonic() - last_data >= IDLE_FLUSH:
                                tracker.flush(now)
                            if tracker.timestamps and tracker.t0 is not None:
                                tracker.tick(now)
                    if rec is not None:
                        rec.flush()
                    continue
                last_data = time.monotonic()
                if source.baud and source.baud != tracker.baud:
                    tracker.baud = source.baud  # a tap follows the rate the application sets
                with lock:
                    if chunk.lost:
                        tracker.gap(chunk.t, chunk.source, chunk.lost)
                    else:
                        tracker.feed(chunk.t, chunk.source, chunk.data)
                    self.chunks += 1
                if rec is not None:
                    rec.chunk(chunk)
        except BaseException as exc:  # reported by wait()/summary(); the thread must not die silently
            if not self._stopping:
                self.error = exc
        finally:
            with lock:
                tracker.finish()
            if rec is not None:
                rec.flush()
            self.ended.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait for the source to end; re-raises what stopped the reading thread, if anything."""
        done = self.ended.wait(timeout)
        if self.error is not None:
            raise self.error
        return done

    def stop(self) -> None:
        """Close the source and wait for the reading thread to finish."""
        self._stopping = True
        self.source.close()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> Monitor:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ results

    def summary(self, errors: int = 50) -> dict[str, Any]:
        """The JSON summary of what was seen so far (see :mod:`hilbench.monitor.summary`)."""
        with self.lock:
            return summary(
                self.tracker,
                source=self.source.name,
                protocol=self.source.protocol or "dynamixel",
                timestamps=self.source.timestamps,
                errors=errors,
            )
