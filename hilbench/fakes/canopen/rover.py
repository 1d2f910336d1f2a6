"""The STM32 rover board as a CANopen node: velocity setpoints in, encoders, odometry and status out.

The CAN interface is :mod:`hilbench.protocols.board_can` (PDOs, object
dictionary); the motion is the rover firmware's own model
(:class:`hilbench.fakes.mecanum_robot.Robot`: setpoint queue, 3 % ramp per
pose cycle, mecanum kinematics, odometry), run with equal wheel and pose
periods so the odometry integrates exactly the motion commanded.

Behaviour, in OPERATIONAL only (as CANopen PDOs are):

- RPDO1 (velocity setpoint) is checked as the firmware would check it:
  length 8 (else EMCY 0x8210, rejected), CRC-8 checksum (else rejected,
  EMCY 0x8200 once per burst), alive counter changed since the previous frame
  (a repeat is rejected; a jump counts the lost frames). An accepted setpoint
  goes into the robot's setpoint queue and restarts the setpoint watchdog;
- the watchdog (RPDO1 event timer, object 0x1400 sub 5, 150 ms by default:
  three 50 ms repeats) stops the rover when no setpoint arrives in time:
  setpoint zero, mode ``timeout``, EMCY 0x8250 (RPDO timeout); the next good
  setpoint clears it (error-reset EMCY);
- TPDO1..4 go out at their event timers (0x1800+k sub 5, writable; a write
  takes effect at once);
- leaving OPERATIONAL stops the rover and the TPDOs.

Fault knobs (profile ``faults`` and the control channel) besides the node's:
``motor_fault`` (EMCY 0x7121 motor blocked, the wheels stop), ``battery_v``
(below 21 V: EMCY 0x3220 under voltage), ``stuck_odometry`` (TPDO2 repeats
its last content), ``dlc_mismatch`` (TPDO2 one byte short, as tools then
count it discarded).
"""

from __future__ import annotations

import threading
from typing import Any

from hilbench.fakes.canopen.node import CanopenNode
from hilbench.fakes.mecanum_robot import INC2RAD, Robot
from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen as co
from hilbench.protocols.can_frame import CanFrame
from hilbench.protocols.problem import Problem

#: Pose (and wheel) control period of the CAN board's firmware model.
CONTROL_PERIOD_US = 10_000
UNDER_VOLTAGE = 21.0
#: Volts the battery sags at full wheel duty.
SAG_AT_FULL_DUTY = 1.2

ROVER_FAULT_KEYS = ("heartbeat_stop", "silent", "sdo_abort", "motor_fault", "battery_v", "stuck_odometry",
                    "dlc_mismatch")


class RoverNode(CanopenNode):
    """The rover board on a CAN bus; see the module docstring."""

    def __init__(self, name: str, config: bc.BoardCanConfig, *, autostart: bool = False,
                 battery_v: float = 24.6, encoder_noise: float = 0.0, seed: int = 0) -> None:
        super().__init__(name, config.node_id, bc.object_dictionary(config), autostart=autostart)
        self.config = config
        self.faults.update({"motor_fault": False, "battery_v": battery_v, "stuck_odometry": False,
                            "dlc_mismatch": False})
        self._t0 = 0.0
        # The robot model advances in the bus thread; pose() and status() may be called from others.
        self._robot_lock = threading.RLock()
        self.encoder_noise = encoder_noise
        self.seed = seed
        self.robot = self._new_robot()
        self.mode = bc.MODE_IDLE
        self.counters = {p.key: 0 for p in bc.PDOS if p.kind == "tpdo"}
        self.stats = {"accepted": 0, "checksum_errors": 0, "counter_errors": 0, "lost_frames": 0,
                      "length_errors": 0, "timeouts": 0}
        self._last_counter: int | None = None
        self._last_valid = 0.0
        self._rejecting = False
        self._last_counts = [0, 0, 0, 0]
        self._stuck: bytes | None = None
        self.setpoint = (0.0, 0.0, 0.0)
        for p in bc.PDOS:
            if p.kind == "tpdo":
                self.od.on_write(p.comm_index, self._write_tpdo_timer)
        self.od.on_write(0x2010, self._write_odometry_reset)
        for index in (0x2001, 0x2002, 0x2003, 0x2004, 0x2011, 0x2012, 0x1001):
            self.od.on_read(index, lambda i, s: self._refresh(self._now()))

    # ------------------------------------------------------------------ time

    def _now(self) -> float:
        return self.now()

    def _t_us(self, t: float) -> float:
        return (t - self._t0) * 1e6

    def start(self, t: float | None = None) -> None:
        t = self._now() if t is None else t
        self._t0 = t
        self.robot = self._new_robot()
        super().start(t)

    def _new_robot(self) -> Robot:
        return Robot(CONTROL_PERIOD_US, CONTROL_PERIOD_US, first_cycle_us=0.0, encoder_noise=self.encoder_noise,
                     seed=self.seed)

    def body_motion(self, t: float) -> tuple[int, float, float, float, float, float, float]:
        """What the wheels did up to bench clock time ``t``, for its world body (a world driver): (epoch, x, y,
        theta of the motion since power-up or reset in metres and radians, body-frame vx, vy, omega now)."""
        if not self._started:
            return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        with self._robot_lock:
            robot = self.robot
            t_us = max(0.0, self._t_us(t))
            robot.advance(t_us)
            return (id(robot), *robot.motion_at(t_us), *robot.body_velocity())

    # ------------------------------------------------------------------ NMT hooks

    def on_state(self, state: int, t: float) -> None:
        if state == co.OPERATIONAL:
            for p in bc.PDOS:
                if p.kind == "tpdo":
                    self._schedule_tpdo(p, t)
        else:
            for p in bc.PDOS:
                self.restart_timer(p.key)
            self.restart_timer("watchdog")
            if self.setpoint != (0.0, 0.0, 0.0) or self.robot.setpoint != (0.0, 0.0, 0.0):
                self._command(0.0, 0.0, 0.0, t)  # outside OPERATIONAL the motors stop
            if self.mode != bc.MODE_FAULT:
                self.mode = bc.MODE_IDLE

    def on_reset(self, t: float) -> None:
        self._t0 = t
        with self._robot_lock:
            self.robot = self._new_robot()
        self.mode = bc.MODE_IDLE
        self.counters = dict.fromkeys(self.counters, 0)
        self.stats = dict.fromkeys(self.stats, 0)
        self._last_counter = None
        self._rejecting = False
        self._last_counts = [0, 0, 0, 0]
        self._stuck = None
        self.setpoint = (0.0, 0.0, 0.0)
        self._check_battery()
        if self.faults["motor_fault"]:
            self.active_errors[co.ERR_MOTOR_BLOCKED] = co.REG_CURRENT

    # ------------------------------------------------------------------ setpoints

    def on_app_frame(self, frame: CanFrame, t: float) -> None:
        if frame.can_id != bc.SETPOINT.cob_id(self.node_id) or frame.remote or self.state != co.OPERATIONAL:
            return
        result = bc.check_setpoint(frame.data)
        if isinstance(result, Problem):
            if result.kind == "length":
                self.stats["length_errors"] += 1
                self.emcy(co.ERR_PDO_LENGTH, co.REG_COMMUNICATION, bytes([len(frame.data)]))
            else:
                self.stats["checksum_errors"] += 1
                if not self._rejecting:
                    self._rejecting = True
                    self.emcy(co.ERR_PROTOCOL, co.REG_COMMUNICATION, bytes([result.expected, result.got]))
            return
        if self._last_counter is not None:
            step = (result.counter - self._last_counter) % 256
            if step == 0:
                self.stats["counter_errors"] += 1
                return
            self.stats["lost_frames"] += step - 1
        self._last_counter = result.counter
        self._rejecting = False
        self.stats["accepted"] += 1
        self.od[(0x2000, 1)], self.od[(0x2000, 2)], self.od[(0x2000, 3)] = (
            round(result.vx * 1000), round(result.vy * 1000), round(result.omega * 1000))
        self.od[(0x2000, 4)], self.od[(0x2000, 5)] = result.counter, frame.data[7]
        self._last_valid = t
        if self.mode == bc.MODE_TIMEOUT:
            self.clear_error(co.ERR_RPDO_TIMEOUT)
        if self.faults["motor_fault"]:
            return  # the motor stage refuses: the wheels stay stopped
        self.mode = bc.MODE_DRIVING
        self._command(result.vx, result.vy, result.omega, t)
        timeout = self.setpoint_timeout_ms / 1000
        if timeout > 0:
            self.call_at(t + timeout, lambda: self._watchdog(t), timer="watchdog")

    @property
    def setpoint_timeout_ms(self) -> int:
        return int(self.od[(0x1400, 5)])

    def _command(self, vx: float, vy: float, omega: float, t: float) -> None:
        self.setpoint = (vx, vy, omega)
        with self._robot_lock:
            self.robot.push_setpoint(max(0.0, self._t_us(t)), vx * 1000, vy * 1000, omega)

    def _watchdog(self, since: float) -> None:
        if self._last_valid != since or self.state != co.OPERATIONAL or self.mode != bc.MODE_DRIVING:
            return
        now = since + self.setpoint_timeout_ms / 1000
        self.stats["timeouts"] += 1
        self.mode = bc.MODE_TIMEOUT
        self._command(0.0, 0.0, 0.0, now)
        self.raise_error(co.ERR_RPDO_TIMEOUT, co.REG_COMMUNICATION)

    # ------------------------------------------------------------------ TPDOs

    def _period(self, pdo: bc.Pdo) -> float:
        return int(self.od[(pdo.comm_index, 5)]) / 1000

    def _schedule_tpdo(self, pdo: bc.Pdo, t: float) -> None:
        self.restart_timer(pdo.key)
        period = self._period(pdo)
        if period > 0:
            self.call_at(t + period, lambda: self._tpdo(pdo, t + period), timer=pdo.key)

    def _tpdo(self, pdo: bc.Pdo, t: float) -> None:
        if self.state != co.OPERATIONAL:
            return
        self._refresh(t)
        data = self._pdo_data(pdo)
        self.send(pdo.cob_id(self.node_id), data)
        period = self._period(pdo)
        if period > 0:
            nxt = t + period
            if nxt < self._now() - period:
                nxt = self._now() + period  # far behind: skip the backlog
            self.call_at(nxt, lambda: self._tpdo(pdo, nxt), timer=pdo.key)

    def _write_tpdo_timer(self, index: int, subindex: int, value: Any) -> int | None:
        if subindex == 5 and self.state == co.OPERATIONAL:
            pdo = next(p for p in bc.PDOS if p.comm_index == index)
            self.od[(index, 5)] = value
            self._schedule_tpdo(pdo, self._now())  # the new period applies from now
        return None

    def _write_odometry_reset(self, index: int, subindex: int, value: Any) -> int | None:
        if value == 1:
            self._refresh(self._now())
            with self._robot_lock:
                self.robot.x = self.robot.y = self.robot.theta = 0.0
            self._refresh(self._now())
        elif value != 0:
            return 0x06090030
        self.od[(0x2010, 0)] = 0
        return None

    def _counts(self) -> list[int]:
        return [round(a / INC2RAD) for a in self.robot.wheel_angle]

    def _refresh(self, t: float) -> None:
        """Bring the object dictionary's live values up to time ``t``."""
        with self._robot_lock:
            state = self.robot.state(max(0.0, self._t_us(t)))
        x, y, theta = state.pose
        for i, count in enumerate(self._counts(), 1):
            self.od[(0x2011, i)] = count
        self.od[(0x2002, 1)], self.od[(0x2002, 2)] = round(x), round(y)
        self.od[(0x2002, 3)] = round(theta / 0.0001)
        vx, vy, omega = state.command
        self.od[(0x2003, 1)], self.od[(0x2003, 2)], self.od[(0x2003, 3)] = round(vx), round(vy), round(omega * 1000)
        self._check_battery(state.duty)
        self.od[(0x2004, 1)] = bc.MODE_FAULT if self.faults["motor_fault"] else self.mode
        self.od[(0x2004, 2)] = (self.stats["checksum_errors"] + self.stats["counter_errors"]
                                + self.stats["length_errors"]) % 256
        self.od[(0x2004, 3)] = self.stats["timeouts"] % 256
        self.od[(0x2004, 4)] = round(self.battery_v(state.duty) / 0.01)
        for i, key in enumerate(("accepted", "checksum_errors", "counter_errors", "lost_frames", "length_errors",
                                 "timeouts"), 1):
            self.od[(0x2012, i)] = self.stats[key] & 0xFFFFFFFF
        self.od[(0x1001, 0)] = self.error_register

    def battery_v(self, duty: tuple[float, ...] = (0.0,)) -> float:
        load = sum(abs(d) for d in duty) / (100.0 * max(1, len(duty)))
        return float(self.faults["battery_v"]) - SAG_AT_FULL_DUTY * load

    def _check_battery(self, duty: tuple[float, ...] = (0.0,)) -> None:
        low = self.battery_v(duty) < UNDER_VOLTAGE
        if low and co.ERR_UNDER_VOLTAGE not in self.active_errors:
            self.raise_error(co.ERR_UNDER_VOLTAGE, co.REG_VOLTAGE)
        elif not low and co.ERR_UNDER_VOLTAGE in self.active_errors and \
                self.battery_v(duty) > UNDER_VOLTAGE + 0.5:
            self.clear_error(co.ERR_UNDER_VOLTAGE)

    def _pdo_data(self, pdo: bc.Pdo) -> bytes:
        key = pdo.key
        count = self.counters[key] = (self.counters[key] + 1) % 256
        values = self.od
        if key == "encoders":
            counts = self._counts()
            deltas = [max(-32768, min(32767, c - last)) for c, last in zip(counts, self._last_counts, strict=True)]
            self._last_counts = counts
            for i, d in enumerate(deltas, 1):
                values[(0x2001, i)] = d
            return bc.LAYOUTS[key].build(dict(zip(("enc_fr", "enc_fl", "enc_bl", "enc_br"), deltas, strict=True)))
        if key == "odometry":
            if self.faults["stuck_odometry"] and self._stuck is not None:
                data = self._stuck
            else:
                data = bc.LAYOUTS[key].build({"x": _clamp(values[(0x2002, 1)], 24), "y": _clamp(values[(0x2002, 2)], 24),
                                              "theta": _clamp(values[(0x2002, 3)], 16)})
                self._stuck = data
            return data[:-1] if self.faults["dlc_mismatch"] else data
        if key == "velocity":
            values[(0x2003, 4)] = count
            return bc.LAYOUTS[key].build({"vx": _clamp(values[(0x2003, 1)], 16), "vy": _clamp(values[(0x2003, 2)], 16),
                                          "omega": _clamp(values[(0x2003, 3)], 16), "counter": count})
        values[(0x2004, 5)] = count
        return bc.LAYOUTS[key].build({"mode": values[(0x2004, 1)], "error_register": values[(0x1001, 0)],
                                      "rejected": values[(0x2004, 2)], "timeouts": values[(0x2004, 3)],
                                      "battery": values[(0x2004, 4)], "counter": count})

    # ------------------------------------------------------------------ faults and status

    def set_faults(self, **knobs: Any) -> dict[str, Any]:
        """Turn fault knobs (see the module docstring); takes effect at once."""
        for key, value in knobs.items():
            if key not in ROVER_FAULT_KEYS:
                raise ValueError(f"unknown fault knob {key!r} (expected one of: {', '.join(ROVER_FAULT_KEYS)})")
            self.faults[key] = value
        if "motor_fault" in knobs:
            if knobs["motor_fault"]:
                self.raise_error(co.ERR_MOTOR_BLOCKED, co.REG_CURRENT)
                self._command(0.0, 0.0, 0.0, self._now())
                self.mode = bc.MODE_FAULT
            else:
                self.clear_error(co.ERR_MOTOR_BLOCKED)
                self.mode = bc.MODE_IDLE
        if "battery_v" in knobs:
            self._check_battery()
        return dict(self.faults)

    def pose(self, t: float | None = None) -> tuple[float, float, float]:
        """The odometry pose (m, m, rad) now."""
        with self._robot_lock:
            state = self.robot.state(max(0.0, self._t_us(self._now() if t is None else t)))
        x, y, theta = state.pose
        return x / 1000, y / 1000, theta

    def status(self) -> dict[str, Any]:
        out = super().status()
        x, y, theta = self.pose()
        out.update({
            "mode": dict(bc.MODES)[bc.MODE_FAULT if self.faults["motor_fault"] else self.mode],
            "setpoint": {"vx": self.setpoint[0], "vy": self.setpoint[1], "omega": self.setpoint[2]},
            "pose": {"x": round(x, 6), "y": round(y, 6), "theta": round(theta, 6)},
            "setpoints": dict(self.stats),
            "setpoint_timeout_ms": self.setpoint_timeout_ms,
            "battery_v": round(self.battery_v(), 3),
            "tpdo_periods_ms": {p.key: int(self.od[(p.comm_index, 5)]) for p in bc.PDOS if p.kind == "tpdo"},
        })
        return out


def _clamp(value: Any, bits: int) -> int:
    lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    v = int(value)
    return lo if v < lo else hi if v > hi else v


__all__ = ["ROVER_FAULT_KEYS", "RoverNode"]
