"""Shared pieces of the transport tests: a recording CAN device, and a CAN bus with one host port's doors."""

from __future__ import annotations

import threading

import pytest

from hilbench.transports.can_medium import CanMedium
from hilbench.transports.can_port import CanPort


class Recorder:
    """A CAN device that keeps every frame it hears."""

    def __init__(self, name="dev"):
        self.name = name
        self.frames = []
        self.lock = threading.Lock()

    def on_frame(self, frame, t):
        with self.lock:
            self.frames.append(frame)


@pytest.fixture
def door_bus():
    """Factory: ``door_bus(options, bitrate=500_000, paced=False)`` starts a CAN medium with a host port opened
    from ``options`` (its doors) and a :class:`Recorder` on it; returns ``(medium, port, dev, dport)``. All are
    closed after the test."""
    made = []

    def make(options, bitrate=500_000, paced=False):
        port = CanPort.open("can", CanPort.check_options(options))
        medium = CanMedium("can", bitrate, paced=paced)
        dev = Recorder()
        dport = medium.add_device(dev)
        medium.add_host(port)
        medium.start()
        made.append((medium, port))
        return medium, port, dev, dport

    yield make
    for medium, port in made:
        medium.close()
        port.close()
