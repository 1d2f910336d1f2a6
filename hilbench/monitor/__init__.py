"""Instruments that watch traffic: the generic monitor frame and the trackers registered per protocol.

- :class:`~hilbench.monitor.live.Monitor`: a source feeding the tracker of its protocol in a thread;
- :class:`~hilbench.monitor.instrument.Instrument`: what a protocol's instrument plug-in provides
  (``hilbench.instruments`` entry points): options, tracker, summary, dashboard views;
- :mod:`~hilbench.monitor.detect`: which instrument watches a source;
- :class:`~hilbench.monitor.errorlog.ErrorLog`: a bounded, timestamped error log for trackers;
- :mod:`hilbench.monitor.dynamixel`: the Dynamixel Protocol 2.0 bus tracker.
"""

from hilbench.monitor.errorlog import ErrorLog
from hilbench.monitor.instrument import Instrument
from hilbench.monitor.live import Monitor

__all__ = ["ErrorLog", "Instrument", "Monitor"]
