"""A bench keeps serving whatever its clients send: hostile input gets the protocol's error and no traceback, a
client limit or the end of the process's descriptors refuses newcomers cleanly, and memory stays bounded.

Each test runs ``hilbench emulate`` in its own process, as a shared bench runs, and reads its stderr."""

from __future__ import annotations

import json
import os
import resource
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.bench.control import ControlClient
from hilbench.protocols import socketcand as sc
from hilbench.pytest_plugin import wait_until
from tests.conftest import interrupt


def _emulate(tmp_path: Path, *args: str, nofile: int | None = None) -> tuple[subprocess.Popen, dict]:
    """``hilbench emulate ARGS`` (its descriptor limit lowered to ``nofile``); returns it and its manifest."""
    manifest = tmp_path / "bench.json"

    def limit() -> None:
        if nofile is not None:
            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", *args, "--manifest", str(manifest)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=limit,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        wait_until(lambda: manifest.exists() or proc.poll() is not None, timeout=30)
        assert proc.poll() is None, proc.communicate()[1]
        return proc, json.loads(manifest.read_text())
    except BaseException:
        proc.kill()
        proc.communicate()
        raise


def _socketcand(manifest: dict) -> tuple[str, int]:
    door = next(ep["socketcand"] for ep in manifest["endpoints"] if ep.get("socketcand"))
    return door["host"], door["port"]


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _python_can_works(address: tuple[str, int]) -> None:
    import can

    bus = can.Bus(interface="socketcand", host=address[0], port=address[1], channel="can0")
    try:
        bus.send(can.Message(arbitration_id=0x7E5, data=[1], is_extended_id=False))
    finally:
        bus.shutdown()


class _Messages:
    """Whole socketcand messages from a socket, however TCP cut or joined them."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.splitter = sc.MessageSplitter()
        self.pending: list[str] = []

    def read(self, timeout: float = 5.0) -> str:
        self.sock.settimeout(timeout)
        while not self.pending:
            chunk = self.sock.recv(256)
            if not chunk:
                return ""
            self.pending += self.splitter.feed(chunk)
        return self.pending.pop(0)


def test_hostile_socketcand_input_is_answered_and_leaves_no_traceback(tmp_path):
    proc, manifest = _emulate(tmp_path, "mecarover-can", "--paced")
    try:
        address = _socketcand(manifest)
        client = socket.create_connection(address)
        replies = _Messages(client)
        assert replies.read() == sc.HI
        huge = "9" * 400
        client.sendall(f"< open can0 >< add {huge} 0 123 1 aa >< subscribe 0 {huge} 123 >< filter {huge} 0 123 1 ff >"
                       f"< muxfilter 0 0 {huge} >".encode())
        assert [replies.read() for _ in range(5)] == [sc.OK, "< error interval out of range >", "< error interval out of range >",
                           "< error interval out of range >", "< error identifier out of range >"]
        client.sendall(f"< controlmode >< statistics {huge} >".encode())
        assert [replies.read() for _ in range(2)] == [sc.OK, "< error statistics interval out of range >"]
        # Counted, and shown where a user looks at the bus (`hilbench can bus`: the socketcand door's counters).
        shown = subprocess.run([sys.executable, "-m", "hilbench.cli", "can", "bus", "--manifest",
                                str(tmp_path / "bench.json"), "--compact"], capture_output=True, text=True, timeout=60)
        door = json.loads(shown.stdout)["bus"]["doors"]["socketcand"]
        assert door["out_of_range"] == 5 and door["clients"] == 1 and door["max_clients"] == 64, door
        # A cyclic job of 1 us, and the client leaves: the bus must go on greeting clients (it went deaf for a
        # minute at 100 % CPU) and end the job with its client.
        client.sendall(b"< bcmmode >< add 0 1 123 8 1 2 3 4 5 6 7 8 >")
        assert replies.read() == sc.OK
        time.sleep(0.2)
        client.close()
        t0 = time.monotonic()
        other = socket.create_connection(address)
        assert _Messages(other).read(timeout=2) == sc.HI
        assert time.monotonic() - t0 < 1
        other.close()
        time.sleep(0.3)  # the job's client is gone by now: the bus idles
        cpu0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(1.0)
        assert (_cpu_seconds(proc.pid) - cpu0) / (time.monotonic() - t0) < 0.3
        _python_can_works(address)
    finally:
        _, err = interrupt(proc)
    assert "Traceback" not in err and "Error" not in err, err


def test_a_bench_out_of_descriptors_refuses_newcomers_and_keeps_serving(tmp_path):
    # 80 descriptors: the bench starts with some 20 open, so about 60 clients fit; the rest find accept() failing
    # with EMFILE, which left the connection pending and the listener readable: a thread waiting on it spun.
    proc, manifest = _emulate(tmp_path, "mecarover-can", "--paced", nofile=80)
    try:
        address = _socketcand(manifest)
        clients = [socket.create_connection(address) for _ in range(120)]
        answers = [_Messages(c).read() for c in clients]
        assert answers.count(sc.HI) >= 10
        assert set(answers) == {sc.HI, "< error too many clients >"}  # each one told, none left hanging
        cpu0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(1.0)
        assert (_cpu_seconds(proc.pid) - cpu0) / (time.monotonic() - t0) < 0.3  # no thread spins
        for c in clients:
            c.close()
        wait_until(lambda: _try(_python_can_works, address), timeout=10)
        door = ControlClient(manifest["control"]).media()["can"]["host"]["socketcand"]
        assert door["out_of_descriptors"] > 0 and door["accepted"] == answers.count(sc.HI) + 1
    finally:
        _, err = interrupt(proc)
    assert "Traceback" not in err and "Error" not in err, err


def _try(fn, *args) -> bool:
    try:
        fn(*args)
    except Exception:  # noqa: BLE001 (not yet)
        return False
    return True


@pytest.mark.slow  # ~10 s of telnet commands parsed on a loaded 2-core machine; the fast check is in test_rfc2217
def test_an_ayt_flood_from_a_client_that_reads_nothing_keeps_memory_bounded(tmp_path):
    proc, manifest = _emulate(tmp_path, "wolfgang", "--serve", "rfc2217")
    try:
        host, port = manifest["endpoints"][0]["rfc2217"].split("//")[1].rsplit(":", 1)
        client = socket.socket()
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        client.connect((host, int(port)))
        before = _rss_mb(proc.pid)
        block = b"\xff\xf6" * (1 << 19)  # 1 MiB of IAC AYT (each one was answered into an unbounded queue)
        peak = before
        for _ in range(8):
            client.sendall(block)
            peak = max(peak, _rss_mb(proc.pid))
        assert peak - before < 16  # it grew by 8.6 MB per MiB before
        client.close()
    finally:
        _, err = interrupt(proc)
    assert "Traceback" not in err, err


#: The bench is started with descriptors 3 to this number taken, so every socket, pty and pipe it opens is
#: numbered above select()'s FD_SETSIZE (1024), as after ~1 000 idle connections.
_TAKEN_BELOW = 1100

#: Runs the bench with descriptors 3 .. _TAKEN_BELOW - 1 open on /dev/null (inheritable, so they survive exec).
_HIGH_FDS = ("import os, resource, sys\n"
             "resource.setrlimit(resource.RLIMIT_NOFILE, (2048, max(2048, resource.getrlimit(resource.RLIMIT_NOFILE)[1])))\n"
             "null = os.open(os.devnull, os.O_RDONLY)\n"
             f"for fd in range(3, {_TAKEN_BELOW}):\n"
             "    if fd != null:\n"
             "        os.dup2(null, fd, inheritable=True)\n"
             "os.execv(sys.executable, [sys.executable, '-m', 'hilbench.cli', *sys.argv[1:]])\n")


def _tcp(url: str) -> tuple[str, int]:
    """``tcp://HOST:PORT`` as an address."""
    host, port = url.split("//")[1].rsplit(":", 1)
    return host, int(port)


def _emulate_high(tmp_path: Path, *args: str) -> tuple[subprocess.Popen, dict]:
    """``hilbench emulate ARGS`` with descriptors 3 .. 1099 taken before it starts; checks that every socket the
    bench opened is numbered beyond them."""
    manifest_path = tmp_path / "bench.json"
    proc = subprocess.Popen([sys.executable, "-c", _HIGH_FDS, "emulate", *args, "--manifest", str(manifest_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        wait_until(lambda: manifest_path.exists() or proc.poll() is not None, timeout=30)
        assert proc.poll() is None, proc.communicate()[1]
        sockets = [int(fd) for fd in os.listdir(f"/proc/{proc.pid}/fd")
                   if os.readlink(f"/proc/{proc.pid}/fd/{fd}").startswith("socket:")]
        assert sockets and min(sockets) >= _TAKEN_BELOW  # (the test does what it says)
        return proc, json.loads(manifest_path.read_text())
    except BaseException:
        proc.kill()
        proc.communicate()
        raise


def test_every_server_serves_descriptors_numbered_beyond_1023(tmp_path):
    # ~1 035 idle socketcand connections once killed the CAN thread (select(): "filedescriptor out of range"), and
    # 1 050 tap connections then an RFC 2217 connect the serial line's. No thread may wait with select(): here
    # every descriptor the bench opens is numbered 1100 or more, and each server and line must still serve.
    import can
    import serial

    from hilbench.protocols import rplidar

    proc, manifest = _emulate_high(tmp_path, "mecarover-can", "--paced", "--serve", "rfc2217")
    bus = None
    try:
        can_ep, lidar_ep = manifest["endpoints"]
        # Idle clients on every TCP server, each one's descriptor in the bench beyond 1023 too.
        idle = [socket.create_connection(_socketcand(manifest)) for _ in range(20)]
        idle += [socket.create_connection(_tcp(ep["tap"])) for ep in (can_ep, lidar_ep) for _ in range(10)]
        # The CAN thread greets a client (python-can waits for ever for its greeting: asked first, with a timeout),
        # and delivers the board's heartbeat (0x702, once a second) to python-can ...
        with socket.create_connection(_socketcand(manifest), timeout=5) as greeter:
            assert _Messages(greeter).read(timeout=5) == sc.HI
        bus = can.Bus(interface="socketcand", host=_socketcand(manifest)[0], port=_socketcand(manifest)[1],
                      channel="can0")
        deadline = time.monotonic() + 5
        while (msg := bus.recv(timeout=max(0.0, deadline - time.monotonic()))) is not None:
            if msg.arbitration_id == 0x702:
                break
        assert msg is not None, "no heartbeat through socketcand"
        # ... the tap streams it ...
        with socket.create_connection(_tcp(can_ep["tap"]), timeout=5) as tap:
            assert tap.recv(4096)
        # ... the serial line answers over RFC 2217 ...
        with serial.serial_for_url(lidar_ep["rfc2217"], baudrate=rplidar.BAUD, timeout=2) as port:
            port.write(rplidar.request(0x52))  # GET_HEALTH
            assert port.read(rplidar.DESCRIPTOR_SIZE + 3)[:2] == b"\xa5\x5a"
        # ... and the control channel answers.
        assert ControlClient(manifest["control"]).media()["can"]["host"]["socketcand"]["accepted"] >= 21
        for s in idle:
            s.close()
    finally:
        if bus is not None:
            bus.shutdown()
        _, err = interrupt(proc)
    assert "Traceback" not in err and "Error" not in err, err


def test_the_scip_port_and_the_xrce_agent_serve_descriptors_numbered_beyond_1023(tmp_path):
    # The same class on the TCP endpoint (a UST-10LX) and the UDP servers (the XRCE agent): each one's thread
    # waits on descriptors numbered beyond 1023 and answers.
    from hilbench.protocols import xrce_dds as x

    (tmp_path / "scanners").mkdir()
    (tmp_path / "agent").mkdir()
    scanners, manifest = _emulate_high(tmp_path / "scanners", "scanners")
    agent, agent_manifest = _emulate_high(tmp_path / "agent", "micro-ros-agent", "--set", "agent.port=0")
    try:
        ust = next(ep for ep in manifest["endpoints"] if ep["name"] == "ust")
        idle = [socket.create_connection((ust["host"], ust["port"])) for _ in range(3)]  # turned away
        for s in idle:
            s.close()
        wait_until(lambda: _try(_scip_version, (ust["host"], ust["port"])), timeout=10)
        ep = agent_manifest["endpoints"][0]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", 0))
            sock.settimeout(5)
            sock.sendto(x.build_message(0x80, 0, 0, [(x.SubmessageId.GET_INFO, x.FLAG_E, x.get_info())]),
                        (ep["host"], ep["port"]))
            assert x.parse_message(sock.recv(65536)).submessages[0].name == "INFO"
    finally:
        errors = [interrupt(proc)[1] for proc in (scanners, agent)]
    for err in errors:
        assert "Traceback" not in err and "Error" not in err, err


def _scip_version(address: tuple[str, int]) -> None:
    """A SCIP 2.0 client's first command over TCP: VV must be answered with status 00."""
    with socket.create_connection(address, timeout=3) as sock:
        sock.sendall(b"VV\n")
        got = b""
        while b"\n\n" not in got:
            chunk = sock.recv(4096)
            if not chunk:
                raise ConnectionError("closed")
            got += chunk
    assert got.startswith(b"VV\n00"), got


def test_no_thread_of_the_package_waits_with_select():
    # select() cannot watch a descriptor numbered 1024 or more (the test above shows what it cost); waits go
    # through selectors' DefaultSelector (epoll) or hilbench.transports.readiness (poll/ppoll).
    import ast

    package = Path(__file__).resolve().parents[2] / "hilbench"
    found = []
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            called = (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                      and (node.value.id, node.attr) in {("select", "select"), ("selectors", "SelectSelector")})
            imported = (isinstance(node, ast.ImportFrom) and node.module == "select"
                        and any(a.name == "select" for a in node.names))
            if called or imported:
                found.append(f"{path.relative_to(package)}:{node.lineno}")
    assert not found, found
