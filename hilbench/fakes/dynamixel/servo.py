"""A stateful Dynamixel device: its control table and what each instruction does to it.

:class:`Servo` knows nothing about wires or timing of the bus: it takes a
decoded request and the time, changes its state and says what it would
answer. The bus (:mod:`hilbench.fakes.dynamixel.bus`) decides who speaks when.
Custom boards (model kind ``board``) share the same code without motion.
"""

from __future__ import annotations

import math
import struct

from hilbench.fakes.control_table_servo import ControlTableServo
from hilbench.fakes.motion import MotionProfile
from hilbench.protocols import dynamixel_models as m
from hilbench.protocols.dynamixel import ALERT_BIT, BACKUP_KEY, CLEAR_KEY, ErrorNumber
from hilbench.protocols.dynamixel_models import Field, Model

#: Unit conversions used by the motion model.
PULSES_PER_REV = 4096
VEL_UNIT = 0.229 / 60 * PULSES_PER_REV  # pulses/s per velocity unit (0.229 rpm)
ACC_UNIT = 214.577 / 3600 * PULSES_PER_REV  # pulses/s^2 per profile acceleration unit
#: Acceleration used when Profile Acceleration is 0 ("infinite"): a stiff servo.
MAX_ACCELERATION = 200 * PULSES_PER_REV
#: Dynamic items refreshed before a read (Realtime Tick .. Present Temperature).
DYNAMIC_LO, DYNAMIC_HI = 120, 148
#: Indirect Data areas and where their addresses live.
INDIRECT_AREAS = ((224, 252, 168), (634, 662, 578))

# The hot paths (every Sync Read/Write touches every servo) read and write the table with struct at
# fixed addresses, bound here once: a module attribute lookup per access is a measurable share of a
# 20-servo cycle.
_U16, _U32, _I32 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<i")
_PWM_CUR_VEL = struct.Struct("<hhi")  # Present PWM, Present Current, Present Velocity (124..131)
_POS_VEL_POS = struct.Struct("<iii")  # Present Position, Velocity Trajectory, Position Trajectory (132..143)
assert (m.PRESENT_POSITION, m.VELOCITY_TRAJECTORY, m.POSITION_TRAJECTORY, m.PRESENT_INPUT_VOLTAGE) == (132, 136, 140, 144)
_BAUD_CODES = m.BAUD_CODES
_BAUD_RATE, _RETURN_DELAY_TIME, _DRIVE_MODE, _OPERATING_MODE = m.BAUD_RATE, m.RETURN_DELAY_TIME, m.DRIVE_MODE, \
    m.OPERATING_MODE
_HOMING_OFFSET, _MAX_VOLTAGE, _MIN_VOLTAGE = m.HOMING_OFFSET, m.MAX_VOLTAGE, m.MIN_VOLTAGE
_MAX_POSITION, _MIN_POSITION, _VELOCITY_LIMIT = m.MAX_POSITION, m.MIN_POSITION, m.VELOCITY_LIMIT
_TORQUE_ENABLE, _STATUS_RETURN_LEVEL, _HARDWARE_ERROR_STATUS = m.TORQUE_ENABLE, m.STATUS_RETURN_LEVEL, \
    m.HARDWARE_ERROR_STATUS
_BUS_WATCHDOG, _GOAL_POSITION = m.BUS_WATCHDOG, m.GOAL_POSITION
_GOALS = (m.GOAL_POSITION, m.GOAL_VELOCITY, m.GOAL_PWM, m.GOAL_CURRENT)
_ALWAYS_APPLY = (m.GOAL_POSITION, m.GOAL_VELOCITY, m.TORQUE_ENABLE)
_LIMITS = {m.GOAL_VELOCITY: (m.VELOCITY_LIMIT, 4), m.GOAL_PWM: (m.PWM_LIMIT, 2), m.GOAL_CURRENT: (m.CURRENT_LIMIT, 2)}


class Servo(ControlTableServo):
    """One emulated device on a Dynamixel bus.

    ``initial`` overrides control-table values by field key at power-up (they
    become the device's EEPROM contents, as if configured once and saved).
    ``supply_voltage`` (V) and ``ambient_temperature`` (C) drive the present
    voltage and temperature.
    """

    def __init__(
        self,
        model: Model,
        dxl_id: int,
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
        board_baud: int | None = None,
    ) -> None:
        super().__init__(model, dxl_id, name=name, initial=initial, supply_voltage=supply_voltage,
                         ambient_temperature=ambient_temperature, reboot_time=reboot_time, seed=seed,
                         firmware=firmware)
        self.board_baud = board_baud
        self._power_on_eeprom = bytes(self.mem[: m.EEPROM_END])
        self._backup: bytes | None = None
        self.is_servo = model.kind == "servo"
        if self.is_servo:  # boards have none of these registers
            self._baud_address = _BAUD_RATE
            self._srl_address = _STATUS_RETURN_LEVEL
            self._return_delay_address = _RETURN_DELAY_TIME
            self._torque_address = _TORQUE_ENABLE
            self._hardware_error_address = _HARDWARE_ERROR_STATUS
            self._shutdown_address = m.SHUTDOWN
        self._eeprom_end = m.EEPROM_END
        start = position if position is not None else (2048 if self.is_servo else 0)
        self.profile = MotionProfile(t, float(start))
        self._goal_at_power_on(start)
        self._last_comm = t
        self._fields = [model.covering(a) for a in range(model.table_size)]

    def _after_power_on(self, t: float, position: float) -> None:
        """After a reboot the horn is where it was and Goal Position holds it there."""
        self.profile = MotionProfile(t, position)
        self._goal_at_power_on(position)

    def _goal_at_power_on(self, position: float) -> None:
        """After power-on or a reboot Goal Position holds where the horn is, not 0, so switching the
        torque on does not swing the servo (ROBOTIS servos keep their position at torque-on)."""
        if self.is_servo:
            self._poke(m.GOAL_POSITION, 4, self._present(round(position)), signed=True)

    # ------------------------------------------------------------------ raw access

    def _peek(self, address: int, size: int, signed: bool = False) -> int:
        return int.from_bytes(self.mem[address : address + size], "little", signed=signed)

    def _poke(self, address: int, size: int, value: int, signed: bool = False) -> None:
        self.mem[address : address + size] = int(value).to_bytes(size, "little", signed=signed)

    # ------------------------------------------------------------------ properties

    @property
    def secondary_id(self) -> int | None:
        if not self.is_servo:
            return None
        sid = self.mem[12]
        return sid if sid <= 252 else None

    @property
    def baud(self) -> int | None:
        """Baud the device listens at; boards have no Baud Rate item and use ``board_baud`` (None: any)."""
        return _BAUD_CODES.get(self.mem[_BAUD_RATE]) if self.is_servo else self.board_baud

    def error_byte(self, number: int = 0) -> int:
        """ERR for a status: the error number plus the Alert bit while a hardware error stands."""
        if self.is_servo and self.mem[_HARDWARE_ERROR_STATUS]:
            return number | ALERT_BIT
        return number

    # ------------------------------------------------------------------ instructions

    def ping(self) -> bytes:
        """Ping reply data: model number and firmware version."""
        return self.mem[0:2] + self.mem[self.model.firmware_address : self.model.firmware_address + 1]

    def condition_bits(self) -> int:
        """The Protocol 1.0 status bits of its condition, when its Protocol Type is 1: Hardware Error Status's
        input voltage (bit 0), overheating (bit 2) and overload (bit 5) sit where Protocol 1.0 has them."""
        return self.hardware_error & 0x25

    def read(self, address: int, length: int, t: float) -> tuple[int, bytes]:
        """A Read: (error number, data). Leaving the table is an Access Error with no data."""
        self._touch(t)
        end = address + length
        if length == 0 or end > self.model.table_size:
            return ErrorNumber.ACCESS_ERROR, b""
        if not self.is_servo:
            return 0, bytes(self.mem[address:end])
        if end > DYNAMIC_LO and address < DYNAMIC_HI:
            self._refresh(t, address, end)
        data = bytes(self.mem[address:end])
        if end > 224 and address < 252 or end > 634:
            data = self._indirect_read(address, data, t)
        return 0, data

    def write(self, address: int, data: bytes, t: float) -> int:
        """A Write: applies it if every check passes; returns the error number (0 = success)."""
        self._touch(t)
        err = self._check_write(address, data)
        if err:
            return err
        end = address + len(data)
        if 64 <= address < 224 and end <= 224:  # RAM, no indirect data: see whether it is one whole field
            f = self._fields[address]
            if f.address == address and f.size == len(data):  # (checked: a field starts here and fills it)
                mem = self.mem
                if mem[address:end] != data:
                    mem[address:end] = data
                    self._after_write(f, t)
                elif address in _ALWAYS_APPLY:
                    self._after_write(f, t)
                return 0
        self._apply_write(address, data, t)
        return 0

    def write_unanswered(self, address: int, data: bytes, t: float) -> None:
        """A write whose status nobody hears (Sync/Bulk Write): :meth:`write`, with a shortcut for a value
        the table already holds where writing it again would change nothing (the goals a control loop
        repeats for joints that hold still)."""
        end = address + len(data)
        if address >= 64 and end <= 224 and self.mem[address:end] == data and not (
                address <= 104 < end or address <= 64 < end):  # (rewriting Goal Velocity, Torque Enable acts)
            if not (address <= _GOAL_POSITION < end) or not self.is_servo or self.mem[_TORQUE_ENABLE] != 1 or (
                    self.mem[_OPERATING_MODE] in (3, 4, 5) and self.profile.rests_at(
                        t, float(self._actual(_I32.unpack_from(self.mem, _GOAL_POSITION)[0])))):
                # whether or not its checks pass, the write leaves everything as it was
                self._touch(t)
                return
        self.write(address, data, t)

    def reg_write(self, address: int, data: bytes, t: float) -> int:
        """Reg Write: checks now, applies on Action."""
        self._touch(t)
        err = self._check_write(address, data)
        if err:
            return err
        self._registered = (address, bytes(data))
        if self.is_servo:
            self.mem[m.REGISTERED_INSTRUCTION] = 1
        return 0

    def action(self, t: float) -> int:
        self._touch(t)
        if self._registered is None:
            return ErrorNumber.INSTRUCTION_ERROR
        address, data = self._registered
        self._registered = None
        if self.is_servo:
            self.mem[m.REGISTERED_INSTRUCTION] = 0
        err = self._check_write(address, data)  # torque may have changed since
        if not err:
            self._apply_write(address, data, t)
        return err

    def clear(self, params: bytes, t: float) -> int:
        """Clear multi-turn (``01 'DXL"'``): Present Position back into one turn."""
        if not self.is_servo or self.firmware < 42 or params[:1] != b"\x01" or params[1:] != CLEAR_KEY:
            return ErrorNumber.INSTRUCTION_ERROR
        s = self.profile.at(t)
        if s.moving:
            return ErrorNumber.RESULT_FAIL
        self.profile = MotionProfile(t, s.position % PULSES_PER_REV)
        return 0

    def backup(self, params: bytes, t: float) -> int:
        """Control Table Backup: ``01`` stores, ``02`` restores the EEPROM area (X, firmware 45+)."""
        if not self.is_servo or not self.model.fast_read or self.firmware < 45 or params[1:] != BACKUP_KEY:
            return ErrorNumber.INSTRUCTION_ERROR
        if self.torque:
            return ErrorNumber.RESULT_FAIL
        if params[0] == 0x01:
            self._backup = bytes(self.mem[: m.EEPROM_END])
            self.mem[147] = 1
            return 0
        if self._backup is None:
            return ErrorNumber.RESULT_FAIL
        self.mem[: m.EEPROM_END] = self._backup
        return self.reboot(t)

    # ------------------------------------------------------------------ writes

    def _check_write(self, address: int, data: bytes) -> int:
        """Access, length, range and limit checks of spec §2.2 for a write."""
        n = len(data)
        end = address + n
        if n == 0 or end > self.model.table_size:
            return ErrorNumber.ACCESS_ERROR
        fields = self._fields
        f = fields[address]
        if f is not None and f.size == n and f.address == address and 64 <= address < 224 and self.is_servo:
            # one whole RAM field (a goal, a torque switch): the write of every control loop
            if f.access != "RW":
                return ErrorNumber.ACCESS_ERROR
            value = f.decode(data)
            if not f.in_range(value):
                return ErrorNumber.DATA_RANGE_ERROR
            return self._check_limit(f, value, address, data)
        pos = address
        torque = self.torque
        while pos < end:
            f = fields[pos]
            if f is None:
                return ErrorNumber.ACCESS_ERROR
            size = f.size
            if f.address != pos or pos + size > end:
                return ErrorNumber.DATA_LENGTH_ERROR
            if f.access != "RW" or (pos < 64 and torque):  # Field.writable, Field.eeprom
                return ErrorNumber.ACCESS_ERROR
            if not (224 <= pos < 252 or pos >= 634):  # indirect data checks its target
                value = f.decode(data[pos - address : pos - address + size])
                if not f.in_range(value):
                    return ErrorNumber.DATA_RANGE_ERROR
                err = self._check_limit(f, value, address, data)
                if err:
                    return err
            pos += size
        return 0

    def _value_after(self, key_address: int, address: int, data: bytes, size: int, signed: bool = False) -> int:
        # A limit written in the same packet counts (e.g. limits then goal in one write).
        if address <= key_address and key_address + size <= address + len(data):
            off = key_address - address
            return int.from_bytes(data[off : off + size], "little", signed=signed)
        return self._peek(key_address, size, signed)

    def _check_limit(self, f: Field, value: int, address: int, data: bytes) -> int:
        if not self.is_servo:
            return 0
        a = f.address
        mem = self.mem
        if a in _GOALS and mem[_BUS_WATCHDOG] == 0xFF:
            return ErrorNumber.DATA_RANGE_ERROR  # watchdog tripped: goals refused until it is cleared
        if a == _GOAL_POSITION:
            if mem[_OPERATING_MODE] == 3:  # the Position Limits bind in position mode only
                if address <= _MIN_POSITION and address + len(data) >= _MIN_POSITION + 4 or \
                        address <= _MAX_POSITION and address + len(data) >= _MAX_POSITION + 4:
                    lo = self._value_after(_MIN_POSITION, address, data, 4)
                    hi = self._value_after(_MAX_POSITION, address, data, 4)
                else:  # the usual goal-only write: the limits are the table's
                    lo, hi = _U32.unpack_from(mem, _MIN_POSITION)[0], _U32.unpack_from(mem, _MAX_POSITION)[0]
                if not lo <= value <= hi:
                    return ErrorNumber.DATA_LIMIT_ERROR
            return 0
        limits = _LIMITS
        if a in limits and self.model.field_at(limits[a][0]) is not None:
            limit_address, size = limits[a]
            if abs(value) > self._value_after(limit_address, address, data, size):
                return ErrorNumber.DATA_LIMIT_ERROR
        return 0

    def _apply_write(self, address: int, data: bytes, t: float) -> None:
        fields = self._fields
        pos, end = address, address + len(data)
        while pos < end:
            f = fields[pos]
            chunk = data[pos - address : pos - address + f.size]
            if self.is_servo and (224 <= f.address < 252 or f.address >= 634):
                self._indirect_write(f.address, chunk, t)
            else:
                old = bytes(self.mem[pos : pos + f.size])
                self.mem[pos : pos + f.size] = chunk
                if old != chunk or f.address in _ALWAYS_APPLY:
                    self._after_write(f, t)
            pos += f.size

    def _after_write(self, f: Field, t: float) -> None:
        """Side effects of a changed item."""
        if not self.is_servo:
            return
        a = f.address
        if a == m.TORQUE_ENABLE:
            self._set_torque(self.mem[a] == 1, t)
        elif a == m.OPERATING_MODE:
            # A new operating mode puts gains and profile items back to their defaults.
            defaults = self.model.defaults()
            for addr in (76, 78, 80, 82, 84, 88, 90, 108, 112):
                g = self.model.field_at(addr)
                if g is not None:
                    self.mem[addr : addr + g.size] = defaults[addr : addr + g.size]
            self.profile.stop(t)
        elif a in (m.GOAL_POSITION, m.PROFILE_VELOCITY, m.PROFILE_ACCELERATION, m.GOAL_VELOCITY, m.GOAL_PWM,
                   m.GOAL_CURRENT):
            self._retarget(t)
        elif a in (m.HOMING_OFFSET, m.DRIVE_MODE):
            # the horn stays where it is: hold that place in the new frame (torque is off: EEPROM)
            self._goal_at_power_on(self.profile.at(t).position)
        elif a == m.BUS_WATCHDOG and self.mem[a] == 0:
            pass  # writing 0 clears a tripped watchdog

    def _present(self, actual: int) -> int:
        """Present Position of the horn's actual position: Drive Mode bit 0 reverses the direction and
        the Homing Offset is added (e-Manual: Present Position = Actual Position + Homing Offset)."""
        mem = self.mem
        sign = -1 if mem[_DRIVE_MODE] & 1 else 1
        return sign * actual + _I32.unpack_from(mem, _HOMING_OFFSET)[0]

    def _actual(self, present: int) -> int:
        """The actual position a Goal Position (in Present Position terms) asks for."""
        sign = -1 if self.mem[m.DRIVE_MODE] & 1 else 1
        return sign * (present - self._peek(m.HOMING_OFFSET, 4, signed=True))

    def _limits(self) -> tuple[float, float]:
        """Velocity and acceleration limits of the profile in pulses/s and pulses/s^2."""
        vlim = self._peek(m.VELOCITY_LIMIT, 4) or 1023
        pv = self._peek(m.PROFILE_VELOCITY, 4)
        vmax = (min(pv, vlim) if pv else vlim) * VEL_UNIT
        pa = self._peek(m.PROFILE_ACCELERATION, 4)
        amax = pa * ACC_UNIT if pa else MAX_ACCELERATION
        return max(vmax, 1.0), max(amax, 1.0)

    def _retarget(self, t: float) -> None:
        if not self.torque:
            return
        if self.mem[_OPERATING_MODE] in (3, 4, 5) and self.profile.rests_at(
                t, float(self._actual(_I32.unpack_from(self.mem, _GOAL_POSITION)[0]))):
            return  # already holding that goal (a control loop repeating its goals): planning again changes nothing
        mode = self.mem[m.OPERATING_MODE]
        vmax, amax = self._limits()
        if mode in (3, 4, 5):
            goal = self._peek(m.GOAL_POSITION, 4, signed=True)
            self.profile.move_to(t, float(self._actual(goal)), vmax, amax)
        elif mode == 1:
            self.profile.run_at(t, self._peek(m.GOAL_VELOCITY, 4, signed=True) * VEL_UNIT, amax)
        elif mode == 16:
            pwm = self._peek(m.GOAL_PWM, 2, signed=True)
            self.profile.run_at(t, pwm / 885 * vmax, amax)
        elif mode == 0:
            cur = self._peek(m.GOAL_CURRENT, 2, signed=True)
            lim = self._peek(m.CURRENT_LIMIT, 2) or 1
            self.profile.run_at(t, max(-1.0, min(1.0, cur / lim)) * vmax, amax)

    # ------------------------------------------------------------------ indirect addressing

    def _indirect_target(self, data_address: int) -> int:
        for lo, hi, addr_base in INDIRECT_AREAS:
            if lo <= data_address < hi:
                return self._peek(addr_base + 2 * (data_address - lo), 2)
        raise ValueError(data_address)

    def _indirect_read(self, address: int, data: bytes, t: float) -> bytes:
        out = bytearray(data)
        for i in range(len(out)):
            a = address + i
            if 224 <= a < 252 or 634 <= a < 662:
                target = self._indirect_target(a)
                if target < self.model.table_size:
                    self._refresh(t, target, target + 1)
                    out[i] = self.mem[target]
        return bytes(out)

    def _indirect_write(self, address: int, chunk: bytes, t: float) -> None:
        for i, byte in enumerate(chunk):
            target = self._indirect_target(address + i)
            f = self._fields[target] if target < self.model.table_size else None
            if f is not None and f.writable and not (f.eeprom and self.torque):
                self.mem[target] = byte
                self._after_write(f, t)

    # ------------------------------------------------------------------ dynamic state

    def _touch(self, t: float) -> None:
        """Note bus traffic for the Bus Watchdog, tripping it first if it had expired."""
        if self.is_servo:
            mem = self.mem
            wd = mem[_BUS_WATCHDOG]
            if 0 < wd < 128 and mem[_TORQUE_ENABLE] == 1 and t - self._last_comm > wd * 0.020:
                mem[_BUS_WATCHDOG] = 0xFF  # -1: tripped, motion stops
                self.profile.stop(self._last_comm + wd * 0.020)
            volts = self.supply_voltage
            if not (mem[_MIN_VOLTAGE] | mem[_MIN_VOLTAGE + 1] << 8) / 10 <= volts \
                    <= (mem[_MAX_VOLTAGE] | mem[_MAX_VOLTAGE + 1] << 8) / 10:
                if not mem[_HARDWARE_ERROR_STATUS] & 0x01:
                    self.raise_hardware_error(0x01, t)
        self._last_comm = t

    def _refresh(self, t: float, lo: int, hi: int) -> None:
        """Write the present values that overlap [lo, hi) into the control table."""
        if not self.is_servo or hi <= DYNAMIC_LO or lo >= DYNAMIC_HI:
            return
        mem = self.mem
        if lo >= 132 and hi <= 144:  # (PRESENT_POSITION .. PRESENT_INPUT_VOLTAGE, as literals: a hot path)
            # Present Position and the trajectories only: what a control loop reads every cycle
            p, v = self.profile.position_velocity(t)
            pos = (-1 if mem[_DRIVE_MODE] & 1 else 1) * int(round(p)) + _I32.unpack_from(mem, _HOMING_OFFSET)[0]
            _POS_VEL_POS.pack_into(mem, 132, pos, int(v / VEL_UNIT), pos)
            return
        s = self.profile.at(t)
        vel_units = s.velocity / VEL_UNIT
        if lo < 124:
            _U16.pack_into(mem, m.REALTIME_TICK, int(t * 1000) % 32768)
            thr = _U32.unpack_from(mem, 24)[0]
            # Moving: the profile is still running or the speed exceeds the Moving Threshold
            mem[m.MOVING] = 1 if s.moving or abs(vel_units) > thr else 0
            in_pos = abs(self.profile.target - s.position) < 20 if math.isfinite(self.profile.target) else False
            mem[m.MOVING_STATUS] = (1 if in_pos else 0) | (2 if s.moving else 0)
        if lo < 132 and hi > 124:
            torque = mem[_TORQUE_ENABLE] == 1
            pwm = int(max(-885, min(885, vel_units / max(1, _U32.unpack_from(mem, _VELOCITY_LIMIT)[0]) * 700))) \
                if torque else 0
            load = (s.acceleration / MAX_ACCELERATION * 800 + (15 if torque else 0)) if torque else 0
            _PWM_CUR_VEL.pack_into(mem, m.PRESENT_PWM, pwm, int(load), int(vel_units))
        if hi > 132 and lo < 144:
            pos = self._present(int(round(s.position)))
            _POS_VEL_POS.pack_into(mem, m.PRESENT_POSITION, pos, int(vel_units), pos)
        if hi > 144:
            sag = 0.2 if s.moving else 0.0
            _U16.pack_into(mem, m.PRESENT_INPUT_VOLTAGE, int(round((self.supply_voltage - sag) * 10)))
            warm = min(8.0, (t - self._torque_since) / 60.0) if self._torque_since is not None else 0.0
            mem[m.PRESENT_TEMPERATURE] = int(self.ambient_temperature + warm)
