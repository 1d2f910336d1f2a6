"""Checksums used by the wire formats, built with crcmod where the CRC is a standard one."""

from __future__ import annotations

import crcmod
import crcmod.predefined

#: CRC-16/BUYPASS (poly 0x8005, init 0, not reflected): Dynamixel Protocol 2.0.
#: Note crcmod's "crc-16" is the reflected CRC-16/ARC and would be wrong here.
crc16_buypass = crcmod.predefined.mkPredefinedCrcFun("crc-16-buypass")

#: CRC-32/MPEG-2 (poly 0x04C11DB7, init 0xFFFFFFFF, not reflected, no xorout): Vel2d frames.
crc32_mpeg2 = crcmod.predefined.mkPredefinedCrcFun("crc-32-mpeg")


def dynamixel1_checksum(body: bytes) -> int:
    """Protocol 1.0 checksum: one's complement of the byte sum of ID..last parameter."""
    # Too small for a library: a sum and an inversion.
    return ~sum(body) & 0xFF


def raw_crc_routine(crcfun):
    """Return ``(routine, table)`` so hot loops can call ``routine(data, 0, table)``.

    crcmod wraps its C routine in a Python closure that stores the routine and
    its table as default arguments; calling the routine directly saves one
    Python frame per packet, which is a third of a decoder's per-packet cost.
    Valid for CRCs with init 0 and xorout 0 (the closure then only forwards).
    """
    _init, table, routine = crcfun.__defaults__
    return routine, table


def sick_crc16(data: bytes) -> int:
    """SICK LMS 2xx telegram CRC-16 (generator 0x8005), over STX .. the byte before the CRC.

    Hand-written because no catalogue CRC matches: the register is shifted
    before the byte is mixed in, and the mixed-in word carries the previous
    byte in its high half (spec sheet laser_scanners.md §2.3), so crcmod's
    table-driven CRCs cannot reproduce it.
    """
    crc = prev = 0
    for b in data:
        carry = crc & 0x8000
        crc = (crc << 1) & 0xFFFF
        if carry:
            crc ^= 0x8005
        crc ^= (prev << 8) | b
        prev = b
    return crc


def scip_sum(data: bytes) -> int:
    """Hokuyo SCIP 2.0 line checksum character: low 6 bits of the byte sum, plus 0x30."""
    # Too small for a library: a sum and a mask.
    return (sum(data) & 0x3F) + 0x30


#: CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF, not reflected; check "123456789" = 0x4B): the
#: AUTOSAR E2E profile 1 CRC, protecting the rover board's CAN velocity setpoint. crcmod's ``initCrc`` is
#: the initial register XORed with ``xorOut``, hence 0x00 for init 0xFF.
crc8_sae_j1850 = crcmod.mkCrcFun(0x11D, initCrc=0x00, rev=False, xorOut=0xFF)
