"""The hilbench command line, run as a user runs it: separate processes, real ptys."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import dynamixel_sdk as sdk
import pytest

from hilbench.pytest_plugin import wait_until


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize(
    "verb", [[], ["emulate"], ["dxl"], ["dxl", "scan"], ["dxl", "ping"], ["dxl", "read"], ["dxl", "write"],
             ["demo"], ["profiles"], ["monitor"], ["record"], ["tap"]],
)
def test_every_verb_has_help(verb):
    proc = hb(*verb, "--help")
    assert proc.returncode == 0
    assert "usage: hilbench" in proc.stdout


@pytest.fixture(scope="module")
def wolfgang(tmp_path_factory):
    """`hilbench emulate wolfgang` in its own process, shared by the dxl tool tests."""
    manifest = tmp_path_factory.mktemp("emu") / "manifest.json"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "wolfgang", "--manifest",
                             str(manifest)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_until(lambda: manifest.exists() or proc.poll() is not None, timeout=30)
    assert proc.poll() is None, proc.stderr.read()
    data = json.loads(manifest.read_text())
    yield data
    proc.terminate()
    proc.wait(timeout=10)
    proc.stdout.close()
    proc.stderr.close()


def test_manifest_lists_endpoints_and_devices(wolfgang):
    (ep,) = wolfgang["endpoints"]
    assert ep["type"] == "pty" and ep["name"] == "dxl" and ep["baud"] == 2_000_000
    assert os.path.exists(ep["path"])
    devices = {d["id"]: d for d in wolfgang["devices"]}
    assert set(devices) == set(range(1, 21)) | {42, 101, 102, 241}
    assert devices[1]["model"] == "MX-64(2.0)" and devices[1]["model_number"] == 311
    assert devices[11]["firmware"] == 42
    assert all(d["endpoint"] == "dxl" for d in devices.values())


def test_dxl_scan_finds_the_bus(wolfgang):
    path = wolfgang["endpoints"][0]["path"]
    proc = hb("dxl", "scan", path, "--baud", "2000000", "--baud", "1000000", "--json")
    assert proc.returncode == 0, proc.stderr
    found = {(d["id"], d["baud"]): d for d in json.loads(proc.stdout)}
    assert {i for i, b in found if b == 2_000_000} == set(range(1, 21)) | {42, 102, 241}  # 101 never answers
    assert not [k for k in found if k[1] == 1_000_000]  # nothing listens at 1 Mbaud
    assert found[(8, 2_000_000)]["model_name"] == "MX-106(2.0)"
    assert found[(16, 2_000_000)]["firmware"] == 42


def test_dxl_ping_read_write(wolfgang):
    path = wolfgang["endpoints"][0]["path"]
    ping = hb("dxl", "ping", path, "5", "--baud", "2000000")
    assert ping.returncode == 0 and "MX-64(2.0) (model 311), firmware 41" in ping.stdout
    read = hb("dxl", "read", path, "5", "present_input_voltage", "--baud", "2000000", "--json")
    assert json.loads(read.stdout)["value"] == 140 and json.loads(read.stdout)["unit"] == "V"
    write = hb("dxl", "write", path, "5", "goal_position", "3000", "--baud", "2000000")
    assert write.returncode == 0, write.stderr
    back = hb("dxl", "read", path, "5", "116", "4", "--baud", "2000000", "--json")
    assert json.loads(back.stdout)["value"] == 3000
    imu = hb("dxl", "read", path, "241", "accel_z", "--baud", "2000000")
    assert "9.81 m/s^2" in imu.stdout


def test_dxl_errors_are_one_line_and_non_zero(wolfgang):
    path = wolfgang["endpoints"][0]["path"]
    silent = hb("dxl", "ping", path, "101", "--baud", "2000000")
    assert silent.returncode == 1
    assert silent.stderr.strip().splitlines() == [
        "hilbench: error: ping ID 101 at 2000000 baud: [TxRxResult] There is no status packet!"]
    limit = hb("dxl", "write", path, "5", "goal_position", "5000", "--baud", "2000000")
    assert limit.returncode == 1 and "data limit error" in limit.stderr
    unknown = hb("dxl", "read", path, "5", "warp_factor", "--baud", "2000000")
    assert unknown.returncode == 2 and "has no field 'warp_factor'" in unknown.stderr  # what you asked: 2
    huge = hb("dxl", "write", path, "5", "goal_position", "-99999999999", "--baud", "2000000")
    assert huge.returncode == 2
    assert huge.stderr.splitlines() == ["hilbench: error: -99999999999 does not fit in 4 byte(s) (a signed item)"]
    noport = hb("dxl", "ping", "/dev/no-such-port", "1")
    assert noport.returncode == 1 and len(noport.stderr.strip().splitlines()) == 1


def test_sdk_in_another_process_runs_a_wolfgang_cycle(wolfgang):
    port = sdk.PortHandler(wolfgang["endpoints"][0]["path"])
    assert port.openPort() and port.setBaudRate(2_000_000)
    ph = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in range(1, 21):
        reader.addParam(i)
    for _ in range(50):
        assert reader.txRxPacket() == sdk.COMM_SUCCESS
    assert all(reader.isAvailable(i, 132, 4) for i in range(1, 21))
    # the foot sensor read of every Wolfgang cycle times out, as on the robot
    assert ph.readTxRx(port, 101, 36, 16)[1] == sdk.COMM_RX_TIMEOUT
    port.closePort()


def test_emulate_links_and_cleans_up(tmp_path):
    manifest = tmp_path / "m.json"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "arm", "--manifest", str(manifest),
                             "--link-dir", str(tmp_path / "dev")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        wait_until(manifest.exists, timeout=30)
        link = tmp_path / "dev" / "arm"
        assert os.path.islink(link)
        assert json.loads(manifest.read_text())["endpoints"][0]["path"] == str(link)
        port = sdk.PortHandler(str(link))
        assert port.openPort()
        assert sdk.PacketHandler(2.0).ping(port, 5)[0] == 1060  # the XL430 gripper
        port.closePort()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert f"arm: {tmp_path / 'dev' / 'arm'} -> /dev/pts/" in out  # the link, then the pty it points to
    assert not manifest.exists() and not os.path.lexists(tmp_path / "dev" / "arm")


def test_demo_runs_the_sdk_against_the_default_bench():
    proc = hb("demo", "--seconds", "3", timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    # the dashboard's last frame (stdout is not a terminal: only the final frame is printed)
    assert "hilbench monitor  demo wolfgang on /dev/" in out and "Device overview" in out
    assert "cycles, done]" in out
    assert all(len(line) <= 80 for line in out.splitlines())
    # what the monitor saw of the staged faults, and what the SDK saw
    assert "monitor: ID 7 dropped out 1 time(s)" in out and "came back" in out
    assert "monitor: ID 12 alert on, hardware error: overheating" in out
    assert "monitor: never answered: ID 101" in out
    summary = out.strip().splitlines()[-1]
    assert summary.startswith("demo: ")
    cycles, failed = int(summary.split()[1]), int(summary.split(", ")[-1].split()[0])
    assert cycles > 100 and failed >= 5  # the Sync Reads that time out while ID 7 is gone


@pytest.mark.parametrize("profile, protocol, error_line", [
    ("poppy-humanoid", "dynamixel1", "the last: overheating"),  # Protocol 1.0: dynamixel-sdk's 1.0 handler
    ("so101-follower", "feetech", "the last: overheat"),  # Feetech's own scservo_sdk
])
def test_demo_drives_each_servo_bus_with_its_own_protocol(profile, protocol, error_line):
    pytest.importorskip("scservo_sdk", reason="feetech-servo-sdk is not installed (it is in the test extra)")
    proc = hb("demo", "--profile", profile, "--seconds", "2", "--unpaced", timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert f"demo {profile} on /dev/" in out and "Device overview" in out
    assert " 0 disconnected" in out and "CRC 0" in out  # the dashboard: every servo answers, clean frames
    assert "dropped out 1 time(s)" in out and "came back" in out
    assert error_line in out  # the staged overheat, in the status error byte
    summary = out.strip().splitlines()[-1]
    cycles, failed = int(summary.split()[1]), int(summary.split(", ")[-1].split()[0])
    # every read succeeds but those of the servo that drops out (a Protocol 2.0 loop failed every one)
    assert cycles > 20 and 0 < failed < cycles / 2


@pytest.mark.parametrize("seconds", [
    "0.5",  # the normal set: a short run (each run costs about 3 s of wall time a virtual second on 2 busy cores)
    pytest.param("2", marks=pytest.mark.slow),  # issue 26's test: 2 virtual seconds
])
def test_demo_in_virtual_time_prints_the_same_figures_in_two_runs(seconds):
    """Issue 26: `demo --virtual-time` runs the SDK's loop in a child process in lockstep with the bench and
    stages the faults as the bench's timers, so two runs print the same cycles, failed reads and monitor lines
    (only the dashboard's pty name and its wall-clock packet rate may differ)."""
    from hilbench.run.build import ShimBuildError, shim_library

    try:
        shim_library()
    except ShimBuildError as exc:
        pytest.skip(f"the preload library cannot be built: {exc}")
    env = {k: v for k, v in os.environ.items() if k not in ("HILBENCH_CLOCK", "PYTHONHASHSEED")}
    # both at once: each run is the other's busy neighbour on the machine, which virtual time does not see
    procs = [subprocess.Popen([sys.executable, "-m", "hilbench.cli", "demo", "--virtual-time", "--seconds", seconds],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for _ in range(2)]
    results = []
    try:
        for proc in procs:
            out, err = proc.communicate(timeout=120)
            results.append((proc.returncode, out, err))
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    figures = []
    for returncode, out, err in results:
        assert returncode == 0, err
        assert "may differ from run to run" not in err  # (a lockstep stall would make the runs differ: say why)
        assert "hilbench monitor  demo wolfgang on /d" in out and f"[SDK: done, virtual {float(seconds):.1f} s]" in out
        figures.append([line for line in out.splitlines() if line.startswith(("monitor: ", "demo: "))])
    assert figures[0] == figures[1]
    monitor = [line for line in figures[0] if line.startswith("monitor: ")]
    started, summary = [line for line in figures[0] if line.startswith("demo: ")]
    # (the control loop's Pings and set-up take the same virtual time in every run)
    assert started.startswith("demo: the control loop started 0.0") and started.endswith(" virtual s after the bench")
    assert monitor[0].startswith("monitor: ID 7 dropped out 1 time(s), missed ") and "came back" in monitor[0]
    assert monitor[1:] == ["monitor: ID 12 alert on, hardware error: overheating", "monitor: never answered: ID 101"]
    assert summary.startswith("demo: ") and f" control cycles in {float(seconds):.1f} virtual s " in summary
    cycles, failed = int(summary.split()[1]), int(summary.split(", ")[-1].split()[0])
    missed = int(monitor[0].split("missed ")[1].split()[0])
    # every failed Sync Read is one of ID 7's replies missed while it was gone (the bench's timer), and no other
    assert cycles > 60 * float(seconds) and failed == missed > 0


def test_demo_refuses_virtual_time_unpaced_in_one_line(capsys):
    from hilbench.cli import main

    assert main(["demo", "--virtual-time", "--unpaced", "--seconds", "1"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "hilbench: error: virtual time is paced: --unpaced and --virtual-time do not go together"]


@pytest.mark.parametrize("profile", ["mecarover", "scanners"])
def test_demo_refuses_a_profile_without_a_servo_bus_in_one_line(profile, capsys):
    from hilbench.cli import main

    assert main(["demo", "--profile", profile, "--seconds", "1"]) == 2  # before any bench starts
    out, err = capsys.readouterr()
    assert out == ""
    (line,) = err.splitlines()
    assert line.startswith(f"hilbench: error: demo drives a servo bus (Dynamixel or Feetech) and profile {profile!r}")
    assert f"hilbench emulate {profile}" in line


def test_demo_on_a_feetech_bus_without_feetechs_sdk_names_it(monkeypatch, capsys):
    from hilbench.cli import main

    monkeypatch.setitem(sys.modules, "scservo_sdk", None)  # an import of it fails
    assert main(["demo", "--profile", "so101-follower", "--seconds", "1"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "hilbench: error: driving a Feetech bus needs scservo_sdk: pip install feetech-servo-sdk"]


def test_the_demo_reaches_servo_buses_through_each_family_s_servo_client():
    """The demo names no family: the servo clients registered (role "servo") say which buses it drives, with
    which SDK link, what else it reads on the bus, and which dashboard views --view takes."""
    from hilbench import registry
    from hilbench.cli import build_parser
    from hilbench.clients.dynamixel_demo import check_profile
    from hilbench.clients.servo_connections import ServoClient, servo_clients
    from hilbench.dashboard.servo_bus_views import VIEWS
    from hilbench.protocols.control_table import Model

    clients = servo_clients()
    assert {p: type(c).__module__ for p, c in clients.items()} == {
        "dynamixel": "hilbench.clients.dynamixel_servos", "feetech": "hilbench.clients.feetech"}
    dxl = clients["dynamixel"]
    assert type(dxl.connection({"protocol_version": 1}, "/dev/null", 57_600)).__name__ == "Dxl1Connection"
    assert type(dxl.connection({}, "/dev/null", 57_600)).__name__ == "Dxl2Connection"
    assert dxl.connection({}, "/dev/null", 1).status_errors is False and clients["feetech"].connection({}, "x", 1).status_errors
    foot, servo = (Model(name=n, number=0, firmware=0, fields=(), table_size=0) for n in ("Wolfgang Foot", "XH540"))
    assert dxl.sensor_reads([(101, foot), (1, servo)]) == [(101, 36, 16)]
    demo = build_parser(["demo"])._subparsers._group_actions[0].choices["demo"]
    view = next(a for a in demo._actions if a.dest == "view")
    assert tuple(view.choices) == VIEWS and view.default == VIEWS[0]

    class AcmeServos(ServoClient):  # an outside family's servo bus joins the list the demo drives
        protocol = "acme-servo"
        bus_title = "Acme"

    registry.clients.register("acme-servo", AcmeServos())
    try:
        from hilbench.bench.profile import load_profile

        with pytest.raises(Exception, match=r"demo drives a servo bus \(Dynamixel or Feetech or Acme\)"):
            check_profile(load_profile("mecarover"))
    finally:
        registry.clients.unregister("acme-servo")


def test_profiles_lists_the_bundled_ones():
    proc = hb("profiles")
    assert proc.returncode == 0
    assert "wolfgang (default)" in proc.stdout and "arm:" in proc.stdout


@pytest.mark.parametrize("args", [[], ["dxl", "read"], ["trace", "x", "--period", "foo=bar"],
                                  ["send-vel", "P", "a", "b", "c"], ["monitor", "x", "--view", "nope"]])
def test_usage_errors_are_one_line(args):
    proc = hb(*args)
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "error:" in proc.stderr and "--help" in proc.stderr
