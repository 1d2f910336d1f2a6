"""Control tables as data: the register map of a servo or board, shared by fakes and monitors.

A :class:`Model` lists its :class:`Field` s (address, size, name, access,
default, range, unit) as the vendor's manual gives them. Servo families
differ in how a register's bytes become a number (little- or big-endian,
two's complement or sign-magnitude with a vendor-chosen sign bit), so a field
carries its own encoding. Behaviour code finds registers by *role*
(``"goal_position"``, ``"present_position"``, ...) through :attr:`Model.roles`
rather than by address, so one servo implementation serves tables that put
the same things in different places (Dynamixel AX/MX with Protocol 1.0, the
XL-320, Feetech STS). Nothing here knows about packets or does I/O.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from functools import lru_cache


@lru_cache(maxsize=4096)
def _key(name: str) -> str:
    # (every model of a family repeats most names: each is worked out once)
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


@dataclass(frozen=True)
class Field:
    """One control-table item.

    ``scale``/``unit`` turn raw values into physical ones (``raw * scale`` in
    ``unit``, e.g. 0.1 V); ``allowed`` lists the only valid values where the
    manual gives a set rather than a range. ``signed`` is two's complement;
    ``sign_bit`` (Feetech, and the direction bit 10 of Dynamixel loads and
    speeds) is sign-magnitude with that bit as the sign. ``big_endian`` is for
    the few tables that store the high byte first (Feetech SCS).
    """

    address: int
    size: int
    name: str
    access: str = "RW"
    default: int | float = 0
    min: int | None = None
    max: int | None = None
    unit: str = ""
    scale: float = 1.0
    signed: bool = False
    is_float: bool = False
    allowed: tuple[int, ...] | None = None
    sign_bit: int | None = None
    big_endian: bool = False

    @property
    def key(self) -> str:
        """snake_case name, e.g. ``present_position``."""
        return _key(self.name)

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    @property
    def eeprom(self) -> bool:
        """In the X/MX(2.0) EEPROM area (0..63); tables with another boundary use :attr:`Model.eeprom_end`."""
        return self.address < 64

    def decode(self, raw: bytes) -> int | float:
        """Raw bytes to the value (sign applied)."""
        if self.is_float:
            return struct.unpack("<f", raw)[0]
        order = "big" if self.big_endian else "little"
        if self.sign_bit is not None:
            v = int.from_bytes(raw, order)
            bit = 1 << self.sign_bit
            return -(v & (bit - 1)) if v & bit else v
        return int.from_bytes(raw, order, signed=self.signed)

    def encode(self, value: int | float) -> bytes:
        """The value as raw bytes (sign-magnitude or two's complement as the field says)."""
        if self.is_float:
            return struct.pack("<f", value)
        order = "big" if self.big_endian else "little"
        v = int(value)
        if self.sign_bit is not None:
            v = (-v | (1 << self.sign_bit)) if v < 0 else v
            return v.to_bytes(self.size, order)
        return v.to_bytes(self.size, order, signed=self.signed)

    def in_range(self, value: int | float) -> bool:
        if self.allowed is not None:
            return value in self.allowed
        if self.min is not None and value < self.min:
            return False
        return not (self.max is not None and value > self.max)

    def physical(self, value: int | float) -> float:
        """The value in :attr:`unit` (``raw * scale``)."""
        return value * self.scale


@dataclass(frozen=True)
class Motion:
    """How a servo model moves, in its own position counts.

    ``counts_per_rev``: position counts per turn (4096 for MX/X/STS; 1228.8
    for the AX/XL-320, whose 1024 counts span 300 degrees). ``speed_unit``:
    counts/s per raw unit of the speed register; ``max_speed``: counts/s when
    the speed register says "as fast as possible" (0). ``accel_unit``:
    counts/s^2 per raw unit of the acceleration register (0: no register or
    "as fast as possible"). ``position_max``: the largest position in joint
    mode (1023 or 4095); present positions wrap modulo ``position_max + 1``.
    """

    counts_per_rev: float
    speed_unit: float
    max_speed: float
    accel_unit: float = 0.0
    position_max: int = 4095
    #: How a Homing Offset register shifts Present Position: +1 adds it (Dynamixel), -1 subtracts it (Feetech).
    offset_sign: int = 1


@dataclass(frozen=True)
class Model:
    """A device model: its number, its control table and what it supports.

    ``protocol`` is the wire protocol its firmware speaks (1 or 2 for
    Dynamixel, ``"feetech"``); ``baud_codes`` maps its Baud Rate register to
    bit/s; ``eeprom_end`` is where RAM starts; ``roles`` names the registers
    behaviour code needs (see :mod:`hilbench.fakes.table_servo`).
    """

    name: str
    number: int
    firmware: int
    fields: tuple[Field, ...]
    table_size: int
    kind: str = "servo"  # "servo" or "board"
    firmware_address: int = 6
    id_address: int = 7
    fast_read: bool = False
    current_unit_ma: float | None = None
    notes: str = ""
    protocol: int | str = 2
    baud_codes: dict[int, int] = field(default_factory=dict, compare=False)
    eeprom_end: int = 64
    roles: dict[str, int] = field(default_factory=dict, compare=False)
    motion: Motion | None = None
    _by_address: dict[int, Field] = field(default_factory=dict, compare=False, repr=False)
    _by_key: dict[str, Field] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        for f in self.fields:
            self._by_address[f.address] = f
            self._by_key[f.key] = f

    def field_at(self, address: int) -> Field | None:
        return self._by_address.get(address)

    def field_named(self, key: str) -> Field:
        """Field by snake_case key or manual name."""
        k = re.sub(r"[^a-z0-9]+", "_", key.lower()).strip("_")
        try:
            return self._by_key[k]
        except KeyError:
            raise KeyError(f"{self.name} has no field {key!r}") from None

    def role(self, name: str) -> Field | None:
        """The field playing ``name`` (``"goal_position"``...), or None if the model has none."""
        address = self.roles.get(name)
        return None if address is None else self._by_address.get(address)

    def covering(self, address: int) -> Field | None:
        """The field whose bytes include ``address``."""
        for f in self.fields:
            if f.address <= address < f.address + f.size:
                return f
        return None

    def defaults(self) -> bytearray:
        """A fresh control table filled with the defaults."""
        mem = bytearray(self.table_size)
        for f in self.fields:
            mem[f.address : f.address + f.size] = f.encode(f.default)
        return mem


def model_named(models: dict[str, Model], name: str, asked: str | int) -> Model:
    """The model of ``models`` whose name is ``name`` in any case; KeyError(``asked``, what was looked up)."""
    for model_name, model in models.items():
        if model_name.lower() == name.lower():
            return model
    raise KeyError(asked)


__all__ = ["Field", "Model", "Motion", "model_named"]
