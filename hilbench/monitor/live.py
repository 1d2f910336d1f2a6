"""A monitor: a byte source feeding a tracker in a background thread.

:class:`Monitor` reads a :class:`~hilbench.transports.sources.Source` chunk by
chunk, feeds the tracker of the source's protocol (an
:class:`~hilbench.monitor.instrument.Instrument` plug-in) under a lock (the
dashboard reads the tracker under the same lock), optionally records every
chunk to a capture file, and keeps the tracker's clock running while a live
medium is quiet (reply timeouts, silence rules, idle flushes of partial
packets). When nobody says what the source carries, the monitor reads its
first bytes and asks every instrument (:func:`~hilbench.monitor.detect.choose`).

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
from collections.abc import Callable
from typing import Any

from hilbench.monitor.detect import choose, detect
from hilbench.monitor.instrument import Instrument, Tracker
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.recording_file import Recording
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
    """Feeds ``source`` into a tracker.

    ``tracker``: one made already; else ``instrument`` (or ``protocol``, or the
    source's own protocol) makes it, with ``tracker_options`` (and what
    ``options(instrument)`` returns, for a command line that checked every
    instrument's options before knowing which one it needs). If none of them
    says what the source carries, the reading thread tells it from the first
    bytes; until then :attr:`tracker` is None.
    """

    def __init__(
        self,
        source: Source,
        *,
        tracker: Tracker | None = None,
        instrument: Instrument | None = None,
        protocol: str | None = None,
        record: CaptureWriter | Recording | None = None,
        options: Callable[[Instrument], dict[str, Any]] | None = None,
        **tracker_options: Any,
    ) -> None:
        self.source = source
        self.tracker_options = tracker_options
        self._options = options
        if tracker is not None and instrument is None:
            instrument = choose(getattr(tracker, "protocol", None), verb=None)
        if instrument is None:
            instrument = choose(protocol or source.protocol)
        self.instrument = instrument
        self.tracker = tracker  #: the instrument's tracker (None until the protocol is known)
        if tracker is None and instrument is not None:
            self.tracker = self._make_tracker(instrument)
        self.recorder = record
        self.lock = threading.Lock()
        self.ended = threading.Event()
        self.error: BaseException | None = None
        self.chunks = 0
        self._thread: threading.Thread | None = None
        self._stopping = False

    def _make_tracker(self, instrument: Instrument) -> Tracker:
        src = self.source
        opts = {**(self._options(instrument) if self._options else {}), **self.tracker_options}
        return instrument.make_tracker(baud=src.baud, timestamps=src.timestamps != "none", **opts)

    @property
    def protocol(self) -> str | None:
        """What the monitor decodes (None while it has not told it yet)."""
        return self.instrument.protocol if self.instrument is not None else None

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
        lock, source, rec = self.lock, self.source, self.recorder
        idle = IDLE_TICK if source.live or source.clock() is not None or getattr(source, "speed", None) else None
        last_data = time.monotonic()
        tracker = self.tracker
        try:
            if tracker is None:
                instrument, source = detect(source)
                if instrument is None:
                    return  # the source ended before saying anything: nothing to track
                tracker = self._make_tracker(instrument)
                with lock:
                    self.source, self.instrument, self.tracker = source, instrument, tracker
            # A tracker of datagram protocols takes each datagram with its addresses.
            datagrams = getattr(tracker, "feed_datagram", None)
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
                    elif chunk.addr is not None and datagrams is not None:
                        datagrams(chunk.t, chunk.source, chunk.data, chunk.addr)
                    else:
                        tracker.feed(chunk.t, chunk.source, chunk.data)
                    self.chunks += 1
                if rec is not None:
                    rec.chunk(chunk)
        except BaseException as exc:  # reported by wait()/summary(); the thread must not die silently
            if not self._stopping:
                self.error = exc
        finally:
            if tracker is not None:
                with lock:
                    tracker.finish()
            try:
                if rec is not None:
                    rec.flush()
            except BaseException as exc:  # a write that failed (disk full): reported, and the monitor still ends
                if self.error is None:
                    self.error = exc
            finally:
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
        """The JSON summary of what was seen so far (the instrument's; a stub while nothing was told)."""
        with self.lock:
            if self.tracker is None or self.instrument is None:
                report = {"source": self.source.name, "protocol": None, "baud": self.source.baud,
                          "timestamps": self.source.timestamps, "bytes": 0,
                          "note": "no traffic seen: the protocol is unknown"}
            else:
                report = self.instrument.summary(self.tracker, source=self.source.name,
                                                 timestamps=self.source.timestamps, errors=errors)
            # Damage in the input itself (a capture cut short, corrupted, with times out of order): the
            # same for every instrument, so the frame adds it.
            report["data_quality"] = self.source.quality()
            return report
