"""The UDP monitor: classification, Xu's broken session replayed (every §1.9.4 flag), RTPS discovery,
rates of a live FreeRTPS bench, the JSON summary, the CLI and the dashboard views."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hilbench.monitor import Monitor
from hilbench.monitor.udp import INSTRUMENT
from hilbench.monitor.udp.classify import classify
from hilbench.monitor.udp.tracker import UdpTracker
from hilbench.protocols import vel2d
from hilbench.protocols import xrce_dds as x
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.sources import open_source
from tests.helpers.domains import free_domain

TESTS = Path(__file__).resolve().parents[1]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(Path(name).stem, TESTS / name)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


V = _load("udp_vectors.py")
BOARD, AGENT = ("192.168.1.249", 19956), ("192.168.1.10", 8888)
T0 = 1742552565.561902
#: Xu's agent log (udp.md §1.9.1) with the sheet's corrections: (ms, direction, bytes).
XU = [(0.000, "c", V.X["X1"]), (0.570, "a", V.X["X2"]), (0.943, "c", V.X["X3"]), (1.305, "a", V.X["X4"]),
      (1.611, "c", V.X["X21"]),
      (1.892, "a", x.build_message(0x00, 0, 0, [(4, 1, x.status_agent(x.Status.ERR_INVALID_DATA))],
                                   client_key=b"\x00\x00\x00\x00"))] + \
    [(ms, "c", V.X["X10"]) for ms in (101.640, 201.685, 301.612, 401.637, 501.677, 601.645, 701.603, 801.620,
                                      901.604)]


def xu_capture(path: Path) -> Path:
    with CaptureWriter(path, protocol="udp", t0=T0, t0_wall=T0, description="Xu 2025 figure 7") as w:
        for ms, who, data in XU:
            src, dst = (BOARD, AGENT) if who == "c" else (AGENT, BOARD)
            w.write(T0 + ms / 1e3, f"udp:{src[0]}:{src[1]}", data, (*src, *dst))
    return path


def run(source: str) -> dict:
    with Monitor(open_source(source)) as mon:
        mon.wait(10)
        return mon.summary()


def test_classification() -> None:
    ports = {8888}
    assert classify(V.R["R1"], 7411, 7411, ports) == "rtps"
    assert classify(V.X["X10"], 40000, 8888, ports) == "xrce"
    assert classify(V.X["X3"], None, None, set()) == "xrce"  # no ports: the sheet's heuristic
    assert classify(vel2d.build(0.1, -0.2, 0.3), 5000, 6000, ports) == "vel2d"
    assert classify(b"IDLE 1 0\nprofile 2 1\n", 5000, 6000, ports) == "stamps"
    assert classify(b"\x17garbage that is not xrce", 5000, 6000, ports) == "unknown"


def test_instruments_contribute_their_datagram_classes() -> None:
    """The UDP monitor names no family: Vel2d frames and trace stamps are the rover board's trace instrument's
    classes, and an outside instrument's class is counted the same way."""
    from hilbench import registry
    from hilbench.monitor.instrument import Instrument

    rover = registry.instruments.get("vel2d")
    assert rover.datagram_classes == ("vel2d", "stamps") and type(rover).__module__ == "hilbench.profiler.stm32_rover"

    class AcmeInstrument(Instrument):
        protocol = "acme-udp"
        datagram_classes = ("acme",)

        def classify_datagram(self, data: bytes) -> str | None:
            return "acme" if data.startswith(b"ACME") else None

    registry.instruments.register("acme-udp", AcmeInstrument())
    try:
        tr = UdpTracker()
        assert list(tr.classes) == ["xrce", "rtps", "vel2d", "stamps", "acme", "unknown"]
        for data in (b"ACME 1", vel2d.build(0.1, 0.0, 0.0), b"ACME 2", b"\x17nothing"):
            tr.feed_datagram(1.0, "net", data, ("127.0.0.1", 5000, "127.0.0.1", 6000))
        assert {k: v[0] for k, v in tr.classes.items() if v[0]} == {"acme": 2, "vel2d": 1, "unknown": 1}
    finally:
        registry.instruments.unregister("acme-udp")


def test_xus_broken_session_raises_every_flag(tmp_path: Path) -> None:
    rep = run(str(xu_capture(tmp_path / "xu.hbcap")))
    flags = rep["flags"]
    for name in ("xrce.zero_fill", "xrce.bad_length", "xrce.bad_create_client", "xrce.session_takeover",
                 "xrce.agent_error", "xrce.stalled_reliable", "xrce.orphan_traffic"):
        assert flags.get(name), (name, flags)
    assert rep["zeroed_datagrams"] == 1 and rep["classes"]["xrce"]["datagrams"] == len(XU)
    (ses,) = rep["xrce"]["sessions"]
    assert (ses["client"], ses["agent"], ses["client_key"], ses["session_id"], ses["state"]) == (
        "192.168.1.249:19956", "192.168.1.10:8888", "60C93570", "0x81", "torn down")
    assert ses["latency_ms"]["ping"]["mean"] == pytest.approx(0.570, abs=1e-3)
    assert ses["latency_ms"]["create_client"]["mean"] == pytest.approx(0.362, abs=1e-3)
    zero = next(e for e in rep["events"] if e["kind"] == "xrce.zero_fill")
    assert "192.168.1.249:19956" in zero["text"] and zero["t"] == pytest.approx(0.001611, abs=1e-6)


def test_heartbeat_train_statistics_of_xus_log() -> None:
    tr = UdpTracker()
    for ms, who, data in XU:
        src, dst = (BOARD, AGENT) if who == "c" else (AGENT, BOARD)
        tr.feed_datagram(T0 + ms / 1e3, "x", data, (*src, *dst))
    (s,) = tr.xrce.sessions.values()
    assert s.submessages["HEARTBEAT"] == 9 and s.windows[("c2a", 0x80)] == 1
    assert tr.flags["xrce.stalled_reliable"] == 1  # flagged once, at the third identical HEARTBEAT


def test_xrce_sessions_topics_and_gaps_without_addresses() -> None:
    tr = UdpTracker()
    key = bytes.fromhex("60C93570")
    for seq in (0, 1, 2, 5, 5, 4):  # a gap of two, a duplicate, a late one
        msg = x.build_message(0x81, 0x01, seq, [(7, 1, x.data(b"\x00\x0a", b"\x00\x15", b"\x2a\x00\x00\x00"))])
        tr.feed(float(seq), "board", msg)
    tr.feed(10.0, "board", V.X["X3"])
    (s,) = tr.xrce.sessions.values()
    st = s.streams[("c2a", 0x01)]
    assert (st.received, st.lost, st.duplicates, st.late) == (6, 2, 1, 1)
    assert s.samples[("c2a", b"\x00\x15")].count == 6 and s.key == key


def test_endianness_flip_is_flagged() -> None:
    tr = UdpTracker()
    addr = ("127.0.0.1", 40000, "127.0.0.1", 8888)
    tr.feed_datagram(0.0, "c", V.X["X3"], addr)
    big_endian_hb = bytes.fromhex("81 00 00 00 0B 00 05 00 00 00 00 00 80")  # E = 0
    tr.feed_datagram(0.1, "c", big_endian_hb, addr)
    assert tr.flags == {"xrce.endianness_flip": 1}


def test_short_datagrams_to_an_agent_are_taken_not_raised_on() -> None:
    """Found by tools/fuzz.py (monitor-udp): a 4 - 7 byte datagram with a session id >= 0x80 (a 4-byte
    header) on the agent's port made the zero-fill check read past its end."""
    tr = UdpTracker()
    addr = ("127.0.0.1", 40000, "127.0.0.1", 8888)
    for n in range(4, 8):
        tr.feed_datagram(float(n), "c", bytes((0x81, 0x01, 0, 0)) + bytes(n - 4), addr)
    assert tr.datagrams == 4 and tr.classes["xrce"][0] == 4


def test_rtps_vectors_give_participants_and_data() -> None:
    tr = UdpTracker()
    for i, name in enumerate(("R3", "R4", "R5", "R1", "R2")):
        tr.feed_datagram(float(i), "x", V.R[name], ("192.168.2.151", 7410, "192.168.2.100", 7410))
    parts = tr.rtps.participants
    assert V.PREFIX_PID_BOARD in parts and parts[V.PREFIX_PID_BOARD].lease_s == 100
    assert len(tr.rtps.writers) == 2  # the set-point board's and the talker's user writers
    assert not tr.flags


def test_non_rtps_on_an_rtps_port_is_counted() -> None:
    tr = UdpTracker()
    tr.feed_datagram(0.0, "x", b"hello", ("127.0.0.1", 5000, "127.0.0.1", 7411))
    assert tr.flags == {"rtps.non_rtps": 1}


def test_live_freertps_bench_rates(tmp_path: Path) -> None:
    from hilbench.bench import Bench
    from hilbench.bench.profile import parse_profile
    from hilbench.pytest_plugin import wait_until
    from hilbench.transports.sources import MediumSource

    domain = free_domain()
    prof = {"schema": 1, "endpoints": {"n": {"type": "udp", "protocol": "rtps", "domain_id": domain}},
            "devices": [{"name": "talker", "participant_index": 0, "topics": [
                {"name": "chatter", "type": "std_msgs/String", "direction": "pub", "rate_hz": 20}]},
                {"name": "listener", "participant_index": 1, "topics": [
                    {"name": "chatter", "type": "std_msgs/String", "direction": "sub"}]}]}
    sources = []  # tapped before any device runs: the monitor must see the discovery to name the topic
    bench = Bench(parse_profile(prof, "n.toml")).start(on_endpoint=lambda ep: sources.append(MediumSource(ep.medium)))
    try:
        mon = Monitor(sources[0]).start()
        wait_until(lambda: bench.device("listener").received["chatter"] >= 30, 10)
        mon.stop()
        rep = mon.summary()
    finally:
        bench.stop()
    topic = next(t for t in rep["rtps"]["topics"] if t["topic"] == "rt/chatter")
    assert topic["type"] == "std_msgs::msg::dds_::String_" and len(topic["writers"]) == 1
    assert 15 <= topic["rate_hz"] <= 25 and topic["lost"] == 0
    assert "FreeRTPS" in {p["vendor"] for p in rep["rtps"]["participants"]}


def test_cli_summary_json(tmp_path: Path) -> None:
    cap = xu_capture(tmp_path / "xu.hbcap")
    r = subprocess.run([sys.executable, "-m", "hilbench.cli", "monitor", str(cap), "--summary", "--json"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["protocol"] == "udp" and rep["zeroed_datagrams"] == 1
    printed = subprocess.run([sys.executable, "-m", "hilbench.cli", "monitor", str(cap), "--summary"],
                             capture_output=True, text=True, timeout=60)
    assert "xrce.zero_fill" in printed.stdout and "torn down" in printed.stdout


@pytest.mark.parametrize("view", ["overview", "xrce", "rtps", "events"])
def test_dashboard_views_fill_the_screen(view: str, tmp_path: Path) -> None:
    from rich.console import Console

    from hilbench.dashboard import Dashboard

    tr = UdpTracker()
    for ms, who, data in XU:
        src, dst = (BOARD, AGENT) if who == "c" else (AGENT, BOARD)
        tr.feed_datagram(T0 + ms / 1e3, "x", data, (*src, *dst))
    for i, name in enumerate(("R3", "R1")):
        tr.feed_datagram(T0 + 1 + i, "x", V.R[name], ("192.168.2.151", 7410, "192.168.2.100", 7410))
    dash = Dashboard(tr, views=INSTRUMENT.views(), view=view, source="xu")
    console = Console(width=100, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    group = dash.render(100, 24)
    assert len(group.renderables) == 24
    console.print(group)
    text = console.export_text()
    assert {"overview": "zeroed datagrams: 1", "xrce": "torn down", "rtps": "2c2f2c4d.59012351",
            "events": "xrce.zero_fill"}[view] in text
