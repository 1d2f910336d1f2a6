"""The control channel against malformed requests: always an error reply, never a traceback on stderr."""

from __future__ import annotations

import json
import socket

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilbench.bench import Bench
from hilbench.bench.control import MAX_CLIENTS, MAX_DEPTH, MAX_LINE, nesting
from hilbench.pytest_plugin import wait_until

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
#: Commands fuzzed with random arguments (wait_report is bounded separately: it may legally wait an hour).
COMMANDS = ["devices", "taps", "status", "button", "reset", "fault", "log", "nosuch", ""]


@pytest.fixture(scope="module")
def rover():
    bench = Bench("mecarover").start()
    bench.serve_control()
    yield bench
    bench.stop()


def request(address, payload: bytes, *, read: bool = True) -> bytes:
    with socket.create_connection(address, timeout=10) as sock:
        sock.sendall(payload)
        if not read:
            return b""
        return sock.makefile("rb").readline()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cmd=st.sampled_from(COMMANDS) | JSON, args=st.dictionaries(st.sampled_from(
    ["device", "knobs", "timeout", "after", "x"]), JSON, max_size=3))
def test_random_requests_get_a_json_reply(rover, cmd, args):
    reply = rover.control.handle(json.dumps({"cmd": cmd, **args}).encode())
    assert isinstance(reply, dict) and reply["ok"] in (True, False)
    if not reply["ok"]:
        assert isinstance(reply["error"], str) and "\n" not in reply["error"]
    json.dumps(reply, default=str)  # what the server sends


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=200) | JSON.map(lambda v: json.dumps(v).encode()))
def test_random_lines_get_an_error_not_an_exception(rover, raw):
    reply = rover.control.handle(raw)
    assert isinstance(reply, dict) and reply["ok"] in (True, False)


@pytest.mark.parametrize("timeout", ["x", -1, 1e400, [1], {"a": 1}, True, 3601])
def test_wait_report_arguments_are_checked(rover, timeout):
    reply = rover.control.handle(json.dumps({"cmd": "wait_report", "timeout": timeout}).encode())
    assert reply["ok"] is False and "wait_report: timeout: expected a number 0..3600" in reply["error"]
    reply = rover.control.handle(json.dumps({"cmd": "wait_report", "timeout": 0, "after": "x"}).encode())
    assert reply["ok"] is False and "after: expected an integer" in reply["error"]


def test_nesting_is_bounded_before_parsing(rover):
    assert nesting(b'{"a": [1, {"b": "[[[[["}]}') == 3
    deep = b"[" * 100_000 + b"]" * 100_000
    assert rover.control.handle(deep[:MAX_LINE])["error"] == f"request nested too deeply (at most {MAX_DEPTH} levels)"
    ok = b'{"cmd": "devices", "x": ' + b"[" * (MAX_DEPTH - 1) + b"]" * (MAX_DEPTH - 1) + b"}"
    assert rover.control.handle(ok)["ok"] is True


def test_the_socket_survives_everything_and_stderr_stays_clean(rover, capfd):
    address = rover.control.address
    cases = [
        b"[" * 60_000 + b"\n",  # deeply nested
        b"\xff\xfe\x00garbage\n",  # not UTF-8
        b"x" * (MAX_LINE + 10),  # too long, no newline
        b'{"cmd": "status"}',  # no newline, then the client leaves
        b"1e999999\n",
        b'{"cmd": "status", "device": ["list"]}\n',
        b'{"cmd": "fault", "knobs": {"drop_rate": 2}}\n',
        b'{"cmd": "fault", "knobs": {"stall": -1}}\n',
        b'{"cmd": "fault", "knobs": [1, 2]}\n',
    ]
    for payload in cases:
        reply = request(address, payload, read=payload.endswith(b"\n") or len(payload) > MAX_LINE)
        if reply:
            doc = json.loads(reply)
            assert doc["ok"] is False and doc["error"]
    # clients that leave before the reply, in the middle of a long line, or after a reset
    for payload in (b'{"cmd": "status"}\n', b"x" * 10_000):
        request(address, payload, read=False)
    with socket.create_connection(address, timeout=10) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")  # RST on close
        sock.sendall(b'{"cmd": "status"}\n')
    # more clients than the bench keeps at once: each newcomer is served, the connection that waited longest
    # gives way (and is told so in a JSON error line)
    wait_until(lambda: rover.control.clients == 0, 5)  # the connections above are gone (none gives way below)
    held = [socket.create_connection(address, timeout=10) for _ in range(MAX_CLIENTS)]
    for sock in held:
        sock.sendall(b'{"cmd": "devices"}\n')
        assert json.loads(sock.makefile("rb").readline())["ok"] is True
    try:
        extra = request(address, b'{"cmd": "devices"}\n')
        assert json.loads(extra)["ok"] is True
        notice = json.loads(held[0].makefile("rb").readline())
        assert notice["ok"] is False and "at most" in notice["error"] and "waited longest" in notice["error"]
    finally:
        for sock in held:
            sock.close()
    reply = json.loads(request(address, b'{"cmd": "devices"}\n'))
    expected = {name: list(rover.family_of(name).control_commands) for name in rover.devices
                if rover.family_of(name).control_commands}
    assert "rover" in expected and reply == {"ok": True, "devices": expected, "endpoints": {}}
    assert json.loads(request(address, b'{"cmd": "status"}\n'))["ok"] is True
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Error" not in err, err
