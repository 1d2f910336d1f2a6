"""Dynamixel device models as data: control tables, defaults, ranges and units.

Each :class:`Model` lists its control-table :class:`Field` s (address, size,
name, access, default, range, unit) as the ROBOTIS e-Manual and spec sheet §5
give them. This is the register-level layout of each device, so it lives with
the protocols: the emulated servos (:mod:`hilbench.fakes.dynamixel.servo`) and
the bus monitor (:mod:`hilbench.monitor`) read the same tables. Nothing here
knows about packets or does I/O.
"""

from __future__ import annotations

from dataclasses import replace
from functools import cache

from hilbench.protocols.control_table import Field, Model, model_named
from hilbench.protocols.dynamixel_classic_models import CLASSIC_MODELS

#: Baud Rate item (address 8) codes to bit/s.
BAUD_CODES: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
BAUD_TO_CODE = {v: k for k, v in BAUD_CODES.items()}
#: The rates the official SDK's PortHandler opens (its ``getCFlagBaud`` table; a test keeps them equal).
SDK_BAUDS = (9_600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 500_000, 576_000, 921_600, 1_000_000,
             1_152_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000, 4_000_000)

#: Control-table addresses used by behaviour code.
MODEL_NUMBER = 0
FIRMWARE = 6
ID = 7
BAUD_RATE = 8
RETURN_DELAY_TIME = 9
DRIVE_MODE = 10
OPERATING_MODE = 11
HOMING_OFFSET = 20
TEMPERATURE_LIMIT = 31
MAX_VOLTAGE = 32
MIN_VOLTAGE = 34
PWM_LIMIT = 36
CURRENT_LIMIT = 38
VELOCITY_LIMIT = 44
MAX_POSITION = 48
MIN_POSITION = 52
SHUTDOWN = 63
TORQUE_ENABLE = 64
LED = 65
STATUS_RETURN_LEVEL = 68
REGISTERED_INSTRUCTION = 69
HARDWARE_ERROR_STATUS = 70
BUS_WATCHDOG = 98
GOAL_PWM = 100
GOAL_CURRENT = 102
GOAL_VELOCITY = 104
PROFILE_ACCELERATION = 108
PROFILE_VELOCITY = 112
GOAL_POSITION = 116
REALTIME_TICK = 120
MOVING = 122
MOVING_STATUS = 123
PRESENT_PWM = 124
PRESENT_CURRENT = 126
PRESENT_VELOCITY = 128
PRESENT_POSITION = 132
VELOCITY_TRAJECTORY = 136
POSITION_TRAJECTORY = 140
PRESENT_INPUT_VOLTAGE = 144
PRESENT_TEMPERATURE = 146
EEPROM_END = 64  # EEPROM is 0..63


# ---------------------------------------------------------------- X / MX(2.0) table

_POS = 360.0 / 4096  # degrees per pulse
_RPM = 0.229
_PWM = 100.0 / 885


def _x_mx_fields(
    *,
    model_number: int,
    firmware: int,
    current_ma: float | None,
    current_limit: int | None,
    velocity_limit: int,
    temperature_limit: int = 80,
    voltage: tuple[int, int] = (160, 95),
    voltage_range: tuple[int, int] = (95, 160),
    vel_pi: tuple[int, int] = (1920, 100),
    pos_dip: tuple[int, int, int] = (0, 0, 850),
    acceleration_limit: bool = False,
    goal_current: bool = True,
    load_instead_of_current: bool = False,
    operating_modes: tuple[int, ...] = (0, 1, 3, 4, 5, 16),
    x_series: bool = True,
    shutdown: int = 52,
) -> tuple[Field, ...]:
    fs = [
        Field(0, 2, "Model Number", "R", model_number),
        Field(2, 4, "Model Information", "R", 0),
        Field(6, 1, "Firmware Version", "R", firmware),
        Field(7, 1, "ID", "RW", 1, 0, 252),
        Field(8, 1, "Baud Rate", "RW", 1, 0, 7),
        Field(9, 1, "Return Delay Time", "RW", 250, 0, 254, "us", 2.0),
        Field(10, 1, "Drive Mode", "RW", 0, 0, 13 if x_series else 1),
        Field(11, 1, "Operating Mode", "RW", 3, allowed=operating_modes),
        Field(12, 1, "Secondary ID", "RW", 255, 0, 255),
        Field(13, 1, "Protocol Type", "RW", 2, 1, 2),
        Field(20, 4, "Homing Offset", "RW", 0, -1_044_479, 1_044_479, "deg", _POS, signed=True),
        Field(24, 4, "Moving Threshold", "RW", 10, 0, 1023, "rpm", _RPM),
        Field(31, 1, "Temperature Limit", "RW", temperature_limit, 0, 100, "C"),
        Field(32, 2, "Max Voltage Limit", "RW", voltage[0], *voltage_range, "V", 0.1),
        Field(34, 2, "Min Voltage Limit", "RW", voltage[1], *voltage_range, "V", 0.1),
        Field(36, 2, "PWM Limit", "RW", 885, 0, 885, "%", _PWM),
    ]
    if current_limit is not None:
        fs.append(Field(38, 2, "Current Limit", "RW", current_limit, 0, current_limit, "mA", current_ma or 1.0))
    if acceleration_limit:
        fs.append(Field(40, 4, "Acceleration Limit", "RW", 32767, 0, 32767))
    fs += [
        Field(44, 4, "Velocity Limit", "RW", velocity_limit, 0, 1023, "rpm", _RPM),
        Field(48, 4, "Max Position Limit", "RW", 4095, 0, 4095, "deg", _POS),
        Field(52, 4, "Min Position Limit", "RW", 0, 0, 4095, "deg", _POS),
    ]
    if x_series:
        fs.append(Field(60, 1, "Startup Configuration", "RW", 0, 0, 3))
    fs += [
        Field(63, 1, "Shutdown", "RW", shutdown, 0, 255),
        Field(64, 1, "Torque Enable", "RW", 0, 0, 1),
        Field(65, 1, "LED", "RW", 0, 0, 1),
        Field(68, 1, "Status Return Level", "RW", 2, 0, 2),
        Field(69, 1, "Registered Instruction", "R", 0),
        Field(70, 1, "Hardware Error Status", "R", 0),
        Field(76, 2, "Velocity I Gain", "RW", vel_pi[0], 0, 16383),
        Field(78, 2, "Velocity P Gain", "RW", vel_pi[1], 0, 16383),
        Field(80, 2, "Position D Gain", "RW", pos_dip[0], 0, 16383),
        Field(82, 2, "Position I Gain", "RW", pos_dip[1], 0, 16383),
        Field(84, 2, "Position P Gain", "RW", pos_dip[2], 0, 16383),
        Field(88, 2, "Feedforward 2nd Gain", "RW", 0, 0, 16383),
        Field(90, 2, "Feedforward 1st Gain", "RW", 0, 0, 16383),
        Field(98, 1, "Bus Watchdog", "RW", 0, 0, 127, "ms", 20.0, signed=True),
        Field(100, 2, "Goal PWM", "RW", 0, -885, 885, "%", _PWM, signed=True),
    ]
    if goal_current:
        lim = current_limit or 2047
        fs.append(Field(102, 2, "Goal Current", "RW", 0, -lim, lim, "mA", current_ma or 1.0, signed=True))
    fs += [
        Field(104, 4, "Goal Velocity", "RW", 0, -1023, 1023, "rpm", _RPM, signed=True),
        Field(108, 4, "Profile Acceleration", "RW", 0, 0, 32767, "rev/min^2", 214.577),
        Field(112, 4, "Profile Velocity", "RW", 0, 0, 32767, "rpm", _RPM),
        Field(116, 4, "Goal Position", "RW", 0, -1_048_575, 1_048_575, "deg", _POS, signed=True),
        Field(120, 2, "Realtime Tick", "R", 0, unit="ms"),
        Field(122, 1, "Moving", "R", 0),
        Field(123, 1, "Moving Status", "R", 0),
        Field(124, 2, "Present PWM", "R", 0, unit="%", scale=_PWM, signed=True),
    ]
    if load_instead_of_current:
        fs.append(Field(126, 2, "Present Load", "R", 0, unit="%", scale=0.1, signed=True))
    else:
        fs.append(Field(126, 2, "Present Current", "R", 0, unit="mA", scale=current_ma or 1.0, signed=True))
    fs += [
        Field(128, 4, "Present Velocity", "R", 0, unit="rpm", scale=_RPM, signed=True),
        Field(132, 4, "Present Position", "R", 2048, unit="deg", scale=_POS, signed=True),
        Field(136, 4, "Velocity Trajectory", "R", 0, unit="rpm", scale=_RPM, signed=True),
        Field(140, 4, "Position Trajectory", "R", 0, unit="deg", scale=_POS, signed=True),
        Field(144, 2, "Present Input Voltage", "R", 120, unit="V", scale=0.1),
        Field(146, 1, "Present Temperature", "R", 30, unit="C"),
    ]
    if x_series:
        fs.append(Field(147, 1, "Backup Ready", "R", 0))
    return (*fs, *_indirect_fields())


@cache
def _indirect_fields() -> tuple[Field, ...]:
    """The 56 Indirect Address/Data pairs every X/MX(2.0) table ends with (one set of frozen fields for all
    models: building them per model was most of this module's import time)."""
    fs = []
    for i in range(28):
        fs.append(Field(168 + 2 * i, 2, f"Indirect Address {i + 1}", "RW", 224 + i, 64, 661))
        fs.append(Field(224 + i, 1, f"Indirect Data {i + 1}", "RW", 0))
    for i in range(28):
        fs.append(Field(578 + 2 * i, 2, f"Indirect Address {i + 29}", "RW", 634 + i, 64, 661))
        fs.append(Field(634 + i, 1, f"Indirect Data {i + 29}", "RW", 0))
    return tuple(fs)


def _servo(name: str, number: int, firmware: int, *, fast_read: bool, **kw) -> Model:
    return Model(
        name=name,
        number=number,
        firmware=firmware,
        fields=_x_mx_fields(model_number=number, firmware=firmware, **kw),
        table_size=662,
        fast_read=fast_read,
        current_unit_ma=kw.get("current_ma"),
        baud_codes=BAUD_CODES,
    )


XM430_W350 = _servo(
    "XM430-W350", 1020, 52, fast_read=True, current_ma=2.69, current_limit=1193, velocity_limit=200,
    pos_dip=(0, 0, 800),
)
XH430_W350 = _servo(
    "XH430-W350", 1000, 52, fast_read=True, current_ma=2.69, current_limit=648, velocity_limit=130,
    pos_dip=(0, 0, 900),
)
XL430_W250 = _servo(
    "XL430-W250", 1060, 52, fast_read=True, current_ma=None, current_limit=None, velocity_limit=265,
    temperature_limit=72, voltage=(140, 60), voltage_range=(60, 140), vel_pi=(1000, 100), pos_dip=(4000, 0, 640),
    goal_current=False, load_instead_of_current=True, operating_modes=(1, 3, 4, 16),
)
# XL330 / XC330 (spec sheet servo_buses.md §3.5): the X-series map; current in 1 mA units, 3.7-7 V.
# XL330-M288 defaults are the e-Manual's; the M077 and the XC330 share them where the sheet has none.
_XL330 = dict(current_ma=1.0, current_limit=1750, velocity_limit=445, temperature_limit=70, voltage=(70, 35),
              voltage_range=(31, 70), vel_pi=(1600, 180), pos_dip=(0, 0, 400), shutdown=53)
XL330_M288 = _servo("XL330-M288", 1200, 46, fast_read=True, **_XL330)
XL330_M077 = _servo("XL330-M077", 1190, 46, fast_read=True, **_XL330)
XC330_T288 = _servo("XC330-T288", 1220, 46, fast_read=True, **{**_XL330, "current_limit": 1193,
                                                            "voltage": (140, 60), "voltage_range": (60, 140)})
XC330_T181 = _servo("XC330-T181", 1210, 46, fast_read=True, **{**_XL330, "current_limit": 1193,
                                                            "voltage": (140, 60), "voltage_range": (60, 140)})
MX28_2 = _servo(
    "MX-28(2.0)", 30, 41, fast_read=False, current_ma=None, current_limit=None, velocity_limit=230,
    acceleration_limit=True, goal_current=False, load_instead_of_current=True, operating_modes=(1, 3, 4, 16),
    x_series=False,
)
MX64_2 = _servo(
    "MX-64(2.0)", 311, 41, fast_read=False, current_ma=3.36, current_limit=1941, velocity_limit=435,
    acceleration_limit=True, x_series=False,
)
MX106_2 = _servo(
    "MX-106(2.0)", 321, 41, fast_read=False, current_ma=3.36, current_limit=2047, velocity_limit=360,
    acceleration_limit=True, x_series=False,
)

# ---------------------------------------------------------------- Wolfgang custom boards
# Layouts are those the thesis monitor knows (spec §5.6). Where the boards keep
# their ID is not documented; hilbench assumes address 3, after the firmware
# version at 2, as in the Protocol 1.0-era layout these boards follow.

_BOARD_HEAD = (
    Field(0, 2, "Model Number", "R"),
    Field(2, 1, "Firmware Version", "R"),
    Field(3, 1, "ID", "RW", 1, 0, 252),
)

_CORE_V = 3.3 * 6 / 1024  # V per raw count of the Core board's ADC inputs

WOLFGANG_CORE = Model(
    name="Wolfgang Core",
    number=0xABBA,
    firmware=1,
    kind="board",
    firmware_address=2,
    id_address=3,
    table_size=38,
    fields=(
        replace(_BOARD_HEAD[0], default=0xABBA),
        replace(_BOARD_HEAD[1], default=1),
        _BOARD_HEAD[2],
        Field(10, 2, "LED", "RW", 0, 0, 1),
        Field(12, 2, "Power", "RW", 1, 0, 1),
        Field(14, 4, "RGB LED 1", "RW", 0, 0, 0xFFFFFF),
        Field(18, 4, "RGB LED 2", "RW", 0, 0, 0xFFFFFF),
        Field(22, 4, "RGB LED 3", "RW", 0, 0, 0xFFFFFF),
        Field(26, 2, "VBAT", "R", 765, unit="V", scale=_CORE_V),
        Field(28, 2, "VEXT", "R", 0, unit="V", scale=_CORE_V),
        Field(30, 2, "VCC", "R", 256, unit="V", scale=_CORE_V),
        Field(32, 2, "VDXL", "R", 760, unit="V", scale=_CORE_V),
        Field(34, 2, "Current", "R", 420),
        Field(36, 2, "Power On", "R", 1000),
    ),
    notes="Rhoban DXL Board firmware; V = raw / 1024 * 3.3 * 6",
)

WOLFGANG_FOOT = Model(
    name="Wolfgang Foot",
    number=0xAFFE,
    firmware=1,
    kind="board",
    firmware_address=2,
    id_address=3,
    table_size=52,
    fields=(
        replace(_BOARD_HEAD[0], default=0xAFFE),
        replace(_BOARD_HEAD[1], default=1),
        _BOARD_HEAD[2],
        Field(36, 4, "Front Left", "R", 0, signed=True),
        Field(40, 4, "Front Right", "R", 0, signed=True),
        Field(44, 4, "Back Left", "R", 0, signed=True),
        Field(48, 4, "Back Right", "R", 0, signed=True),
    ),
    notes="BitFoot: four raw load cells, read together as 36/16",
)

WOLFGANG_IMU = Model(
    name="Wolfgang IMU",
    number=0xBAFF,
    firmware=1,
    kind="board",
    firmware_address=2,
    id_address=3,
    table_size=78,
    fields=(
        replace(_BOARD_HEAD[0], default=0xBAFF),
        replace(_BOARD_HEAD[1], default=1),
        _BOARD_HEAD[2],
        Field(36, 4, "Accel X", "R", 0.0, unit="m/s^2", is_float=True),
        Field(40, 4, "Accel Y", "R", 0.0, unit="m/s^2", is_float=True),
        Field(44, 4, "Accel Z", "R", 9.81, unit="m/s^2", is_float=True),
        Field(48, 4, "Gyro X", "R", 0.0, unit="deg/s", is_float=True),
        Field(52, 4, "Gyro Y", "R", 0.0, unit="deg/s", is_float=True),
        Field(56, 4, "Gyro Z", "R", 0.0, unit="deg/s", is_float=True),
        Field(60, 4, "Quaternion X", "R", 0.0, is_float=True),
        Field(64, 4, "Quaternion Y", "R", 0.0, is_float=True),
        Field(68, 4, "Quaternion Z", "R", 0.0, is_float=True),
        Field(72, 4, "Quaternion W", "R", 1.0, is_float=True),
        Field(76, 1, "Gyro Range", "RW", 3, 0, 3),
        Field(77, 1, "Accel Range", "RW", 3, 0, 3),
    ),
    notes="bitbots IMU module",
)

#: Every known model, by name.
MODELS: dict[str, Model] = {
    m.name: m
    for m in (
        XM430_W350,
        XH430_W350,
        XL430_W250,
        XL330_M288,
        XL330_M077,
        XC330_T288,
        XC330_T181,
        MX28_2,
        MX64_2,
        MX106_2,
        *CLASSIC_MODELS,
        WOLFGANG_CORE,
        WOLFGANG_FOOT,
        WOLFGANG_IMU,
    )
}
#: Every known model, by model number.
MODELS_BY_NUMBER: dict[int, Model] = {m.number: m for m in MODELS.values()}

#: Short aliases accepted in profiles ("MX-64" for "MX-64(2.0)", "core" for the Core board).
ALIASES: dict[str, str] = {
    "MX-28": "MX-28(2.0)",
    "MX-64": "MX-64(2.0)",
    "MX-106": "MX-106(2.0)",
    "core": "Wolfgang Core",
    "foot": "Wolfgang Foot",
    "imu": "Wolfgang IMU",
    "AX-12": "AX-12A",
    "AX-12+": "AX-12A",
    "AX-18": "AX-18A",
    "AX-18F": "AX-18A",
    "XL320": "XL-320",
}
#: On a Protocol 1.0 bus the short MX names mean the Protocol 1.0 firmware (pypot's "MX-28").
ALIASES_P1: dict[str, str] = {"MX-28": "MX-28(1.0)", "MX-64": "MX-64(1.0)", "MX-106": "MX-106(1.0)"}


def find_model(name_or_number: str | int, protocol: int | None = None) -> Model:
    """Look a model up by name, alias or model number; KeyError if unknown.

    ``protocol`` (1 or 2) resolves the short MX names to that firmware's table.
    """
    if isinstance(name_or_number, int):
        return MODELS_BY_NUMBER[name_or_number]
    key = ALIASES_P1.get(name_or_number) if protocol == 1 else None
    return model_named(MODELS, key or ALIASES.get(name_or_number, name_or_number), name_or_number)


def model_names() -> list[str]:
    """Names and aliases a profile may use."""
    return sorted(MODELS) + sorted(ALIASES)

#: Names of every model number the spec sheet lists (§5.1), including models hilbench
#: has no control table for; a monitor names what it sees even if it cannot emulate it.
MODEL_NAMES: dict[int, str] = {
    **{number: model.name for number, model in MODELS_BY_NUMBER.items()},
    1030: "XM430-W210",
    16897: "USB2AX",
}
