"""The UDP surfaces as a user runs them: `hilbench emulate` of an agent and of FreeRTPS nodes (manifests),
`hilbench tap udp LISTEN UPSTREAM`, `hilbench record` of a bench's datagrams with their addresses, to pcapng."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.bench.profile import load_profile
from hilbench.fakes.xrce_client import XrceClient
from hilbench.protocols import cdr
from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader
from tests.helpers.domains import free_domain

AGENT_TOML = """schema = 1
[endpoints.agent]
type = "udp"
protocol = "xrce-dds"
port = 0
"""
STRING = cdr.ros_type("std_msgs/String")


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_bundled_profiles_load() -> None:
    agent = load_profile("micro-ros-agent")
    assert agent.endpoints["agent"].port_options["port"] == 8888 and agent.endpoints["agent"].protocol == "xrce-dds"
    rover = load_profile("mecarover-micro-ros")
    assert rover.devices[1].agent == "agent" and rover.devices[1].preset == "micro-ros-50-30"


def test_emulated_agent_manifest_and_a_session(tmp_path: Path, hilbench_emulator) -> None:
    prof = tmp_path / "agent.toml"
    prof.write_text(AGENT_TOML)
    m = hilbench_emulator(str(prof))
    (ep,) = m["endpoints"]
    assert (ep["type"], ep["protocol"], ep["role"], ep["host"]) == ("udp", "xrce-dds", "agent", "127.0.0.1")
    c = XrceClient((ep["host"], ep["port"]), name="c")
    try:
        c.start()
        wait_until(lambda: c.state == "running", 10)
    finally:
        c.close()


@pytest.mark.slow  # a long CLI session (relay, agent, monitor): the slow set
def test_tap_udp_relays_and_decodes_both_ways(tmp_path: Path, hilbench_emulator) -> None:
    prof = tmp_path / "agent.toml"
    prof.write_text(AGENT_TOML)
    ep = hilbench_emulator(str(prof))["endpoints"][0]
    pcap = tmp_path / "relay.pcapng"
    tap = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "tap", "udp", "0", f"127.0.0.1:{ep['port']}",
                            "--summary", "--json", "--seconds", "6", "--record", str(pcap)],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = tap.stderr.readline()  # the banner: stderr (stdout is the one JSON document)
        assert "clients send to udp://127.0.0.1:" in first, first + tap.stderr.read()
        port = int(first.split("udp://127.0.0.1:")[1].split(",")[0])
        got: list[str] = []
        c = XrceClient(("127.0.0.1", port), name="c")
        w = c.publish_on("rt/chatter", STRING.dds_name)
        c.subscribe("rt/chatter", STRING.dds_name, lambda d, le: got.append(STRING.decode(d).data))
        try:
            c.start()
            wait_until(lambda: c.state == "running", 10)
            time.sleep(0.2)  # the READ_DATA is on its way (reliable): give the agent its round trip
            for i in range(3):
                c.write(w, STRING.encode({"data": f"via relay {i}"}))
            wait_until(lambda: len(got) == 3, 5)
        finally:
            c.close()
        out, err = tap.communicate(timeout=30)
    finally:
        if tap.poll() is None:
            tap.kill()
    assert tap.returncode == 0, err
    rep = json.loads(out)
    (ses,) = rep["xrce"]["sessions"]
    assert ses["agent"] == f"127.0.0.1:{ep['port']}" and ses["state"] == "closed"
    topics = {(t["direction"], t["topic"]): t["count"] for t in ses["topics"]}
    assert topics == {("c2a", "rt/chatter"): 3, ("a2c", "rt/chatter"): 3}
    assert "relayed" in err and pcap.stat().st_size > 0


def test_tap_of_a_serial_port_refuses_extra_arguments() -> None:
    r = hb("tap", "/dev/ttyUSB0", "surplus")
    assert r.returncode == 2 and "unexpected arguments" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = hb("tap", "udp", "8888")
    assert r.returncode == 2 and "usage: hilbench tap udp LISTEN UPSTREAM" in r.stderr


def test_record_a_freertps_bench_with_addresses_then_pcapng(tmp_path: Path, hilbench_emulator) -> None:
    domain = free_domain()
    prof = tmp_path / "nodes.toml"
    prof.write_text(f"""schema = 1
[endpoints.nodes]
type = "udp"
protocol = "rtps"
domain_id = {domain}
[[devices]]
name = "talker"
participant_index = 0
topics = [{{ name = "chatter", type = "std_msgs/String", direction = "pub", rate_hz = 20, value = "Hello" }}]
[[devices]]
name = "setpoint"
participant_index = 1
topics = [{{ name = "desiredVolt", type = "std_msgs/UInt32", direction = "pub", rate_hz = 20, value = 1638 }}]
[[devices]]
name = "listener"
participant_index = 2
topics = [{{ name = "chatter", type = "std_msgs/String", direction = "sub" }},
          {{ name = "desiredVolt", type = "std_msgs/UInt32", direction = "sub" }}]
""")
    m = hilbench_emulator(str(prof))
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({k: v for k, v in m.items() if k != "process"}))
    cap = tmp_path / "nodes.hbcap"
    r = hb("record", f"{manifest}#nodes", str(cap), "--seconds", "2")
    assert r.returncode == 0, r.stderr
    chunks = list(CaptureReader(cap))
    assert chunks and all(c.addr is not None for c in chunks)
    user = [c for c in chunks if len(c.data) in (64, 70)]
    assert {len(c.data) for c in user} == {64, 70}  # FreeRTPS's UInt32 and "Hello" messages
    assert all(c.addr[0] == "127.0.0.1" and c.addr[2] == "127.0.0.1" for c in chunks)
    pcap = tmp_path / "nodes.pcapng"
    assert hb("record", str(cap), str(pcap)).returncode == 0
    summary = json.loads(hb("monitor", str(pcap), "--summary", "--json").stdout)
    # The recording began after discovery: the writers are known by their GUIDs and samples alone.
    writers = summary["rtps"]["writers_without_discovery"] + [e for e in summary["rtps"]["endpoints"]
                                                              if e["kind"] == "writer"]
    assert len(writers) == 2 and all(w["samples"]["count"] > 10 and w["sequence"]["lost"] == 0 for w in writers)
    assert {p["vendor"] for p in summary["rtps"]["participants"]} == {"FreeRTPS"}
    if shutil.which("tshark"):
        lens = subprocess.run(["tshark", "-r", str(pcap), "-T", "fields", "-e", "frame.len"], capture_output=True,
                              text=True, timeout=60).stdout.split()
        assert "106" in lens and "112" in lens  # the sheet's frames, as Wireshark counts them
        expert = subprocess.run(["tshark", "-r", str(pcap), "-q", "-z", "expert,warn"], capture_output=True,
                                text=True, timeout=60).stdout
        assert "Malformed" not in expert


@pytest.mark.parametrize("dev, expected", [
    ({"preset": "freertos-50-30", "agent": "127.0.0.1:8888"}, "agent: only for the micro-ros-* presets"),
    ({"preset": "micro-ros-50-30", "micro_ros": {"domain_id": 1}}, "micro_ros: only with agent"),
    ({"preset": "micro-ros-50-30", "agent": "nowhere"}, "agent: no endpoint named 'nowhere'"),
    ({"preset": "micro-ros-50-30", "agent": "127.0.0.1:99999"}, "agent: expected \"HOST:PORT\""),
])
def test_rover_micro_ros_profile_errors(tmp_path: Path, dev: dict, expected: str) -> None:
    from hilbench.bench.profile import ProfileError, parse_profile

    prof = {"schema": 1, "endpoints": {"rover": {"type": "pty", "protocol": "vel2d"}},
            "devices": [{"model": "stm32f767-rover", **dev}]}
    with pytest.raises(ProfileError, match=re.escape(expected)):
        parse_profile(prof, "r.toml")


def test_agent_profile_errors() -> None:
    from hilbench.bench.profile import ProfileError, parse_profile

    base = {"schema": 1, "endpoints": {"a": {"type": "udp", "protocol": "xrce-dds"}}}
    with pytest.raises(ProfileError, match=r"a.toml: endpoints.a.baud: a UDP agent has no baud rate"):
        parse_profile({**base, "endpoints": {"a": {"type": "udp", "protocol": "xrce-dds", "baud": 9600}}}, "a.toml")
    with pytest.raises(ProfileError, match=r"devices\[0\].zeroed: expected one of teardown, keep"):
        parse_profile({**base, "devices": [{"model": "micro-ros-agent", "zeroed": "maybe"}]}, "a.toml")
    with pytest.raises(ProfileError, match=r'endpoints.a.type: expected "udp" for protocol "xrce-dds"'):
        parse_profile({**base, "endpoints": {"a": {"type": "pty", "protocol": "xrce-dds"}}}, "a.toml")
