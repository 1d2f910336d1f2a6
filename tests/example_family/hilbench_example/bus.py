"""The blink bus: what an endpoint with ``protocol = "blink"`` is (a serial line on a pty, one board)."""

from __future__ import annotations

from hilbench.bench.bus import BusKind


class BlinkBus(BusKind):
    protocol = "blink"
    endpoint_types = ("pty",)
    max_devices = 1
    one_device_reason = "a blinker's UART is point to point"

    def summary(self, endpoint) -> str:
        boards = ", ".join(f"{name} (board {dev.board_id})" for name, dev in endpoint.devices.items())
        return f"blink, {endpoint.spec.baud} baud, {boards or 'no board'}"


BUS_KIND = BlinkBus()
