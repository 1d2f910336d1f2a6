"""The control channel under many, slow and leaving clients: nobody locks the others out, nothing outlives its
client, and the well-behaved `hilbench board status` / ControlClient is served throughout."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
import time

import pytest

from hilbench.bench import Bench
from hilbench.bench.control import MAX_CLIENTS, ControlClient, ControlServer
from hilbench.pytest_plugin import wait_until

NEVER = 2**31 - 1  # a report count the board never reaches: wait_report waits for its whole timeout


@pytest.fixture(scope="module")
def rover():
    bench = Bench("mecarover").start()
    bench.serve_control()
    yield bench
    bench.stop()


@pytest.fixture
def small(rover):
    """A second channel on the same bench with small limits (3 clients, 0.4 s per request, 1 s idle)."""
    server = ControlServer(rover, max_clients=3, request_timeout=0.4, idle_timeout=1.0)
    yield server
    server.close()


def commands_running() -> int:
    return sum(t.name == "hilbench-control-command" for t in threading.enumerate())


def ask(address, payload: bytes) -> dict:
    with socket.create_connection(address, timeout=10) as sock:
        sock.sendall(payload)
        return json.loads(sock.makefile("rb").readline())


def wait_report(address, timeout: float = 60.0) -> socket.socket:
    """A client whose wait_report runs (for up to ``timeout`` s) once this returns."""
    before = commands_running()
    sock = socket.create_connection(address, timeout=10)
    sock.sendall(json.dumps({"cmd": "wait_report", "timeout": timeout, "after": NEVER}).encode() + b"\n")
    wait_until(lambda: commands_running() > before, 5)
    return sock


def test_hundreds_of_slow_and_idle_clients_do_not_lock_out_the_cli(rover, tmp_path):
    address = rover.control.address
    manifest = tmp_path / "rover.json"
    manifest.write_text(json.dumps(rover.manifest()))
    idle = [socket.create_connection(address, timeout=10) for _ in range(150)]  # connect, say nothing
    slow = []
    for _ in range(150):  # half a request line each, then nothing (slowloris)
        sock = socket.create_connection(address, timeout=10)
        sock.sendall(b'{"cmd": "sta')
        slow.append(sock)
    try:
        t0 = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "hilbench.cli", "board", "--manifest", str(manifest), "status"],
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        assert "rover" in done.stdout
        assert ControlClient(rover.control.address_text).call("status")["ok"] is True
        assert time.monotonic() - t0 < 20
        assert rover.control.clients <= MAX_CLIENTS
        # the connections that gave way were told why, in the channel's own error format
        notice = json.loads(idle[0].makefile("rb").readline())
        assert notice["ok"] is False and f"at most {MAX_CLIENTS}" in notice["error"]
    finally:
        for sock in idle + slow:
            sock.close()


def test_a_half_sent_request_times_out_and_an_idle_connection_is_closed(small):
    with socket.create_connection(small.address, timeout=10) as stalled, \
            socket.create_connection(small.address, timeout=10) as idle:
        stalled.sendall(b'{"cmd": "dev')
        t0 = time.monotonic()
        reply = json.loads(stalled.makefile("rb").readline())
        assert reply == {"ok": False, "error": "request timed out (a request line must arrive within 0.4 s)"}
        assert 0.3 < time.monotonic() - t0 < 3
        assert stalled.recv(100) == b""
        assert idle.recv(100) == b""  # after idle_timeout, no message: it asked nothing
    assert small.stats["request_timeouts"] == 1 and small.stats["idle_closed"] == 1


def test_a_client_that_never_reads_its_replies_is_closed_and_costs_one_reply(small):
    with socket.socket() as greedy:
        greedy.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        greedy.connect(small.address)
        greedy.sendall(b'{"cmd": "manifest"}\n' * 5000)  # pipelined, never read
        wait_until(lambda: small.stats["reply_timeouts"] == 1, 10)
        # what the kernel buffers both ways, then one reply waited; the rest were never run
        assert small.stats["requests"] < 500
    assert ask(small.address, b'{"cmd": "devices"}\n')["ok"] is True


def test_wait_report_ends_when_its_client_leaves(rover):
    address = rover.control.address
    before = commands_running()
    clients = [wait_report(address) for _ in range(3)]
    assert commands_running() == before + 3
    for sock in clients:
        sock.close()
    wait_until(lambda: commands_running() == before, 5)  # not the 60 s they asked for
    assert ControlClient(rover.control.address_text).call("devices")["ok"] is True


def test_a_newcomer_is_refused_only_when_every_kept_client_runs_a_command(small):
    waiting = [wait_report(small.address) for _ in range(3)]
    try:
        reply = ask(small.address, b'{"cmd": "devices"}\n')
        assert reply == {"ok": False, "error": "too many control clients (at most 3, all running commands)"}
        assert small.stats["refused"] == 1
    finally:
        waiting.pop().close()
    wait_until(lambda: small.clients == 2, 5)
    assert ask(small.address, b'{"cmd": "devices"}\n')["ok"] is True
    for sock in waiting:
        sock.close()


def test_a_half_closed_client_still_gets_its_reply(small):
    with socket.create_connection(small.address, timeout=10) as sock:
        sock.sendall(b'{"cmd": "devices"}')  # no newline: the end of its input ends the request
        sock.shutdown(socket.SHUT_WR)
        reply = json.loads(sock.makefile("rb").readline())
    assert reply["ok"] is True and "rover" in reply["devices"]


def test_the_control_command_reports_the_limits_and_what_was_turned_away(small):
    ask(small.address, b"x" * 70_000)
    status = ControlClient(small.address_text).control()
    assert status["max_clients"] == 3 and status["request_timeout"] == 0.4 and status["too_long"] == 1
