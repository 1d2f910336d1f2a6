"""`hilbench monitor`, `record` and `tap` run as a user runs them: separate processes, real ptys and sockets."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import dynamixel_sdk as sdk
import pytest

from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader
from tests.conftest import interrupt

OK = sdk.COMM_SUCCESS


def hb(*args: str, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout, **kw)


def summary_of(*args: str, **kw) -> dict:
    proc = hb("monitor", *args, "--json", **kw)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.fixture(scope="module")
def trace(tmp_path_factory):
    from tests.conftest import WOLFGANG_TRACE

    return str(WOLFGANG_TRACE)


def test_monitor_summary_of_the_wolfgang_capture(trace):
    report = summary_of(trace, "--max-length", "65535")
    assert report["crc_errors"] == 948 and report["problems"]["truncated"] == 4
    assert {k: v for k, v in report["packets"].items() if v} == {
        "ping": 20, "read": 889, "status": 21_069, "sync_read": 1_057, "sync_write": 426, "write": 17}
    devices = report["devices"]
    assert set(devices) == {str(i) for i in range(1, 21)} | {"101"}
    assert devices["1"]["model"] == 311 and devices["1"]["model_name"] == "MX-64(2.0)"
    assert devices["1"]["firmware"] == 41 and devices["1"]["state"] == "connected"
    foot = devices["101"]
    assert (foot["state"], foot["never_answered"], foot["misses"]) == ("disconnected", True, 889)
    assert report["models"]["<unknown>"]["ids"] == [7, 10, 12, 101]
    assert report["bus"]["main_cycle"]["count"] == 1038


def test_record_converts_a_raw_dump_and_replays_to_the_same_summary(trace, tmp_path):
    out = tmp_path / "wolfgang.hbcap"
    proc = hb("record", trace, str(out), "--baud", "2000000")
    assert proc.returncode == 0, proc.stderr
    assert "recorded 528509 bytes" in proc.stdout
    with CaptureReader(out) as r:
        assert r.timestamps == "synthetic" and r.info.baud == 2_000_000
    direct = summary_of(trace, "--baud", "2000000", "--compact")
    replayed = summary_of(str(out), "--compact")
    for report in (direct, replayed):
        report.pop("source")
    assert replayed == direct
    assert direct["timestamps"] == "synthetic" and direct["bus"]["load"] == pytest.approx(1.0, abs=0.001)
    # stdin works too, and the text summary names the silent device
    with open(trace, "rb") as fh:
        proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "monitor", "-", "--summary"], stdin=fh,
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "never answered: ID 101" in proc.stdout


def test_monitor_and_record_a_bench_in_another_process(hilbench_emulator, tmp_path, patient_sdk):
    manifest = hilbench_emulator("wolfgang")
    path = manifest["endpoints"][0]["path"]
    assert manifest["endpoints"][0]["tap"].startswith("tcp://127.0.0.1:")
    mfile = tmp_path / "bench.json"
    mfile.write_text(json.dumps({k: v for k, v in manifest.items() if k != "process"}))
    capture = tmp_path / "live.hbcap"
    procs = [
        # --baud overrides what the tap's header says (the user knows the line better)
        subprocess.Popen([sys.executable, "-m", "hilbench.cli", "monitor", str(mfile), "--json", "--seconds", "2",
                          "--baud", "3000000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
        subprocess.Popen([sys.executable, "-m", "hilbench.cli", "record", str(mfile), str(capture), "--seconds",
                          "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True),
    ]
    port = sdk.PortHandler(path)
    assert port.openPort() and port.setBaudRate(2_000_000)
    ph = sdk.PacketHandler(2.0)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in range(1, 21):
        reader.addParam(i)
    while any(p.poll() is None for p in procs):
        assert reader.txRxPacket() == OK
    port.closePort()
    outs = [p.communicate(timeout=10) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    assert json.loads(outs[0][0])["baud"] == 3_000_000
    for report in (json.loads(outs[0][0]), summary_of(str(capture))):
        sync_reads, statuses = report["packets"]["sync_read"], report["packets"]["status"]
        assert sync_reads > 10 and abs(statuses - 20 * sync_reads) <= 20  # a cycle may be cut at either end
        assert report["crc_errors"] == 0
        assert {report["devices"][str(i)]["state"] for i in range(1, 21)} == {"connected"}
        assert report["devices"]["1"]["latency_ms"]["max"] < 50


def test_tap_forwards_a_full_sdk_session_byte_exactly(hilbench_bench, tmp_path, patient_sdk):
    bench = hilbench_bench("wolfgang")
    ep = bench.endpoint()
    seen: list[tuple[str, bytes]] = []
    lock = threading.Lock()

    def on_line(t, source, data):
        with lock:
            seen.append((source, data))

    ep.medium.add_tap(on_line)
    link = tmp_path / "app"
    capture = tmp_path / "tap.hbcap"
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "tap", ep.path, "--link", str(link),
                             "--record", str(capture), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: os.path.islink(link) or proc.poll() is not None, timeout=30)
        assert proc.poll() is None, proc.stderr.read()
        port = sdk.PortHandler(str(link))
        assert port.openPort() and port.setBaudRate(2_000_000)  # the tap follows: the bench hears 2 Mbaud
        ph = sdk.PacketHandler(2.0)
        assert ph.ping(port, 3)[1:] == (OK, 0)
        # Goal PWM -1 and Goal Current -3 in one write: FF FF FD FF, the header pattern, sent unstuffed
        assert ph.write4ByteTxRx(port, 3, 100, 0xFFFDFFFF) == (OK, 0)
        assert ph.read4ByteTxRx(port, 3, 100) == (0xFFFDFFFF, OK, 0)
        reader = sdk.GroupSyncRead(port, ph, 132, 4)
        writer = sdk.GroupSyncWrite(port, ph, 116, 4)
        for i in range(1, 21):
            reader.addParam(i)
            writer.addParam(i, [0, 8, 0, 0])
        for _ in range(20):
            assert reader.txRxPacket() == OK
            assert writer.txPacket() == OK
        bulk = sdk.GroupBulkRead(port, ph)
        bulk.addParam(1, 144, 2)
        bulk.addParam(2, 0, 2)
        assert bulk.txRxPacket() == OK
        assert ph.readTxRx(port, 101, 36, 16)[1] == sdk.COMM_RX_TIMEOUT
        port.closePort()
        wait_until(lambda: sum(len(d) for s, d in list(seen) if s == "dxl") == 10 + 16 + 14 + 20 * (34 + 114)
                   + 20 + 14)
    finally:
        out, err = interrupt(proc)
    assert proc.returncode == 0, err
    # byte-exact: what the application sent is what the bench received, and back
    with lock:
        to_bench = b"".join(d for s, d in seen if s == "dxl")
        from_bench = b"".join(d for s, d in seen if s == "dxl-devices")
    with CaptureReader(capture) as r:
        chunks = list(r)
    assert b"".join(c.data for c in chunks if c.source == "app") == to_bench
    assert b"".join(c.data for c in chunks if c.source == "device") == from_bench
    report = json.loads(out[out.index("{"):])
    assert report["baud"] == 2_000_000  # the bus load is computed at the rate the application set
    assert {k: v for k, v in report["packets"].items() if v} == {
        "ping": 1, "write": 1, "read": 2, "sync_read": 20, "sync_write": 20, "bulk_read": 1,
        "status": 1 + 1 + 1 + 20 * 20 + 2}
    values = report["devices"]["3"]["values"]
    assert (values["goal_pwm"]["raw"], values["goal_current"]["raw"], values["goal_current"]["how"]) == (-1, -3, "read")
    assert report["devices"]["2"]["model_name"] == "MX-64(2.0)"  # from its Model Number read
    assert "forwarded" in err


def test_monitor_errors_are_one_line(tmp_path):
    proc = hb("monitor", str(tmp_path / "nothing.hbcap"), "--json")  # not there: exit 1 (errors.py's rule)
    assert proc.returncode == 1 and proc.stderr.strip() == (
        f"hilbench: error: {tmp_path / 'nothing.hbcap'}: no such file, port or source")
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    proc = hb("monitor", str(bad), "--json")
    assert proc.returncode == 2 and "not a bench manifest" in proc.stderr
    proc = hb("tap", "/dev/no-such-port")  # not there: exit 1
    assert proc.returncode == 1 and len(proc.stderr.strip().splitlines()) == 1


def test_monitor_refuses_a_line_that_is_not_dynamixel(hilbench_emulator, tmp_path):
    manifest = hilbench_emulator("mecarover")
    mfile = tmp_path / "bench.json"
    mfile.write_text(json.dumps({k: v for k, v in manifest.items() if k != "process"}))
    proc = hb("monitor", f"{mfile}#rover", "--json")
    assert proc.returncode == 2
    from hilbench import registry

    mine = "/".join(i.protocol for i in registry.instruments.values() if i.verb == "monitor")
    assert proc.stderr.strip() == (f"hilbench: error: {mfile}#rover carries vel2d, not {mine} "
                                   "(a board's trace output: use `hilbench trace`)")


@pytest.mark.parametrize("size", [300, 100_000])
def test_random_bytes_are_no_known_traffic(tmp_path, size):
    """Noise is not called anyone's traffic (a board's trace decoder finds a few well-formed words in it)."""
    import random

    noise = tmp_path / "noise.bin"
    noise.write_bytes(random.Random(size).randbytes(size))
    proc = hb("monitor", str(noise), "--summary")
    assert proc.returncode == 2 and proc.stdout == ""
    (line,) = proc.stderr.splitlines()
    assert line.startswith(f"hilbench: error: {noise}: no known traffic recognised in its first {min(size, 8192)} "
                           "bytes (if it carries one of can, dynamixel")
    assert line.endswith("say which: --protocol P)")


def test_a_trace_is_still_told_from_its_bytes(tmp_path):
    from tests.stm32_vectors import TRACE_64, lines

    path = tmp_path / "t64.txt"
    path.write_bytes(lines(TRACE_64))
    proc = hb("monitor", str(path), "--summary")
    assert proc.returncode == 2
    assert "carries vel2d" in proc.stderr and "use `hilbench trace`" in proc.stderr


def test_random_bytes_are_no_can_frames_nor_a_scanner_for_the_other_verbs(tmp_path):
    """The neighbours of monitor's refusal: `can dump` decoded noise as frames (exit 0), `lidar` tried a file as
    a serial port (exit 1, an ioctl error); raw SocketCAN frames still dump."""
    import random
    import struct

    from tests.conftest import WOLFGANG_TRACE

    noise = tmp_path / "noise.bin"
    noise.write_bytes(random.Random(7).randbytes(4096))
    for path, says in ((noise, "no CAN frames recognised in its first bytes"),
                       (WOLFGANG_TRACE, "it carries dynamixel")):
        proc = hb("can", "dump", str(path))
        assert proc.returncode == 2 and proc.stdout == "", proc.stderr
        assert proc.stderr.splitlines() == [f"hilbench: error: {path}: {says} (can dump reads candump and python-can "
                                            "logs, hilbench captures of a CAN bus and raw SocketCAN frames)"]
    raw = tmp_path / "raw.bin"
    raw.write_bytes(b"".join(struct.pack("<IB3x8s", 0x702, 1, b"\x7f" + bytes(7)) for _ in range(3)))
    proc = hb("can", "dump", str(raw))
    assert proc.returncode == 0 and proc.stdout.splitlines() == ["(0.000000) can0 702#7F"] * 3, proc.stderr
    proc = hb("lidar", str(noise))
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        f"hilbench: error: {noise}: a file, not a scanner's port: lidar drives a live scanner (a serial port, "
        "tcp://HOST:PORT, a manifest's FILE.json#ENDPOINT); `hilbench monitor` reads a recording of one"]


@pytest.mark.parametrize("argv", [["dxl", "ping", "{f}", "1"], ["dxl", "scan", "{f}", "--baud", "57600"],
                                  ["send-vel", "{f}", "0", "0", "0"], ["tap", "{f}", "--seconds", "1"]])
def test_a_file_given_as_a_serial_port_is_a_usage_error(tmp_path, argv):
    """A capture where a port belongs: one line saying so, exit 2 (pyserial said 'Inappropriate ioctl for
    device', exit 1), and the file is not touched."""
    f = tmp_path / "bus.bin"
    f.write_bytes(b"\xff\xff\xfd\x00" * 8)
    proc = hb(*(a.format(f=f) for a in argv))
    assert proc.returncode == 2 and proc.stderr.splitlines() == [
        f"hilbench: error: {f}: a file, not a serial port (a recording of a bus is read by `hilbench monitor`)"]
    assert f.read_bytes() == b"\xff\xff\xfd\x00" * 8
