"""Vel2d frames: spec sheet §6.1 vectors, CRC pitfalls, the idle-line framer cases, and robustness."""

from __future__ import annotations

import math
import struct
import zlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hilbench.protocols import vel2d
from hilbench.protocols.checksums import crc32_mpeg2
from hilbench.protocols.problem import Problem
from hilbench.protocols.vel2d import IdleLineFramer, Velocity
from tests.stm32_vectors import crc32_mpeg2_bitwise


def stm32_word_mode_crc(data: bytes) -> int:
    """The STM32 CRC unit fed 32-bit words from a little-endian buffer: each 4-byte group enters byte-reversed."""
    swapped = b"".join(data[i : i + 4][::-1] for i in range(0, len(data), 4))
    return crc32_mpeg2_bitwise(swapped)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


VECTORS = {  # name: ((x, y, z), frame hex, crc, firmware units)
    "A": ((0.0, 0.0, 0.0), "00" * 24 + "3a7cacfb", 0xFBAC7C3A, (0.0, 0.0, 0.0)),
    "B": ((0.5, 0.0, 0.0), "000000000000e03f" + "00" * 16 + "6f0c4a8e", 0x8E4A0C6F, (500.0, 0.0, 0.0)),
    "C": ((0.1, -0.2, 0.3), "9a9999999999b93f9a9999999999c9bf333333333333d33fd51b8a0c", 0x0C8A1BD5,
          (100.0, -200.0, 0.3)),
    "D": ((0.0, 0.0, 1.0), "00" * 16 + "000000000000f03f" + "f6b5e9e4", 0xE4E9B5F6, (0.0, 0.0, 1.0)),
    "E": ((-0.25, 0.25, -0.5), "000000000000d0bf000000000000d03f000000000000e0bf9600cce4", 0xE4CC0096,
          (-250.0, 250.0, -0.5)),
}


def test_crc_check_values():
    assert crc32_mpeg2(b"123456789") == 0x0376E6E7
    assert crc32_mpeg2_bitwise(b"123456789") == 0x0376E6E7
    assert crc32_mpeg2(bytes(24)) == 0xFBAC7C3A


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_spec_vectors_build_and_decode(name):
    (x, y, z), frame_hex, crc, units = VECTORS[name]
    frame = h(frame_hex)
    assert vel2d.build(x, y, z) == frame
    assert vel2d.build_with_construct(x, y, z) == frame  # the construct layout agrees with the fast path
    got = vel2d.decode(frame)
    assert got == Velocity(x, y, z, crc)
    assert vel2d.parse(frame) == got
    assert got.firmware_units() == pytest.approx(units)


@pytest.mark.parametrize("name", sorted(VECTORS))
def test_frames_from_an_independent_crc_are_accepted(name):
    (x, y, z), _, _, _ = VECTORS[name]
    payload = struct.pack("<3d", x, y, z)
    frame = payload + struct.pack("<I", crc32_mpeg2_bitwise(payload))
    assert isinstance(vel2d.decode(frame), Velocity)


def test_b_prime_fails_crc_and_c_prime_is_short():
    b_prime = bytearray(h(VECTORS["B"][1]))
    b_prime[7] ^= 0x80
    got = vel2d.decode(bytes(b_prime))
    assert got == Problem("crc", bytes(b_prime), "crc mismatch!", expected=0x4C99698E, got=0x8E4A0C6F)
    c_prime = h(VECTORS["C"][1])[:27]
    short = vel2d.decode(c_prime)
    assert short.kind == "length" and short.detail == "parsing velocity failed: insufficient bytes received"
    with pytest.raises(vel2d.Vel2dError, match="CRC mismatch"):
        vel2d.parse(bytes(b_prime))
    with pytest.raises(vel2d.Vel2dError, match="expected 28 bytes"):
        vel2d.parse(c_prime)


@pytest.mark.parametrize(
    "name,word_mode,zlib_crc",
    [("A", 0xFBAC7C3A, 0xA3C1CA20), ("B", 0xD619A086, 0x15117CA3), ("C", 0x6DE624D2, 0xFACD19B3)],
)
def test_misconfigured_crcs_are_rejected(name, word_mode, zlib_crc):
    payload = h(VECTORS[name][1])[:24]
    assert stm32_word_mode_crc(payload) == word_mode  # the sheet's guard values, recomputed
    assert zlib.crc32(payload) == zlib_crc
    for wrong in {word_mode, zlib_crc} - {crc32_mpeg2(payload)}:
        got = vel2d.decode(payload + struct.pack("<I", wrong))
        assert isinstance(got, Problem) and got.kind == "crc"
    # A CRC over all 28 bytes has no constant residue: only recomputing over 0..23 is right.
    assert crc32_mpeg2(h(VECTORS[name][1])) != crc32_mpeg2(h(VECTORS["D"][1]))


BYTE = 10 / 115_200


def kinds(results):
    return [r.kind if isinstance(r, Problem) else "ok" for r in results]


def test_idle_line_framer_cases_of_the_spec():
    a, c = h(VECTORS["A"][1]), h(VECTORS["C"][1])
    # A and C back to back: the full buffer ends each frame.
    assert kinds(vel2d.frame_stream([(a + c, 0.0)])) == ["ok", "ok"]
    assert kinds(vel2d.frame_stream([(a, 0.0), (c, 28 * BYTE)])) == ["ok", "ok"]
    # One 0x00, then A with no gap: 28 bytes fail the CRC, then one byte is a length error.
    got = vel2d.frame_stream([(b"\x00" + a, 0.0)])
    assert kinds(got) == ["crc", "length"] and len(got[1].raw) == 1
    # C' (27 bytes), an idle gap, then A: one length error, then a valid frame.
    got = vel2d.frame_stream([(c[:27], 0.0), (a, 27 * BYTE + 2 * BYTE)])
    assert kinds(got) == ["length", "ok"]


def test_framer_event_times_and_gap_threshold():
    a = h(VECTORS["A"][1])
    f = IdleLineFramer(115_200)
    (raw, t_end), = f.feed(a, 1.0)
    assert raw == a and t_end == pytest.approx(1.0 + 28 * BYTE)  # buffer full: at the last byte
    assert f.feed(a[:10], 2.0) == []
    assert f.idle_deadline() == pytest.approx(2.0 + 11 * BYTE)
    assert f.poll(2.0 + 10.5 * BYTE) == []
    # A gap shorter than one character time does not end the frame.
    assert f.feed(a[10:], 2.0 + 10 * BYTE + 0.5 * BYTE)[0][0] == a
    # Bytes stamped too early queue behind those still on the wire.
    f.feed(a[:5], 3.0)
    f.feed(a[5:], 3.0)
    assert f.flush() == [] and f.pending == b""


@given(st.binary(max_size=200))
def test_decode_never_raises(data):
    result = vel2d.decode(data)
    assert isinstance(result, Velocity | Problem)


@given(st.floats(allow_nan=False), st.floats(allow_nan=False), st.floats(allow_nan=False))
def test_round_trip(x, y, z):
    got = vel2d.decode(vel2d.build(x, y, z))
    assert (got.x, got.y, got.z) == (x, y, z)
    assert crc32_mpeg2_bitwise(vel2d.build(x, y, z)[:24]) == got.crc


def test_nan_payload_is_still_a_frame():
    got = vel2d.decode(vel2d.build(math.nan, 0.0, 0.0))
    assert isinstance(got, Velocity) and math.isnan(got.x)
