"""The rover board over micro-ROS against hilbench's agent on one bench: its session and entities, cmd_vel
driving the robot, odometry out, its own topics routed back, and Xu's zeroed-datagram fault."""

from __future__ import annotations

import pytest

from hilbench.bench.profile import load_profile, parse_profile
from hilbench.fakes.xrce_client import XrceClient
from hilbench.monitor import Monitor
from hilbench.protocols import cdr
from hilbench.pytest_plugin import wait_until
from hilbench.transports.sources import MediumSource

TWIST = cdr.ros_type("geometry_msgs/Twist")
POSE2D = cdr.ros_type("geometry_msgs/Pose2D")


def rover_profile(zero: bool = False):
    prof = load_profile("mecarover-micro-ros")
    raw = {"schema": 1, "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0},
                                      "rover": {"type": "pty", "protocol": "vel2d", "baud": 2_000_000}},
           "devices": [{"model": "micro-ros-agent", "name": "agent", "endpoint": "agent"},
                       {"model": "stm32f767-rover", "name": "rover", "endpoint": "rover", "preset": prof.devices[1].preset,
                        "output": "v2", "agent": "agent", "body": "rover",
                        "micro_ros": {"client_key": 0x60C93570, "zero_after_session": zero}}],
           "world": {"bodies": [{"name": "rover", "shape": "box", "size": [0.5, 0.4]}]}}
    return parse_profile(raw, "rover.toml")


@pytest.fixture
def bench(hilbench_bench):
    """Factory: the agent and the rover board on one started bench (``bench(zero=True)``), stopped after."""
    return lambda zero=False: hilbench_bench(rover_profile(zero), port_state=False)


def test_board_session_entities_and_cmd_vel(bench) -> None:
    b = bench()
    link = b.family("stm32-rover").board().clients[0]
    agent = b.family("micro-ros-agent").agent()
    wait_until(lambda: link.client.state == "running" and link.self_samples["odometry"] > 3, 10)
    s = agent.by_key[bytes.fromhex("60C93570")]
    topics = {e.topic for e in s.entities.values() if e.topic}
    assert topics == {"rt/cmd_vel", "rt/encoder_data", "rt/odometry", "rt/wheel_vel"}
    types = {e.topic: e.type_name for e in s.entities.values() if e.topic}
    assert types["rt/encoder_data"] == "control_msgs::msg::dds_::MecanumDriveControllerState_"
    odo: list[dict] = []
    teleop = XrceClient(tuple(b.endpoint("agent").port.address), name="teleop")
    pub = teleop.publish_on("rt/cmd_vel", TWIST.dds_name, reliable=True)
    teleop.subscribe("rt/odometry", POSE2D.dds_name, lambda d, le: odo.append(POSE2D.try_decode(d, le)[0]))
    try:
        teleop.start()
        wait_until(lambda: teleop.state == "running" and any(s.reads for s in agent.sessions.values()
                                                               if s.key == teleop.key), 5)
        teleop.write(pub, TWIST.encode({"linear": {"x": 0.2, "y": 0.0, "z": 0.0}}))
        wait_until(lambda: link.cmd_vel_received == 1, 5)
        # m/s -> mm/s, as cmd_vel_cb does; taken at the next pose cycle.
        wait_until(lambda: b.family("stm32-rover").board().robot_state().setpoint == (200.0, 0.0, 0.0), 2)
        wait_until(lambda: odo and odo[-1]["x"] > 1.0, 10)  # the board moves and says so
        assert wait_until(lambda: b.world.body("rover").pose[0] > 0.005, 5)  # and the Twist moved its body
        teleop.write(pub, TWIST.encode({"linear": {"x": 0.0, "y": 0.0, "z": 0.0}}))
        assert wait_until(lambda: b.world.body("rover").velocity == (0.0, 0.0, 0.0), 5)
        n = len(odo)
        assert wait_until(lambda: len(odo) > n + 2, 5)
        # The micro-ROS build's odometry runs per encoder message (spec §2.2): it loses no wheel delta, so the
        # odometry it publishes is the truth (mm on the topic, m in the world).
        assert odo[-1]["x"] / 1000.0 == pytest.approx(b.world.body("rover").pose[0], abs=0.001)
        assert odo[-1]["x"] > 5.0  # (the mailbox would have lost a third: 2 mm and more)
    finally:
        teleop.close()
    st = link.status()
    assert st["state"] == "running" and st["time_offset_ns"] is not None
    assert st["counters"]["zeroed"] == 0 and st["own_samples_back"]["encoder_data"] > 0


def test_zeroed_datagram_fault_breaks_every_session(bench) -> None:
    b = bench(zero=True)
    mon = Monitor(MediumSource(b.endpoint("agent").medium)).start()
    link = b.family("stm32-rover").board().clients[0]
    agent = b.family("micro-ros-agent").agent()
    wait_until(lambda: agent.counters["takeovers"] >= 1 and link.client.counters["creation_failures"] >= 1, 10)

    def seen() -> bool:  # the tap joined after the bench started: its first session may predate it
        flags = mon.summary()["flags"]
        return flags.get("xrce.zero_fill", 0) >= 1 and flags.get("xrce.session_takeover", 0) >= 1 and \
            flags.get("xrce.stalled_reliable", 0) >= 1  # the board heartbeats into the void

    wait_until(seen, 15)
    mon.stop()
    assert link.self_samples["odometry"] == 0
    assert any("entity creation failed" in line.message for line in b.family("stm32-rover").board().log)


def test_control_channel_zeroes_the_next_datagram(bench) -> None:
    from hilbench.families.stm32_rover import FAMILY

    b = bench()
    link = b.family("stm32-rover").board().clients[0]
    wait_until(lambda: link.client.state == "running" and link.self_samples["odometry"] > 0, 10)
    before = b.family("micro-ros-agent").agent().counters["takeovers"]
    out = FAMILY.control(b, b.family("stm32-rover").board(), "micro_ros", {"zeroed_next": 1})
    assert out["micro_ros"]["state"] == "running"
    wait_until(lambda: b.family("micro-ros-agent").agent().counters["takeovers"] == before + 1, 5)
    assert link.client.counters["zeroed"] == 1
