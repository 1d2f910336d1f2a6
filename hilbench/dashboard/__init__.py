"""The terminal dashboard: a generic live frame over a monitor, with each instrument's views.

:class:`Dashboard` refreshes at most :data:`MAX_FPS` times a second and handles
keys; what it shows comes from the view set (:class:`~hilbench.dashboard.app.ViewSet`)
of the tracker's instrument, e.g. :mod:`hilbench.dashboard.servo_bus_views`
(device overview, model overview, device details, error log).
"""

from hilbench.dashboard.app import MAX_FPS, Dashboard, ViewSet

__all__ = ["MAX_FPS", "Dashboard", "ViewSet"]
