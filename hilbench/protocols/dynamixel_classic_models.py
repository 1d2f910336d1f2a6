"""The classic Dynamixel control tables: AX-12A, AX-18A, MX-28/64/106 with Protocol 1.0 firmware, and the XL-320.

Layouts and defaults are the ROBOTIS e-Manual's (spec sheet
``servo_buses.md`` §3.2-3.4, §3.6). These servos keep goal and present
values in 2-byte registers, give speeds and loads a direction bit (bit 10:
set = clockwise), and count positions 0..1023 over 300 degrees (AX, XL-320)
or 0..4095 over 360 degrees (MX). The emulated servo for all of them is
:class:`hilbench.fakes.table_servo.TableServo`, which finds the registers
through :attr:`Model.roles`.
"""

from __future__ import annotations

from hilbench.protocols.control_table import Field, Model, Motion

#: Protocol 1.0 Baud Rate register (address 4) codes to bit/s: bps = 2 000 000 / (code + 1), plus the MX's
#: 250-252. Every code maps; a profile picks its baud from the ones clients can open.
P1_BAUD_CODES: dict[int, int] = {**{v: round(2_000_000 / (v + 1)) for v in range(0, 250)},
                                 250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
#: The rates hosts open for the common codes (nominal rates the real ones round to within 3 %).
P1_NOMINAL_BAUDS: dict[int, int] = {1: 1_000_000, 3: 500_000, 4: 400_000, 7: 250_000, 9: 200_000,
                                    16: 115_200, 34: 57_600, 103: 19_200, 207: 9_600,
                                    250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
#: XL-320 Baud Rate register (address 4).
XL320_BAUD_CODES: dict[int, int] = {0: 9_600, 1: 57_600, 2: 115_200, 3: 1_000_000}

_AX_DEG = 300.0 / 1024
_MX_DEG = 360.0 / 4096
_RPM_AX = 0.111
_RPM_MX = 0.114

#: Roles shared by the AX and MX (Protocol 1.0) tables.
_P1_ROLES = {
    "model_number": 0, "firmware": 2, "id": 3, "baud": 4, "return_delay": 5, "min_position": 6, "max_position": 8,
    "temperature_limit": 11, "min_voltage": 12, "max_voltage": 13, "max_torque": 14, "status_return_level": 16,
    "torque_enable": 24, "led": 25, "goal_position": 30, "goal_speed": 32, "torque_limit": 34,
    "present_position": 36, "present_speed": 38, "present_load": 40, "present_voltage": 42,
    "present_temperature": 43, "registered": 44, "moving": 46, "lock": 47,
}


def _p1_head(number: int, firmware: int, *, position_max: int, baud: int, temperature: int, max_voltage: int,
             max_torque: int) -> list[Field]:
    deg = _AX_DEG if position_max == 1023 else _MX_DEG
    return [
        Field(0, 2, "Model Number", "R", number),
        Field(2, 1, "Firmware Version", "R", firmware),
        Field(3, 1, "ID", "RW", 1, 0, 253),
        Field(4, 1, "Baud Rate", "RW", baud, 0, 254),
        Field(5, 1, "Return Delay Time", "RW", 250, 0, 254, "us", 2.0),
        Field(6, 2, "CW Angle Limit", "RW", 0, 0, position_max, "deg", deg),
        Field(8, 2, "CCW Angle Limit", "RW", position_max, 0, position_max, "deg", deg),
        Field(11, 1, "Temperature Limit", "RW", temperature, 0, 150, "C"),
        Field(12, 1, "Min Voltage Limit", "RW", 60, 50, 250, "V", 0.1),
        Field(13, 1, "Max Voltage Limit", "RW", max_voltage, 50, 250, "V", 0.1),
        Field(14, 2, "Max Torque", "RW", max_torque, 0, 1023, "%", 0.1),
        Field(16, 1, "Status Return Level", "RW", 2, 0, 2),
        Field(17, 1, "Alarm LED", "RW", 36, 0, 127),
        Field(18, 1, "Shutdown", "RW", 36, 0, 127),
    ]


def _p1_tail(position_max: int, rpm: float) -> list[Field]:
    deg = _AX_DEG if position_max == 1023 else _MX_DEG
    return [
        Field(24, 1, "Torque Enable", "RW", 0, 0, 1),
        Field(25, 1, "LED", "RW", 0, 0, 1),
        Field(30, 2, "Goal Position", "RW", position_max // 2 + 1, 0, position_max, "deg", deg),
        Field(32, 2, "Moving Speed", "RW", 0, 0, 2047, "rpm", rpm),
        Field(34, 2, "Torque Limit", "RW", 1023, 0, 1023, "%", 0.1),
        Field(36, 2, "Present Position", "R", position_max // 2 + 1, unit="deg", scale=deg),
        Field(38, 2, "Present Speed", "R", 0, unit="rpm", scale=rpm, sign_bit=10),
        Field(40, 2, "Present Load", "R", 0, unit="%", scale=0.1, sign_bit=10),
        Field(42, 1, "Present Voltage", "R", 120, unit="V", scale=0.1),
        Field(43, 1, "Present Temperature", "R", 30, unit="C"),
        Field(44, 1, "Registered", "R", 0),
        Field(46, 1, "Moving", "R", 0),
        Field(47, 1, "Lock", "RW", 0, 0, 1),
    ]


def _ax(name: str, number: int, *, temperature: int, max_torque: int, max_rpm: float) -> Model:
    fields = _p1_head(number, 24, position_max=1023, baud=1, temperature=temperature, max_voltage=140,
                      max_torque=max_torque)
    fields += [
        Field(26, 1, "CW Compliance Margin", "RW", 1, 0, 255),
        Field(27, 1, "CCW Compliance Margin", "RW", 1, 0, 255),
        Field(28, 1, "CW Compliance Slope", "RW", 32, 0, 254),
        Field(29, 1, "CCW Compliance Slope", "RW", 32, 0, 254),
    ]
    fields += _p1_tail(1023, _RPM_AX)
    fields.append(Field(48, 2, "Punch", "RW", 32, 0, 1023))
    cpr = 1024 * 360 / 300
    return Model(
        name=name, number=number, firmware=24, fields=tuple(sorted(fields, key=lambda f: f.address)),
        table_size=50, firmware_address=2, id_address=3, protocol=1, baud_codes=P1_BAUD_CODES, eeprom_end=24,
        roles=dict(_P1_ROLES), motion=Motion(cpr, _RPM_AX / 60 * cpr, max_rpm / 60 * cpr, position_max=1023),
        notes="Protocol 1.0; 1024 counts over 300 degrees",
    )


def _mx1(name: str, number: int, *, max_voltage: int, max_rpm: float, current: bool, drive_mode: bool) -> Model:
    fields = _p1_head(number, 40, position_max=4095, baud=34, temperature=80, max_voltage=max_voltage,
                      max_torque=1023)
    if drive_mode:
        fields.append(Field(10, 1, "Drive Mode", "RW", 0, 0, 3))
    fields += [
        Field(20, 2, "Multi Turn Offset", "RW", 0, -24576, 24576, signed=True),
        Field(22, 1, "Resolution Divider", "RW", 1, 1, 4),
        Field(26, 1, "D Gain", "RW", 0, 0, 254),
        Field(27, 1, "I Gain", "RW", 0, 0, 254),
        Field(28, 1, "P Gain", "RW", 32, 0, 254),
    ]
    fields += _p1_tail(4095, _RPM_MX)
    fields += [
        Field(48, 2, "Punch", "RW", 0, 0, 1023),
        Field(50, 2, "Realtime Tick", "R", 0, unit="ms"),
        Field(73, 1, "Goal Acceleration", "RW", 0, 0, 254, "deg/s^2", 8.583),
    ]
    roles = {**_P1_ROLES, "realtime_tick": 50, "goal_acceleration": 73}
    if current:
        fields += [
            Field(68, 2, "Current", "RW", 2048, 0, 4095, "mA", 4.5),
            Field(70, 1, "Torque Control Mode Enable", "RW", 0, 0, 1),
            Field(71, 2, "Goal Torque", "RW", 0, 0, 2047, sign_bit=10),
        ]
        roles["present_current"] = 68
    return Model(
        name=name, number=number, firmware=40, fields=tuple(sorted(fields, key=lambda f: f.address)),
        table_size=74, firmware_address=2, id_address=3, protocol=1, baud_codes=P1_BAUD_CODES, eeprom_end=24,
        roles=roles,
        motion=Motion(4096, _RPM_MX / 60 * 4096, max_rpm / 60 * 4096, 8.583 / 360 * 4096, position_max=4095),
        notes="Protocol 1.0 firmware; 4096 counts over 360 degrees",
    )


AX12A = _ax("AX-12A", 12, temperature=70, max_torque=1023, max_rpm=59)
AX18A = _ax("AX-18A", 18, temperature=75, max_torque=983, max_rpm=97)
MX28_1 = _mx1("MX-28(1.0)", 29, max_voltage=160, max_rpm=55, current=False, drive_mode=False)
MX64_1 = _mx1("MX-64(1.0)", 310, max_voltage=240, max_rpm=63, current=True, drive_mode=False)
MX106_1 = _mx1("MX-106(1.0)", 320, max_voltage=160, max_rpm=45, current=True, drive_mode=True)


def _xl320() -> Model:
    deg = _AX_DEG
    fields = (
        Field(0, 2, "Model Number", "R", 350),
        Field(2, 1, "Firmware Version", "R", 29),
        Field(3, 1, "ID", "RW", 1, 0, 252),
        Field(4, 1, "Baud Rate", "RW", 3, 0, 3),
        Field(5, 1, "Return Delay Time", "RW", 250, 0, 254, "us", 2.0),
        Field(6, 2, "CW Angle Limit", "RW", 0, 0, 1023, "deg", deg),
        Field(8, 2, "CCW Angle Limit", "RW", 1023, 0, 1023, "deg", deg),
        Field(11, 1, "Control Mode", "RW", 2, 1, 2),
        Field(12, 1, "Temperature Limit", "RW", 65, 0, 150, "C"),
        Field(13, 1, "Min Voltage Limit", "RW", 60, 50, 250, "V", 0.1),
        Field(14, 1, "Max Voltage Limit", "RW", 90, 50, 250, "V", 0.1),
        Field(15, 2, "Max Torque", "RW", 1023, 0, 1023, "%", 0.1),
        Field(17, 1, "Status Return Level", "RW", 2, 0, 2),
        Field(18, 1, "Shutdown", "RW", 3, 0, 7),
        Field(24, 1, "Torque Enable", "RW", 0, 0, 1),
        Field(25, 1, "LED", "RW", 0, 0, 7),
        Field(27, 1, "D Gain", "RW", 0, 0, 254),
        Field(28, 1, "I Gain", "RW", 0, 0, 254),
        Field(29, 1, "P Gain", "RW", 32, 0, 254),
        Field(30, 2, "Goal Position", "RW", 512, 0, 1023, "deg", deg),
        Field(32, 2, "Moving Speed", "RW", 0, 0, 2047, "rpm", _RPM_AX),
        Field(35, 2, "Torque Limit", "RW", 1023, 0, 1023, "%", 0.1),
        Field(37, 2, "Present Position", "R", 512, unit="deg", scale=deg),
        Field(39, 2, "Present Speed", "R", 0, unit="rpm", scale=_RPM_AX, sign_bit=10),
        Field(41, 2, "Present Load", "R", 0, unit="%", scale=0.1, sign_bit=10),
        Field(45, 1, "Present Voltage", "R", 75, unit="V", scale=0.1),
        Field(46, 1, "Present Temperature", "R", 30, unit="C"),
        Field(47, 1, "Registered Instruction", "R", 0),
        Field(49, 1, "Moving", "R", 0),
        Field(50, 1, "Hardware Error Status", "R", 0),
        Field(51, 2, "Punch", "RW", 32, 0, 1023),
    )
    cpr = 1024 * 360 / 300
    return Model(
        name="XL-320", number=350, firmware=29, fields=fields, table_size=53, firmware_address=2, id_address=3,
        protocol=2, baud_codes=XL320_BAUD_CODES, eeprom_end=24,
        roles={"model_number": 0, "firmware": 2, "id": 3, "baud": 4, "return_delay": 5, "min_position": 6,
               "max_position": 8, "operating_mode": 11, "temperature_limit": 12, "min_voltage": 13,
               "max_voltage": 14, "max_torque": 15, "status_return_level": 17, "shutdown": 18,
               "torque_enable": 24, "led": 25, "goal_position": 30, "goal_speed": 32, "torque_limit": 35,
               "present_position": 37, "present_speed": 39, "present_load": 41, "present_voltage": 45,
               "present_temperature": 46, "registered": 47, "moving": 49, "hardware_error": 50},
        motion=Motion(cpr, _RPM_AX / 60 * cpr, 114 / 60 * cpr, position_max=1023),
        notes="Protocol 2.0 framing with its own table; Control Mode 1 = wheel, 2 = joint",
    )


XL320 = _xl320()

#: The classic models, by name.
CLASSIC_MODELS: tuple[Model, ...] = (AX12A, AX18A, MX28_1, MX64_1, MX106_1, XL320)

__all__ = ["AX12A", "AX18A", "CLASSIC_MODELS", "MX28_1", "MX64_1", "MX106_1", "P1_BAUD_CODES",
           "P1_NOMINAL_BAUDS", "XL320", "XL320_BAUD_CODES"]
