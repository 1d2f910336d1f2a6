"""Instruments that watch traffic: the generic monitor frame and the trackers registered per protocol.

- :class:`~hilbench.monitor.live.Monitor`: a source feeding the tracker of its protocol in a thread;
- :class:`~hilbench.monitor.instrument.Instrument`: what a protocol's instrument plug-in provides
  (``hilbench.instruments`` entry points): options, tracker, summary, dashboard views;
- :mod:`~hilbench.monitor.detect`: which instrument watches a source;
- :class:`~hilbench.monitor.errorlog.ErrorLog`: a bounded, timestamped error log for trackers;
- :mod:`hilbench.monitor.dynamixel`: the Dynamixel Protocol 2.0 bus tracker.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hilbench.exports import lazy_exports

if TYPE_CHECKING:
    from hilbench.monitor.errorlog import ErrorLog
    from hilbench.monitor.instrument import Instrument
    from hilbench.monitor.live import Monitor

#: Imported when first used: an instrument plug-in (a subpackage) loads none of the frame's modules.
_HOMES = {"ErrorLog": "errorlog", "Instrument": "instrument", "Monitor": "live"}

__all__ = ["ErrorLog", "Instrument", "Monitor"]
__getattr__, __dir__ = lazy_exports(__name__, _HOMES)
