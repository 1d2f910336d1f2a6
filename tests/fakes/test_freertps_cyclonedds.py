"""The FreeRTPS nodes against a standard DDS participant: Eclipse Cyclone DDS (``cyclonedds``), unmodified,
in a separate process, multicast off, 127.0.0.1 its peer. It discovers the nodes, receives their samples at
the stated rate, and gets its own samples echoed back."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from tests.helpers.domains import free_domain

pytestmark = pytest.mark.slow  # Cyclone DDS against the emulated nodes: the slow real-client set

pytest.importorskip("cyclonedds", reason="the cyclonedds package (a standard DDS participant) is not installed")
PEER = Path(__file__).resolve().parents[1] / "helpers" / "cyclone_peer.py"


def profile(domain: int) -> dict:
    return {"schema": 1, "endpoints": {"nodes": {"type": "udp", "protocol": "rtps", "domain_id": domain}},
            "devices": [
                {"name": "talker", "participant_index": 0, "topics": [
                    {"name": "chatter", "type": "std_msgs/String", "direction": "pub", "rate_hz": 20,
                     "value": "Hello {n}"}]},
                {"name": "setpoint", "participant_index": 1, "topics": [
                    {"name": "desiredVolt", "type": "std_msgs/UInt32", "direction": "pub", "rate_hz": 10,
                     "value": 1638}]},
                {"name": "reliable", "participant_index": 3, "topics": [
                    {"name": "status", "type": "std_msgs/String", "direction": "pub", "rate_hz": 20,
                     "value": "ok {n}", "reliable": True}]},
                {"name": "echo", "participant_index": 2, "topics": [
                    {"name": "echo_in", "type": "std_msgs/String", "direction": "sub"},
                    {"name": "echo_out", "type": "std_msgs/String", "direction": "pub", "echo_of": "echo_in"}]},
            ]}


def peer(cfg: dict, timeout: float = 40) -> dict:
    r = subprocess.run([sys.executable, str(PEER), json.dumps(cfg)], capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture
def nodes():
    domain = free_domain()
    bench = Bench(parse_profile(profile(domain), "nodes.toml")).start()
    yield bench, domain
    bench.stop()


def test_cyclone_receives_the_talker_at_its_rate(nodes) -> None:
    bench, domain = nodes
    got = peer({"mode": "listen", "domain": domain, "topic": "rt/chatter", "seconds": 3.0})
    values, times = got["values"], got["times"]
    assert len(values) >= 20, got
    assert all(v.startswith("Hello ") for v in values)
    numbers = [int(v.split()[1]) for v in values]
    assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)
    # The stated 20 Hz, measured over the samples received (first to last).
    rate = (len(times) - 1) / (times[-1] - times[0])
    assert 15 <= rate <= 25, rate
    talker = bench.device("talker").participant
    assert any(r.vendor_id == b"\x01\x10" for r in talker.remotes.values())  # Cyclone's own vendor id


def test_cyclone_decodes_the_uint32_setpoint(nodes) -> None:
    _, domain = nodes
    got = peer({"mode": "listen", "domain": domain, "topic": "rt/desiredVolt", "type": "std_msgs/UInt32",
                "seconds": 2.0})
    assert got["values"] and set(got["values"]) == {1638}


def test_a_reliable_reader_gets_a_reliable_writer_in_order(nodes) -> None:
    bench, domain = nodes
    got = peer({"mode": "listen", "domain": domain, "topic": "rt/status", "reliable": True, "seconds": 3.0})
    numbers = [int(v.split()[1]) for v in got["values"]]
    assert len(numbers) >= 20 and numbers == list(range(numbers[0], numbers[0] + len(numbers)))  # no gap
    writer = bench.device("reliable").writers["status"]
    assert writer.reliable and writer.matched  # Cyclone's ACKNACKs reached the writer
    assert bench.device("reliable").participant.counters["heartbeats_sent"] > 0


def test_the_echo_node_returns_cyclones_samples(nodes) -> None:
    bench, domain = nodes
    got = peer({"mode": "echo", "domain": domain, "topic": "rt/echo_in", "reply_topic": "rt/echo_out", "count": 10})
    assert got["matched"] >= 1
    assert got["back"] == got["sent"]
    echo = bench.device("echo")
    assert echo.received["echo_in"] == 10 and echo.published["echo_out"] == 10
    assert [s["data"] for s in echo.samples["echo_in"]] == got["sent"]


def test_agent_bridge_a_micro_ros_client_and_cyclone_see_each_other() -> None:
    from hilbench.fakes.xrce_client import XrceClient
    from hilbench.protocols import cdr
    from hilbench.pytest_plugin import wait_until

    domain = free_domain()
    prof = {"schema": 1, "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0}},
            "devices": [{"model": "micro-ros-agent", "name": "agent",
                         "bridge": {"domain_id": domain, "participant_index": 0}}]}
    bench = Bench(parse_profile(prof, "agent.toml")).start()
    string = cdr.ros_type("std_msgs/String")
    got: list[str] = []
    client = XrceClient(tuple(bench.endpoint().port.address), name="uros")
    pub = client.publish_on("rt/chatter", string.dds_name)
    client.subscribe("rt/from_ros", string.dds_name, lambda d, le: got.append(string.decode(d).data))
    try:
        client.start()
        wait_until(lambda: client.state == "running", 5)
        listener = subprocess.Popen([sys.executable, str(PEER), json.dumps(
            {"mode": "listen", "domain": domain, "topic": "rt/chatter", "seconds": 4.0})], stdout=subprocess.PIPE,
            text=True)
        try:
            for i in range(70):
                client.write(pub, string.encode({"data": f"uros {i}"}))
                if listener.poll() is not None:
                    break
                import time

                time.sleep(0.05)
            heard = json.loads(listener.communicate(timeout=30)[0].strip().splitlines()[-1])["values"]
        finally:
            if listener.poll() is None:
                listener.kill()
        assert heard and all(v.startswith("uros ") for v in heard)
        back = peer({"mode": "publish", "domain": domain, "topic": "rt/from_ros", "count": 5, "prefix": "ros"})
        assert back["matched"] >= 1
        wait_until(lambda: got == back["sent"], 5)
        assert bench.manifest()["endpoints"][0]["bridge"]["domain_id"] == domain
    finally:
        client.close()
        bench.stop()
