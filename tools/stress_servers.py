#!/usr/bin/env python3
"""Hostile clients against every server of a running bench, and a well-behaved client after each attack.

For each server (``--servers``) the script starts a bench in another process
(``hilbench emulate`` of a small profile holding that server, on 127.0.0.1,
as a user would), then runs its attacks (``--attacks``) one after another:

- ``churn``: connections opened and closed as fast as the server takes them;
- ``slow``: connections that send half a request and stall (slowloris), held;
- ``exhaust``: idle connections up to the bench's descriptor limit (2 048
  unless ``--bench-nofile``) plus a few hundred, crossing select()'s 1 024 on
  the way (the attacker raises its own limit with ``resource.setrlimit``), held;
- ``unread``: clients that ask (or listen) and never read what comes;
- ``flood``: the server's own protocol at full speed: RFC 2217 ``IAC AYT``,
  socketcand commands (hundreds of digits among them), tap clients under a
  datagram flood, Vel2d datagrams to the UDP board, RTPS SPDP from thousands
  of made-up participants (and locators no socket can reach), XRCE sessions
  from thousands of clients (and a FRAGMENT nested 2 000 deep), GD requests
  whose scans nobody reads.

After each attack a well-behaved client of the server's own kind must be
served, while the attackers still hold their connections (a lock-out), or
once they left (a flood; and for the ports that serve one client at a time,
as the serial port or the Hokuyo they stand for: RFC 2217, SCIP over TCP):
``ControlClient`` (and
``hilbench board status``), python-can's ``socketcand`` interface, pyserial's
``rfc2217://``, a tap reader, hokuyolx, a Vel2d host on UDP, an RTPS
participant (its SPDP answered, the node's own announcements still coming),
an XRCE client (ping and session). Per server and attack it prints JSON
figures (``{"name", "value", "unit", "reference", "ratio", ...}``):

- ``stress_<server>_<attack>_inputs``: connections, bytes or datagrams sent;
- ``stress_<server>_<attack>_tracebacks``: tracebacks that appeared on the
  bench's stderr (the rule is 0);
- ``stress_<server>_<attack>_served``: 1 if the well-behaved client was
  served (tried again for up to 10 s; with the seconds it took, or why not);
- ``stress_<server>_<attack>_rss``: the bench's peak RSS during the attack
  against the RSS before it (MB), and after (held connections closed, the
  bench given ``--settle`` seconds).

A bench that died or stopped serving is restarted for the next attack (and
said so). The script reports what it finds, it does not judge: it exits 0
unless it could not run. ``--quick`` scales everything down (for the tests).

Usage: tools/stress_servers.py [--servers control,socketcand,...] [--attacks churn,slow,...]
                               [--scale F] [--quick] [--settle S] [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import os
import resource
import selectors
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO, emit  # noqa: E402

SOFT_NOFILE, HARD_NOFILE = resource.getrlimit(resource.RLIMIT_NOFILE)
#: The descriptor limit a bench runs with by default (``--bench-nofile``): "the limit plus a few hundred"
#: connections (``exhaust``) then cross select()'s 1 024 on the way and end at the limit itself.
BENCH_NOFILE = min(2048, HARD_NOFILE)
#: How long the well-behaved client keeps trying after an attack (seconds).
RETRY_S = 10.0
RTPS_DOMAIN = 57  # (ports 21660 and up: away from the usual domains other benches use)

# --------------------------------------------------------------------------- profiles

SCENE = '[scene]\nwalls = [ [[-3.0, -2.0], [3.0, -2.0], [3.0, 2.0], [-3.0, 2.0], [-3.0, -2.0]] ]\n'
ROVER = '''[endpoints.rover]
type = "pty"
protocol = "vel2d"
baud = 115_200

[[devices]]
model = "stm32f767-rover"
name = "rover"
endpoint = "rover"
preset = "freertos-50-30"
output = "v3"
'''
ROVER_UDP = '''[endpoints.rover_udp]
type = "udp"
protocol = "vel2d"
baud = 1_152_000
port = 0

[[devices]]
model = "stm32f767-rover"
name = "rover_udp"
endpoint = "rover_udp"
preset = "freertos-1000"
output = "binary"
'''
CAN = '''[endpoints.can]
type = "can"
protocol = "can"
bitrate = 500_000
socketcand = { port = 0, channel = "can0" }

[[devices]]
model = "stm32f767-rover-canopen"
name = "node"
endpoint = "can"
node_id = 2
heartbeat_ms = 100
'''
AGENT = '''[endpoints.agent]
type = "udp"
protocol = "xrce-dds"
port = 0

[[devices]]
model = "micro-ros-agent"
name = "agent"
endpoint = "agent"
'''
NODES = f'''[endpoints.nodes]
type = "udp"
protocol = "rtps"
port = 0
domain_id = {RTPS_DOMAIN}
peers = ["127.0.0.1"]

[[devices]]
model = "freertps-node"
name = "talker"
endpoint = "nodes"
participant_index = 0
mac = "2C:4D:59:01:23:53"
topics = [{{ name = "chatter", type = "std_msgs/String", direction = "pub", rate_hz = 10, value = "Hello" }}]
'''
UST = '''[endpoints.ust]
type = "tcp"
protocol = "scip2"
port = 0

[[devices]]
model = "ust-10lx"
name = "ust"
endpoint = "ust"
pose = { x = 0.5, y = 0.3, heading = 0.0 }
'''


# --------------------------------------------------------------------------- the bench


class BenchProcess:
    """``hilbench emulate`` of a profile in another process, at the descriptor limit users get."""

    def __init__(self, profile: str, serve: tuple[str, ...] = (), nofile: int = BENCH_NOFILE) -> None:
        self.tmp = tempfile.TemporaryDirectory(prefix="hilbench-stress-")
        path = Path(self.tmp.name) / "stress.toml"
        path.write_text('schema = 1\ndescription = "tools/stress_servers.py"\n' + profile)
        self.manifest_path = Path(self.tmp.name) / "manifest.json"
        self.stderr_path = Path(self.tmp.name) / "stderr.txt"
        self.stderr = self.stderr_path.open("wb")
        argv = [sys.executable, "-m", "hilbench.cli", "emulate", str(path), "--manifest", str(self.manifest_path)]
        for name in serve:
            argv += ["--serve", name]
        self.proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=self.stderr, cwd=REPO,
                                     preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_NOFILE,
                                                                           (nofile, HARD_NOFILE)))
        deadline = time.monotonic() + 30
        while not self.manifest_path.exists():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise SystemExit(f"the bench did not start:\n{self.stderr_path.read_text()[-2000:]}")
            time.sleep(0.02)
        time.sleep(0.1)
        self.manifest = json.loads(self.manifest_path.read_text())
        self.endpoints = {e["name"]: e for e in self.manifest["endpoints"]}
        self.pid = self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def rss_mb(self) -> float:
        try:
            for line in Path(f"/proc/{self.pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
        except OSError:
            pass
        return 0.0

    def nofile(self) -> int:
        """The bench's soft descriptor limit."""
        try:
            for line in Path(f"/proc/{self.pid}/limits").read_text().splitlines():
                if line.startswith("Max open files"):
                    return int(line.split()[3])
        except (OSError, ValueError):
            pass
        return BENCH_NOFILE

    def fds(self) -> int:
        """Descriptors the bench holds now."""
        try:
            return len(os.listdir(f"/proc/{self.pid}/fd"))
        except OSError:
            return 0

    def tracebacks(self) -> int:
        self.stderr.flush()
        return self.stderr_path.read_bytes().count(b"Traceback (most recent call last)")

    def stderr_tail(self, since: int = 0) -> str:
        return self.stderr_path.read_bytes()[since:].decode(errors="replace")[-1500:]

    def stderr_size(self) -> int:
        return self.stderr_path.stat().st_size

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        self.stderr.close()
        self.tmp.cleanup()


class RssSampler:
    """The bench's peak RSS while an attack runs (sampled every 20 ms)."""

    def __init__(self, bench: BenchProcess) -> None:
        self.bench = bench
        self.peak = bench.rss_mb()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            self.peak = max(self.peak, self.bench.rss_mb())

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return max(self.peak, self.bench.rss_mb())


# --------------------------------------------------------------------------- what attackers hold


@dataclass
class Attack:
    """What an attack did: how many inputs of which kind, and the sockets it still holds."""

    inputs: int
    unit: str
    held: list[socket.socket] = field(default_factory=list)
    note: str = ""
    #: The well-behaved client comes after the attackers left (a flood), not while they hold on (a lock-out).
    after: bool = False

    def release(self) -> None:
        for sock in self.held:
            with contextlib.suppress(OSError):
                sock.close()
        self.held.clear()


def tcp_address(url: str) -> tuple[str, int]:
    """``tcp://h:p``, ``rfc2217://h:p``, ``socketcand://h:p/ch`` or ``h:p`` to ``(h, p)``."""
    rest = url.split("://", 1)[-1].split("/", 1)[0]
    host, _, port = rest.rpartition(":")
    return host, int(port)


def connect(address: tuple[str, int], timeout: float = 1.0) -> socket.socket | None:
    try:
        sock = socket.create_connection(address, timeout=timeout)
    except OSError:
        return None
    return sock


def churn(address: tuple[str, int], n: int, payload: bytes = b"", deadline_s: float = 30.0) -> Attack:
    """``n`` connections opened (with ``payload`` sent) and closed at once (until 20 in a row fail)."""
    made = failed = tried = 0
    t_end = time.monotonic() + deadline_s
    for _ in range(n):
        if time.monotonic() > t_end or failed >= 20:
            break
        tried += 1
        sock = connect(address, timeout=0.5)
        if sock is None:
            failed += 1
            continue
        failed = 0
        made += 1
        with contextlib.suppress(OSError):
            if payload:
                sock.sendall(payload)
        sock.close()
    return Attack(tried, "connections", note=f"{made} connected" + ("" if tried == n else f", gave up after {tried}"))


def hold(address: tuple[str, int], n: int, payload: bytes = b"", stall_s: float = 5.0) -> Attack:
    """``n`` connections held open, each having sent ``payload`` (half a request, or nothing). Connects go out
    256 at a time without blocking, and complete as fast as the server (and the kernel's queue) takes them;
    it stops early once none completed for ``stall_s`` seconds."""
    sel = selectors.DefaultSelector()
    held: list[socket.socket] = []
    pending: dict[int, socket.socket] = {}
    failed = 0
    last_progress = time.monotonic()
    while len(held) < n and time.monotonic() - last_progress < stall_s:
        while len(held) + len(pending) < n and len(pending) < 256:
            sock = socket.socket()
            sock.setblocking(False)
            if sock.connect_ex(address) not in (0, errno.EINPROGRESS):
                sock.close()
                failed += 1
                continue
            pending[sock.fileno()] = sock
            sel.register(sock, selectors.EVENT_WRITE)
        for key, _ in sel.select(timeout=0.5):
            sock = key.fileobj
            sel.unregister(sock)
            del pending[sock.fileno()]
            if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
                sock.close()
                failed += 1
                continue
            last_progress = time.monotonic()
            with contextlib.suppress(OSError):
                if payload:
                    sock.send(payload)
            held.append(sock)
        if not pending and len(held) + failed >= n:
            break
    for sock in pending.values():
        sock.close()
    sel.close()
    return Attack(n, "connections", held, note=f"{len(held)} held, {failed + len(pending)} refused or not taken "
                                               f"within {stall_s:g} s")


def pipelined(address: tuple[str, int], clients: int, request: bytes, total: int, rcvbuf: int = 4096) -> Attack:
    """``clients`` connections that send ``total`` bytes of ``request`` each and never read a reply."""
    held = []
    sent = 0
    for _ in range(clients):
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        sock.settimeout(1.0)
        try:
            sock.connect(address)
        except OSError:
            sock.close()
            continue
        held.append(sock)
    blob = request * max(1, 65536 // len(request))
    deadline = time.monotonic() + 10
    for sock in held:
        sock.setblocking(False)
    while sent < total * len(held) and time.monotonic() < deadline:
        progressed = False
        for sock in held:
            try:
                sent += sock.send(blob)
                progressed = True
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                pass
        if not progressed:
            time.sleep(0.01)
    return Attack(sent, "bytes", held, note=f"{len(held)} clients, {sent} bytes sent unread-for")


def stream(address: tuple[str, int], total: int, make: Callable[[int], bytes], prefix: bytes = b"",
           seconds: float = 20.0, after: bool = True) -> Attack:
    """One connection sending ``total`` bytes (``make(n)`` gives the next piece) and reading nothing; the
    well-behaved client comes once it left (``after``), or while it holds on."""
    sock = connect(address, timeout=2.0)
    if sock is None:
        return Attack(0, "bytes", note="could not connect", after=after)
    sent = 0
    deadline = time.monotonic() + seconds
    sock.settimeout(0.5)
    try:
        if prefix:
            sock.sendall(prefix)
        while sent < total and time.monotonic() < deadline:
            try:
                sent += sock.send(make(min(65536, total - sent)))
            except TimeoutError:
                continue
    except OSError as exc:
        return Attack(sent, "bytes", [sock], note=f"the server closed after {sent} bytes ({exc.strerror or exc})",
                      after=after)
    return Attack(sent, "bytes", [sock], note=f"{sent} bytes in {seconds - max(0, deadline - time.monotonic()):.1f} s",
                  after=after)


def datagrams(address: tuple[str, int], make: Callable[[int], bytes], n: int, sockets: int = 1,
              seconds: float = 20.0) -> Attack:
    """``n`` datagrams (``make(i)``) from ``sockets`` sockets, as fast as they go."""
    socks = []
    for _ in range(sockets):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        socks.append(s)
    sent = 0
    deadline = time.monotonic() + seconds
    i = 0
    while i < n and time.monotonic() < deadline:
        try:
            socks[i % sockets].sendto(make(i), address)
            sent += 1
        except (BlockingIOError, InterruptedError):
            time.sleep(0.0005)
            continue
        except OSError:
            pass
        i += 1
    for s in socks:
        s.close()
    return Attack(sent, "datagrams", note=f"{sent} datagrams from {sockets} sockets", after=True)


# --------------------------------------------------------------------------- well-behaved clients


def in_time(fn: Callable[[], str], timeout: float) -> tuple[bool, str, float]:
    """Run a client check in a thread: (served, what happened, seconds)."""
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box["ok"] = fn()
        except Exception as exc:  # noqa: BLE001 (a refusal is a result)
            box["error"] = f"{type(exc).__name__}: {exc}"

    t0 = time.monotonic()
    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(timeout)
    dt = time.monotonic() - t0
    if thread.is_alive():
        return False, f"no answer within {timeout:g} s", dt
    if "error" in box:
        return False, box["error"][:300], dt
    return True, box["ok"], dt


def check_control(bench: BenchProcess) -> str:
    from hilbench.bench.control import ControlClient

    devices = ControlClient(bench.manifest["control"], timeout=10).call("devices")["devices"]
    done = subprocess.run([sys.executable, "-m", "hilbench.cli", "board", "--manifest", str(bench.manifest_path),
                           "status"], capture_output=True, text=True, timeout=30, cwd=REPO)
    if done.returncode != 0:
        raise RuntimeError(f"hilbench board status exited {done.returncode}: {done.stderr.strip()[-200:]}")
    return f"ControlClient devices {sorted(devices)}; hilbench board status ok"


def check_socketcand(bench: BenchProcess) -> str:
    """python-can in a process of its own, as a user's: its socketcand interface waits with select(), which
    fails on a descriptor beyond 1 023, and this process holds the attackers' thousands of sockets."""
    info = bench.endpoints["can"]["socketcand"]
    code = ("import can, json\n"
            f"with can.Bus(interface='socketcand', host={info['host']!r}, port={info['port']}, "
            f"channel={info['channel']!r}) as bus:\n"
            "    msg = bus.recv(timeout=5)\n"
            "print(json.dumps(None if msg is None else msg.arbitration_id))\n")
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        raise RuntimeError("python-can got nothing within 20 s") from None
    if done.returncode != 0:
        raise RuntimeError(f"python-can: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
    can_id = json.loads(done.stdout)
    if can_id is None:
        raise RuntimeError("python-can received no frame in 5 s (the node beats every 100 ms)")
    return f"python-can socketcand received 0x{can_id:X}"


def check_tap(bench: BenchProcess, endpoint: str = "rover_udp") -> str:
    """A tap reader sees a Vel2d frame sent to the UDP board in its capture stream."""
    from hilbench.protocols import vel2d

    addr = tcp_address(bench.endpoints[endpoint]["tap"])
    board = (bench.endpoints[endpoint]["host"], bench.endpoints[endpoint]["port"])
    frame = vel2d.build(0.25, -0.5, 0.75)
    with socket.create_connection(addr, timeout=5) as sock, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as host:
        sock.settimeout(0.3)
        got = b""
        with contextlib.suppress(TimeoutError):
            got += sock.recv(65536)  # the capture's header
        if not got:
            raise RuntimeError("the tap sent no capture header")
        deadline = time.monotonic() + 5
        while frame not in got and time.monotonic() < deadline:
            host.sendto(frame, board)
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            if not chunk:
                raise RuntimeError(f"the tap closed after {len(got)} bytes")
            got += chunk
        if frame not in got:
            raise RuntimeError("the tap did not show a frame sent to the board within 5 s")
        return f"a tap reader saw a frame sent to the board ({len(got)} bytes of capture)"


def check_rfc2217(bench: BenchProcess) -> str:
    """pyserial's rfc2217:// sends the board a velocity and reads the board's log line about it."""
    import serial

    from hilbench.protocols import vel2d

    url = bench.endpoints["rover"]["rfc2217"]
    with serial.serial_for_url(url, baudrate=115200, timeout=0.5) as port:
        got = b""
        deadline = time.monotonic() + 5
        while b"recv vel" not in got and time.monotonic() < deadline:
            port.write(vel2d.build(0.1, -0.2, 0.3))
            got += port.read(4096)
        if b"recv vel" not in got:
            raise RuntimeError(f"pyserial rfc2217:// got no answer to a velocity in 5 s ({len(got)} bytes)")
        return f"pyserial rfc2217:// got the board's answer to a velocity ({len(got)} bytes)"


def check_scip(bench: BenchProcess) -> str:
    ep = bench.endpoints["ust"]
    code = ("import json, sys\nfrom hokuyolx import HokuyoLX\n"
            f"laser = HokuyoLX(addr=({ep['host']!r}, {ep['port']}))\n"
            "ts, scan = laser.get_dist()\nlaser.close()\nprint(json.dumps({'steps': len(scan)}))\n")
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        raise RuntimeError("hokuyolx got no scan within 20 s") from None
    if done.returncode != 0:
        raise RuntimeError(f"hokuyolx: {done.stderr.strip().splitlines()[-1] if done.stderr.strip() else '?'}")
    return f"hokuyolx read a scan of {json.loads(done.stdout)['steps']} steps"


def check_vel2d(bench: BenchProcess) -> str:
    from hilbench.protocols import vel2d

    addr = (bench.endpoints["rover_udp"]["host"], bench.endpoints["rover_udp"]["port"])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.5)
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline:
            sock.sendto(vel2d.build(0.1, 0.0, 0.0), addr)  # a host registers by sending
            try:
                data = sock.recv(65536)
            except TimeoutError:
                continue
            return f"a Vel2d host got {len(data)} bytes of the board's output"
        raise RuntimeError("the UDP board sent nothing to a new host in 5 s")


def spdp(prefix: bytes, meta_port: int, sn: int = 1) -> bytes:
    from hilbench.protocols import rtps as r

    body = r.spdp_payload(prefix, meta_port=meta_port, user_port=meta_port + 1, lease_s=10, vendor_id=b"\x01\x0f",
                          domain_id=RTPS_DOMAIN)
    return r.message(prefix, r.data(r.ENTITYID_UNKNOWN, r.SPDP_WRITER, sn, body,
                                    inline_qos=r.key_hash_qos(prefix + r.ENTITYID_PARTICIPANT)), vendor_id=b"\x01\x0f")


def check_rtps(bench: BenchProcess) -> str:
    from hilbench.protocols import rtps as r

    node_meta = r.ports(RTPS_DOMAIN, 0)["metatraffic_unicast"]
    peer_meta = r.ports(RTPS_DOMAIN, 5)["metatraffic_unicast"]  # a participant index the node announces to
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listen, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as mine:
        listen.bind(("127.0.0.1", peer_meta))
        listen.settimeout(3.5)
        try:
            data = listen.recv(65536)  # the node's own periodic announcement (every second)
        except TimeoutError:
            raise RuntimeError("the node's SPDP announcements stopped (none in 3.5 s)") from None
        if not data.startswith(b"RTPS"):
            raise RuntimeError("the node's announcement is not RTPS")
        mine.bind(("127.0.0.1", 0))
        mine.settimeout(3)
        port = mine.getsockname()[1]
        mine.sendto(spdp(bytes.fromhex("010F5555555555555555AAAA"), port), ("127.0.0.1", node_meta))
        try:
            mine.recv(65536)
        except TimeoutError:
            raise RuntimeError("the node did not answer a newcomer's SPDP in 3 s") from None
        return "the node announces itself and answered a newcomer's SPDP"


def check_xrce(bench: BenchProcess) -> str:
    from hilbench.protocols import xrce_dds as x

    addr = (bench.endpoints["agent"]["host"], bench.endpoints["agent"]["port"])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(3)
        sock.sendto(x.build_message(0x80, 0, 0, [(x.SubmessageId.GET_INFO, x.FLAG_E, x.get_info())]), addr)
        sock.recv(65536)
        sock.sendto(x.build_message(0x80, 0, 0, [(x.SubmessageId.CREATE_CLIENT, x.FLAG_E, x.client_representation(
            b"\x0a\x0b\x0c\x0d", 0x81))]), addr)
        reply = x.parse_message(sock.recv(65536))
        if not reply.submessages or reply.submessages[0].name != "STATUS_AGENT":
            raise RuntimeError("no STATUS_AGENT for a new client")
        sock.sendto(x.build_message(0x81, 0, 0, [(x.SubmessageId.DELETE, x.FLAG_E, x.delete(
            b"\x00\x0b", x.OBJECT_CLIENT))]), addr)
        return "an XRCE client pinged and got its session"


# --------------------------------------------------------------------------- attacks per server


def mib(scale: float, n: float) -> int:
    return max(65536, int(n * scale * (1 << 20)))


def count(scale: float, n: int, least: int = 5) -> int:
    return max(least, int(n * scale))


def exhaust_count(bench: BenchProcess, scale: float) -> int:
    """The bench's descriptor limit plus a few hundred (scaled down with --scale < 1)."""
    return count(scale, bench.nofile() + 300, 20)


def exhaust(bench: BenchProcess, address: tuple[str, int], scale: float) -> Attack:
    """Idle connections up to the bench's descriptor limit plus a few hundred, held; the note says how many
    descriptors the bench itself took (a connection the client sees made may wait in the kernel's queue)."""
    fds0 = fds = bench.fds()
    n, held, failed, accepting = exhaust_count(bench, scale), [], 0, True
    t_end = time.monotonic() + 90
    # In batches the size of a small listen() queue, each given the time the server takes to accept it: a
    # connection the kernel completed for the client but the server's queue dropped is no descriptor of its.
    while len(held) < n and time.monotonic() < t_end:
        batch = hold(address, min(16, n - len(held)), stall_s=2.0)
        held += batch.held
        failed += batch.inputs - len(batch.held)
        if not batch.held:
            break
        wait_end = time.monotonic() + (1.0 if accepting else 0.05)
        while time.monotonic() < wait_end and bench.fds() < fds + len(batch.held):
            time.sleep(0.005)
        now = bench.fds()
        accepting, fds = now > fds, now
    done = Attack(n, "connections", held, note=f"{len(held)} held, {failed} refused or not taken")
    fds, deadline, still = bench.fds(), time.monotonic() + 30, 0
    while time.monotonic() < deadline and still < 4:  # the server takes the queued ones at its pace
        time.sleep(0.5)
        now = bench.fds()
        still = still + 1 if now == fds else 0
        fds = now
    done.note += f"; the bench's descriptors {fds0} -> {fds} (limit {bench.nofile()})"
    return done


def control_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    addr = tcp_address(bench.manifest["control"])
    return {
        "churn": lambda: churn(addr, count(scale, 1000), b'{"cmd": "devices"}\n'),
        "slow": lambda: hold(addr, count(scale, 300), b'{"cmd": "dev'),
        "exhaust": lambda: exhaust(bench, addr, scale),
        "unread": lambda: pipelined(addr, count(scale, 20, 2), b'{"cmd": "manifest"}\n', mib(scale, 4)),
        "flood": lambda: stream(addr, mib(scale, 32), lambda n: b"[" * n),
    }


def socketcand_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    info = bench.endpoints["can"]["socketcand"]
    addr = (info["host"], info["port"])
    open_raw = b"< open can0 >< rawmode >"

    def unread() -> Attack:
        listeners = pipelined(addr, count(scale, 20, 2), b"< echo >", 0)  # open, never read
        for sock in listeners.held:
            with contextlib.suppress(OSError):
                sock.send(open_raw)
        frames = b"< send 123 8 11 22 33 44 55 66 77 88 >" * 1000
        talker = stream(addr, mib(scale, 16), lambda n: frames[:n], prefix=open_raw, seconds=10, after=False)
        return Attack(talker.inputs, "bytes", listeners.held + talker.held,
                      note=f"{len(listeners.held)} raw clients not reading; {talker.note}")

    big = "9" * 400
    hostile = "".join(f"< {c} >" for c in (f"add {big} 0 123 0", f"subscribe 0 {big} 123", f"filter {big} 0 123 1 FF",
                                           f"muxfilter {big} 0 123 1 FF 00 00 00 00 00 00 00")).encode()
    hostile += b"< controlmode >< statistics " + big.encode() + b" >< bcmmode >"
    return {
        "churn": lambda: churn(addr, count(scale, 1000), b"< open can0 >"),
        "slow": lambda: hold(addr, count(scale, 300), b"< open ca"),
        "exhaust": lambda: exhaust(bench, addr, scale),
        "unread": unread,
        "flood": lambda: stream(addr, mib(scale, 8), lambda n: (hostile * (n // len(hostile) + 1))[:n],
                                prefix=b"< open can0 >"),
    }


def tap_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    addr = tcp_address(bench.endpoints["rover_udp"]["tap"])
    board = (bench.endpoints["rover_udp"]["host"], bench.endpoints["rover_udp"]["port"])

    def unread() -> Attack:
        from hilbench.protocols import vel2d

        readers = hold(addr, count(scale, 40, 2))
        frame = vel2d.build(0.1, 0.2, 0.3) * 36  # 1 kB datagrams: every one a transmission the taps record
        flood = datagrams(board, lambda i: frame, count(scale, 200_000, 1000), seconds=15)
        return Attack(flood.inputs, "datagrams", readers.held, note=f"{len(readers.held)} tap clients not reading; "
                                                                     f"{flood.note}")

    return {
        "churn": lambda: churn(addr, count(scale, 1000)),
        "exhaust": lambda: exhaust(bench, addr, scale),
        "unread": unread,
    }


def rfc2217_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    addr = tcp_address(bench.endpoints["rover"]["rfc2217"])
    ayt = bytes((0xFF, 0xF6)) * 32768
    return {
        "churn": lambda: churn(addr, count(scale, 300)),
        "slow": lambda: hold(addr, 1, bytes((0xFF, 0xFA, 44, 1, 0, 1))),  # half a SET-BAUDRATE, then nothing
        "exhaust": lambda: exhaust(bench, addr, scale),
        "flood": lambda: stream(addr, mib(scale, 32), lambda n: ayt[:n]),
    }


def scip_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    addr = (bench.endpoints["ust"]["host"], bench.endpoints["ust"]["port"])
    gd = b"BM\n" + b"GD0000108000\n" * 1000

    def half() -> Attack:
        a = churn(addr, 1, b"QTxyz")  # a command begun, never ended: the next client must not run it
        time.sleep(0.2)
        return a

    return {
        "churn": lambda: churn(addr, count(scale, 1000), b"VV\n"),
        "slow": half,
        "exhaust": lambda: exhaust(bench, addr, scale),
        "unread": lambda: stream(addr, count(scale, 200_000, 2000), lambda n: gd[:n], seconds=10, after=False),
        "flood": lambda: stream(addr, mib(scale, 16), lambda n: os.urandom(n)),
    }


def vel2d_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    from hilbench.protocols import vel2d

    board = (bench.endpoints["rover_udp"]["host"], bench.endpoints["rover_udp"]["port"])
    frame = vel2d.build(0.1, 0.2, 0.3)
    return {
        "flood": lambda: datagrams(board, lambda i: frame * 32, count(scale, 400_000, 2000), seconds=15),
    }


def rtps_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    from hilbench.protocols import rtps as r

    node = ("127.0.0.1", r.ports(RTPS_DOMAIN, 0)["metatraffic_unicast"])

    def participants() -> Attack:
        return datagrams(node, lambda i: spdp(b"\x01\x0f" + struct.pack(">I", i) + b"\x77" * 6, 40000 + i % 20000),
                         count(scale, 50_000, 500))

    def hostile() -> Attack:
        a = datagrams(node, lambda i: spdp(b"\x01\x0f\xde\xad" + struct.pack(">I", i) + b"\x00" * 4,
                                           (70000, 2**31 - 1, 0)[i % 3]), 30)
        time.sleep(1.5)  # the node's announcement timer runs once a second
        return a

    return {"flood": participants, "locators": hostile}


def xrce_attacks(bench: BenchProcess, scale: float) -> dict[str, Callable[[], Attack]]:
    from hilbench.protocols import xrce_dds as x

    agent = (bench.endpoints["agent"]["host"], bench.endpoints["agent"]["port"])
    S = x.SubmessageId

    def sessions() -> Attack:
        n = count(scale, 5000, 50)
        socks, made = [], 0
        for i in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", 0))
            with contextlib.suppress(OSError):
                s.sendto(x.build_message(0x80, 0, 0, [(S.CREATE_CLIENT, x.FLAG_E, x.client_representation(
                    struct.pack(">I", 0x10000 + i), 0x81))]), agent)
                made += 1
            socks.append(s)
            if len(socks) >= 500:
                for s in socks:
                    s.close()
                socks = []
        for s in socks:
            s.close()
        return Attack(made, "sessions", note=f"{made} clients each created a session and vanished")

    def nested() -> Attack:
        inner = x.build_submessage(S.HEARTBEAT, x.heartbeat(0, 0, 0x80))
        for _ in range(2000):
            inner = x.build_submessage(S.FRAGMENT, inner, x.FLAG_E | x.FLAG_LAST_FRAGMENT)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.sendto(x.build_message(0x80, 0, 0, [(S.CREATE_CLIENT, x.FLAG_E, x.client_representation(
            b"\x01\x02\x03\x04", 0x81))]), agent)
        time.sleep(0.05)
        sock.sendto(x.build_header(0x81, 0x80, 0) + inner, agent)
        time.sleep(0.2)
        sock.close()
        return Attack(1, "datagrams", note=f"a FRAGMENT nested 2000 deep ({8 + len(inner)} bytes)")

    return {"flood": sessions, "nested": nested,
            "garbage": lambda: datagrams(agent, lambda i: os.urandom(1 + i % 512), count(scale, 100_000, 1000))}


@dataclass(frozen=True)
class Server:
    profile: str
    serve: tuple[str, ...]
    attacks: Callable[[BenchProcess, float], dict[str, Callable[[], Attack]]]
    check: Callable[[BenchProcess], str]
    client: str
    #: A port that serves one client at a time, as the device or serial port it stands for: while an attacker
    #: holds it, another client is turned away by design, so the client is checked after the attackers left.
    one_client: bool = False


SERVERS: dict[str, Server] = {
    "control": Server(ROVER, (), control_attacks, check_control, "ControlClient + hilbench board status"),
    "socketcand": Server(CAN, (), socketcand_attacks, check_socketcand, "python-can socketcand"),
    "tap": Server(ROVER_UDP, (), tap_attacks, check_tap, "a tap reader"),
    "rfc2217": Server(ROVER, ("rfc2217",), rfc2217_attacks, check_rfc2217, "pyserial rfc2217://", one_client=True),
    "scip": Server(SCENE + UST, (), scip_attacks, check_scip, "hokuyolx", one_client=True),
    "vel2d-udp": Server(ROVER_UDP, (), vel2d_attacks, check_vel2d, "a Vel2d host on UDP"),
    "rtps": Server(NODES, (), rtps_attacks, check_rtps, "an RTPS participant (SPDP)"),
    "xrce": Server(AGENT, (), xrce_attacks, check_xrce, "an XRCE client (ping, session)"),
}


# --------------------------------------------------------------------------- running


def settle(bench: BenchProcess, seconds: float) -> float:
    """The bench's RSS once it stopped shrinking (or after ``seconds``)."""
    deadline = time.monotonic() + seconds
    last = bench.rss_mb()
    while time.monotonic() < deadline:
        time.sleep(0.25)
        now = bench.rss_mb()
        if abs(now - last) < 0.2:
            return now
        last = now
    return last


def run_server(name: str, server: Server, attacks: list[str] | None, scale: float, settle_s: float,
               results: list[dict[str, Any]], nofile: int = BENCH_NOFILE, retry_s: float = RETRY_S) -> None:
    bench = BenchProcess(server.profile, server.serve, nofile)

    def check(bench: BenchProcess = bench) -> tuple[bool, str, float]:
        """The well-behaved client, tried again until served or ``RETRY_S`` passed (a server that lags behind
        an attack a moment is served; one that stays locked is not)."""
        t0 = time.monotonic()
        while True:
            if not bench.alive():
                return False, "the bench process died", time.monotonic() - t0
            ok, detail, _ = in_time(lambda: server.check(bench), 25)
            if ok or time.monotonic() - t0 > retry_s:
                return ok, detail, time.monotonic() - t0
            time.sleep(0.5)

    try:
        ok, detail, dt = check(bench)
        print(f"{name}: before any attack, {server.client}: {'served' if ok else 'NOT served'} ({detail})",
              file=sys.stderr, flush=True)
        table = server.attacks(bench, scale)
        for attack in [a for a in table if attacks is None or a in attacks]:
            if not bench.alive() or not ok:
                bench.stop()
                bench = BenchProcess(server.profile, server.serve, nofile)
                table = server.attacks(bench, scale)
                print(f"{name}: bench restarted before {attack}", file=sys.stderr, flush=True)
            tb0, err0 = bench.tracebacks(), bench.stderr_size()
            before = settle(bench, 1.0)
            sampler = RssSampler(bench)
            t0 = time.monotonic()
            try:
                done = table[attack]()
            except Exception as exc:  # noqa: BLE001 (an attack that could not run is reported, not fatal)
                done = Attack(0, "inputs", note=f"the attack failed: {type(exc).__name__}: {exc}")
            seconds = time.monotonic() - t0
            if done.after or server.one_client:
                done.release()
            ok, detail, dt = check(bench)
            done.release()
            peak = sampler.stop()
            after = settle(bench, settle_s) if bench.alive() else 0.0
            tracebacks = bench.tracebacks() - tb0
            row = {"server": name, "attack": attack, "inputs": done.inputs, "unit": done.unit, "note": done.note,
                   "seconds": round(seconds, 2), "served": ok, "client": server.client, "detail": detail,
                   "serve_seconds": round(dt, 2), "tracebacks": tracebacks, "rss_before": round(before, 1),
                   "rss_peak": round(peak, 1), "rss_after": round(after, 1), "alive": bench.alive()}
            if tracebacks or not bench.alive():
                row["stderr"] = bench.stderr_tail(err0)
            results.append(row)
            key = f"stress_{name}_{attack}".replace("-", "_")
            emit(f"{key}_inputs", done.inputs, done.unit, done.inputs, 1.0, note=done.note, seconds=round(seconds, 2))
            emit(f"{key}_tracebacks", tracebacks, "tracebacks", done.inputs, tracebacks / max(done.inputs, 1))
            emit(f"{key}_served", int(ok), "served", 1, int(ok), client=server.client, detail=detail,
                 seconds=round(dt, 2))
            emit(f"{key}_rss", peak, "MB", before, peak / before if before else 0.0, digits=1,
                 before=round(before, 1), after=round(after, 1))
            print(f"{name:10s} {attack:9s} {done.inputs:>10} {done.unit:11s} tracebacks {tracebacks:3d}  "
                  f"{'served' if ok else 'NOT SERVED'} ({dt:.1f} s)  RSS {before:.0f} -> {peak:.0f} -> {after:.0f} MB"
                  f"{'' if bench.alive() else '  BENCH DIED'}", file=sys.stderr, flush=True)
    finally:
        bench.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--servers", help=f"comma-separated, of {', '.join(SERVERS)} (default: all)")
    ap.add_argument("--attacks", help="comma-separated attack names (default: each server's all)")
    ap.add_argument("--scale", type=float, default=1.0, help="multiply connection counts and flood sizes")
    ap.add_argument("--quick", action="store_true", help="--scale 0.03, a short settle and 2 s of retries "
                                                           "(for tests)")
    ap.add_argument("--settle", type=float, default=3.0, help="seconds the bench gets to give memory back")
    ap.add_argument("--bench-nofile", type=int, default=BENCH_NOFILE,
                    help=f"the benches' descriptor limit (default {BENCH_NOFILE}; 'exhaust' opens it plus 300)")
    ap.add_argument("--json", metavar="FILE", help="also write every result to FILE")
    args = ap.parse_args()
    names = args.servers.split(",") if args.servers else list(SERVERS)
    unknown = [n for n in names if n not in SERVERS]
    if unknown:
        ap.error(f"no server named {', '.join(unknown)} (servers: {', '.join(SERVERS)})")
    scale, settle_s, retry_s = (0.03, 0.5, 2.0) if args.quick else (args.scale, args.settle, RETRY_S)
    # The attacker may hold more sockets than a bench (which keeps the limit users get).
    resource.setrlimit(resource.RLIMIT_NOFILE, (HARD_NOFILE, HARD_NOFILE))
    attacks = args.attacks.split(",") if args.attacks else None
    results: list[dict[str, Any]] = []
    for name in names:
        run_server(name, SERVERS[name], attacks, scale, settle_s, results, min(args.bench_nofile, HARD_NOFILE),
                   retry_s)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    bad = [r for r in results if r["tracebacks"] or not r["served"]]
    print(f"{len(results)} attacks, {len(bad)} with a traceback or a client not served", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
