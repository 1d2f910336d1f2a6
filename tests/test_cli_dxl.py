"""``hilbench dxl`` on a Protocol 1.0 bus: --protocol on every tool, and the scan's progress on a terminal."""

from __future__ import annotations

import io
import json
import os
import threading
from pathlib import Path

import pytest

from hilbench.cli import main
from hilbench.cli.dynamixel import ScanCounter, found_line

PROFILE = str(Path(__file__).resolve().parent / "data" / "protocol1_bus.toml")
pytestmark = pytest.mark.hilbench_profile(PROFILE)


def dxl(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["dxl", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_read_and_write_speak_protocol_1(bench, capsys, patient_sdk):
    path = bench.endpoint().path
    p1 = ("--baud", "1000000", "--protocol", "1")
    code, out, _ = dxl(capsys, "read", path, "3", "model_number", *p1, "--json")
    assert code == 0 and json.loads(out)["value"] == 29  # the MX-28 with 1.0 firmware
    assert dxl(capsys, "write", path, "3", "goal_position", "2000", *p1)[0] == 0
    code, out, _ = dxl(capsys, "read", path, "3", "30", "2", *p1, "--json")
    assert json.loads(out)["value"] == 2000
    code, out, _ = dxl(capsys, "ping", path, "1", *p1)
    assert out.strip() == "ID 1: AX-12A (model 12), firmware 24"  # the firmware read at the model's address
    # a goal beyond the angle limits (1024..3072): the servo clamps it and sets the angle limit bit
    code, _, err = dxl(capsys, "write", path, "3", "goal_position", "4000", *p1)
    assert code == 1 and err.splitlines() == [
        "hilbench: error: write ID 3 address 30: device reports angle limit error"]
    # Protocol 2.0 (the default) gets no answer from a Protocol 1.0 bus
    code, _, err = dxl(capsys, "read", path, "3", "model_number", "--baud", "1000000")
    assert code == 1 and "no status packet" in err


def test_scan_shows_progress_on_a_terminal_and_says_what_it_found(bench, capsys, monkeypatch):
    import dynamixel_sdk.port_handler as port_handler

    # Protocol 1.0 has no broadcast ping: 253 pings; a 10 ms reply timeout keeps this test short
    monkeypatch.setattr(port_handler, "LATENCY_TIMER", 4)
    master, slave = os.openpty()
    tty = open(slave, "w", buffering=1)  # noqa: SIM115 (closed below)
    shown = bytearray()
    reader = threading.Thread(target=_drain, args=(master, shown))  # a terminal reads as it is written
    reader.start()
    monkeypatch.setattr("sys.stderr", tty)
    try:
        code = main(["dxl", "scan", bench.endpoint().path, "--baud", "1000000", "--protocol", "1"])
    finally:
        tty.close()
        reader.join(timeout=10)
        os.close(master)
    out = capsys.readouterr().out
    assert code == 0
    assert out.splitlines()[-1] == "5 devices: 5 at 1000000 baud"
    assert all(f" {i} " in out for i in range(1, 6))
    text = shown.decode()
    assert "scanning at 1000000 baud: ID 0/252, 0 found" in text  # the counter, rewritten in place
    assert text.endswith("\r\x1b[K")  # and cleared when the scan ends


def _drain(fd: int, into: bytearray) -> None:
    while True:
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # EIO: the terminal's other side closed
            return
        if not chunk:
            return
        into += chunk


def test_scan_counter_stays_silent_off_a_terminal():
    stream = io.StringIO()
    counter = ScanCounter(stream)
    counter(57_600, 0, 0)
    counter(57_600, None, 3)
    counter.close()
    assert stream.getvalue() == ""


def test_found_line():
    from hilbench.clients.dynamixel import Found

    found = [Found(1, 12, 24, 57_600), Found(2, 12, 24, 57_600), Found(9, 29, 40, 1_000_000)]
    assert found_line(found, (57_600, 115_200, 1_000_000)) == "3 devices: 2 at 57600 baud, 1 at 1000000 baud"
    assert found_line(found[:1], (57_600,)) == "1 device: 1 at 57600 baud"
    assert found_line([], (57_600, 9_600)) == "no device answered at 57600, 9600 baud"


def test_a_scan_nobody_answers_is_status_1_in_either_form(capsys):
    """No device answered: one error line and status 1, as text and as --json (whose stdout stays one document,
    an empty list)."""
    import pty
    import tty

    master, slave = pty.openpty()
    tty.setraw(slave)
    try:
        path = os.ttyname(slave)
        code, out, err = dxl(capsys, "scan", path, "--baud", "1000000")
        assert (code, out, err) == (1, "", "hilbench: error: no device answered at 1000000 baud\n")
        code, out, err = dxl(capsys, "scan", path, "--baud", "1000000", "--json")
        assert (code, json.loads(out), err) == (1, [], "hilbench: error: no device answered at 1000000 baud\n")
    finally:
        os.close(master)
        os.close(slave)
