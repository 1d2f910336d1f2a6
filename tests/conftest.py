"""Shared test helpers: where the test data lives (in the repository, so a fresh clone has it)."""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "tests" / "data"
#: The raw Wolfgang bus capture (MIT/Apache-2.0; see tests/data/dynamixel/README.md).
WOLFGANG_TRACE = DATA / "dynamixel" / "wolfgang_trace.bin"


@pytest.fixture(scope="session")
def wolfgang_capture() -> bytes:
    """The raw Wolfgang bus capture's bytes."""
    return WOLFGANG_TRACE.read_bytes()


@pytest.fixture
def patient_sdk(monkeypatch):
    """Official SDK reply timeouts of ~200 ms instead of ~35 ms (spec §7.2: LATENCY_TIMER is read at call time).

    For tests about bytes and state, not timing, that run the SDK next to other busy threads or
    processes on a loaded 2-core machine.
    """
    import dynamixel_sdk.port_handler as port_handler

    monkeypatch.setattr(port_handler, "LATENCY_TIMER", 100)


@pytest.fixture
def official_sdk(bench, patient_sdk):
    """``open(protocol)``: the official SDK's PortHandler on the bench's only endpoint, opened at the
    endpoint's baud, and its PacketHandler for ``protocol`` (1.0 or 2.0); closed at the end."""
    import dynamixel_sdk as sdk

    ports = []

    def open_(protocol: float):
        port = sdk.PortHandler(bench.endpoint().path)
        assert port.openPort() and port.setBaudRate(bench.endpoint().spec.baud)
        ports.append(port)
        return port, sdk.PacketHandler(protocol)

    yield open_
    for port in ports:
        port.closePort()


def interrupt(proc: subprocess.Popen, timeout: float = 20) -> tuple[str, str]:
    """Ctrl-C a hilbench command and collect its output; one that does not end within ``timeout`` fails
    with every thread's stack (the CLI dumps them on SIGUSR1), so a hang says where it is."""
    proc.send_signal(signal.SIGINT)
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)
        try:
            proc.communicate(timeout=2)
        except subprocess.TimeoutExpired:
            pass
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"{proc.args} did not end within {timeout} s of SIGINT; stderr:\n{err}") from None
