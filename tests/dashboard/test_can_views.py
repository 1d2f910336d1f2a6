"""The CAN dashboard views rendered off-screen at 80x24: content, heights, keys."""

from __future__ import annotations

from rich.console import Console

from hilbench.dashboard import Dashboard
from hilbench.monitor.can.decoders import load_dbc
from hilbench.monitor.can.tracker import CanTracker
from hilbench.protocols import board_can as bc
from hilbench.protocols import can_frame as cf
from hilbench.protocols import canopen as co
from hilbench.protocols.can_frame import data_frame


def tracker() -> CanTracker:
    tr = CanTracker(baud=500_000, decoders=[load_dbc("mecarover-can")])
    t = 0.0
    tr.feed(t, "rover", cf.pack(data_frame(0x702, b"\x00")))
    for i in range(60):
        t = i * 0.02
        tr.feed(t, "rover", cf.pack(data_frame(0x182, bc.encode("encoders", enc_fr=i))))
        if i % 5 == 0:
            tr.feed(t, "rover", cf.pack(data_frame(0x282, bc.encode("odometry", x=i / 100, theta=0.1))))
        if i % 10 == 0:
            tr.feed(t, "rover", cf.pack(data_frame(0x702, b"\x05")))
    tr.feed(t, "rover", cf.pack(data_frame(0x082, co.emcy_frame(0x2310, 0x03))))
    tr.feed(t, "host", cf.pack(data_frame(0x602, co.initiate(0x40, 0x1018, 1))))
    tr.feed(t, "rover", cf.pack(data_frame(0x582, co.sdo_abort(0x1018, 1, co.ABORT_GENERAL))))
    return tr


def screen(dash: Dashboard, width: int = 80, height: int = 24) -> list[str]:
    console = Console(width=width, record=True, force_terminal=False, color_system=None)
    console.print(dash.render(width, height))
    return console.export_text().splitlines()


def test_views_fit_and_show_what_was_seen():
    dash = Dashboard(tracker(), source="bench mecarover-can")
    lines = screen(dash)
    assert len(lines) == 24 and all(len(line) <= 80 for line in lines)
    assert "hilbench monitor  bench mecarover-can" in lines[0] and "6 IDs  1 nodes" in lines[0]
    assert "load  1.6%" in lines[1]
    text = "\n".join(lines)
    assert "Identifiers" in text and "WheelEncoders_02" in text and "enc_fr=59" in text
    row = next(line for line in lines if line.startswith("0x182"))
    assert row.split()[2:5] == ["60", "50.0", "20.00"]  # count, Hz, period ms
    assert "aborted by server" in lines[-2]  # the newest problem
    dash.handle_key("2")
    text = "\n".join(screen(dash))
    assert "CANopen nodes" in text and "OPERATIONAL" in text and "0x2310" in text
    assert "abort 0x08000000" in text
    dash.handle_key("3")
    text = "\n".join(screen(dash))
    assert "Signals" in text and "0x082  EMCY_02" in text and "continuous over current" in text
    dash.handle_key("right")
    dash.handle_key("right")
    text = "\n".join(screen(dash))
    assert "0x282  OdometryPose_02" in text and "theta" in text and "period mean 100.00 ms" in text
    dash.handle_key("4")
    text = "\n".join(screen(dash))
    assert "Event log" in text and "boot-up" in text and "aborted by server" in text
