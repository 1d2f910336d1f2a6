"""The rover board's micro-ROS side (branch ``micro-ros-profiling``): an XRCE client on UDP to an agent.

The firmware's ``micro_ros_node`` (``application/micro_ros/*.cpp``) as the
board runs it over LwIP/UDP: after pinging the agent and creating its session
it creates, in binary, what its three executors use:

================  =============================================  ==========  =================
topic             type                                           direction   QoS / rate
================  =============================================  ==========  =================
``cmd_vel``       geometry_msgs/Twist                            subscribe   reliable
``encoder_data``  control_msgs/MecanumDriveControllerState       both        best effort, wheel rate
``odometry``      geometry_msgs/Pose2D                           both        best effort, pose rate
``wheel_vel``     control_msgs/MecanumDriveControllerState       both        best effort, pose rate
================  =============================================  ==========  =================

(topic names get ROS 2's ``rt/`` prefix on the wire). ``cmd_vel`` samples set
the robot's velocity setpoint (x, y in m/s to mm/s, as ``cmd_vel_cb`` does);
the published values come from the board's robot model: encoder deltas of one
wheel period, the integrated pose, the wheel-speed setpoints. The board
subscribes to its own topics too (its executors talk through the agent), so
the agent routes them back, as it does for the real firmware.

The zeroed-datagram fault (Xu's D-cache bug, spec sheet §1.9.4) is a knob:
``zero_after_session`` zeroes the first datagram of every session (the board
then never gets its entities, as in the thesis); ``zero_next(n)`` the next n.
"""

from __future__ import annotations

import threading
from typing import Any

from hilbench.fakes.xrce_client import XrceClient
from hilbench.protocols import cdr

TWIST = cdr.ros_type("geometry_msgs/Twist")
POSE2D = cdr.ros_type("geometry_msgs/Pose2D")
DRIVE = cdr.ros_type("control_msgs/msg/MecanumDriveControllerState")
ENC_FRAME = "wheel encoder delta in radian"
VEL_FRAME = "wheel angular velocity setpoint"


class MicroRosClient:
    """The board's XRCE client and its timers; a board client (:meth:`Board.attach_client`)."""

    def __init__(self, agent: Any, *, client_key: int | None = None, domain_id: int = 0,
                 zero_after_session: bool = False, node: str = "micro_ros_node", net: Any = None) -> None:
        #: ``(host, port)``, or a callable giving it when the board starts (an agent of the same bench).
        self.agent = agent
        #: On a virtual clock: the datagram net of the bench's agent endpoint (or a callable giving it when
        #: the board starts); the session then runs as a participant of the bench's loop, in process.
        self.net = net
        self.client_key = client_key
        self.domain_id = domain_id
        self.zero_after_session = zero_after_session
        self.node = node
        self.board: Any = None
        self.client: XrceClient | None = None
        self.cmd_vel_received = 0
        self.self_samples: dict[str, int] = {"encoder_data": 0, "odometry": 0, "wheel_vel": 0}
        self.last_cmd_vel: dict[str, Any] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._epoch = 0

    # ------------------------------------------------------------------ board client protocol

    def start(self, board: Any) -> None:
        self.board = board
        agent = self.agent() if callable(self.agent) else self.agent
        clock = board.clock
        net = self.net() if callable(self.net) else self.net
        if clock.virtual and net is None:
            raise RuntimeError(f"{board.name}: a micro-ROS client in virtual time needs its agent's net (net=)")
        c = XrceClient(tuple(agent), client_key=self.client_key, domain_id=self.domain_id,
                       zero_after_session=self.zero_after_session, name=f"{board.name}-uros",
                       on_event=self._log, net=net if clock.virtual else None)
        self.client = c
        self._pub = {name: c.publish_on(f"rt/{name}", t.dds_name) for name, t in
                     (("encoder_data", DRIVE), ("odometry", POSE2D), ("wheel_vel", DRIVE))}
        c.subscribe("rt/cmd_vel", TWIST.dds_name, self._on_cmd_vel, reliable=True)
        for name, t in (("odometry", POSE2D), ("encoder_data", DRIVE), ("wheel_vel", DRIVE)):
            c.subscribe(f"rt/{name}", t.dds_name, lambda data, le, _n=name: self._on_own(_n), reliable=False)
        self._stop.clear()
        if clock.virtual and board.port is not None:
            # In virtual time the bench's loop runs the client's timers, and the XRCE session takes turns with
            # it as a participant of the loop (timers first: queued before the session can queue anything, so
            # their places in the loop's sequence are the same in every run).
            self._epoch += 1
            preset = board.config.preset
            self._vt_timer(self._epoch, 1.0 / preset.wheel_hz, lambda dt: self._publish_wheel(dt))
            self._vt_timer(self._epoch, 1.0 / preset.pose_hz, lambda dt: self._publish_pose())
            c.start()
            return
        c.start()
        self._thread = threading.Thread(target=self._run, name=f"uros-{board.name}", daemon=True)
        self._thread.start()

    def _vt_timer(self, epoch: int, period: float, publish) -> None:
        port = self.board.port

        def tick(t: float) -> None:
            if epoch != self._epoch:
                return  # stopped since
            publish(period)
            port.call_at(t + period, lambda: tick(t + period))

        t0 = port.now() + period
        port.call_at(t0, lambda: tick(t0))

    def stop(self) -> None:
        self._epoch += 1  # (ends the loop timers of virtual time)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        if self.client is not None:
            self.client.close()

    def reset(self) -> None:
        """A board reset reboots the MCU: the session starts over."""
        if self.board is not None and self.client is not None:
            board = self.board
            self.stop()
            self.start(board)

    # ------------------------------------------------------------------ traffic

    def _log(self, level: str, text: str) -> None:
        board = self.board
        if board is not None:
            with board.lock:
                board.fw.log_line(level, text, immediate=True)  # ULOG goes out on the UART

    def _on_cmd_vel(self, data: bytes, le: bool) -> None:
        value, err = TWIST.try_decode(data, le)
        if err is not None:
            return
        self.cmd_vel_received += 1
        self.last_cmd_vel = value
        board = self.board
        with board.lock:
            # cmd_vel_cb: linear x, y in m/s -> mm/s; angular z in rad/s.
            board.fw.robot.push_setpoint(board.fw.now, value["linear"]["x"] * 1000.0, value["linear"]["y"] * 1000.0,
                                         value["angular"]["z"])

    def _on_own(self, name: str) -> None:
        self.self_samples[name] += 1

    def _run(self) -> None:
        preset = self.board.config.preset
        wheel_s, pose_s = 1.0 / preset.wheel_hz, 1.0 / preset.pose_hz
        clock = self.board.clock
        t0 = clock.now()
        next_wheel, next_pose = t0 + wheel_s, t0 + pose_s
        while not self._stop.is_set():
            now = clock.now()
            if now >= next_wheel:
                next_wheel += wheel_s * max(1, int((now - next_wheel) / wheel_s) + 1)
                self._publish_wheel(wheel_s)
            if now >= next_pose:
                next_pose += pose_s * max(1, int((now - next_pose) / pose_s) + 1)
                self._publish_pose()
            clock.wait(self._stop, max(0.0, min(next_wheel, next_pose) - clock.now()))

    def _stamp(self) -> dict[str, int]:
        clock = self.board.clock
        ns = int(clock.wall(clock.now()) * 1e9) + (self.client.time_offset_ns or 0 if self.client else 0)
        return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}

    def _publish_wheel(self, dt: float) -> None:
        c = self.client
        if c is None or c.state != "running":
            return
        st = self.board.robot_state()
        fr, fl, bl, br = (w * dt for w in st.wheels)
        c.write(self._pub["encoder_data"], DRIVE.encode({
            "header": {"stamp": self._stamp(), "frame_id": ENC_FRAME}, "front_right_wheel_velocity": fr,
            "front_left_wheel_velocity": fl, "back_left_wheel_velocity": bl, "back_right_wheel_velocity": br}))

    def _publish_pose(self) -> None:
        c = self.client
        if c is None or c.state != "running":
            return
        st = self.board.robot_state()
        x, y, theta = st.pose
        c.write(self._pub["odometry"], POSE2D.encode({"x": x, "y": y, "theta": theta}))
        fr, fl, bl, br = st.wheels
        c.write(self._pub["wheel_vel"], DRIVE.encode({
            "header": {"stamp": self._stamp(), "frame_id": VEL_FRAME}, "front_right_wheel_velocity": fr,
            "front_left_wheel_velocity": fl, "back_left_wheel_velocity": bl, "back_right_wheel_velocity": br}))

    def status(self) -> dict[str, Any]:
        out = self.client.status() if self.client is not None else {"state": "stopped"}
        out.update(cmd_vel_received=self.cmd_vel_received, last_cmd_vel=self.last_cmd_vel,
                   own_samples_back=dict(self.self_samples), zero_after_session=self.zero_after_session)
        return out


__all__ = ["MicroRosClient"]
