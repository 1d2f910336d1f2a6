"""labgrid, as a lab runs it: real labgrid-coordinator, labgrid-exporter and labgrid-client processes on
127.0.0.1 with the configuration hilbench writes, a place acquired, labgrid's own SerialDriver pinging a servo
through RFC 2217; and the same through the environment file, without a coordinator.

These need labgrid (the ``labgrid`` extra); ``make test-labgrid`` installs it into a venv of its own (it
replaces pyserial's ``serial`` with pyserial-labgrid's) and runs them. Without labgrid they skip.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.bench.control import ControlClient
from hilbench.protocols import dynamixel as dxl
from hilbench.pytest_plugin import wait_until

labgrid = pytest.importorskip("labgrid", reason="labgrid is not installed here; `make test-labgrid` runs these")

pytestmark = pytest.mark.slow
BIN = Path(sys.executable).parent
USER_SUITE = Path(__file__).parent / "user_suite"
PING_3 = dxl.instruction_packet(3, dxl.Instruction.PING)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _hilbench(*args: str, **kw) -> subprocess.CompletedProcess:
    out = subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True, timeout=60,
                         **kw)
    assert out.returncode == 0, out.stderr
    return out


@pytest.fixture
def served_arm(hilbench_emulator, tmp_path):
    """``hilbench emulate arm --serve rfc2217`` in its own process; its manifest written to a file."""
    manifest = hilbench_emulator("arm", "--serve", "rfc2217")
    path = tmp_path / "arm.json"
    path.write_text(json.dumps({k: v for k, v in manifest.items() if k != "process"}))
    return manifest, path


def _rfc2217_connections(manifest) -> int:
    return ControlClient(manifest["control"]).servers()["arm"]["rfc2217"]["connections"]


def _run_user_suite(env_file: Path, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-W",
                           "ignore::DeprecationWarning", "--lg-env", str(env_file), "--hilbench-labgrid",
                           str(USER_SUITE)], capture_output=True, text=True, timeout=180, cwd=cwd)


class Processes:
    """Background processes of one test, ended (and their logs kept for failures) afterwards."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[tuple[str, subprocess.Popen]] = []

    def start(self, name: str, *cmd: str, **kw) -> subprocess.Popen:
        log = open(self.tmp / f"{name}.log", "w")  # noqa: SIM115 (closed with the process)
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=self.tmp, **kw)
        self.procs.append((name, proc))
        return proc

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text()

    def stop(self) -> None:
        for _, proc in reversed(self.procs):
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


@pytest.fixture
def processes(tmp_path):
    procs = Processes(tmp_path)
    yield procs
    procs.stop()


def test_exporter_config_uses_classes_labgrid_knows(served_arm, tmp_path):
    import yaml
    from labgrid.factory import target_factory

    manifest, path = served_arm
    text = _hilbench("labgrid", "exporter-config", str(path)).stdout
    config = yaml.safe_load(text)
    group = config["arm"]
    assert set(group) == {"arm", "arm-tap", "control"}
    for entry in group.values():
        assert entry["cls"] in target_factory.resources
    assert group["arm"] == {"cls": "NetworkSerialPort", "host": "127.0.0.1",
                            "port": int(manifest["endpoints"][0]["rfc2217"].rsplit(":", 1)[1]),
                            "speed": 1_000_000, "protocol": "rfc2217"}
    assert group["control"]["protocol"] == "raw"


def test_a_place_on_a_coordinator_pings_a_servo_with_labgrids_serial_driver(served_arm, processes, tmp_path):
    manifest, path = served_arm
    coordinator = f"127.0.0.1:{_free_port()}"
    env = {**os.environ, "LG_COORDINATOR": coordinator}
    processes.start("coordinator", str(BIN / "labgrid-coordinator"), "-l", coordinator)
    exporter_yaml = tmp_path / "exporter.yaml"
    _hilbench("labgrid", "exporter-config", str(path), "-o", str(exporter_yaml))

    def client(*args: str, check: bool = True) -> subprocess.CompletedProcess:
        out = subprocess.run([str(BIN / "labgrid-client"), *args], capture_output=True, text=True, timeout=60,
                             env=env, cwd=tmp_path)
        assert not check or out.returncode == 0, f"labgrid-client {' '.join(args)}: {out.stderr}"
        return out

    wait_until(lambda: client("places", check=False).returncode == 0, timeout=30, interval=0.2)
    processes.start("exporter", str(BIN / "labgrid-exporter"), "-c", coordinator, "-n", "benchpc",
                    "--hostname", "127.0.0.1", str(exporter_yaml))
    wait_until(lambda: "Resource 'control'" in client("-v", "resources").stdout, timeout=30, interval=0.2)
    listed = client("-v", "resources").stdout
    for name in ("arm", "arm-tap", "control"):
        assert f"Resource '{name}' (benchpc/arm/NetworkSerialPort[/{name}])" in listed

    client("-p", "hil-arm", "create")
    client("-p", "hil-arm", "add-match", "benchpc/arm/*")
    client("-p", "hil-arm", "acquire")
    shown = client("-p", "hil-arm", "show").stdout
    assert "acquired:" in shown and "benchpc/arm/*" in shown

    remote_env = tmp_path / "remote.yaml"
    remote_env.write_text(f"""
targets:
  main:
    resources:
      RemotePlace:
        name: hil-arm
    drivers:
      - SerialDriver: {{name: arm-console, bindings: {{port: arm}}}}
options:
  coordinator_address: {coordinator}
""")
    # labgrid's own SerialDriver, bound to the place's NetworkSerialPort, pings servo 3
    script = f"""
import labgrid
from hilbench.protocols import dynamixel as dxl
target = labgrid.Environment({str(remote_env)!r}).get_target()
port = target.get_driver("SerialDriver")
assert port.serial.baudrate == 1_000_000, port.serial.baudrate  # the resource's speed
port.write({PING_3!r})
data = b""
while len(data) < 14:
    data += port.read(size=14 - len(data), timeout=3.0)
reply = dxl.Decoder().feed(data)[0]
print("PING", reply.id, int.from_bytes(reply.data[:2], "little"))
target.cleanup()
"""
    before = _rfc2217_connections(manifest)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "PING 3 1020" in out.stdout
    assert _rfc2217_connections(manifest) == before + 1

    # the user's test suite, unchanged, takes its bench from the place
    before = _rfc2217_connections(manifest)
    suite = _run_user_suite(remote_env, tmp_path)
    assert suite.returncode == 0, suite.stdout[-3000:] + suite.stderr[-2000:]
    assert "2 passed" in suite.stdout
    assert _rfc2217_connections(manifest) > before  # the SDK's traffic went through the remote port

    client("-p", "hil-arm", "release")
    client("-p", "hil-arm", "delete")


def test_the_environment_file_drives_the_bench_without_a_coordinator(served_arm, tmp_path):
    from labgrid import Environment

    manifest, path = served_arm
    env_file = tmp_path / "env.yaml"
    _hilbench("labgrid", "env", str(path), "-o", str(env_file))
    target = Environment(str(env_file)).get_target()
    try:
        port = target.get_driver("SerialDriver", name="arm-console")
        port.write(PING_3)
        data = b""
        while len(data) < 14:
            data += port.read(size=14 - len(data), timeout=3.0)
        assert dxl.Decoder().feed(data)[0].id == 3
        target.deactivate(port)

        dyn = target.get_driver("DynamixelDriver")
        assert dyn.ping(5) == (1060, 52)
        assert dyn.broadcast_ping() == {1: (1020, 52), 2: (1020, 52), 3: (1020, 52), 4: (1020, 52),
                                        5: (1060, 52)}
        dyn.write(1, 112, (77).to_bytes(4, "little"))  # Profile Velocity
        assert dyn.sync_read([1, 2], 112, 4) == {1: (77).to_bytes(4, "little"), 2: b"\x00\x00\x00\x00"}
        with pytest.raises(Exception, match="ID 9 did not answer"):
            dyn.ping(9)
        control = target.get_driver("BenchControlDriver")
        assert control.manifest()["name"] == "arm"
    finally:
        target.cleanup()

    before = _rfc2217_connections(manifest)
    suite = _run_user_suite(env_file, tmp_path)
    assert suite.returncode == 0, suite.stdout[-3000:] + suite.stderr[-2000:]
    assert "2 passed" in suite.stdout
    assert _rfc2217_connections(manifest) > before


def test_the_strategy_brings_the_bench_to_ready(served_arm, tmp_path):
    import yaml
    from labgrid import Environment

    _, path = served_arm
    env_file = tmp_path / "env.yaml"
    _hilbench("labgrid", "env", str(path), "-o", str(env_file))
    config = yaml.safe_load(env_file.read_text())
    config["targets"]["main"]["drivers"].append(
        {"HilbenchStrategy": {"addresses": [1, 5], "bindings": {"bus": "arm-dxl", "control": "bench-control"}}})
    env_file.write_text(yaml.safe_dump(config))
    target = Environment(str(env_file)).get_target()
    try:
        strategy = target.get_driver("HilbenchStrategy")
        strategy.transition("ready")
        assert strategy.status.name == "ready"
        assert strategy.bus.ping(1)[0] == 1020
        strategy.transition("off")
        assert strategy.status.name == "off"
    finally:
        target.cleanup()


def test_a_second_labgrid_user_gets_a_busy_port(served_arm, tmp_path):
    """Two SerialDrivers on one RFC 2217 port: the second is refused as a busy real port would be."""
    from labgrid import Environment

    _, path = served_arm
    env_file = tmp_path / "env.yaml"
    _hilbench("labgrid", "env", str(path), "-o", str(env_file))
    first = Environment(str(env_file)).get_target()
    second = Environment(str(env_file)).get_target("main")
    try:
        first.get_driver("SerialDriver", name="arm-console")
        t0 = time.monotonic()
        # labgrid wraps pyserial's SerialException ("Could not open serial port ..."); the hang-up may
        # also surface as the socket's own error (broken pipe, reset) during negotiation
        with pytest.raises(Exception, match="Could not open serial port|Broken pipe|Connection reset"):
            second.get_driver("SerialDriver", name="arm-console")
        assert time.monotonic() - t0 < 10
    finally:
        first.cleanup()
        second.cleanup()
