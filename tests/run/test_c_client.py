"""A compiled client (plain libc calls, as C/C++ drivers make them) under `hilbench run`: its modem-line
ioctls, breaks, flush and 8E1 framing reach a device on the bench, in order; it reads back the lines the
device drives; other ptys and an unreachable bench leave it with a plain pty's behaviour."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import termios
from pathlib import Path

import pytest

from hilbench.run.build import shim_library
from tests.run.port_event_recorder import (
    BreakCondition,
    ModemSignals,
    OutputFlushed,
    PortEventRecorder,
    SerialSettings,
)

pytestmark = [pytest.mark.slow, pytest.mark.skipif(shutil.which("cc") is None,
                                                   reason="no C compiler (cc): the test client cannot be built")]
SOURCE = Path(__file__).parent / "clients" / "modem_client.c"
SIZE = 3000
PAYLOAD = bytes(0x41 + i % 26 for i in range(SIZE))


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> str:
    exe = tmp_path_factory.mktemp("c-client") / "modem_client"
    subprocess.run(["cc", "-O1", "-Wall", "-o", str(exe), str(SOURCE)], check=True, capture_output=True)
    return str(exe)


@pytest.fixture
def other_pty():
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(master)
    os.close(slave)


def results(stdout: str) -> dict[str, tuple[int, int, int]]:
    out = {}
    for line in stdout.splitlines():
        name, rc, err, value = line.split()
        out[name] = (int(rc), int(err), int(value))
    return out


def test_c_client_under_hilbench_run(hilbench_bench, hilbench_run, client, other_pty):
    bench = hilbench_bench("arm")
    ep = bench.endpoint()
    rec = PortEventRecorder().attach(ep)
    cmd = hilbench_run.command(bench, client, ep.path, other_pty, str(SIZE), shim="c")
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    got = results(proc.stdout)
    assert all(got[name][:2] == (0, 0) for name in got if name != "other-TIOCMGET"), got
    # Both lines cleared: the device answered with CTS, DSR and CD before TIOCMGET asked.
    assert got["TIOCMGET"][2] == termios.TIOCM_CTS | termios.TIOCM_DSR | termios.TIOCM_CAR
    assert got["parenb"][2] == 1  # it reads back the parity it set, which the pty itself forgot
    assert got["other-TIOCMGET"][:2] == (-1, errno.ENOTTY)  # not a bench pty: untouched
    assert rec.sequence() == [
        SerialSettings(115_200, 8, "E", 1.0),
        ModemSignals(False, True), ModemSignals(False, False), ModemSignals(True, False), ModemSignals(False, True),
        BreakCondition(True, 0.25), BreakCondition(True), BreakCondition(False),
        PAYLOAD,  # every byte, although tcflush(TCOFLUSH) came right after the write
        OutputFlushed(),
    ]


def test_c_client_without_hilbench_run_sees_a_plain_pty(hilbench_bench, client, other_pty):
    bench = hilbench_bench("arm", port_state=False)
    rec = PortEventRecorder().attach(bench.endpoint())
    proc = subprocess.run([client, bench.endpoint().path, other_pty, str(SIZE)], capture_output=True, text=True,
                          timeout=60)
    got = results(proc.stdout)
    for name in ("TIOCMBIC-dtr", "TIOCMBIC-rts", "TIOCMGET", "TIOCMBIS-dtr", "TIOCMSET-rts"):
        assert got[name][:2] == (-1, errno.ENOTTY)
    assert got["tcflush"][0] == 0 and got["parenb"][2] == 0
    assert not [e for e in rec.events() if not isinstance(e, SerialSettings)]


def test_shim_fails_open_when_the_bench_is_gone(hilbench_bench, client, other_pty, tmp_path):
    bench = hilbench_bench("arm", port_state=False)
    rdev = bench.endpoint().port.rdev
    env = {**os.environ, "LD_PRELOAD": str(shim_library()),
           "HILBENCH_RUN_PORTS": f"{rdev}={tmp_path / 'gone.sock'}"}
    proc = subprocess.run([client, bench.endpoint().path, other_pty, str(SIZE)], capture_output=True, text=True,
                          timeout=60, env=env)
    assert proc.returncode == 0
    got = results(proc.stdout)
    assert got["TIOCMGET"][:2] == (-1, errno.ENOTTY)  # what a pty answers: the real call ran
    assert got["tcflush"][0] == 0 and got["write"] == (0, 0, SIZE)
