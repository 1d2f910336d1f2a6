"""The terminal dashboard: rich views of a bus monitor's state (device overview,
model overview, device details, error log) on one live screen."""

from hilbench.dashboard.app import MAX_FPS, Dashboard
from hilbench.dashboard.views import TITLES, VIEWS

__all__ = ["MAX_FPS", "TITLES", "VIEWS", "Dashboard"]
