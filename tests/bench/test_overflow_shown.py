"""A bench's bounded queues show what they turned away where a user looks (issue 23, "Memory"): the control
channel's ``status`` (and ``overflow``), the manifest's limits and ``hilbench monitor``'s ``bench`` line.

Each test floods a real bench (``hilbench emulate`` in its own process) over real sockets and checks that a
counter the flood makes non-zero is shown: without the key these tests fail."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from urllib.parse import urlparse

import serial

from hilbench.bench import control
from hilbench.bench.control import ControlClient, control_overflow
from hilbench.cli.monitor import _BenchStatus
from hilbench.protocols import vel2d
from hilbench.pytest_plugin import wait_until
from hilbench.transports import rfc2217, tap_server


def _tap(endpoint: dict, read: bool) -> socket.socket:
    """A client of an endpoint's traffic tap; one that never reads keeps a small receive buffer (it fills soon)."""
    url = urlparse(endpoint["tap"])
    sock = socket.socket()
    if not read:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((url.hostname, url.port))
    return sock


def _flood(endpoint: dict, seconds: float) -> int:
    """Vel2d datagrams into the rover board's UDP door as fast as this process sends them (~20x the UART's pace)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    frame, sent = vel2d.build(0.1, 0.0, 0.0), 0
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            for _ in range(200):
                try:
                    sock.sendto(frame, (endpoint["host"], endpoint["port"]))
                    sent += 1
                except OSError:  # (the kernel's buffers are full)
                    pass
    finally:
        sock.close()
    return sent


def _monitor(source: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", "monitor", source, *args], capture_output=True,
                          text=True, timeout=60)


def test_status_carries_the_overflow_of_a_flood_and_of_a_tap_client_that_never_reads(hilbench_emulator):
    """The board's ``status`` keeps its keys and adds the bench's ``overflow``: the tap's bytes dropped for a
    client that never reads, the board's receive FIFO overruns; ``overflow ENDPOINT`` says the same alone."""
    bench = hilbench_emulator("mecarover-udp")
    ep = bench["endpoints"][0]
    client = ControlClient(bench["control"])
    before = client.call("status")
    assert set(before) == {"ok", "status", "overflow"} and "truth" in before["status"]  # the board's, unchanged
    quiet = before["overflow"]["endpoints"][ep["name"]]
    assert quiet["tap"]["bytes_dropped"] == 0 and quiet["devices"]["rover"]["rx_overruns"] == 0
    assert quiet["tap"]["max_buffer"] == tap_server.MAX_BUFFER and quiet["tap"]["max_clients"] == tap_server.MAX_CLIENTS
    assert before["overflow"]["control"]["max_clients"] == control.MAX_CLIENTS

    unread = _tap(ep, read=False)
    try:
        _flood(ep, 1.5)
        after = client.call("status")["overflow"]["endpoints"][ep["name"]]
        assert after["tap"]["bytes_dropped"] > 0, after
        assert after["devices"]["rover"]["rx_overruns"] > 0, after
        assert after["devices"]["rover"]["limits"]["rx_fifo_bytes"] == bench["devices"][0]["rx_fifo"]["bytes"]
        alone = client.overflow(ep["name"])
        assert list(alone["endpoints"]) == [ep["name"]]
        assert alone["endpoints"][ep["name"]]["tap"]["bytes_dropped"] >= after["tap"]["bytes_dropped"]
    finally:
        unread.close()


def test_the_manifest_limits_are_the_ones_the_servers_enforce(hilbench_emulator):
    """``tap_limits``, ``rfc2217_limits`` and ``control_limits`` are the code's own bounds: one client beyond
    each limit is refused, and the refusal is counted in ``overflow``."""
    bench = hilbench_emulator("arm", "--serve", "rfc2217")
    ep = bench["endpoints"][0]
    assert ep["tap_limits"] == {"max_clients": tap_server.MAX_CLIENTS, "max_buffer": tap_server.MAX_BUFFER,
                                "read_grace_s": tap_server.READ_GRACE, "stall_timeout_s": tap_server.STALL_TIMEOUT,
                                "send_buffer": tap_server.SEND_BUFFER}
    assert ep["rfc2217_limits"]["max_clients"] == 1 and ep["rfc2217_limits"]["max_held"] == rfc2217.MAX_HELD
    assert bench["control_limits"]["max_line"] == control.MAX_LINE
    assert bench["control_limits"]["max_clients"] == control.MAX_CLIENTS
    client = ControlClient(bench["control"])

    # The tap: max_clients clients that read keep their places; the next one reads the refusal.
    readers = [_tap(ep, read=True) for _ in range(ep["tap_limits"]["max_clients"])]
    try:
        for sock in readers:
            sock.settimeout(5)
            assert sock.recv(4096)  # the capture header: read, so the client is not let go for a newcomer
        extra = _tap(ep, read=True)
        extra.settimeout(5)
        assert extra.recv(4096).startswith(tap_server.REFUSAL_PREFIX)
        extra.close()
        assert client.overflow(ep["name"])["endpoints"][ep["name"]]["tap"]["refused"] == 1
    finally:
        for sock in readers:
            sock.close()

    # RFC 2217: one client, as a real port; the second is told who holds it.
    first = serial.serial_for_url(ep["rfc2217"], timeout=1)
    try:
        url = urlparse(ep["rfc2217"])
        second = socket.create_connection((url.hostname, url.port))
        second.settimeout(5)
        assert b"port busy" in second.recv(4096)
        second.close()
        wait_until(lambda: client.overflow(ep["name"])["endpoints"][ep["name"]]["rfc2217"]["refused"] == 1, 5)
    finally:
        first.close()

    # The control channel: a line longer than max_line is answered and counted.
    host, port = bench["control"].rsplit(":", 1)
    with socket.create_connection((host, int(port))) as sock:
        sock.sendall(b"x" * (bench["control_limits"]["max_line"] + 1))
        sock.settimeout(5)
        assert b"too long" in sock.recv(4096)
    assert client.overflow()["control"]["too_long"] == 1


def test_monitor_ends_its_summary_with_the_benchs_overflow(hilbench_emulator):
    """``monitor MANIFEST#ENDPOINT --json`` / ``--summary`` end with the endpoint's overflow, asked of the bench
    when the summary is printed; the dashboard's status shows it once non-zero; a bench that is gone is left out."""
    bench = hilbench_emulator("mecarover-can")
    ep = next(e for e in bench["endpoints"] if e["name"] == "can")
    source = f"{bench['manifest_path']}#{ep['name']}"
    door = ep["socketcand"]
    with socket.create_connection((door["host"], door["port"])) as hostile:
        hostile.settimeout(5)
        huge = "9" * 400
        hostile.sendall(f"< open can0 >< add 1 {huge} 123 1 aa >< add 1 {huge} 124 1 aa >".encode())
        got = b""
        while got.count(b"out of range") < 2:
            got += hostile.recv(4096)

    # The dashboard's status line (asked in the background, shown once a counter is non-zero).
    status = _BenchStatus(lambda: control_overflow(bench["control"], ep["name"]))
    line = wait_until(lambda: status(), 5)
    assert line == f"bench {ep['name']} overflow: socketcand.out_of_range 2", line

    done = _monitor(source, "--json", "--seconds", "0.5")
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)["bench"]
    assert shown["endpoint"] == ep["name"] and shown["socketcand"]["out_of_range"] == 2, shown
    assert shown["tap"]["bytes_dropped"] == 0 and shown["tap"]["max_clients"] == tap_server.MAX_CLIENTS
    text = _monitor(source, "--summary", "--seconds", "0.5")
    assert text.returncode == 0, text.stderr
    assert text.stdout.strip().splitlines()[-1] == f"bench {ep['name']} overflow: socketcand.out_of_range 2"

    # A bench that is gone (killed: its tap ends the stream, its control channel refuses): no bench line.
    watcher = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "monitor", source, "--json"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = ControlClient(bench["control"])
    wait_until(lambda: client.taps()[ep["name"]]["clients"] == 1, 20)  # the monitor is watching
    bench["process"].send_signal(signal.SIGKILL)
    out, err = watcher.communicate(timeout=30)
    assert watcher.returncode == 0, err
    report = json.loads(out)
    assert report["protocol"] == "can" and "bench" not in report and "Traceback" not in err, err


def test_monitor_of_an_in_process_bench_shows_its_overflow():
    """``monitor bench:PROFILE``: the endpoint's counters come from the bench in this process."""
    done = _monitor("bench:mecarover-can", "--json", "--seconds", "0.5")
    assert done.returncode == 0, done.stderr
    shown = json.loads(done.stdout)["bench"]
    assert shown["endpoint"] == "can" and shown["socketcand"]["out_of_range"] == 0
    assert shown["socketcand"]["max_clients"] == 64
