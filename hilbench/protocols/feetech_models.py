"""Feetech servo models as data: the STS3215 (SO-100/SO-101 arms) and the SCS0009.

Addresses are Feetech's (their Python SDK's constants and Arduino header) and
LeRobot's tables (spec sheet ``servo_buses.md`` §4.3). The model number lives
at address 3 (not 0), after the firmware major/minor version bytes and the
endianness flag. The STS stores words little-endian with sign-magnitude
offsets and positions (sign bit 11 for the Homing Offset, 15 for goal and
present positions and speeds, 10 for the load); the SCS stores them
big-endian without signs. Where no vendor table gives a default, the value is
the one LeRobot configures or a plausible one (noted in the sheet's §10).

Torque Enable is 1 at power-on (the sheet's §4.3 said 0, from no vendor
table): the servo holds where its horn is, and a goal moves it with no torque
write first. Feetech's own examples (FTServo_Python's ``sms_sts`` and
``scscl`` ping/write/read_write/sync_write) never write Torque Enable and
expect motion, and integrators of real SO-101 arms report the servos stiff at
power-on and a goal sent after Torque Enable 0 not moving them, so a goal
does not switch the torque on again (unlike Dynamixel Protocol 1.0).
"""

from __future__ import annotations

from hilbench.protocols.control_table import Field, Model, Motion, model_named

#: Baud Rate register codes (address 6) to bit/s, as Feetech's own SDK and memory table give them.
STS_BAUD_CODES: dict[int, int] = {0: 1_000_000, 1: 500_000, 2: 250_000, 3: 128_000, 4: 115_200, 5: 76_800,
                                  6: 57_600, 7: 38_400}
SCS_BAUD_CODES = dict(STS_BAUD_CODES)

_STEP_DEG = 360.0 / 4096

_ROLES = {
    "firmware": 0, "model_number": 3, "id": 5, "baud": 6, "return_delay": 7, "status_return_level": 8,
    "min_position": 9, "max_position": 11, "temperature_limit": 13, "max_voltage": 14, "min_voltage": 15,
    "max_torque": 16, "torque_enable": 40, "goal_acceleration": 41, "goal_position": 42, "goal_speed": 46,
    "present_position": 56, "present_speed": 58, "present_load": 60, "present_voltage": 62,
    "present_temperature": 63, "moving": 66,
}


def _head(number: int, *, big: bool, firmware: tuple[int, int], position_max: int) -> list[Field]:
    return [
        Field(0, 1, "Firmware Major Version", "R", firmware[0]),
        Field(1, 1, "Firmware Minor Version", "R", firmware[1]),
        Field(2, 1, "END", "R", 1 if big else 0),
        Field(3, 2, "Model Number", "R", number, big_endian=big),
        Field(5, 1, "ID", "RW", 1, 0, 253),
        Field(6, 1, "Baud Rate", "RW", 0, 0, 7),
        Field(7, 1, "Return Delay Time", "RW", 0, 0, 254, "us", 2.0),
        Field(8, 1, "Response Status Level", "RW", 1, 0, 1),
        Field(9, 2, "Min Position Limit", "RW", 0, 0, position_max, big_endian=big),
        Field(11, 2, "Max Position Limit", "RW", position_max, 0, position_max, big_endian=big),
        Field(13, 1, "Max Temperature Limit", "RW", 70, 0, 100, "C"),
        Field(14, 1, "Max Voltage Limit", "RW", 140, 0, 254, "V", 0.1),
        Field(15, 1, "Min Voltage Limit", "RW", 40, 0, 254, "V", 0.1),
        Field(16, 2, "Max Torque Limit", "RW", 1000, 0, 1000, "%", 0.1, big_endian=big),
        Field(18, 1, "Phase", "RW", 12, 0, 255),
        Field(19, 1, "Unloading Condition", "RW", 44, 0, 255),
        Field(20, 1, "LED Alarm Condition", "RW", 47, 0, 255),
        Field(21, 1, "P Coefficient", "RW", 32, 0, 254),
        Field(22, 1, "D Coefficient", "RW", 32, 0, 254),
        Field(23, 1, "I Coefficient", "RW", 0, 0, 254),
        Field(24, 2, "Minimum Startup Force", "RW", 16, 0, 1000, big_endian=big),
        Field(26, 1, "CW Dead Zone", "RW", 1, 0, 32),
        Field(27, 1, "CCW Dead Zone", "RW", 1, 0, 32),
    ]


def _sts3215() -> Model:
    fields = _head(777, big=False, firmware=(3, 10), position_max=4095) + [
        Field(28, 2, "Protection Current", "RW", 500, 0, 511),
        Field(30, 1, "Angular Resolution", "RW", 1, 1, 3),
        Field(31, 2, "Homing Offset", "RW", 0, -2047, 2047, "deg", _STEP_DEG, sign_bit=11),
        Field(33, 1, "Operating Mode", "RW", 0, 0, 3),
        Field(34, 1, "Protective Torque", "RW", 20, 0, 100),
        Field(35, 1, "Protection Time", "RW", 200, 0, 254),
        Field(36, 1, "Overload Torque", "RW", 80, 0, 100),
        Field(37, 1, "Velocity P Coefficient", "RW", 10, 0, 100),
        Field(38, 1, "Over Current Protection Time", "RW", 200, 0, 254),
        Field(39, 1, "Velocity I Coefficient", "RW", 200, 0, 254),
        Field(40, 1, "Torque Enable", "RW", 1, 0, 128),  # on at power-on, holding the horn (see the docstring)
        Field(41, 1, "Acceleration", "RW", 0, 0, 254),
        Field(42, 2, "Goal Position", "RW", 2048, -32767, 32767, "deg", _STEP_DEG, sign_bit=15),
        Field(44, 2, "Goal Time", "RW", 0, 0, 65535),
        Field(46, 2, "Goal Velocity", "RW", 0, -32767, 32767, "step/s", sign_bit=15),
        Field(48, 2, "Torque Limit", "RW", 1000, 0, 1000, "%", 0.1),
        Field(55, 1, "Lock", "RW", 0, 0, 1),
        Field(56, 2, "Present Position", "R", 2048, unit="deg", scale=_STEP_DEG, sign_bit=15),
        Field(58, 2, "Present Velocity", "R", 0, unit="step/s", sign_bit=15),
        Field(60, 2, "Present Load", "R", 0, unit="%", scale=0.1, sign_bit=10),
        Field(62, 1, "Present Voltage", "R", 74, unit="V", scale=0.1),
        Field(63, 1, "Present Temperature", "R", 30, unit="C"),
        Field(65, 1, "Status", "R", 0),
        Field(66, 1, "Moving", "R", 0),
        Field(69, 2, "Present Current", "R", 0, unit="mA", scale=6.5),
        Field(71, 2, "Goal Position 2", "R", 0),
        Field(80, 1, "Moving Velocity Threshold", "RW", 1, 0, 255),
        Field(81, 1, "DTs", "RW", 1, 0, 255),
        Field(82, 1, "Velocity Unit Factor", "RW", 1, 0, 255),
        Field(83, 1, "Hts", "RW", 0, 0, 255),
        Field(84, 1, "Maximum Velocity Limit", "RW", 254, 0, 255),
        Field(85, 1, "Maximum Acceleration", "RW", 254, 0, 255),
        Field(86, 1, "Acceleration Multiplier", "RW", 0, 0, 255),
    ]
    return Model(
        name="STS3215", number=777, firmware=3, fields=tuple(fields), table_size=87, firmware_address=0,
        id_address=5, protocol="feetech", baud_codes=STS_BAUD_CODES, eeprom_end=40,
        roles={**_ROLES, "homing_offset": 31, "operating_mode": 33, "torque_limit": 48, "lock": 55,
               "present_current": 69},
        motion=Motion(4096, 1.0, 3073.0, 100.0, position_max=4095, offset_sign=-1),
        notes="sign-magnitude: Homing Offset bit 11, positions and speeds bit 15, load bit 10; "
              "Present Position = Actual Position - Homing Offset",
    )


def _scs0009() -> Model:
    big = True
    fields = _head(1284, big=big, firmware=(1, 8), position_max=1023) + [
        Field(37, 1, "Protective Torque", "RW", 20, 0, 100),
        Field(38, 1, "Protection Time", "RW", 200, 0, 254),
        Field(40, 1, "Torque Enable", "RW", 1, 0, 1),
        Field(41, 1, "Acceleration", "RW", 0, 0, 254),
        Field(42, 2, "Goal Position", "RW", 512, 0, 1023, "deg", 300 / 1024, big_endian=big),
        Field(44, 2, "Running Time", "RW", 0, 0, 65535, big_endian=big),
        Field(46, 2, "Goal Velocity", "RW", 0, 0, 65535, big_endian=big),
        Field(48, 1, "Lock", "RW", 0, 0, 1),
        Field(56, 2, "Present Position", "R", 512, unit="deg", scale=300 / 1024, big_endian=big),
        Field(58, 2, "Present Velocity", "R", 0, big_endian=big),
        Field(60, 2, "Present Load", "R", 0, big_endian=big),
        Field(62, 1, "Present Voltage", "R", 50, unit="V", scale=0.1),
        Field(63, 1, "Present Temperature", "R", 30, unit="C"),
        Field(64, 1, "Sync Write Flag", "R", 0),
        Field(65, 1, "Status", "R", 0),
        Field(66, 1, "Moving", "R", 0),
    ]
    cpr = 1024 * 360 / 300
    return Model(
        name="SCS0009", number=1284, firmware=1, fields=tuple(fields), table_size=84, firmware_address=0,
        id_address=5, protocol="feetech", baud_codes=SCS_BAUD_CODES, eeprom_end=40,
        roles={**_ROLES, "lock": 48},
        motion=Motion(cpr, 1.0, 100 / 60 * cpr, 0.0, position_max=1023),
        notes="big-endian words (END = 1), 1024 counts over 300 degrees, no signed registers",
    )


STS3215 = _sts3215()
SCS0009 = _scs0009()

#: Every Feetech model, by name and by model number.
MODELS: dict[str, Model] = {m.name: m for m in (STS3215, SCS0009)}
MODELS_BY_NUMBER: dict[int, Model] = {m.number: m for m in MODELS.values()}
ALIASES = {"sts3215": "STS3215", "scs0009": "SCS0009"}


def find_model(name_or_number: str | int) -> Model:
    """Look a model up by name (any case), LeRobot's name, or model number; KeyError if unknown."""
    if isinstance(name_or_number, int):
        return MODELS_BY_NUMBER[name_or_number]
    return model_named(MODELS, ALIASES.get(name_or_number.lower(), name_or_number), name_or_number)


def model_names() -> list[str]:
    """Names a profile may use."""
    return sorted(MODELS) + sorted(ALIASES)


__all__ = ["MODELS", "MODELS_BY_NUMBER", "SCS0009", "STS3215", "STS_BAUD_CODES", "find_model", "model_names"]
