"""The rover board's CAN interface, described once: its PDOs, its object dictionary, its DBC and EDS.

The STM32 rover board is a CANopen node (node id ``n``, default 2). Besides
the CANopen services (:mod:`hilbench.protocols.canopen`) it has five PDOs,
all little-endian and byte aligned:

=========  =============  ===  =====================================================  ==========
PDO        COB-ID         len  signals (physical = raw x scale)                       period
=========  =============  ===  =====================================================  ==========
RPDO1      0x200 + n      8    ``vx``, ``vy`` (int16, 0.001 m/s), ``omega`` (int16,    host, 50 ms
                               0.001 rad/s), ``counter`` (u8, +1 per frame),
                               ``checksum`` (u8, CRC-8/SAE-J1850 of bytes 0..6)
TPDO1      0x180 + n      8    ``enc_fr``, ``enc_fl``, ``enc_bl``, ``enc_br``          20 ms
                               (int16: encoder increments since the previous
                               frame, 3072 per wheel turn)
TPDO2      0x280 + n      8    ``x``, ``y`` (int24, 0.001 m), ``theta`` (int16,        50 ms
                               0.0001 rad): the odometry pose
TPDO3      0x380 + n      7    ``vx``, ``vy``, ``omega`` (as RPDO1): the ramped        50 ms
                               command the wheels follow; ``counter`` (u8)
TPDO4      0x480 + n      7    ``mode`` (u8: idle, driving, timeout, fault),           100 ms
                               ``error_register`` (0x1001), ``rejected``,
                               ``timeouts`` (u8, wrapping), ``battery`` (u16,
                               0.01 V), ``counter`` (u8)
=========  =============  ===  =====================================================  ==========

The velocity setpoint is the Vel2d content (linear x, linear y, angular z)
packed for classic CAN: millimetres per second instead of float64 m/s, and an
alive counter plus a CRC-8 (AUTOSAR E2E profile 1's polynomial) instead of the
CRC-32. The periods are the TPDO event timers (0x1800+k sub 5, writable);
RPDO1's event timer (0x1400 sub 5) is the setpoint timeout.

From this one table come the ``construct`` layouts the fake board and the
decoders use (:data:`LAYOUTS`), the object dictionary the board's SDO server
serves (:func:`object_dictionary`), the DBC cantools reads (:func:`dbc`) and
the EDS the ``canopen`` package imports (:func:`eds`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

from construct import Int8sl, Int8ul, Int16sl, Int16ul, Int24sl, Int24ul, Int32sl, Int32ul, Struct

from hilbench.protocols import canopen as co
from hilbench.protocols import canopen_od as od
from hilbench.protocols.checksums import crc8_sae_j1850
from hilbench.protocols.dbc import Message, Signal, dbc_text
from hilbench.protocols.problem import Problem

#: Encoder increments per wheel turn.
INCREMENTS_PER_TURN = 3072

MODE_IDLE = 0
MODE_DRIVING = 1
MODE_TIMEOUT = 2
MODE_FAULT = 3
MODES = ((MODE_IDLE, "idle"), (MODE_DRIVING, "driving"), (MODE_TIMEOUT, "timeout"), (MODE_FAULT, "fault"))


@dataclass(frozen=True)
class Pdo:
    """One PDO of the board: ``kind`` ``"tpdo"`` (board -> host) or ``"rpdo"``, its number and signals."""

    key: str
    kind: str
    number: int
    name: str
    length: int
    signals: tuple[Signal, ...]
    period_ms: int
    comment: str

    @property
    def function(self) -> int:
        """The COB-ID without the node id (``0x180`` for TPDO1)."""
        base = 0x180 if self.kind == "tpdo" else 0x200
        return base + 0x100 * (self.number - 1)

    @property
    def comm_index(self) -> int:
        return (0x1800 if self.kind == "tpdo" else 0x1400) + self.number - 1

    @property
    def map_index(self) -> int:
        return (0x1A00 if self.kind == "tpdo" else 0x1600) + self.number - 1

    def cob_id(self, node_id: int) -> int:
        return self.function + node_id


def _s(name: str, offset: int, bits: int, signed: bool, scale: float, unit: str, od_entry: tuple[int, int],
       comment: str, choices: tuple = ()) -> Signal:
    return Signal(name, 8 * offset, bits, signed, scale, unit, comment, choices, od_entry)


#: RPDO1, the velocity setpoint the host sends (see the module docstring).
SETPOINT = Pdo("setpoint", "rpdo", 1, "VelocitySetpoint", 8, (
    _s("vx", 0, 16, True, 0.001, "m/s", (0x2000, 1), "forward velocity (Vel2d linear.x)"),
    _s("vy", 2, 16, True, 0.001, "m/s", (0x2000, 2), "sideways velocity, left positive (Vel2d linear.y)"),
    _s("omega", 4, 16, True, 0.001, "rad/s", (0x2000, 3), "yaw rate, counter-clockwise positive (Vel2d angular.z)"),
    _s("counter", 6, 8, False, 1, "", (0x2000, 4), "alive counter: +1 (mod 256) per frame; a repeated value is "
                                                   "rejected"),
    _s("checksum", 7, 8, False, 1, "", (0x2000, 5), "CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF) of "
                                                    "bytes 0..6"),
), 50, "velocity setpoint from the host, repeated every 50 ms; the board stops when none arrives within the RPDO "
       "event timer (0x1400 sub 5)")

ENCODERS = Pdo("encoders", "tpdo", 1, "WheelEncoders", 8, tuple(
    _s(f"enc_{w}", 2 * i, 16, True, 1, "inc", (0x2001, i + 1),
       f"{label} wheel: encoder increments since the previous frame ({INCREMENTS_PER_TURN} per turn)")
    for i, (w, label) in enumerate((("fr", "front right"), ("fl", "front left"), ("bl", "back left"),
                                    ("br", "back right")))
), 20, "wheel encoder deltas")

ODOMETRY = Pdo("odometry", "tpdo", 2, "OdometryPose", 8, (
    _s("x", 0, 24, True, 0.001, "m", (0x2002, 1), "odometry x (forward at start)"),
    _s("y", 3, 24, True, 0.001, "m", (0x2002, 2), "odometry y (left at start)"),
    _s("theta", 6, 16, True, 0.0001, "rad", (0x2002, 3), "odometry heading, -pi..pi"),
), 50, "odometry pose integrated from the wheel motion")

VELOCITY = Pdo("velocity", "tpdo", 3, "Velocity", 7, (
    _s("vx", 0, 16, True, 0.001, "m/s", (0x2003, 1), "forward velocity the wheels follow (ramped setpoint)"),
    _s("vy", 2, 16, True, 0.001, "m/s", (0x2003, 2), "sideways velocity the wheels follow"),
    _s("omega", 4, 16, True, 0.001, "rad/s", (0x2003, 3), "yaw rate the wheels follow"),
    _s("counter", 6, 8, False, 1, "", (0x2003, 4), "+1 (mod 256) per frame"),
), 50, "the rover's velocity: the setpoint after the firmware's ramp")

STATUS = Pdo("status", "tpdo", 4, "BoardStatus", 7, (
    _s("mode", 0, 8, False, 1, "", (0x2004, 1), "what the board does", MODES),
    _s("error_register", 1, 8, False, 1, "", (0x1001, 0), "CANopen error register (object 0x1001)"),
    _s("rejected", 2, 8, False, 1, "", (0x2004, 2), "setpoint frames rejected (checksum, counter, length), mod 256"),
    _s("timeouts", 3, 8, False, 1, "", (0x2004, 3), "setpoint timeouts, mod 256"),
    _s("battery", 4, 16, False, 0.01, "V", (0x2004, 4), "battery voltage"),
    _s("counter", 6, 8, False, 1, "", (0x2004, 5), "+1 (mod 256) per frame"),
), 100, "board status")

PDOS: tuple[Pdo, ...] = (SETPOINT, ENCODERS, ODOMETRY, VELOCITY, STATUS)
BY_KEY = {p.key: p for p in PDOS}

_INTS = {(8, False): Int8ul, (8, True): Int8sl, (16, False): Int16ul, (16, True): Int16sl, (24, False): Int24ul,
         (24, True): Int24sl, (32, False): Int32ul, (32, True): Int32sl}


def _layout(pdo: Pdo) -> Struct:
    offset = 0
    fields = []
    for s in pdo.signals:
        if s.start != 8 * offset or s.bits % 8:
            raise ValueError(f"{pdo.name}.{s.name}: signals must be byte aligned and contiguous")
        fields.append(s.name / _INTS[(s.bits, s.signed)])
        offset += s.bits // 8
    if offset != pdo.length:
        raise ValueError(f"{pdo.name}: signals cover {offset} of {pdo.length} bytes")
    return Struct(*fields)


#: The construct layout (raw values) of every PDO, by key.
LAYOUTS: dict[str, Struct] = {p.key: _layout(p) for p in PDOS}


def _raw(signal: Signal, value: float) -> int:
    lo, hi = signal.raw_range
    return max(lo, min(hi, round(value / signal.scale)))


def encode(key: str, **values: float) -> bytes:
    """A PDO's bytes from physical values (clamped to the signal's range; missing signals are 0)."""
    pdo = BY_KEY[key]
    return LAYOUTS[key].build({s.name: _raw(s, values.get(s.name, 0)) for s in pdo.signals})


def decode(key: str, data: bytes) -> dict[str, float]:
    """A PDO's physical values; ValueError if ``data`` has the wrong length."""
    pdo = BY_KEY[key]
    if len(data) != pdo.length:
        raise ValueError(f"{pdo.name} has {pdo.length} bytes, got {len(data)}")
    raw = LAYOUTS[key].parse(data)
    return {s.name: raw[s.name] * s.scale if s.scale != 1 else raw[s.name] for s in pdo.signals}


def setpoint_checksum(data: bytes) -> int:
    """The setpoint's checksum: CRC-8/SAE-J1850 of its first seven bytes."""
    return crc8_sae_j1850(bytes(data[:7]))


def build_setpoint(vx: float, vy: float, omega: float, counter: int) -> bytes:
    """RPDO1's 8 bytes for a velocity (m/s, m/s, rad/s) with its alive counter and checksum."""
    body = encode("setpoint", vx=vx, vy=vy, omega=omega, counter=counter % 256)[:7]
    return body + bytes([setpoint_checksum(body)])


class Setpoint(NamedTuple):
    """A setpoint frame that passed its checks: SI units, raw counter."""

    vx: float
    vy: float
    omega: float
    counter: int


def check_setpoint(data: bytes) -> Setpoint | Problem:
    """Check RPDO1's length and checksum as the board does; never raises.

    A frame the board rejects is a :class:`~hilbench.protocols.problem.Problem`: ``kind`` ``length`` or
    ``checksum`` (with the ``expected`` and the ``got`` checksum byte).
    """
    data = bytes(data)
    if len(data) != SETPOINT.length:
        return Problem("length", data)
    expected = setpoint_checksum(data)
    if data[7] != expected:
        return Problem("checksum", data, expected=expected, got=data[7])
    v = decode("setpoint", data)
    return Setpoint(v["vx"], v["vy"], v["omega"], int(v["counter"]))


# --------------------------------------------------------------------------- configuration

@dataclass(frozen=True)
class BoardCanConfig:
    """What a profile sets of the board's CAN interface (and the object dictionary's defaults)."""

    node_id: int = 2
    heartbeat_ms: int = 1000
    setpoint_timeout_ms: int = 150
    periods_ms: dict[str, int] = field(default_factory=lambda: {p.key: p.period_ms for p in PDOS if p.kind == "tpdo"})
    vendor_id: int = 0x0048424E
    product_code: int = 0x00F76701
    revision: int = 0x00010000
    serial: int = 0x00000001
    device_name: str = "hilbench STM32F767 rover board (CANopen)"
    hardware_version: str = "NUCLEO-F767ZI"
    software_version: str = "hilbench-rover-can 1.0"
    bitrate: int = 500_000


def _mapping_value(s: Signal) -> int:
    index, sub = s.od  # type: ignore[misc]
    return (index << 16) | (sub << 8) | s.bits


def _signal_var(s: Signal, access: str, default: Any = 0) -> od.Variable:
    index, sub = s.od  # type: ignore[misc]
    types = {(8, False): od.UNSIGNED8, (8, True): od.INTEGER8, (16, False): od.UNSIGNED16, (16, True): od.INTEGER16,
             (24, False): od.UNSIGNED24, (24, True): od.INTEGER24, (32, False): od.UNSIGNED32,
             (32, True): od.INTEGER32}
    return od.Variable(index, sub, s.name, types[(s.bits, s.signed)], access, default, pdo=True,
                       factor=s.scale, unit=s.unit, description=s.comment)


def object_dictionary(cfg: BoardCanConfig) -> list[od.Entry]:
    """The board's object dictionary (defaults with ``$NODEID`` where the EDS keeps them relative)."""
    u8, u16, u32, vs = od.UNSIGNED8, od.UNSIGNED16, od.UNSIGNED32, od.VISIBLE_STRING
    entries: list[od.Entry] = [
        od.Variable(0x1000, 0, "Device type", u32, "ro", 0, description="no standard device profile"),
        od.Variable(0x1001, 0, "Error register", u8, "ro", 0, pdo=True),
        od.Record(0x1003, "Pre-defined error field", (
            od.Variable(0x1003, 0, "Number of errors", u8, "rw", 0, description="write 0 to clear the history"),
            *(od.Variable(0x1003, i, f"Standard error field {i}", u32, "ro", 0) for i in range(1, 9)),
        ), array=True),
        od.Variable(0x1008, 0, "Manufacturer device name", vs, "const", cfg.device_name),
        od.Variable(0x1009, 0, "Manufacturer hardware version", vs, "const", cfg.hardware_version),
        od.Variable(0x100A, 0, "Manufacturer software version", vs, "const", cfg.software_version),
        od.Variable(0x1014, 0, "COB-ID EMCY", u32, "ro", "$NODEID+0x80"),
        od.Variable(0x1017, 0, "Producer heartbeat time", u16, "rw", cfg.heartbeat_ms, unit="ms"),
        od.Record(0x1018, "Identity object", (
            od.sub0(0x1018, 4),
            od.Variable(0x1018, 1, "Vendor-ID", u32, "ro", cfg.vendor_id),
            od.Variable(0x1018, 2, "Product code", u32, "ro", cfg.product_code),
            od.Variable(0x1018, 3, "Revision number", u32, "ro", cfg.revision),
            od.Variable(0x1018, 4, "Serial number", u32, "ro", cfg.serial),
        )),
        od.Record(0x1200, "SDO server parameter", (
            od.sub0(0x1200, 2),
            od.Variable(0x1200, 1, "COB-ID client to server", u32, "ro", "$NODEID+0x600"),
            od.Variable(0x1200, 2, "COB-ID server to client", u32, "ro", "$NODEID+0x580"),
        )),
    ]
    for p in PDOS:
        trans = 0xFF if p.kind == "rpdo" else 0xFE
        period = cfg.setpoint_timeout_ms if p.kind == "rpdo" else cfg.periods_ms.get(p.key, p.period_ms)
        timer_name = "Event timer (setpoint timeout)" if p.kind == "rpdo" else "Event timer"
        members = [od.sub0(p.comm_index, 5),
                   od.Variable(p.comm_index, 1, f"COB-ID used by {p.kind.upper()}", u32, "ro",
                               f"$NODEID+0x{p.function:X}"),
                   od.Variable(p.comm_index, 2, "Transmission type", u8, "ro", trans)]
        if p.kind == "tpdo":
            members.append(od.Variable(p.comm_index, 3, "Inhibit time", u16, "ro", 0))
        members.append(od.Variable(p.comm_index, 5, timer_name, u16, "rw", period, unit="ms"))
        word = "receive" if p.kind == "rpdo" else "transmit"
        entries.append(od.Record(p.comm_index, f"{p.kind.upper()}{p.number} communication parameter ({p.name})",
                                 tuple(members)))
        entries.append(od.Record(p.map_index, f"{p.kind.upper()}{p.number} mapping parameter", (
            od.Variable(p.map_index, 0, "Number of mapped application objects", u8, "ro", len(p.signals)),
            *(od.Variable(p.map_index, i, f"Application object {i}", u32, "ro", _mapping_value(s),
                          description=f"{word}s {s.name}")
              for i, s in enumerate(p.signals, 1)),
        )))

    def record(index: int, name: str, pdo: Pdo, access: str) -> od.Record:
        own = [s for s in pdo.signals if s.od[0] == index]  # type: ignore[index]
        return od.Record(index, name, (od.sub0(index, len(own)), *(_signal_var(s, access) for s in own)))

    i32 = od.INTEGER32
    entries += [
        record(0x2000, "Velocity setpoint", SETPOINT, "rww"),
        record(0x2001, "Wheel encoder deltas", ENCODERS, "ro"),
        record(0x2002, "Odometry pose", ODOMETRY, "ro"),
        record(0x2003, "Velocity", VELOCITY, "ro"),
        od.Record(0x2004, "Board status", (
            od.sub0(0x2004, 5), *(_signal_var(s, "ro") for s in STATUS.signals if s.od[0] == 0x2004))),  # type: ignore[index]
        od.Variable(0x2010, 0, "Odometry reset", u8, "rw", 0, description="write 1: pose back to 0, 0, 0"),
        od.Record(0x2011, "Wheel encoder counts", (
            od.sub0(0x2011, 4),
            *(od.Variable(0x2011, i, f"count_{w}", i32, "ro", 0, unit="inc", description=f"{w} wheel, since boot")
              for i, w in enumerate(("fr", "fl", "bl", "br"), 1)),
        )),
        od.Record(0x2012, "Setpoint statistics", (
            od.sub0(0x2012, 6),
            *(od.Variable(0x2012, i, name, u32, "ro", 0, description=text) for i, (name, text) in enumerate((
                ("accepted", "setpoint frames accepted"),
                ("checksum_errors", "frames with a wrong checksum"),
                ("counter_errors", "frames repeating the previous counter"),
                ("lost_frames", "frames missing according to counter jumps"),
                ("length_errors", "frames of the wrong length"),
                ("timeouts", "setpoint timeouts"),
            ), 1)),
        )),
    ]
    return entries


def device_info(cfg: BoardCanConfig, name: str = "rover") -> od.DeviceInfo:
    """The EDS's ``[DeviceInfo]`` facts."""
    return od.DeviceInfo(
        vendor_name="hilbench (emulated)", vendor_number=cfg.vendor_id, product_name=cfg.device_name,
        product_number=cfg.product_code, revision_number=cfg.revision, order_code="hilbench-rover-can",
        description=f"STM32F767 rover board as CANopen node {cfg.node_id} ({name}), emulated by hilbench",
        file_name=f"{name}.eds", rx_pdos=sum(p.kind == "rpdo" for p in PDOS),
        tx_pdos=sum(p.kind == "tpdo" for p in PDOS),
        comments=["Generated by hilbench from hilbench/protocols/board_can.py.",
                  "PDO mappings are static; the TPDO event timers (0x1800+k sub 5) and the setpoint timeout "
                  "(0x1400 sub 5) are writable."])


def eds(cfg: BoardCanConfig, name: str = "rover") -> str:
    """The board's EDS (node-id relative COB-IDs)."""
    return od.eds_text(object_dictionary(cfg), device_info(cfg, name))


# --------------------------------------------------------------------------- DBC

HOST = "HOST"


def node_name(name: str) -> str:
    """A device name as a DBC node name (``rover`` -> ``ROVER``)."""
    text = "".join(ch if ch.isalnum() else "_" for ch in name.upper())
    return text if text and not text[0].isdigit() else f"N_{text}"


def messages(cfg: BoardCanConfig, name: str = "rover") -> list[Message]:
    """Every frame the board sends or takes, as DBC messages (PDOs and CANopen services of node ``n``)."""
    n = cfg.node_id
    board = node_name(name)
    suffix = f"_{n:02X}"
    out: list[Message] = []
    for p in PDOS:
        sender, receivers = (board, (HOST,)) if p.kind == "tpdo" else (HOST, (board,))
        cycle = p.period_ms if p.kind == "rpdo" else cfg.periods_ms.get(p.key, p.period_ms)
        out.append(Message(p.name + suffix, p.cob_id(n), p.length, sender, receivers, p.signals,
                           f"{p.kind.upper()}{p.number} of node {n}: {p.comment}", cycle))
    state_choices = tuple(sorted((v, k.replace("-", "_")) for v, k in co.STATE_NAMES.items()))
    out.append(Message(f"Heartbeat{suffix}", 0x700 + n, 1, board, (HOST,), (
        Signal("nmt_state", 0, 7, False, 1, "", "NMT state (0 = boot-up)", state_choices),
        Signal("toggle", 7, 1, False, 1, "", "node guarding toggle bit (0 in heartbeats)"),
    ), f"heartbeat and boot-up of node {n} (period: object 0x1017)", cfg.heartbeat_ms))
    emcy_choices = tuple(sorted(co.EMCY_CODES.items()))
    out.append(Message(f"EMCY{suffix}", 0x080 + n, 8, board, (HOST,), (
        Signal("error_code", 0, 16, False, 1, "", "CiA 301 emergency error code", emcy_choices),
        Signal("error_register", 16, 8, False, 1, "", "object 0x1001 when the error occurred"),
        Signal("vendor_data", 24, 40, False, 1, "", "manufacturer-specific error field"),
    ), f"emergency messages of node {n}"))
    sdo_signals = (
        Signal("command", 0, 8, False, 1, "", "SDO command specifier byte"),
        Signal("index", 8, 16, False, 1, "", "object index (initiate and abort frames)"),
        Signal("subindex", 24, 8, False, 1, "", "object sub-index (initiate and abort frames)"),
        Signal("data", 32, 32, False, 1, "", "expedited data, size or abort code (segments carry bytes 1..7)"),
    )
    out.append(Message(f"SDO_Request{suffix}", 0x600 + n, 8, HOST, (board,), sdo_signals,
                       f"SDO client to server (node {n})"))
    out.append(Message(f"SDO_Response{suffix}", 0x580 + n, 8, board, (HOST,), sdo_signals,
                       f"SDO server to client (node {n})"))
    return out


def bus_messages() -> list[Message]:
    """The node-independent frames: the NMT command and SYNC."""
    nmt_choices = tuple(sorted((k, v.replace("-", "_")) for k, v in co.NMT_COMMANDS.items()))
    return [
        Message("NMT", 0x000, 2, HOST, (), (
            Signal("command", 0, 8, False, 1, "", "NMT command specifier", nmt_choices),
            Signal("node", 8, 8, False, 1, "", "addressed node (0 = all)"),
        ), "NMT module control (master)"),
        Message("SYNC", 0x080, 0, HOST, (), (), "SYNC (not used by the board; listed so every frame decodes)"),
    ]


def dbc(boards: list[tuple[str, BoardCanConfig]]) -> str:
    """The DBC of a bus with these boards (``(device name, config)``)."""
    msgs = bus_messages()
    for name, cfg in boards:
        msgs += messages(cfg, name)
    nodes = [HOST] + [node_name(name) for name, _ in boards]
    return dbc_text(msgs, nodes, comment="Generated by hilbench from hilbench/protocols/board_can.py")


__all__ = ["BY_KEY", "ENCODERS", "INCREMENTS_PER_TURN", "LAYOUTS", "MODES", "ODOMETRY", "PDOS", "SETPOINT", "STATUS",
           "VELOCITY", "BoardCanConfig", "Pdo", "Setpoint", "build_setpoint", "check_setpoint",
           "dbc", "decode", "device_info", "eds", "encode", "messages", "object_dictionary", "setpoint_checksum"]
