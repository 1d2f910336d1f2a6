"""The CAN command line as a user runs it: `hilbench emulate mecarover-can` in one process, `hilbench can ...`,
`hilbench record` and `hilbench monitor` in others; the exported DBC decodes every frame of a whole session."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import can
import canopen
import cantools
import pytest

from hilbench.bench.control import ControlClient
from hilbench.bench.profile import load_profile, parse_profile
from hilbench.errors import UsageError
from hilbench.protocols import board_can as bc
from hilbench.protocols import can_frame as cf
from hilbench.pytest_plugin import wait_until
from hilbench.transports.chunk import Chunk
from hilbench.transports.sources import open_source
from tests.conftest import REPO, interrupt


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


#: `hilbench can`'s own sub-commands, and those the CANopen board family adds (entry point `can.canopen`).
GENERIC_COMMANDS = ("dump", "send", "nmt", "sdo", "bus")
BOARD_COMMANDS = ("dbc", "eds", "drive", "status", "fault", "emcy", "reset", "state")


def test_can_help_lists_the_canopen_board_commands_its_extension_adds():
    from hilbench import registry
    from hilbench.cli import build_parser

    assert registry.verbs.get("can.canopen").__name__ == "hilbench.cli.canopen_board"
    parser = build_parser(["can", "--help"])
    verb = parser._subparsers._group_actions[0].choices["can"]
    commands = verb._subparsers._group_actions[0].choices
    assert tuple(commands) == GENERIC_COMMANDS + BOARD_COMMANDS
    assert {commands[c].get_default("func").__module__ for c in GENERIC_COMMANDS} == {"hilbench.cli.can"}
    assert {commands[c].get_default("func").__module__ for c in BOARD_COMMANDS} == {"hilbench.cli.canopen_board"}
    out = hb("can", "--help")
    assert out.returncode == 0, out.stderr
    listed = out.stdout.split("positional arguments:")[1]
    assert all(f"\n    {c} " in listed for c in GENERIC_COMMANDS + BOARD_COMMANDS), listed
    # the extension's synopsis lines join the verb's list of commands, before the text after it
    synopsis = out.stdout.split("positional arguments:")[0]
    assert (synopsis.index("hilbench can bus --manifest") < synopsis.index("hilbench can dbc PROFILE")
            < synopsis.index("hilbench can status|fault|emcy|reset|state") < synopsis.index("BUS is a bench"))


def test_dbc_and_eds_exports(tmp_path):
    out = hb("can", "dbc", "mecarover-can")
    assert out.returncode == 0, out.stderr
    db = cantools.database.load_string(out.stdout, "dbc")
    assert db.get_message_by_frame_id(0x202).name == "VelocitySetpoint_02"
    eds = tmp_path / "rover.eds"
    out = hb("can", "eds", "mecarover-can", "-o", str(eds))
    assert out.returncode == 0, out.stderr
    od = canopen.import_od(str(eds), 2)
    assert od[0x1017].default == 1000 and od[0x1800][1].default == 0x182
    bad = hb("can", "dbc", "mecarover")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no CANopen boards" in bad.stderr


@pytest.mark.parametrize(("endpoint", "where"), [
    ({"bitrate": 2_000_000}, "endpoints.can.bitrate"),
    ({"bitrate": 500_000, "baud": 500_000}, "endpoints.can.baud"),
    ({"socketcand": {"prt": 1}}, "endpoints.can.socketcand.prt"),
    ({"socketcand": {"channel": "a b"}}, "endpoints.can.socketcand.channel"),
    ({"bus_faults": {"error_rate": 3}}, "endpoints.can.bus_faults.error_rate"),
    ({"slcan": 5}, "endpoints.can.slcan"),
])
def test_profile_mistakes_are_one_line(endpoint, where):
    data = {"schema": 1, "endpoints": {"can": {"type": "can", "protocol": "can", **endpoint}},
            "devices": [{"model": "stm32f767-rover-canopen"}]}
    with pytest.raises(UsageError) as exc:
        parse_profile(data, "p.toml")
    assert str(exc.value).startswith(f"p.toml: {where}: ") and "\n" not in str(exc.value)


def test_two_boards_need_two_node_ids():
    data = {"schema": 1, "endpoints": {"can": {"type": "can", "protocol": "can"}},
            "devices": [{"model": "stm32f767-rover-canopen", "name": "a"},
                        {"model": "stm32f767-rover-canopen", "name": "b"}]}
    with pytest.raises(UsageError, match="devices\\[1\\].node_id: node id 2 is taken"):
        parse_profile(data, "p.toml")
    data["devices"][1]["node_id"] = 3
    assert [d.node_id for d in parse_profile(data, "p.toml").devices_of("canopen")] == [2, 3]
    assert load_profile("mecarover-can").endpoints["can"].baud == 500_000


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".trc"])
def test_python_can_log_formats_round_trip(tmp_path, suffix):
    from hilbench.transports.can_log import RECORDER

    class Src:
        protocol, live, wall_offset = "can", False, 1_700_000_000.0

    path = str(tmp_path / f"run{suffix}")
    assert RECORDER.accepts(path, "can") and not RECORDER.accepts(path, "dynamixel")
    rec = RECORDER.open(path, source=Src())
    frames = [cf.data_frame(0x182, bytes(range(8))), cf.data_frame(0x18FF50E5, b"\x01", extended=True),
              cf.data_frame(0x702, b"\x05")]
    for i, f in enumerate(frames):
        rec.chunk(Chunk(i * 0.5, "rover", cf.pack(f)))
    rec.close()
    with open_source(path) as source:
        assert source.protocol == "can"
        got = [(c.t, cf.split(c.data)[0][0]) for c in source]
    assert [f for _, f in got] == frames
    times = [t for t, _ in got]
    assert times[1] - times[0] == pytest.approx(0.5, abs=1e-3)


def test_not_candump_log_is_an_ordinary_file(tmp_path):
    path = tmp_path / "notes.log"
    path.write_text("hello\n")
    with open_source(str(path)) as source:
        assert source.protocol is None


def test_socketcan_source_says_why(tmp_path):
    from hilbench.transports.socketcan import af_can_status

    if af_can_status()[0]:
        pytest.skip("the kernel has AF_CAN: no error to see")
    out = hb("monitor", "socketcan://vcan0", "--summary", "--json")
    assert out.returncode == 2 and "AF_CAN" in out.stderr and out.stderr.count("\n") == 1


def _wait_for_raw_client(manifest: str) -> None:
    """Until a socketcand client (a CLI started in another process) is in raw mode, i.e. hears the bus."""
    control = ControlClient.from_manifest(manifest)
    wait_until(lambda: control.media()["can"]["host"]["socketcand"]["modes"].get("raw", 0) >= 1, timeout=20,
               interval=0.05)


@pytest.fixture
def can_bench(hilbench_emulator):
    manifest = hilbench_emulator("mecarover-can")
    path = manifest["process"].args[manifest["process"].args.index("--manifest") + 1]
    s = manifest["endpoints"][0]["socketcand"]
    return path, f"socketcand://{s['host']}:{s['port']}/{s['channel']}", manifest


def test_sdo_to_an_absent_node_is_one_line_of_ours(can_bench):
    """canopen logs its own abort ("Transfer aborted by client ...") first; the command says it once."""
    pytest.importorskip("canopen", reason="canopen is not installed (it is in the can extra)")
    manifest, _, _ = can_bench
    out = hb("can", "sdo", manifest, "read", "1018:1", "--node", "5", "--timeout", "0.3")
    assert out.returncode == 1 and out.stdout == ""
    assert out.stderr.splitlines() == [
        "hilbench: error: node 5 0x1018:01: no SDO response within 0.3 s (is node 5 on the bus?)"]
    bad = hb("can", "sdo", manifest, "read", "1018:9", "--node", "2")  # the node's own abort: one line too
    assert bad.returncode == 1 and bad.stderr.splitlines() == [
        "hilbench: error: node 2 0x1018:09: SDO aborted: Code 0x06090011, Subindex does not exist"]


@pytest.mark.slow  # a long CLI session against python-can and cantools: the slow real-client set
def test_a_whole_session_decodes_with_the_exported_dbc(can_bench, tmp_path):
    manifest, url, data = can_bench
    log = tmp_path / "session.log"
    recorder = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "record", f"{manifest}#can", str(log)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        control = ControlClient.from_manifest(manifest)
        # recording (the bench's other endpoint, the rover's RPLIDAR, has a tap nobody reads)
        wait_until(lambda: control.taps()["can"]["clients"] >= 1, timeout=30)
        assert hb("can", "nmt", manifest, "start", "--node", "2").returncode == 0
        out = hb("can", "sdo", manifest, "read", "1018:1", "--node", "2")
        assert out.returncode == 0 and out.stdout.startswith(str(bc.BoardCanConfig().vendor_id)), out.stderr
        out = hb("can", "sdo", manifest, "read", "1008", "--node", "2", "--type", "str")
        assert out.stdout.strip() == bc.BoardCanConfig().device_name
        assert hb("can", "sdo", manifest, "write", "1017", "500", "--type", "u16", "--node", "2").returncode == 0
        bad = hb("can", "sdo", manifest, "read", "5555", "--node", "2")
        assert bad.returncode == 1 and "0x06020000" in bad.stderr
        out = hb("can", "drive", manifest, "--vx", "0.2", "--seconds", "1")
        assert out.returncode == 0, out.stderr
        drive = json.loads(out.stdout)
        assert drive["pose"]["x"] > 0.12 and drive["nmt_state"] == 5
        # faster than the wheels turn: sent as given (the board saturates them), with one warning line
        out = hb("can", "drive", manifest, "--vx", "0.6", "--omega", "0.5", "--seconds", "0.2")
        assert out.returncode == 0 and json.loads(out.stdout)["setpoints_sent"] >= 1, out.stderr
        assert out.stderr.count("\n") == 1 and "warning: x 0.6 m/s, y 0 m/s, z 0.5 rad/s needs a wheel at 15.12 " \
                                                "rad/s" in out.stderr, out.stderr
        out = hb("can", "emcy", "--manifest", manifest, "0x2310", "--data", "0102")
        assert out.returncode == 0, out.stderr
        status = json.loads(hb("can", "status", "--manifest", manifest).stdout)
        assert status["status"]["heartbeat_ms"] == 500 and status["status"]["pose"]["x"] > 0.12
        # the record must hold heartbeats at the new period: see three on the bus (two 500 ms gaps)
        s = data["endpoints"][0]["socketcand"]
        with can.Bus(interface="socketcand", host=s["host"], port=s["port"], channel=s["channel"]) as bus:
            seen = 0
            deadline = time.monotonic() + 10
            while seen < 3 and time.monotonic() < deadline:
                frame = bus.recv(timeout=1)
                seen += frame is not None and frame.arbitration_id == 0x702
            assert seen == 3
    finally:
        _, err = interrupt(recorder, timeout=30)
    assert recorder.returncode == 0, err
    db = cantools.database.load_string(hb("can", "dbc", "mecarover-can").stdout, "dbc")
    messages = list(can.LogReader(str(log)))
    ids = {m.arbitration_id for m in messages}
    assert {0x000, 0x082, 0x182, 0x202, 0x282, 0x382, 0x482, 0x582, 0x602, 0x702} <= ids
    for m in messages:  # every frame of the session, strictly
        db.decode_message(m.arbitration_id, bytes(m.data))
    # cantools' own command line reads the candump log and decodes every line with the exported DBC.
    dbc = tmp_path / "rover.dbc"
    dbc.write_text(hb("can", "dbc", "mecarover-can").stdout)
    decoded = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line", str(dbc)],
                             input=log.read_text(), capture_output=True, text=True, timeout=60)
    lines = decoded.stdout.splitlines()
    assert decoded.returncode == 0 and len(lines) == len(messages)
    assert all(" :: " in line and "Unknown frame id" not in line for line in lines)
    assert any(":: OdometryPose_02(x: " in line for line in lines)
    report = json.loads(hb("monitor", str(log), "--summary", "--json", "--dbc", "mecarover-can").stdout)
    node = report["nodes"]["2"]
    assert node["nmt_state"] == "OPERATIONAL" and node["heartbeat_period_ms"] == 500.0
    assert node["sdo"]["aborts"] == 1 and node["last_emcy"]["code"] == "0x2310"
    assert report["ids"]["0x282"]["name"] == "OdometryPose_02" and report["ids"]["0x282"]["signals"]["x"] > 0.12
    assert report["ids"]["0x182"]["rate_hz"] == pytest.approx(50, rel=0.1)


@pytest.mark.slow  # a long CLI session on a live CAN bench: the slow set
def test_monitor_a_live_bench_with_faults(can_bench):
    manifest, url, data = can_bench
    assert hb("can", "fault", "--manifest", manifest, "heartbeat_stop=true").returncode == 0
    out = hb("can", "bus", "--manifest", manifest, "error_next=3", "--compact")
    assert out.returncode == 0 and json.loads(out.stdout)["bus"]["faults"]["error_next"] == 3
    # Nothing is sent while the heartbeat is off; the first heartbeat after switching it back on takes the errors.
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "monitor", f"{url}?bitrate=500000", "--summary",
                             "--json", "--seconds", "4.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=REPO)
    _wait_for_raw_client(manifest)  # the monitor listens before the heartbeat (and the errors) come back
    assert hb("can", "fault", "--manifest", manifest, "heartbeat_stop=false").returncode == 0
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    report = json.loads(out)
    assert report["protocol"] == "can" and report["bitrate"] == 500_000
    assert report["error_frames"]["total"] == 3 and report["error_frames"]["classes"]["protocol"] == 3
    assert report["ids"]["0x702"]["count"] >= 2 and report["nodes"]["2"]["nmt_state"] == "PRE-OPERATIONAL"
    assert report["bus"]["mean_load"] is not None


def test_send_and_dump(can_bench):
    manifest, url, data = can_bench
    dump = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "can", "dump", url, "--dbc", "mecarover-can",
                             "-n", "8", "--seconds", "20"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    _wait_for_raw_client(manifest)  # the dump listens before anything is sent
    out = hb("can", "send", manifest, "000#0102", "123#DEADBEEF")
    assert out.returncode == 0, out.stderr
    lines, err = dump.communicate(timeout=30)
    assert dump.returncode == 0, err
    assert any(" can0 000#0102 :: NMT(command: start, node: 2)" in line for line in lines.splitlines())
    assert any(line.endswith(" can0 123#DEADBEEF") for line in lines.splitlines())
    wait_until(lambda: json.loads(hb("can", "status", "--manifest", manifest).stdout)["status"]["nmt_state"]
               == "OPERATIONAL", timeout=10)
    bad = hb("can", "send", manifest, "12#00")
    assert bad.returncode == 2 and "cansend" in bad.stderr


@pytest.mark.slow  # a long CLI session on a live CAN bench: the slow set
def test_record_a_live_bus_to_a_capture_and_convert_it(can_bench, tmp_path):
    manifest, url, data = can_bench
    cap = tmp_path / "bus.hbcap"
    out = hb("record", f"{url}?bitrate=500000", str(cap), "--seconds", "2.5")
    assert out.returncode == 0, out.stderr
    report = json.loads(hb("monitor", str(cap), "--summary", "--json").stdout)
    assert report["protocol"] == "can" and report["bitrate"] == 500_000
    assert report["ids"]["0x702"]["count"] >= 2 and report["nodes"]["2"]["nmt_state"] == "PRE-OPERATIONAL"
    log = tmp_path / "bus.log"
    assert hb("record", str(cap), str(log)).returncode == 0  # capture -> candump log, times kept as Unix time
    messages = list(can.LogReader(str(log)))
    assert [m.arbitration_id for m in messages] == [0x702] * len(messages) and len(messages) >= 2
    assert abs(messages[-1].timestamp - time.time()) < 60
