"""The dashboard: every view fits 80x24, keys select views and devices, the refresh cap holds."""

from __future__ import annotations

import io
import threading
import time

import pytest
from rich.console import Console

from hilbench.dashboard import Dashboard
from hilbench.dashboard.keys import split_keys
from hilbench.dashboard.servo_bus_views import TITLES, VIEWS
from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.protocols import dynamixel as dxl


@pytest.fixture(scope="module")
def wolfgang(wolfgang_capture) -> BusTracker:
    tr = BusTracker(baud=2_000_000)
    for i in range(0, len(wolfgang_capture), 64):  # byte time at 2 Mbaud
        tr.feed((i + 64) * 5e-6, "bus", wolfgang_capture[i : i + 64])
    tr.finish()
    return tr


def text(dash: Dashboard, width: int = 80, height: int = 24) -> list[str]:
    console = Console(width=width, height=height, force_terminal=True, color_system=None, file=io.StringIO())
    with console.capture() as cap:
        console.print(dash.render(width, height), end="")
    return cap.get().splitlines()


@pytest.mark.parametrize("view", VIEWS)
def test_every_view_fits_80x24(wolfgang, view):
    lines = text(Dashboard(wolfgang, source="wolfgang_trace.bin", view=view, device=101, status=lambda: "ended"))
    assert len(lines) == 24 and max(len(line) for line in lines) <= 80
    assert lines[2].startswith(TITLES[view])
    assert lines[0].strip().endswith("20 connected  1 disconnected")
    assert "cycle 393 Hz" in lines[1] and "CRC 952" in lines[1]
    assert lines[-1].endswith("[ended]")


def test_views_show_what_a_person_needs(wolfgang):
    dash = Dashboard(wolfgang, source="trace", status=lambda: "ended")
    overview = "\n".join(text(dash))
    assert "<unknown>                  3            1         7,10,12,101" in overview
    assert "101 DISC" in overview and " 18 ok " in overview
    dash.handle_key("2")
    models = "\n".join(text(dash))
    assert "Model overview: MX-106(2.0)" in models and "MX-106 (18)" in models
    dash.handle_key("right")
    assert "Model overview: MX-64(2.0)" in "\n".join(text(dash))
    dash.handle_key("3")
    dash.device = 101
    details = "\n".join(text(dash))
    assert "Device details: ID 101  <unknown>" in details
    assert "disconnected - never answered" in details and "missed 889" in details
    dash.handle_key("right")
    assert dash.device == 1  # after the last device comes the first again
    details = "\n".join(text(dash))
    assert "Present Position" in details and "Present Input Voltage" in details and " V (" in details
    assert "model 311 (ping)  fw 41" in details
    dash.handle_key("4")
    log = text(dash)
    assert log[2].startswith("Error log: ") and log[4].startswith("[+00:02.6")


def test_keys_and_escape_sequences():
    assert split_keys("3\x1b[C\x1b[D\tq") == ["3", "right", "left", "tab", "q"]
    assert split_keys("\x1b[6~\x1b[5~\x1b") == ["pgdn", "pgup", "escape"]
    dash = Dashboard(BusTracker())
    assert dash.handle_key("tab") and dash.view == "models"
    assert dash.handle_key("backtab") and dash.view == "devices"
    assert dash.handle_key("e") and dash.view == "log"
    assert not dash.handle_key("q")
    with pytest.raises(ValueError):
        Dashboard(BusTracker(), view="nope")


def test_refresh_is_capped_at_ten_frames_a_second_however_fast_data_arrives():
    tr = BusTracker(baud=1_000_000)
    dash = Dashboard(tr, lock=threading.Lock())
    stop = threading.Event()
    fed = 0

    def feed():
        nonlocal fed
        req = dxl.instruction_packet(0xFE, dxl.Instruction.SYNC_READ, bytes([132, 0, 4, 0, 1, 2]))
        replies = dxl.status_packet(1, 0, bytes(4)) + dxl.status_packet(2, 0, bytes(4))
        while not stop.is_set():
            with dash.lock:
                tr.feed(time.monotonic(), "bus", req + replies)
            fed += 1

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    console = Console(width=80, height=24, force_terminal=True, file=io.StringIO())
    t0 = time.monotonic()
    dash.run(console=console, stop=lambda: time.monotonic() - t0 > 1.0, screen_mode=False)
    elapsed = time.monotonic() - t0
    stop.set()
    feeder.join()
    assert fed > 100  # hundreds of cycles a second arrived ...
    assert 3 <= dash.frames <= 10 * elapsed + 2  # ... and the screen refreshed at most 10 times a second
