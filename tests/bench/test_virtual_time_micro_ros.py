"""The rover board's micro-ROS client on a virtual-time bench (issue 26 step 3b): its XRCE session is a
participant of the bench's loop, so the session, its publications and a teleop's cmd_vel happen at exact
virtual instants, the same in every run, in a fraction of the wall time.

Real parts: the bundled profile ``mecarover-micro-ros`` (hilbench's agent on a UDP endpoint, the board on a pty),
the board's own XRCE client, a second client (the teleop) on the same net, a tap of the agent's net.
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from hilbench.bench import Bench
from hilbench.bench.profile import load_profile
from hilbench.errors import UsageError
from hilbench.fakes.xrce_client import CREATION_TIMEOUT_S, XrceClient
from hilbench.protocols import cdr
from hilbench.protocols import xrce_dds as x

TWIST = cdr.ros_type("geometry_msgs/Twist")
POSE2D = cdr.ros_type("geometry_msgs/Pose2D")
S = x.SubmessageId
EPOCH = 1_700_000_000
SECONDS = 4.0


def rover_profile(zero: bool = False, agent: str = "agent"):
    """The bundled ``mecarover-micro-ros``, with Xu's fault on (``zero``) or another ``agent``."""
    return load_profile("mecarover-micro-ros", {"devices.rover.micro_ros.zero_after_session": zero,
                                                "devices.rover.agent": agent})


def run(seconds: float, zero: bool = False, teleop: bool = True) -> dict[str, Any]:
    """One run: the bench for ``seconds`` virtual seconds, a teleop joining at +0.25 s and sending one Twist
    at +1 s; what the agent's net carried (ports named by role), counts, the wall time of the run."""
    records: list[tuple[float, str, bytes, tuple]] = []

    def tap_agent(ep) -> None:
        if ep.name == "agent":
            ep.medium.add_tap(lambda t, source, data, addr: records.append((t, source, bytes(data), addr)))

    bench = Bench(rover_profile(zero), virtual_time=True, virtual_epoch=EPOCH, seed=0)
    bench.start(on_endpoint=tap_agent)
    try:
        t0 = bench.clock.now()
        ep = bench.endpoint("agent")
        link = bench.family("stm32-rover").board().clients[0]
        odo: list[dict] = []
        tele = None
        if teleop:  # another client on the agent's net (scheduled while the clock holds: at instants no other
            # event has)
            tele = XrceClient(tuple(ep.port.address), client_key=0x7E1E0B, name="teleop", net=ep.medium)
            pub = tele.publish_on("rt/cmd_vel", TWIST.dds_name, reliable=True)
            tele.subscribe("rt/odometry", POSE2D.dds_name, lambda d, le: odo.append(POSE2D.try_decode(d, le)[0]))
            bench.loop.call_at(t0 + 0.25, tele.start)
            bench.loop.call_at(t0 + 1.0, lambda: tele.write(pub, TWIST.encode({"linear": {"x": 0.2, "y": 0.0,
                                                                                         "z": 0.0}})))
        wall = time.monotonic()
        bench.clock.run_until(t0 + seconds + 0.005, timeout=60)
        wall = time.monotonic() - wall
        client = link.client
        roles = {ep.port.address[1]: "agent", client.local_address[1]: "board"}
        if tele is not None and tele.local_address is not None:
            roles[tele.local_address[1]] = "teleop"
        named = [(t - t0, _name(source, roles), data, (roles.get(a[1], a[1]), roles.get(a[3], a[3])))
                 for t, source, data, a in records]
        out = {"records": named, "wall": wall, "status": link.status(), "turns": getattr(getattr(getattr(client, "_link", None), "participant", None), "turns", None),
               "preset": bench.family("stm32-rover").board().config.preset, "odo": odo,
               "pose": bench.world.body("rover").pose, "cmd_vel": link.cmd_vel_received,
               "agent": dict(bench.family("micro-ros-agent").agent().counters),
               "writers": {p.writer: p.topic for p in client.publications}}
        if tele is not None:
            tele.close()
        return out
    finally:
        bench.stop()


def _name(source: str, roles: dict[int, str]) -> str:
    if source.startswith("udp:"):
        return roles.get(int(source.rsplit(":", 1)[1]), source)
    return source


def board_writes(r: dict[str, Any]) -> list[tuple[float, str, int]]:
    """(virtual time after the start, topic, best-effort sequence number) of every WRITE_DATA the board sent."""
    out = []
    for t, source, data, _ in r["records"]:
        if source != "board" or data[1] != x.STREAM_BEST_EFFORT:
            continue
        _, _, seq, subs, _ = x.scan(data)
        for sub_id, _, off, _ in subs:
            if sub_id == S.WRITE_DATA:
                out.append((t, r["writers"][data[off + 2:off + 4]], seq))
    return out


def test_board_session_publications_and_cmd_vel_on_the_virtual_clock() -> None:
    a = run(SECONDS)
    preset = a["preset"]
    st = a["status"]
    # The session: one ping, one CREATE_CLIENT, all at the start instant (no wall-clock waits in between),
    # and a time sync against the agent on the same clock: offset exactly 0.
    assert st["state"] == "running" and st["counters"]["pings"] == 1 and st["counters"]["create_client"] == 1
    assert st["time_offset_ns"] == 0 and st["counters"]["retransmissions"] == 0
    board_first = [(t, data[4]) for t, source, data, _ in a["records"] if source == "board"][:2]
    assert board_first == [(0.0, S.GET_INFO), (0.0, S.CREATE_CLIENT)]
    # The publications the agent received: encoder_data at the wheel rate, odometry and wheel_vel at the pose
    # rate, each at its exact tick, one best-effort stream numbered without a gap.
    writes = board_writes(a)
    n_wheel, n_pose = round(SECONDS * preset.wheel_hz), int(SECONDS * preset.pose_hz + 1e-6)
    by_topic = {topic: [t for t, tp, _ in writes if tp == topic] for topic in ("rt/encoder_data", "rt/odometry",
                                                                             "rt/wheel_vel")}
    assert len(by_topic["rt/encoder_data"]) == n_wheel
    assert len(by_topic["rt/odometry"]) == len(by_topic["rt/wheel_vel"]) == n_pose
    assert by_topic["rt/encoder_data"] == pytest.approx([(k + 1) / preset.wheel_hz for k in range(n_wheel)],
                                                        abs=1e-9)
    assert by_topic["rt/odometry"] == pytest.approx([(k + 1) / preset.pose_hz for k in range(n_pose)], abs=1e-9)
    assert [seq for _, _, seq in writes] == list(range(len(writes)))
    # Routed: each to the board's own reader, odometry also to the teleop's (from +0.25 s), and the Twist.
    assert a["agent"]["samples_routed"] == len(writes) + len([t for t in by_topic["rt/odometry"] if t > 0.25]) + 1
    assert len(a["odo"]) == len([t for t in by_topic["rt/odometry"] if t > 0.25])
    # The teleop's Twist reached the board at the instant it was sent (in process: no wall-clock delivery),
    # and the board drove its body after it (its firmware ramps up to 0.2 m/s), not before.
    to_board = [t for t, source, data, addr in a["records"] if source == "agent" and addr[1] == "board"
                and any(sub_id == S.DATA for sub_id, *_ in x.scan(data)[3]) and t >= 1.0]
    assert a["cmd_vel"] == 1 and st["last_cmd_vel"]["linear"]["x"] == 0.2
    assert a["odo"][-1]["x"] > 300  # (mm: the board's odometry, as the teleop reads it)
    assert a["odo"][round((1.0 - 0.25) * preset.pose_hz) - 1]["x"] == 0.0
    assert a["pose"][0] > 0.3
    assert min(to_board) == 1.0
    # No wall-time bound: the board's 1 ms firmware steps keep this bench busy, so how much faster than real
    # time it runs (3 - 4x, vt_micro_ros_speed in tools/bench_virtual_time.py) depends on the machine's load
    # (0.85 wall s per virtual s at load 5). The exact instants above are what a wall-clock session breaks.


def test_two_runs_carry_the_same_datagrams_at_the_same_instants() -> None:
    a, b = run(SECONDS), run(SECONDS)
    assert len(a["records"]) > 1000
    assert a["records"] == b["records"]  # every datagram, its bytes, its instant and its ends (ports by role)
    assert a["status"]["counters"] == b["status"]["counters"] and a["turns"] == b["turns"]
    assert a["pose"] == b["pose"] and a["odo"] == b["odo"]


def test_zeroed_datagram_fault_retries_at_exact_virtual_instants() -> None:
    """Xu's fault in virtual time: every session loses its first datagram after creation (the agent tears
    it down), the board HEARTBEATs its unacknowledged entities every 100 ms until the creation timeout, and
    starts over 1 s later: the same instants in every run."""
    seconds = 11.0
    a, b = run(seconds, zero=True, teleop=False), run(seconds, zero=True, teleop=False)
    assert a["records"] == b["records"]
    board = [(t, data) for t, source, data, _ in a["records"] if source == "board"]
    starts = [t for t, data in board if data[0] == x.SESSION_NONE_WITHOUT_KEY and data[4] == S.CREATE_CLIENT
              and not x.is_zero_fill(data)]
    timeout = CREATION_TIMEOUT_S * (19 // 4)  # (19 entities: a participant, 4 topics, 3 + 3 and 4 + 4 below)
    period = timeout + 1.0
    assert starts == pytest.approx([k * period for k in range(3)], abs=1e-9)
    zeroed = [t for t, data in board if x.is_zero_fill(data)]
    assert zeroed == starts  # (the first datagram after each session's creation)
    heartbeats = [t for t, data in board if t < period and data[0] == 0x81 and data[4] == S.HEARTBEAT]
    assert heartbeats == pytest.approx([k * 0.1 for k in range(round(timeout / 0.1) + 1)], abs=1e-9)
    c = a["status"]["counters"]
    assert c["creation_failures"] == 2 and c["sessions"] == 3 and a["agent"]["takeovers"] == 3
    assert not board_writes(a)


def test_a_virtual_bench_refuses_an_external_agent() -> None:
    bench = Bench(rover_profile(agent="127.0.0.1:8888"), virtual_time=True)
    with pytest.raises(UsageError, match=r"devices\[1\]\.agent: a virtual-time bench needs its micro-ROS agent"):
        bench.start()
    bench.stop()
