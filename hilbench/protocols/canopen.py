"""CANopen framing (CiA 301): COB-IDs, NMT, heartbeat, SDO, EMCY; used by the fake node and the monitor alike.

Predefined connection set (node id n = 1..127)::

    0x000        NMT command            [2] command specifier, node id (0 = all)
    0x080        SYNC                   [0] (or a 1-byte counter)
    0x080 + n    EMCY                   [8] u16 error code, u8 error register, 5 vendor bytes
    0x180 + n .. 0x480 + n  TPDO1..4    node -> any
    0x200 + n .. 0x500 + n  RPDO1..4    any -> node
    0x580 + n    SDO server -> client   [8]
    0x600 + n    SDO client -> server   [8]
    0x700 + n    heartbeat / boot-up    [1] NMT state (bit 7: node guarding toggle)

SDO frames are 8 bytes: a command byte, the index (u16, little-endian), the
sub-index, and 4 data bytes (expedited) or a size; segments carry 7 data bytes
after the command byte. :data:`SdoInitiate` and :data:`SdoSegment` are the
layouts; :data:`InitiateCommand`, :data:`SegmentCommand` and :func:`specifier` read a
command byte's fields.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from construct import BitsInteger, BitStruct, Bytes, Flag, Int8ul, Int16ul, Int32ul, Struct

# --------------------------------------------------------------------------- COB-IDs

NMT_ID = 0x000
SYNC_ID = 0x080
TIME_ID = 0x100
LSS_MASTER_ID = 0x7E5
LSS_SLAVE_ID = 0x7E4

#: Function code (COB-ID & 0x780) -> name, for node-addressed objects.
FUNCTIONS = {
    0x080: "EMCY", 0x180: "TPDO1", 0x200: "RPDO1", 0x280: "TPDO2", 0x300: "RPDO2", 0x380: "TPDO3",
    0x400: "RPDO3", 0x480: "TPDO4", 0x500: "RPDO4", 0x580: "SDO-TX", 0x600: "SDO-RX", 0x700: "NMT-EC",
}


class CobId(NamedTuple):
    """What a standard identifier means in the predefined connection set: ``function`` and ``node`` (0: none)."""

    function: str
    node: int


def classify(can_id: int, extended: bool = False) -> CobId:
    """Name a COB-ID: ``NMT``, ``SYNC``, ``TIME``, ``LSS``, ``EMCY``, ``TPDOn``, ``RPDOn``, ``SDO-TX`` (server
    responses), ``SDO-RX`` (client requests), ``NMT-EC`` (heartbeat/boot-up) with its node, or ``other``."""
    if extended:
        return CobId("other", 0)
    if can_id == NMT_ID:
        return CobId("NMT", 0)
    if can_id == SYNC_ID:
        return CobId("SYNC", 0)
    if can_id == TIME_ID:
        return CobId("TIME", 0)
    if can_id in (LSS_MASTER_ID, LSS_SLAVE_ID):
        return CobId("LSS", 0)
    node = can_id & 0x7F
    function = FUNCTIONS.get(can_id & 0x780)
    if function is None or node == 0:
        return CobId("other", 0)
    return CobId(function, node)


# --------------------------------------------------------------------------- NMT

NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82
NMT_COMMANDS = {NMT_START: "start", NMT_STOP: "stop", NMT_PRE_OPERATIONAL: "pre-operational",
                NMT_RESET_NODE: "reset-node", NMT_RESET_COMMUNICATION: "reset-communication"}

#: States as the heartbeat reports them.
BOOTUP = 0x00
STOPPED = 0x04
OPERATIONAL = 0x05
PRE_OPERATIONAL = 0x7F
STATE_NAMES = {BOOTUP: "BOOTUP", STOPPED: "STOPPED", OPERATIONAL: "OPERATIONAL", PRE_OPERATIONAL: "PRE-OPERATIONAL"}

#: The NMT command frame.
NmtCommand = Struct("command" / Int8ul, "node" / Int8ul)
#: A heartbeat (or boot-up, or node-guarding reply: bit 7 is then the toggle bit).
Heartbeat = BitStruct("toggle" / Flag, "state" / BitsInteger(7))


def nmt_command(command: int, node: int = 0) -> bytes:
    """The 2 data bytes of an NMT command (``node`` 0 addresses every node)."""
    return NmtCommand.build({"command": command, "node": node})


def state_name(state: int) -> str:
    """A heartbeat state's name (``UNKNOWN(0x..)`` for others)."""
    return STATE_NAMES.get(state & 0x7F, f"UNKNOWN(0x{state & 0x7F:02X})")


# --------------------------------------------------------------------------- SDO

# Client command specifiers (bits 7..5 of a request's first byte).
CCS_DOWNLOAD_SEGMENT = 0
CCS_INITIATE_DOWNLOAD = 1
CCS_INITIATE_UPLOAD = 2
CCS_UPLOAD_SEGMENT = 3
CCS_ABORT = 4
CCS_BLOCK_UPLOAD = 5
CCS_BLOCK_DOWNLOAD = 6
# Server command specifiers (bits 7..5 of a response's first byte).
SCS_UPLOAD_SEGMENT = 0
SCS_DOWNLOAD_SEGMENT = 1
SCS_INITIATE_UPLOAD = 2
SCS_INITIATE_DOWNLOAD = 3
SCS_ABORT = 4
SCS_BLOCK_DOWNLOAD = 5
SCS_BLOCK_UPLOAD = 6

#: Initiate (and abort) frames: command byte, index, sub-index, 4 bytes of data or size or abort code.
SdoInitiate = Struct("command" / Int8ul, "index" / Int16ul, "subindex" / Int8ul, "data" / Bytes(4))
#: Segment frames: command byte and 7 data bytes.
SdoSegment = Struct("command" / Int8ul, "data" / Bytes(7))
#: An abort's payload.
SdoAbort = Struct("command" / Int8ul, "index" / Int16ul, "subindex" / Int8ul, "code" / Int32ul)
#: Initiate command byte: specifier, reserved, n (unused bytes of an expedited transfer), e, s.
InitiateCommand = BitStruct("cs" / BitsInteger(3), "x" / BitsInteger(1), "n" / BitsInteger(2),
                            "expedited" / Flag, "size_indicated" / Flag)
#: Segment command byte: specifier, toggle, n (unused bytes of the segment), c (last segment).
SegmentCommand = BitStruct("cs" / BitsInteger(3), "toggle" / Flag, "n" / BitsInteger(3), "last" / Flag)

_INITIATE = struct.Struct("<BHB4s")


def specifier(command: int) -> int:
    """The command specifier (bits 7..5) of an SDO command byte."""
    return command >> 5


def sdo_abort(index: int, subindex: int, code: int) -> bytes:
    """An abort frame's 8 bytes."""
    return SdoAbort.build({"command": 0x80, "index": index, "subindex": subindex, "code": code})


def initiate(command: int, index: int, subindex: int, data: bytes = bytes(4)) -> bytes:
    """An initiate frame's 8 bytes (``data`` padded to 4)."""
    return _INITIATE.pack(command, index, subindex, bytes(data).ljust(4, b"\0")[:4])


def parse_initiate(data: bytes) -> tuple[int, int, int, bytes]:
    """``(command, index, subindex, 4 data bytes)`` of an 8-byte initiate frame (shorter frames are padded)."""
    return _INITIATE.unpack(bytes(data[:8]).ljust(8, b"\0"))


def expedited_upload_response(index: int, subindex: int, value: bytes) -> bytes:
    """The server's expedited upload response carrying 1..4 bytes."""
    n = 4 - len(value)
    return initiate(0x43 | (n << 2), index, subindex, value)


def expedited_download_request(index: int, subindex: int, value: bytes) -> bytes:
    """The client's expedited download of 1..4 bytes."""
    n = 4 - len(value)
    return initiate(0x23 | (n << 2), index, subindex, value)


def expedited_size(command: int) -> int:
    """Data bytes of an expedited initiate with command byte ``command`` (4 if the size is not indicated)."""
    return 4 - ((command >> 2) & 3) if command & 0x01 else 4


def segment(toggle: int, data: bytes, last: bool, *, server: bool) -> bytes:
    """A segment frame (upload segment response from a server, download segment request from a client)."""
    n = 7 - len(data)
    cs = SCS_UPLOAD_SEGMENT if server else CCS_DOWNLOAD_SEGMENT
    return bytes([(cs << 5) | (toggle << 4) | (n << 1) | int(last)]) + bytes(data).ljust(7, b"\0")


#: CiA 301 abort codes and their meaning.
ABORT_CODES = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "client/server command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write only object",
    0x06010002: "attempt to write a read only object",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "number and length of mapped objects exceed the PDO length",
    0x06040043: "general parameter incompatibility",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed due to a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length of service parameter too high",
    0x06070013: "data type does not match, length of service parameter too low",
    0x06090011: "sub-index does not exist",
    0x06090030: "invalid value for parameter",
    0x06090031: "value of parameter written too high",
    0x06090032: "value of parameter written too low",
    0x06090036: "maximum value is less than minimum value",
    0x060A0023: "resource not available: SDO connection",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored because of local control",
    0x08000022: "data cannot be transferred or stored because of the present device state",
    0x08000023: "object dictionary dynamic generation fails or no object dictionary is present",
    0x08000024: "no data available",
}
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_LENGTH = 0x06070010
ABORT_TOO_LONG = 0x06070012
ABORT_TOO_SHORT = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_STATE = 0x08000022


def abort_text(code: int) -> str:
    """An abort code's meaning."""
    return ABORT_CODES.get(code, "unknown abort code")


# --------------------------------------------------------------------------- EMCY

#: The EMCY frame: error code, error register (object 0x1001), 5 manufacturer-specific bytes.
Emcy = Struct("code" / Int16ul, "register" / Int8ul, "data" / Bytes(5))

ERR_RESET = 0x0000
ERR_GENERIC = 0x1000
ERR_OVER_CURRENT = 0x2310
ERR_UNDER_VOLTAGE = 0x3220
ERR_SOFTWARE = 0x6100
ERR_CAN_OVERRUN = 0x8110
ERR_CAN_PASSIVE = 0x8120
ERR_HEARTBEAT = 0x8130
ERR_BUS_OFF_RECOVERED = 0x8140
ERR_PROTOCOL = 0x8200
ERR_PDO_LENGTH = 0x8210
ERR_RPDO_TIMEOUT = 0x8250
ERR_MOTOR_BLOCKED = 0x7121

#: Error register bits.
REG_GENERIC = 0x01
REG_CURRENT = 0x02
REG_VOLTAGE = 0x04
REG_TEMPERATURE = 0x08
REG_COMMUNICATION = 0x10
REG_PROFILE = 0x20
REG_MANUFACTURER = 0x80

#: Exact codes first, then their groups (CiA 301 table "emergency error codes", CiA 402 for motors).
EMCY_CODES = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2310: "continuous over current",
    0x3210: "over voltage",
    0x3220: "under voltage",
    0x6100: "internal software",
    0x7121: "motor blocked",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
}
EMCY_GROUPS = {
    0x10: "generic", 0x20: "current", 0x21: "current, device input side", 0x22: "current inside the device",
    0x23: "current, device output side", 0x30: "voltage", 0x31: "mains voltage", 0x32: "voltage inside the device",
    0x33: "output voltage", 0x40: "temperature", 0x41: "ambient temperature", 0x42: "device temperature",
    0x50: "device hardware", 0x60: "device software", 0x61: "internal software", 0x62: "user software",
    0x63: "data set", 0x70: "additional modules", 0x80: "monitoring", 0x81: "communication",
    0x82: "protocol error", 0x90: "external error", 0xF0: "additional functions", 0xFF: "device specific",
}


def emcy_text(code: int) -> str:
    """An EMCY error code's meaning (exact where known, else its group)."""
    if code in EMCY_CODES:
        return EMCY_CODES[code]
    group = EMCY_GROUPS.get(code >> 8) or EMCY_GROUPS.get((code >> 12) << 4)
    return f"{group} (0x{code:04X})" if group else f"0x{code:04X}"


def emcy_frame(code: int, register: int, data: bytes = bytes(5)) -> bytes:
    """An EMCY frame's 8 data bytes."""
    return Emcy.build({"code": code, "register": register, "data": bytes(data).ljust(5, b"\0")[:5]})


__all__ = [
    "ABORT_CODES", "BOOTUP", "EMCY_CODES", "Emcy", "FUNCTIONS", "Heartbeat", "InitiateCommand", "NMT_COMMANDS",
    "NmtCommand", "OPERATIONAL", "PRE_OPERATIONAL", "STATE_NAMES", "STOPPED", "CobId", "SdoAbort", "SdoInitiate",
    "SdoSegment", "SegmentCommand", "abort_text", "classify", "emcy_frame", "emcy_text", "expedited_download_request",
    "expedited_size", "expedited_upload_response", "initiate", "nmt_command", "parse_initiate", "sdo_abort",
    "segment", "specifier", "state_name",
]
