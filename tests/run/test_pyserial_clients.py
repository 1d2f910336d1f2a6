"""A pyserial client in its own process under `hilbench run`, through the preload shim and through the
Python fallback: DTR/RTS, CTS/DSR/RI/CD, reset_output_buffer after a write and send_break reach the
bench. Without `hilbench run` the same client still runs, with what pyserial gives on any pty."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.run.port_event_recorder import (
    BreakCondition,
    ModemSignals,
    OutputFlushed,
    PortEventRecorder,
    SerialSettings,
)

CLIENT = str(Path(__file__).parent / "clients" / "pyserial_client.py")
SIZE = 3000
PAYLOAD = bytes(0x41 + i % 26 for i in range(SIZE))
SHIMS = [pytest.param("c", marks=pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc)")),
         "python"]


def run_client(cmd: list[str], **kwargs) -> dict:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60, **kwargs)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.mark.parametrize("shim", SHIMS)
def test_pyserial_client_under_hilbench_run(hilbench_bench, hilbench_run, shim):
    bench = hilbench_bench("arm")
    ep = bench.endpoint()
    rec = PortEventRecorder().attach(ep)
    out = run_client(hilbench_run.command(bench, sys.executable, CLIENT, ep.path, str(SIZE), shim=shim))
    assert out == {"shim": shim, "dtr": None, "rts": None, "lines": [True, True, False, True], "break": None}
    assert rec.sequence() == [
        SerialSettings(57_600),
        ModemSignals(False, True), ModemSignals(False, False),
        PAYLOAD,  # reset_output_buffer() right after write(): on an adapter the bytes are already out
        OutputFlushed(),
        BreakCondition(True, 0.1),  # pyserial's send_break(0.25) is tcsendbreak(fd, 1): glibc's 0.1 s
    ]


def test_pyserial_client_without_hilbench_run(hilbench_bench):
    bench = hilbench_bench("arm", port_state=False)
    rec = PortEventRecorder().attach(bench.endpoint())
    out = run_client([sys.executable, CLIENT, bench.endpoint().path, str(SIZE)])
    # As on any pty: pyserial's modem-line calls fail with ENOTTY (pyserial ignores that only inside
    # open()), BREAK and the flush succeed without effect; the bytes that were not flushed away arrive.
    assert out == {"shim": None, "dtr": "errno 25", "rts": "errno 25", "lines": "errno 25", "break": None}
    assert not [e for e in rec.events() if not isinstance(e, SerialSettings)]
    assert PAYLOAD.startswith(rec.received())


def test_against_hilbench_emulate(hilbench_emulator, hilbench_run):
    manifest = hilbench_emulator("arm")
    path = manifest["endpoints"][0]["path"]
    assert manifest["port_state"]["ports"]["arm"]["path"] == path
    out = run_client(hilbench_run.command(manifest, sys.executable, CLIENT, path, str(SIZE), shim="python"))
    assert out == {"shim": "python", "dtr": None, "rts": None, "lines": [False, False, False, False],
                   "break": None}


def test_python_fallback_keeps_an_existing_sitecustomize(hilbench_bench, hilbench_run, tmp_path):
    (tmp_path / "sitecustomize.py").write_text("import os\nos.environ['THEIRS'] = 'ran'\n")
    bench = hilbench_bench("arm")
    env = hilbench_run.env(bench, shim="python")
    env["PYTHONPATH"] += f":{tmp_path}"
    code = ("import os, serial, sys; s = serial.Serial(sys.argv[1]); s.dtr = False; "
            "print(os.environ.get('THEIRS'), s.cts)")
    proc = subprocess.run([sys.executable, "-c", code, bench.endpoint().path], capture_output=True, text=True,
                          env=env, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["ran", "False"]
    assert bench.endpoint().port.port_state.dtr is False


def test_in_process_pyserial_against_an_emulator(hilbench_emulator):
    import serial

    path = hilbench_emulator("arm")["endpoints"][0]["path"]
    with serial.Serial(path, 1_000_000) as ser:
        ser.dtr = False  # ENOTTY on a plain pty; the emulator's port-state server takes it
        assert ser.cts is False
        ser.write(b"x" * 100)
        ser.reset_output_buffer()
