"""A line faster than its baud rate (a bench with ``paced = false``) is "unpaced", not 267 % loaded."""

from __future__ import annotations

import io

from rich.console import Console

from hilbench.dashboard import Dashboard
from hilbench.monitor.can.summary import print_summary as print_can
from hilbench.monitor.can.summary import summary as can_summary
from hilbench.monitor.can.tracker import CanTracker
from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.monitor.servo_bus.summary import print_summary, summary
from hilbench.protocols import can_frame as cf
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.can_frame import data_frame
from hilbench.transports.line_load import UNPACED_ABOVE, is_unpaced

READ = dxl.instruction_packet(1, dxl.Instruction.READ, bytes((132, 0, 4, 0)))
REPLY = dxl.status_packet(1, 0, bytes(4))


def servo_line(baud: int, seconds: float = 2.0, per_second: int = 500) -> BusTracker:
    """Read/reply pairs (14 + 15 bytes) at ``per_second``: 14.5 kB/s, 2.5 times what 57 600 baud carries."""
    tr = BusTracker(baud=baud, timestamps=True)
    for k in range(int(seconds * per_second)):
        t = k / per_second
        tr.feed(t, "host", READ)
        tr.feed(t + 0.0005, "dxl", REPLY)
    return tr


def shown(renderable, width: int = 80) -> str:
    console = Console(width=width, record=True, force_terminal=False, color_system=None, file=io.StringIO())
    console.print(renderable)
    return console.export_text()


def test_the_threshold():
    assert not is_unpaced(None) and not is_unpaced(1.0) and not is_unpaced(UNPACED_ABOVE)
    assert is_unpaced(0.2, 2.67)


def test_a_servo_line_faster_than_its_baud_is_unpaced_in_the_summary_and_the_dashboard():
    fast = summary(servo_line(57_600), source="bench")
    assert fast["bus"]["unpaced"] is True and fast["bus"]["load"] is None
    text = io.StringIO()
    print_summary(fast, Console(file=text, width=120, color_system=None))
    assert "unpaced" in text.getvalue() and "load" not in text.getvalue()
    header = shown(Dashboard(servo_line(57_600), source="bench").render(80, 24)).splitlines()[1]
    assert "unpaced" in header and "%" not in header
    # at 1 Mbaud the same traffic is 14.5 % of the line: a load
    paced = summary(servo_line(1_000_000), source="bench")
    assert paced["bus"]["unpaced"] is False and 0.14 < paced["bus"]["load"] < 0.15
    header = shown(Dashboard(servo_line(1_000_000), source="bench").render(80, 24)).splitlines()[1]
    assert "load  15%" in header


def test_a_can_bus_faster_than_its_bitrate_is_unpaced():
    tr = CanTracker(baud=10_000)  # 2 000 8-byte frames a second: about 26 times 10 kbit/s
    for k in range(4000):
        tr.feed(k / 2000, "rover", cf.pack(data_frame(0x182, bytes(8))))
    rep = can_summary(tr, source="bench")
    assert rep["bus"]["unpaced"] is True and rep["bus"]["load"] is None and rep["bus"]["peak_load"] is None
    text = io.StringIO()
    print_can(rep, Console(file=text, width=120, color_system=None))
    assert "bus unpaced" in text.getvalue() and "%" not in text.getvalue().splitlines()[1]
    header = shown(Dashboard(tr, source="bench").render(80, 24)).splitlines()[1]
    assert "unpaced" in header and "load" not in header
