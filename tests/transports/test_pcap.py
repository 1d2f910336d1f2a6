"""pcap/pcapng both ways: the sheet's 106- and 112-byte frames, hbcap <-> pcap through `hilbench record`,
captures from other link types, and (when tshark is installed) Wireshark's RTPS dissector on what we wrote."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import dpkt
import pytest

from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.chunk import CaptureError, Chunk
from hilbench.transports.pcap import PcapReader, PcapWriter, frame

spec = importlib.util.spec_from_file_location("udp_vectors", Path(__file__).resolve().parents[1] / "udp_vectors.py")
V = importlib.util.module_from_spec(spec)
spec.loader.exec_module(V)
SETPOINT, PID = ("192.168.2.152", 7411), ("192.168.2.151", 7411)


def hb(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True, timeout=60)


def test_the_sheets_frames_are_106_and_112_bytes(tmp_path: Path) -> None:
    f1 = frame(V.R["R1"], (*SETPOINT, *PID))
    f2 = frame(V.R["R2"], ("192.168.2.153", 7411, "192.168.2.100", 7411))
    assert len(f1) == 106 and len(f2) == 112
    eth = dpkt.ethernet.Ethernet(f1)
    assert eth.data.len == 92 and eth.data.data.ulen == 72  # IPv4 total length and UDP length of §2.7
    assert f1[14 + 12:14 + 20] == V.FRAME_106[26:34]  # the addresses of the sheet's frame
    assert f1[42:] == V.FRAME_106[42:]


@pytest.mark.parametrize("suffix", [".pcap", ".pcapng"])
def test_write_and_read_back(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"r{suffix}"
    with PcapWriter(path) as w:
        w.write(1436564565.0, V.R["R1"], (*SETPOINT, *PID))
        w.write(1436564565.1, V.X["X3"], ("192.168.1.249", 19956, "192.168.1.10", 8888))
    r = PcapReader(path)
    chunks = list(r)
    r.close()
    assert [c.data for c in chunks] == [V.R["R1"], V.X["X3"]]
    assert chunks[1].addr == ("192.168.1.249", 19956, "192.168.1.10", 8888)
    assert chunks[0].t == pytest.approx(1436564565.0) and chunks[1].source == "udp:192.168.1.249:19956"


def test_a_tcpdump_any_capture_with_other_traffic(tmp_path: Path) -> None:
    """Linux cooked capture (tcpdump -i any), with a TCP packet to skip, read through the source plug-in."""
    path = tmp_path / "any.pcap"
    with open(path, "wb") as f:
        w = dpkt.pcap.Writer(f, linktype=dpkt.pcap.DLT_LINUX_SLL)
        udp = dpkt.udp.UDP(sport=40000, dport=8888, data=V.X["X1"])
        udp.ulen = 8 + len(V.X["X1"])
        ip = dpkt.ip.IP(src=bytes([127, 0, 0, 1]), dst=bytes([127, 0, 0, 1]), p=17, data=udp)
        ip.len = 20 + udp.ulen
        sll = dpkt.sll.SLL(type=0, hrd=772, hlen=6, hdr=b"\0" * 8, ethtype=0x0800, data=ip)
        w.writepkt(bytes(sll), ts=100.0)
        tcp_ip = dpkt.ip.IP(src=bytes([127, 0, 0, 1]), dst=bytes([127, 0, 0, 1]), p=6, data=dpkt.tcp.TCP())
        w.writepkt(bytes(dpkt.sll.SLL(type=0, hrd=772, hlen=6, hdr=b"\0" * 8, ethtype=0x0800, data=tcp_ip)), ts=101)
    r = hb("monitor", str(path), "--summary", "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["datagrams"] == 1 and rep["classes"]["xrce"]["datagrams"] == 1


def test_record_converts_both_ways(tmp_path: Path) -> None:
    hbcap = tmp_path / "a.hbcap"
    with CaptureWriter(hbcap, protocol="udp", t0=50.0, t0_wall=1436564565.0) as w:
        w.write(50.0, "setpoint", V.R["R1"], (*SETPOINT, *PID))
        w.write(50.5, "talker", V.R["R2"], ("192.168.2.153", 7411, "192.168.2.100", 7411))
    pcap = tmp_path / "a.pcapng"
    r = hb("record", str(hbcap), str(pcap))
    assert r.returncode == 0, r.stderr
    back = list(PcapReader(pcap))
    assert [len(frame(c.data, c.addr)) for c in back] == [106, 112]
    assert back[0].t == pytest.approx(1436564565.0) and back[1].t == pytest.approx(1436564565.5)
    again = tmp_path / "b.hbcap"
    assert hb("record", str(pcap), str(again)).returncode == 0
    chunks = list(CaptureReader(again))
    assert [(c.data, c.addr) for c in chunks] == [(V.R["R1"], (*SETPOINT, *PID)),
                                                 (V.R["R2"], ("192.168.2.153", 7411, "192.168.2.100", 7411))]
    assert chunks[1].t - chunks[0].t == pytest.approx(0.5)


def test_serial_bytes_cannot_become_a_pcap(tmp_path: Path) -> None:
    w = PcapWriter(tmp_path / "x.pcap")
    with pytest.raises(CaptureError, match="not UDP traffic"):
        w.chunk(Chunk(0.0, "bus", b"\xff\xff\xfd\x00"))
    w.close()
    raw = tmp_path / "raw.bin"
    raw.write_bytes(b"\xff\xff\xfd\x00\x01")
    r = hb("record", str(raw), str(tmp_path / "y.pcap"))
    assert r.returncode == 2 and "not UDP traffic" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_not_a_pcap_is_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pcap"
    bad.write_bytes(b"definitely not a capture")
    r = hb("monitor", str(bad), "--summary")
    assert r.returncode == 2 and "not a pcap or pcapng file" in r.stderr


@pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark (Wireshark) is not installed")
def test_wiresharks_rtps_dissector_reads_what_we_wrote(tmp_path: Path) -> None:
    path = tmp_path / "rtps.pcapng"
    with PcapWriter(path) as w:
        for i, name in enumerate(("R3", "R4", "R5", "R1", "R2")):
            w.write(1436564565.0 + i, V.R[name], (*SETPOINT, *PID))
    # RTPS is found by Wireshark's heuristic dissector (the magic), as in a capture of a real board.
    r = subprocess.run(["tshark", "-r", str(path), "-T", "fields", "-e", "frame.len",
                        "-e", "rtps.sm.id", "-e", "rtps.sm.wrEntityId", "-E", "separator=;"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    rows = [line.split(";") for line in r.stdout.strip().splitlines()]
    assert [row[0] for row in rows] == ["298", "94", "106", "106", "112"]
    assert [row[1] for row in rows] == ["0x09,0x15", "0x07", "0x0e,0x06", "0x09,0x15", "0x09,0x15"]
    assert rows[0][2] == "0x000100c2" and rows[3][2] == "0x00000103"  # SPDP writer; the user writer
    expert = subprocess.run(["tshark", "-r", str(path), "-q", "-z", "expert,warn"], capture_output=True, text=True,
                            timeout=60)
    assert expert.returncode == 0 and "Malformed" not in expert.stdout and "Warning" not in expert.stdout
