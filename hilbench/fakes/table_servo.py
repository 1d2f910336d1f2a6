"""A servo whose control table is data: the classic Dynamixel tables (AX, MX 1.0, XL-320) and Feetech STS/SCS.

:class:`TableServo` finds every register it acts on through the model's
roles (:attr:`hilbench.protocols.control_table.Model.roles`), so one
implementation serves tables that put goal and present values in different
places and encode them differently (sign-magnitude, big-endian). It keeps the
interface of :class:`hilbench.fakes.dynamixel.servo.Servo` (read, write,
reg_write, action, reboot, factory_reset, ping, error numbers of Protocol
2.0), so the Protocol 2.0 bus hosts an XL-320 as it hosts an X-series servo,
and the Protocol 1.0 and Feetech buses map the same error numbers to their
error bits.

What the registers do:

- Goal Position moves the horn (velocity- and acceleration-limited, see
  :mod:`hilbench.fakes.motion`); a goal outside the angle limits is
  clamped to them (and reported as an angle-limit error where the protocol
  has one). Both angle limits 0 (AX/MX) or a wheel Control/Operating Mode
  turn the speed register into a signed wheel speed.
- Present Position/Speed/Load/Voltage/Temperature (and MX-64/106 Current,
  Realtime Tick, Moving) are computed when read.
- A Homing Offset shifts Present Position in the model's own direction
  (``Motion.offset_sign``: Feetech subtracts it); the horn does not move when
  the offset changes.
- Torque Limit starts at Max Torque; writing Goal Position to a Protocol 1.0
  servo switches its torque on, as the e-Manual says.
- EEPROM (below ``Model.eeprom_end``) refuses writes while Lock is set
  (AX/MX) or, on the XL-320, while the torque is on.

State lives as long as the bench: a client closing and reopening its port
changes nothing, as on a powered servo.
"""

from __future__ import annotations

import math

from hilbench.fakes.control_table_servo import ControlTableServo
from hilbench.fakes.motion import MotionProfile
from hilbench.protocols.control_table import Field, Model
from hilbench.protocols.dynamixel import ALERT_BIT, ErrorNumber

#: Acceleration when the model has no acceleration register or it says 0 (a stiff servo), in revs/s^2.
MAX_ACCELERATION_REVS = 200

#: Status bits of Protocol 1.0 / Feetech that describe the servo's condition rather than the instruction.
INPUT_VOLTAGE_BIT = 0x01
OVERHEAT_BIT = 0x04

#: Roles whose change makes the horn go somewhere else (one retarget per write, however many change).
_MOTION_ROLES = frozenset({"goal_position", "goal_speed", "goal_acceleration", "min_position", "max_position",
                           "operating_mode"})
_DYNAMIC_ROLES = ("present_position", "present_speed", "present_load", "present_voltage", "present_temperature",
                  "moving", "present_current", "realtime_tick")


class TableServo(ControlTableServo):
    """One emulated servo of a role-described control table (see the module docstring)."""

    is_servo = True

    def __init__(
        self,
        model: Model,
        servo_id: int,
        *,
        name: str | None = None,
        initial: dict[str, int | float] | None = None,
        position: float | None = None,
        supply_voltage: float = 12.0,
        ambient_temperature: float = 30.0,
        reboot_time: float = 0.2,
        t: float = 0.0,
        seed: int = 0,
        firmware: int | None = None,
        auto_torque: bool | None = None,
        eeprom_needs_torque_off: bool | None = None,
        **_: object,
    ) -> None:
        if model.motion is None:
            raise ValueError(f"{model.name} has no motion description")
        super().__init__(model, servo_id, name=name, initial=initial, supply_voltage=supply_voltage,
                         ambient_temperature=ambient_temperature, reboot_time=reboot_time, seed=seed,
                         firmware=firmware)
        self.motion = model.motion
        roles = model.roles
        self._r = roles
        self._f: dict[str, Field] = {k: f for k in roles if (f := model.role(k)) is not None}
        #: Protocol 1.0 servos switch their torque on when a goal position arrives (e-Manual).
        self.auto_torque = model.protocol == 1 if auto_torque is None else auto_torque
        self.eeprom_needs_torque_off = (model.protocol == 2) if eeprom_needs_torque_off is None \
            else eeprom_needs_torque_off
        self._fields = [model.covering(a) for a in range(model.table_size)]
        # per address, the roles whose bytes it holds (a write looks up only what it touches)
        self._roles_at: list[tuple[tuple[str, Field], ...]] = [() for _ in range(model.table_size)]
        for key, f in self._f.items():
            for a in range(f.address, f.address + f.size):
                self._roles_at[a] += ((key, f),)
        self._baud_address = roles.get("baud")
        self._srl_address = roles.get("status_return_level")
        self._return_delay_address = roles.get("return_delay")
        self._torque_address = roles.get("torque_enable")
        self._hardware_error_address = roles.get("hardware_error")
        self._shutdown_address = roles.get("shutdown")
        self._eeprom_end = model.eeprom_end
        spans = [(f.address, f.address + f.size) for k in _DYNAMIC_ROLES if (f := self._f.get(k)) is not None]
        self._dyn_lo = min((a for a, _ in spans), default=0)
        self._dyn_hi = max((b for _, b in spans), default=0)
        self._after_power_on(t, position)

    def _after_power_on(self, t: float, position: float | None) -> None:
        """RAM items that start from EEPROM ones, and the horn where it was."""
        if "torque_limit" in self._f and "max_torque" in self._f:
            self._set_role("torque_limit", self._role("max_torque"))
        start = position if position is not None else self._actual(self._role("present_position"))
        self.profile = MotionProfile(t, float(start))
        self._hold(t)
        if self.torque:  # on at power-on (Feetech): holding the horn, warming from now
            self._set_torque(True, t)
        self._refresh(t)

    # ------------------------------------------------------------------ register access by role

    def _role(self, key: str) -> int:
        f = self._f.get(key)
        if f is None:
            return 0
        return f.decode(bytes(self.mem[f.address : f.address + f.size]))

    def _set_role(self, key: str, value: int) -> None:
        f = self._f.get(key)
        if f is not None:
            self.mem[f.address : f.address + f.size] = f.encode(value)

    # ------------------------------------------------------------------ properties

    @property
    def secondary_id(self) -> None:
        return None

    @property
    def baud(self) -> int | None:
        a = self._baud_address
        return None if a is None else self.model.baud_codes.get(self.mem[a])

    @property
    def wheel(self) -> bool:
        """Wheel (velocity) mode: both angle limits 0, or Control/Operating Mode 1."""
        if "operating_mode" in self._f:
            return self._role("operating_mode") == 1
        return self._role("min_position") == 0 and self._role("max_position") == 0

    def error_byte(self, number: int = 0) -> int:
        """Protocol 2.0 ERR (the XL-320): the error number plus the Alert bit while a hardware error stands."""
        return number | (ALERT_BIT if self.hardware_error else 0)

    def condition_bits(self) -> int:
        """Protocol 1.0 / Feetech status bits of the servo's condition: input voltage, overheating."""
        bits = 0
        if "min_voltage" in self._f:
            lo, hi = self._role("min_voltage") / 10, self._role("max_voltage") / 10
            if not lo <= self.supply_voltage <= hi:
                bits |= INPUT_VOLTAGE_BIT
        if "temperature_limit" in self._f and self.ambient_temperature > self._role("temperature_limit"):
            bits |= OVERHEAT_BIT
        return bits

    # ------------------------------------------------------------------ instructions

    def ping(self) -> bytes:
        """Protocol 2.0 Ping reply data: model number and firmware version."""
        m = self.model
        return bytes(self.mem[0:2]) + bytes((self.mem[m.firmware_address],))

    def read(self, address: int, length: int, t: float) -> tuple[int, bytes]:
        """A Read: (error number, data). Leaving the table is an Access Error with no data."""
        end = address + length
        if length == 0 or end > self.model.table_size:
            return ErrorNumber.ACCESS_ERROR, b""
        if end > self._dyn_lo and address < self._dyn_hi:
            self._refresh(t)
        return 0, bytes(self.mem[address:end])

    def write(self, address: int, data: bytes, t: float) -> int:
        """A Write: applies it if the checks pass; returns the error number (0 = success).

        A goal outside the angle limits is clamped and reported as a limit error (it still moves).
        """
        err = self._check_write(address, data)
        if err and err != ErrorNumber.DATA_LIMIT_ERROR:
            return err
        self._apply_write(address, data, t)
        return err

    def write_unanswered(self, address: int, data: bytes, t: float) -> None:
        """A write whose status nobody hears (Sync/Bulk Write on a Protocol 2.0 bus)."""
        self.write(address, data, t)

    def reg_write(self, address: int, data: bytes, t: float) -> int:
        """Reg Write: checks now, applies on Action."""
        err = self._check_write(address, data)
        if err and err != ErrorNumber.DATA_LIMIT_ERROR:
            return err
        self._registered = (address, bytes(data))
        self._set_role("registered", 1)
        return 0

    def action(self, t: float) -> int:
        if self._registered is None:
            return ErrorNumber.INSTRUCTION_ERROR
        address, data = self._registered
        self._registered = None
        self._set_role("registered", 0)
        return self.write(address, data, t)

    def clear(self, params: bytes, t: float) -> int:
        return ErrorNumber.INSTRUCTION_ERROR

    def backup(self, params: bytes, t: float) -> int:
        return ErrorNumber.INSTRUCTION_ERROR

    # ------------------------------------------------------------------ writes

    def _check_write(self, address: int, data: bytes) -> int:
        """Access and range checks; the angle limits give DATA_LIMIT_ERROR (the write still applies)."""
        end = address + len(data)
        if not data or end > self.model.table_size:
            return ErrorNumber.ACCESS_ERROR
        eeprom_end = self.model.eeprom_end
        locked = address < eeprom_end and (
            (self.eeprom_needs_torque_off and self.torque) or ("lock" in self._f and self._lock_refuses()))
        fields = self._fields
        pos = address
        err = 0
        while pos < end:
            f = fields[pos]
            if f is None:
                pos += 1  # a reserved byte: stored, as the classic firmwares do
                continue
            if not f.writable or (locked and f.address < eeprom_end):
                return ErrorNumber.ACCESS_ERROR
            if f.address < address or f.address + f.size > end:
                pos = f.address + f.size  # a partial write of a field (Protocol 1.0 allows it): no range check
                continue
            value = f.decode(bytes(data[f.address - address : f.address - address + f.size]))
            if not f.in_range(value):
                return ErrorNumber.DATA_RANGE_ERROR
            if f is self._f.get("goal_position") and not self.wheel:
                lo, hi = self._limits_after(address, data)
                if not lo <= value <= hi:
                    err = ErrorNumber.DATA_LIMIT_ERROR
            pos = f.address + f.size
        return err

    def _lock_refuses(self) -> bool:
        """Whether Lock refuses EEPROM writes: a Dynamixel's Lock 1 does until power-off; a Feetech's Lock 1
        only keeps them from being saved across a power cycle, which a bench run never sees."""
        return self.model.protocol == 1 and self._role("lock") == 1

    def _limits_after(self, address: int, data: bytes) -> tuple[int, int]:
        """The angle limits, as changed by this write if it writes them too."""
        out = []
        for key in ("min_position", "max_position"):
            f = self._f[key]
            if address <= f.address and f.address + f.size <= address + len(data):
                off = f.address - address
                out.append(f.decode(bytes(data[off : off + f.size])))
            else:
                out.append(self._role(key))
        return out[0], out[1]

    def _apply_write(self, address: int, data: bytes, t: float) -> None:
        end = address + len(data)
        old = bytes(self.mem[address:end])
        self.mem[address:end] = data
        touched: dict[str, Field] = {}
        roles_at = self._roles_at
        for a in range(address, end):
            for key, f in roles_at[a]:
                touched[key] = f
        if not touched:
            return
        goal = touched.get("goal_position")
        if goal is not None and not self.wheel:
            lo, hi = self._role("min_position"), self._role("max_position")
            g = self._role("goal_position")
            if not lo <= g <= hi:
                self._set_role("goal_position", max(lo, min(hi, g)))
        motion = False
        for key, f in touched.items():
            lo, hi = max(0, f.address - address), f.address + f.size - address
            if old[lo:hi] == bytes(data[lo:hi]):
                # the same value again (a sync loop repeating its goals): nothing changes, but a goal
                # still switches a Protocol 1.0 servo's torque on
                if key == "goal_position" and self.auto_torque and not self.torque:
                    motion = True
                continue
            if key in _MOTION_ROLES:
                motion = True
            else:
                self._after_write(f, t, key)
        if motion:
            if goal is not None and self.auto_torque and not self.torque:
                self._set_role("torque_enable", 1)
                self._set_torque(True, t)
            else:
                self._retarget(t)

    def _after_write(self, f: Field, t: float, key: str | None = None) -> None:
        """Side effects of a changed item."""
        if key is None:
            key = next((k for k, g in self._f.items() if g is f), "")
        if key == "torque_enable":
            self._set_torque(self.torque, t)
        elif key == "goal_position":
            if self.auto_torque and not self.torque:
                self._set_role("torque_enable", 1)
                self._set_torque(True, t)
            else:
                self._retarget(t)
        elif key in ("goal_speed", "goal_acceleration", "min_position", "max_position", "operating_mode"):
            self._retarget(t)
        elif key == "homing_offset":
            self._hold(t)  # the horn stays; its goal follows the new frame
        elif key == "max_torque":
            pass  # Torque Limit takes it at the next power-on

    # ------------------------------------------------------------------ motion

    def _offset(self) -> int:
        return self._role("homing_offset") * self.motion.offset_sign if "homing_offset" in self._f else 0

    def _present(self, actual: float) -> int:
        """Present Position of the horn's actual position (wraps in one turn like the encoder)."""
        return (int(round(actual)) + self._offset()) % (self.motion.position_max + 1)

    def _actual(self, present: int) -> int:
        """The actual position a Goal Position asks for."""
        return (present - self._offset()) % (self.motion.position_max + 1)

    def _hold(self, t: float) -> None:
        """Goal Position = where the horn is, so torque-on does not swing it (and the profile stays put)."""
        self._set_role("goal_position", self._present(self.profile.at(t).position))

    def _speed_limits(self) -> tuple[float, float]:
        mo = self.motion
        f = self._f.get("goal_speed")
        raw = self._role("goal_speed") if f is not None else 0
        # Dynamixel: bits 0-9 are the speed (bit 10 is a wheel's direction); Feetech: sign-magnitude
        magnitude = raw & 1023 if f is not None and f.sign_bit is None else abs(raw)
        vmax = min(magnitude * mo.speed_unit, mo.max_speed) if magnitude else mo.max_speed
        acc = self._role("goal_acceleration") if "goal_acceleration" in self._f else 0
        amax = acc * mo.accel_unit if acc and mo.accel_unit else MAX_ACCELERATION_REVS * mo.counts_per_rev
        return max(vmax, 1.0), max(amax, 1.0)

    def _retarget(self, t: float) -> None:
        if not self.torque:
            return
        mo = self.motion
        vmax, amax = self._speed_limits()
        if self.wheel:
            raw = self._role("goal_speed")
            if self._f["goal_speed"].sign_bit is None:
                # Dynamixel wheel speed: bits 0-9 magnitude, bit 10 set = clockwise (negative)
                raw = -(raw & 1023) if raw & 1024 else raw & 1023
            self.profile.run_at(t, max(-mo.max_speed, min(mo.max_speed, raw * mo.speed_unit)), amax)
            return
        goal = self._actual(self._role("goal_position"))
        now = self.profile.at(t).position
        # the shorter way round for encoders that wrap (the goal is modulo one turn of counts)
        span = mo.position_max + 1
        if mo.position_max >= 4095:
            goal = now + ((goal - now + span / 2) % span - span / 2)
        self.profile.move_to(t, float(goal), vmax, amax)

    # ------------------------------------------------------------------ present values

    def _refresh(self, t: float, lo: int = 0, hi: int = 0) -> None:
        """Write every present value into the control table (called before a read that covers one; the
        values are few, so all are written whatever range [``lo``, ``hi``) is read)."""
        s = self.profile.at(t)
        mo = self.motion
        f = self._f
        if "present_position" in f:
            self._set_role("present_position", self._present(s.position))
        speed = s.velocity / mo.speed_unit
        if "present_speed" in f:
            self._set_role("present_speed", _clip(speed, f["present_speed"]))
        torque = self.torque
        load = (s.acceleration / (MAX_ACCELERATION_REVS * mo.counts_per_rev) * 800 + math.copysign(15, speed or 1)) \
            if torque else 0.0
        if "present_load" in f:
            self._set_role("present_load", _clip(load, f["present_load"]))
        if "present_current" in f:
            cur = f["present_current"]
            base = 2048 if cur.default == 2048 else 0  # MX-64/106: 2048 means no current
            self._set_role("present_current", int(base + abs(load) / 4))
        if "present_voltage" in f:
            sag = 0.2 if s.moving else 0.0
            self._set_role("present_voltage", int(round((self.supply_voltage - sag) * 10)))
        if "present_temperature" in f:
            warm = min(8.0, (t - self._torque_since) / 60.0) if self._torque_since is not None else 0.0
            self._set_role("present_temperature", int(self.ambient_temperature + warm))
        if "moving" in f:
            self._set_role("moving", 1 if s.moving else 0)
        if "realtime_tick" in f:
            self._set_role("realtime_tick", int(t * 1000) % 32768)


def _clip(value: float, f: Field) -> int:
    """A present value within what its register can say (and never all ones: USB2AX readers take 0xFF.. as lost)."""
    lim = (1 << f.sign_bit) - 1 if f.sign_bit is not None else (1 << 8 * f.size - (1 if f.signed else 0)) - 2
    v = int(max(-lim, min(lim, value)))
    return v if (f.sign_bit is not None or f.signed) else abs(v)


__all__ = ["TableServo"]
