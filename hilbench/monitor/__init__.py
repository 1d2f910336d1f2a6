"""The bus monitor: turning Dynamixel traffic into device and bus state.

- :class:`~hilbench.monitor.tracker.BusTracker`: pure state machine, fed bytes
  with times (no I/O), testable with bytes alone;
- :class:`~hilbench.monitor.devices.DeviceState`: what is known about one device;
- :class:`~hilbench.monitor.errorlog.ErrorLog`: bounded, timestamped error log;
- :func:`~hilbench.monitor.summary.summary`: the JSON summary;
- :class:`~hilbench.monitor.live.Monitor`: a source feeding a tracker in a thread.
"""

from hilbench.monitor.devices import DeviceState
from hilbench.monitor.errorlog import ErrorLog
from hilbench.monitor.live import Monitor
from hilbench.monitor.summary import summary
from hilbench.monitor.tracker import BusTracker

__all__ = ["BusTracker", "DeviceState", "ErrorLog", "Monitor", "summary"]
