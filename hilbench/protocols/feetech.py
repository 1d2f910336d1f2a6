"""Feetech STS/SMS/SCS serial-bus servos: instruction set, error bits and value encodings.

Feetech's packets are byte for byte Dynamixel Protocol 1.0 packets
(spec sheet ``servo_buses.md`` §4.1)::

    FF FF | ID | LEN | INST (ERR in a status) | PARAMS... | CHECKSUM

so the layout, the fast builder and the stream decoder are
:mod:`hilbench.protocols.dynamixel_protocol1`'s (one definition of the
format). What differs is what the bytes mean: SYNC_READ is 0x82 and every
listed servo answers with its own status, in request order; a broadcast PING
is answered by every servo; values are little-endian (STS/SMS, "END" 0) or
big-endian (SCS, "END" 1), with sign-magnitude encodings whose sign bit
depends on the register (:func:`sign_magnitude`).
"""

from __future__ import annotations

from enum import IntEnum

from construct import Struct

from hilbench.protocols.dynamixel_protocol1 import (
    BROADCAST_ID,
    HEADER,
    Decoder1,
    Packet,
    Packet1,
    SyncReadParams,
    build,
    frame,
    parse,
)
from hilbench.protocols.dynamixel_protocol1 import PARAMS as P1_PARAMS

#: The highest servo ID (scservo_sdk's MAX_ID).
MAX_ID = 0xFC


class Instruction(IntEnum):
    """Feetech instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


INSTRUCTION_NAMES: dict[int, str] = {i.value: i.name.lower() for i in Instruction}

#: Status ERR bits (scservo_sdk getRxPacketError).
ERROR_BITS: dict[int, str] = {
    0x01: "input voltage",
    0x02: "angle sensor",
    0x04: "overheat",
    0x08: "overcurrent",
    0x20: "overload",
}

#: Parameter layouts: Protocol 1.0's for every instruction Feetech shares with it (same codes, same
#: parameters); SYNC_READ has Feetech's own code with the layout of the USB2AX's.
PARAMS: dict[int, Struct] = {
    i: SyncReadParams if i == Instruction.SYNC_READ else P1_PARAMS[i] for i in Instruction
}


def build_instruction(packet_id: int, instruction: int, **fields) -> bytes:
    """Build an instruction from its named parameter fields."""
    return build(packet_id, instruction, PARAMS[instruction].build(fields))


def describe_error(err: int) -> str:
    """The ERR byte in words (``"ok"`` for 0)."""
    if not err:
        return "ok"
    names = [name for bit, name in ERROR_BITS.items() if err & bit]
    rest = err & ~sum(ERROR_BITS)
    if rest:
        names.append(f"bits 0x{rest:02x}")
    return ", ".join(names)


def sign_magnitude(value: int, sign_bit: int) -> int:
    """Encode ``value`` with ``sign_bit`` as the sign (LeRobot's encode_sign_magnitude)."""
    return (-value | (1 << sign_bit)) if value < 0 else value


def from_sign_magnitude(raw: int, sign_bit: int) -> int:
    """Decode a sign-magnitude register value."""
    bit = 1 << sign_bit
    return -(raw & (bit - 1)) if raw & bit else raw


__all__ = [
    "BROADCAST_ID",
    "ERROR_BITS",
    "HEADER",
    "INSTRUCTION_NAMES",
    "MAX_ID",
    "PARAMS",
    "Decoder1",
    "Instruction",
    "Packet",
    "Packet1",
    "build",
    "build_instruction",
    "describe_error",
    "frame",
    "from_sign_magnitude",
    "parse",
    "sign_magnitude",
]
