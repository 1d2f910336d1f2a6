"""What every emulated servo with a control table does the same way, whatever the table's layout.

:class:`ControlTableServo` is the base of the X/MX(2.0) :class:`~hilbench.fakes.dynamixel.servo.Servo`
and the role-described :class:`~hilbench.fakes.table_servo.TableServo` (AX, MX 1.0, XL-320,
Feetech): loading the table at power-on, values by field key, identity, the registers the
buses ask about (torque, hardware error, Status Return Level, Return Delay), falling silent,
fault knobs, switching the torque, Reboot and Factory Reset. A subclass says where those
registers are (``_*_address``, None where its table has no such register) and what its
table does on a write, on power-on and in motion.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

from hilbench.fakes.motion import MotionProfile
from hilbench.protocols.control_table import Field, Model


@dataclass
class Faults:
    """Fault knobs; tests and profiles set them to rehearse what goes wrong on real benches.

    Rates are probabilities per reply (drawn from a seeded generator so runs
    repeat); ``*_next`` counters affect exactly the next N replies.
    """

    drop_rate: float = 0.0
    drop_next: int = 0
    corrupt_rate: float = 0.0
    corrupt_next: int = 0
    delay: float = 0.0  # extra seconds before each reply
    vanished_until: float = 0.0  # silent until this monotonic time (math.inf: until revived)
    seed: int = 0
    rng: random.Random = field(default_factory=random.Random, repr=False)

    def __post_init__(self) -> None:
        self.rng.seed(self.seed)

    def take_drop(self) -> bool:
        """Whether the next reply is lost."""
        if self.drop_next > 0:
            self.drop_next -= 1
            return True
        return self.drop_rate > 0 and self.rng.random() < self.drop_rate

    def take_corrupt(self) -> bool:
        """Whether the next reply is damaged."""
        if self.corrupt_next > 0:
            self.corrupt_next -= 1
            return True
        return self.corrupt_rate > 0 and self.rng.random() < self.corrupt_rate


class ControlTableServo:
    """One emulated device with a control table (see the module docstring)."""

    #: Where the table's registers are; None where the model has none.
    _baud_address: int | None = None
    _srl_address: int | None = None
    _return_delay_address: int | None = None
    _torque_address: int | None = None
    _hardware_error_address: int | None = None
    _shutdown_address: int | None = None
    #: Where RAM starts: Reboot keeps what lies below, Factory Reset restores it.
    _eeprom_end: int = 64
    profile: MotionProfile

    def __init__(
        self,
        model: Model,
        servo_id: int,
        *,
        name: str | None,
        initial: dict[str, int | float] | None,
        supply_voltage: float,
        ambient_temperature: float,
        reboot_time: float,
        seed: int,
        firmware: int | None,
    ) -> None:
        self.model = model
        self.name = name or f"{model.name}#{servo_id}"
        self.supply_voltage = supply_voltage
        self.ambient_temperature = ambient_temperature
        self.reboot_time = reboot_time  #: seconds a reboot keeps the servo silent
        self.faults = Faults(seed=seed or servo_id)
        self.initial = dict(initial or {})
        self._registered: tuple[int, bytes] | None = None
        self._rebooting_until = 0.0
        self._torque_since: float | None = None
        self._sticky_hw_error = 0
        # the table at power-on: defaults, then what was configured once and saved (``initial``)
        self.mem = model.defaults()
        try:
            #: Where its Protocol Type register is (None: the model has none): a servo with one speaks the
            #: protocol it names (see ServoBusBase._hearing).
            self.protocol_type_address: int | None = model.field_named("protocol_type").address
        except KeyError:
            self.protocol_type_address = None
        if firmware is not None:
            self.mem[model.firmware_address] = firmware
        self.mem[model.id_address] = servo_id
        for key, value in self.initial.items():
            f = model.field_named(key)
            self.mem[f.address : f.address + f.size] = f.encode(value)

    # ------------------------------------------------------------------ what a servo provides

    def _refresh(self, t: float, lo: int, hi: int) -> None:
        """Write the present values that overlap [``lo``, ``hi``) as they are at bus time ``t``."""
        raise NotImplementedError

    def _after_write(self, f: Field, t: float) -> None:
        """Side effects of a changed item."""
        raise NotImplementedError

    def _after_power_on(self, t: float, position: float) -> None:
        """RAM items that start from others, and the horn where it was, after a reboot."""
        raise NotImplementedError

    def _retarget(self, t: float) -> None:
        raise NotImplementedError

    @property
    def baud(self) -> int | None:
        """Baud the device listens at (None: any)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ values by field key

    def get(self, key: str, t: float | None = None) -> int | float:
        """A control-table value by field key (refreshing present values at ``t``)."""
        f = self.model.field_named(key)
        if t is not None:
            self._refresh(t, f.address, f.address + f.size)
        return f.decode(bytes(self.mem[f.address : f.address + f.size]))

    def set(self, key: str, value: int | float, t: float = 0.0) -> None:
        """Set a value directly, bypassing access rules (for tests and scenarios)."""
        f = self.model.field_named(key)
        self.mem[f.address : f.address + f.size] = f.encode(value)
        self._after_write(f, t)

    # ------------------------------------------------------------------ registers the buses ask about

    @property
    def id(self) -> int:
        """The ID the servo answers to."""
        return self.mem[self.model.id_address]

    @property
    def firmware(self) -> int:
        """Firmware version (read-only register)."""
        return self.mem[self.model.firmware_address]

    @property
    def status_return_level(self) -> int:
        """Which instructions are answered (2, all, where the table has no such register)."""
        a = self._srl_address
        return 2 if a is None else self.mem[a]

    @property
    def return_delay(self) -> float:
        """Return Delay Time in seconds (2 us units)."""
        a = self._return_delay_address
        return self.mem[a] * 2e-6 if a is not None else 0.0

    @property
    def torque(self) -> bool:
        """Torque Enable is on."""
        a = self._torque_address
        return a is not None and self.mem[a] == 1

    @property
    def hardware_error(self) -> int:
        """Hardware Error Status bits (0 where the table has none)."""
        a = self._hardware_error_address
        return self.mem[a] if a is not None else 0

    def silent(self, t: float) -> bool:
        """True while rebooting or vanished: the device hears nothing."""
        return t < self._rebooting_until or t < self.faults.vanished_until

    def listens(self, t: float, baud: int | None) -> bool:
        """Whether it hears a transmission at ``t`` sent at ``baud`` (None: any): not :meth:`silent`, and at its
        :attr:`baud`."""
        if t < self._rebooting_until or t < self.faults.vanished_until:
            return False
        if baud is None:
            return True
        b = self.baud
        return b is None or b == baud

    # ------------------------------------------------------------------ fault knobs

    def vanish(self, t: float, duration: float = math.inf) -> None:
        """Fall silent (cable pulled) for ``duration`` seconds, or until :meth:`revive`."""
        self.faults.vanished_until = t + duration

    def revive(self) -> None:
        """Come back after :meth:`vanish`."""
        self.faults.vanished_until = 0.0

    def raise_hardware_error(self, bits: int, t: float, *, sticky: bool = False) -> None:
        """Set Hardware Error Status bits where the table has the register; shutdown bits switch the torque off.

        ``sticky`` bits come back after a reboot (a fault that is still there).
        """
        a = self._hardware_error_address
        if a is None:
            return
        self.mem[a] = self.hardware_error | bits
        if sticky:
            self._sticky_hw_error |= bits
        if bits & self._shutdown_bits():
            self._set_torque(False, t)

    def clear_hardware_error(self) -> None:
        """Clear the Hardware Error Status, sticky bits included."""
        self._sticky_hw_error = 0
        a = self._hardware_error_address
        if a is not None:
            self.mem[a] = 0

    def _shutdown_bits(self) -> int:
        a = self._shutdown_address
        return self.mem[a] if a is not None else 0

    def _set_torque(self, on: bool, t: float) -> None:
        if on and self.hardware_error & self._shutdown_bits():
            on = False  # in shutdown: only a reboot brings the torque back
        a = self._torque_address
        if a is not None:
            self.mem[a] = 1 if on else 0
        if on:
            self._torque_since = t
            self._retarget(t)
        else:
            self._torque_since = None
            self.profile.stop(t)

    # ------------------------------------------------------------------ instructions

    def reboot(self, t: float) -> int:
        """Restart: RAM back to defaults, EEPROM kept, errors cleared (but sticky ones), silent for
        :attr:`reboot_time`."""
        end = self._eeprom_end
        keep = bytes(self.mem[:end])
        pos = self.profile.at(t).position
        self.mem = self.model.defaults()
        self.mem[:end] = keep
        self._registered = None
        self._torque_since = None
        self._after_power_on(t, pos)
        self._rebooting_until = t + self.reboot_time
        if self._sticky_hw_error and self._hardware_error_address is not None:
            self.mem[self._hardware_error_address] = self._sticky_hw_error
        return 0

    def factory_reset(self, mode: int, t: float) -> int:
        """Factory Reset: ``0xFF`` everything, ``0x01`` all but ID, ``0x02`` all but ID and baud."""
        servo_id, firmware = self.id, self.firmware
        baud_at = self._baud_address
        baud = self.mem[baud_at] if baud_at is not None else 0
        end = self._eeprom_end
        self.mem[:end] = self.model.defaults()[:end]
        self.mem[self.model.firmware_address] = firmware  # read-only: the firmware stays what it is
        if mode in (0x01, 0x02):
            self.mem[self.model.id_address] = servo_id
        if mode == 0x02 and baud_at is not None:
            self.mem[baud_at] = baud
        return self.reboot(t)


__all__ = ["ControlTableServo", "Faults"]
