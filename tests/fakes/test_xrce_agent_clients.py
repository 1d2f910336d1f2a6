"""eProsima's Micro XRCE-DDS client examples, unmodified, against hilbench's agent on 127.0.0.1.

The client library is on no package index, so these tests run examples built from its
sources by whoever runs them: ``HILBENCH_XRCE_EXAMPLES`` names the ``examples`` directory
of a Micro-XRCE-DDS-Client build with its examples on (``UCLIENT_BUILD_EXAMPLES=ON``, as
the client's README says; measured with tag v3.0.0). Without it every test skips and
says so.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile

pytestmark = pytest.mark.slow

AGENT = {"schema": 1, "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0}}}
EXAMPLES = "HILBENCH_XRCE_EXAMPLES"


@pytest.fixture(scope="module")
def examples() -> Path:
    where = os.environ.get(EXAMPLES)
    if not where:
        pytest.skip(f"{EXAMPLES} is not set: build eProsima's Micro-XRCE-DDS-Client with its examples "
                    "(UCLIENT_BUILD_EXAMPLES=ON, see its README) and name the build's examples directory")
    path = Path(where).expanduser()
    if not (path / "PingAgent").is_dir():
        pytest.fail(f"{EXAMPLES}={where}: no PingAgent example there (name the build's examples directory)")
    return path


@pytest.fixture
def agent(tmp_path: Path):
    bench = Bench(parse_profile(AGENT, "agent.toml")).start()
    yield bench
    bench.stop()


def _exe(examples: Path, name: str) -> str:
    found = [p for p in (examples / name).iterdir() if p.is_file() and os.access(p, os.X_OK)]
    assert found, f"no executable in {examples / name}"
    return str(found[0])


def _run(cmd: list[str], timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run(["stdbuf", "-oL", *cmd] if shutil.which("stdbuf") else cmd, capture_output=True,
                          text=True, timeout=timeout)


def _pub_sub(examples: Path, agent: Bench, pub: str, sub: str, n: int, timeout: float = 30) -> tuple[str, str]:
    port = str(agent.endpoint().port.address[1])
    subscriber = subprocess.Popen(["stdbuf", "-oL", _exe(examples, sub), "127.0.0.1", port, str(n)],
                                  stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        a = agent.family("micro-ros-agent").agent()
        # The subscriber is ready once its READ_DATA reached the agent.
        deadline = time.monotonic() + 10
        while not any(s.reads for s in a.sessions.values()):
            assert time.monotonic() < deadline, "the subscriber never asked for data"
            time.sleep(0.01)
        published = _run([_exe(examples, pub), "127.0.0.1", port, str(n)], timeout)
        out, _ = subscriber.communicate(timeout=timeout)
    finally:
        if subscriber.poll() is None:
            subscriber.kill()
            subscriber.communicate()
    return published.stdout, out


def test_ping_agent_with_and_without_a_session(examples: Path, agent: Bench) -> None:
    port = str(agent.endpoint().port.address[1])
    r = _run([str(examples / "PingAgent" / "UDP" / "PingAgentUDP"), "127.0.0.1", port])
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Agent is up" in r.stdout and "without a session" in r.stdout and "within a session" in r.stdout


def test_reliable_publisher_to_subscriber(examples: Path, agent: Bench) -> None:
    pub, sub = _pub_sub(examples, agent, "PublishHelloWorld", "SubscribeHelloWorld", 5)
    assert re.findall(r"Send topic: Hello DDS world!, id: (\d+)", pub) == ["1", "2", "3", "4", "5"]
    assert re.findall(r"Received topic: Hello DDS world!, id: (\d+)", sub)[:5] == ["1", "2", "3", "4", "5"]
    a = agent.family("micro-ros-agent").agent()
    assert a.counters["sessions_created"] == 2 and a.counters["samples_routed"] >= 5
    assert not a.sessions  # both deleted their sessions


def test_best_effort_publisher_to_subscriber(examples: Path, agent: Bench) -> None:
    pub, sub = _pub_sub(examples, agent, "PublishHelloWorldBestEffort", "SubscribeHelloWorldBestEffort", 5)
    got = re.findall(r"Received topic: Hello DDS world!, id: (\d+)", sub)
    assert got and got == sorted(set(got), key=int)  # in order, no duplicates


def test_fragmented_samples_both_ways(examples: Path, agent: Bench) -> None:
    pub, sub = _pub_sub(examples, agent, "PublishBigHelloWorld", "SubscribeBigHelloWorld", 2)
    assert pub.count("Send topic with size 49999") == 2
    assert re.findall(r"Received topic with size (\d+), id: (\d+)", sub)[:2] == [("49999", "0"), ("49999", "1")]
    c = agent.family("micro-ros-agent").agent().counters
    assert c["fragments_in"] > 100 and c["fragments_out"] > 100


def test_binary_entities_and_a_client_reading_its_own_writer(examples: Path, agent: Bench) -> None:
    port = str(agent.endpoint().port.address[1])
    r = _run([_exe(examples, "BinaryEntityCreation"), "127.0.0.1", port, "3"])
    assert r.returncode == 0, r.stdout
    assert re.findall(r"Received topic: (\d+)", r.stdout) == ["0", "1", "2"]


def test_time_sync(examples: Path, agent: Bench) -> None:
    port = str(agent.endpoint().port.address[1])
    proc = subprocess.Popen(["stdbuf", "-oL", _exe(examples, "TimeSync"), "127.0.0.1", port],
                            stdout=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
    finally:
        proc.kill()
        proc.communicate()
    offsets = [int(m.group(1)) for line in lines if (m := re.search(r"time offset\s+(-?\d+) us", line))]
    assert len(offsets) == 2 and all(abs(o) < 100_000 for o in offsets)  # same clock: well under 0.1 s


def test_request_reply_adder(examples: Path, agent: Bench) -> None:
    """RequestAdder asks ReplyAdder for sums through a REQUESTER and a REPLIER (XML with no space between
    attributes, as the agent's parser accepts); each reply names the request it answers."""
    port = str(agent.endpoint().port.address[1])
    procs = []
    try:
        replier = subprocess.Popen(["stdbuf", "-oL", _exe(examples, "ReplyAdder"), "127.0.0.1", port],
                                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(replier)
        a = agent.family("micro-ros-agent").agent()
        deadline = time.monotonic() + 10
        while not any(s.reads for s in a.sessions.values()):
            assert replier.poll() is None, replier.communicate()[0]
            assert time.monotonic() < deadline, "the replier never asked for requests"
            time.sleep(0.01)
        requester = subprocess.Popen(["stdbuf", "-oL", _exe(examples, "RequestAdder"), "127.0.0.1", port],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(requester)
        sent, replies = {}, []
        deadline = time.monotonic() + 20
        while len(replies) < 2:  # one request a second; each reply arrives during the next second
            assert time.monotonic() < deadline, f"replies: {replies}, requests: {sent}"
            line = requester.stdout.readline()
            assert line, "RequestAdder ended"
            if m := re.search(r"Request sent: \((\d+) \+ \d+\) \[id: (\d+)\]", line):
                sent[m.group(2)] = int(m.group(1))
            elif m := re.search(r"Reply received: (\d+) \[id: (\d+)\]", line):
                replies.append((int(m.group(1)), m.group(2)))
    finally:
        for p in procs:
            p.kill()
            p.communicate()
    assert all(total == 2 * sent[rid] for total, rid in replies), (replies, sent)
    assert a.counters["replies_routed"] >= 2
