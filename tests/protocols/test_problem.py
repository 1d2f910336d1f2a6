"""One type for what decoders drop: every decoder and check reports damage as protocols.problem.Problem."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

import hilbench
from hilbench.protocols import board_can as bc
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as dxl1
from hilbench.protocols import rfc2217, scip, vel2d
from hilbench.protocols import rplidar as rp
from hilbench.protocols import sick_lms200 as lms
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols.problem import Problem


def problems(items: list) -> list[Problem]:
    return [i for i in items if type(i) is Problem]


def test_the_dynamixel_decoders_keep_time_and_bytes():
    good = dxl.instruction_packet(1, dxl.Instruction.PING)
    bad = good[:-1] + bytes((good[-1] ^ 0xFF,))
    (p,) = problems(dxl.Decoder().feed(bad + good, t=2.5))
    assert (p.kind, p.raw, p.detail, p.t) == ("crc", bad, "mismatched checksum", 2.5)
    good1 = dxl1.build(1, dxl1.Instruction1.PING)
    bad1 = good1[:-1] + bytes((good1[-1] ^ 0xFF,))
    (p,) = problems(dxl1.Decoder1().feed(bad1 + good1, t=1.0))
    assert (p.kind, p.raw, p.t) == ("checksum", bad1, 1.0)


def test_the_scanner_decoders_report_dropped_bytes():
    (p,) = problems(rp.RequestDecoder().feed(b"\x01\x02" + bytes((rp.SYNC, 0x25))))
    assert (p.kind, p.raw) == ("garbage", b"\x01\x02")
    (p,) = problems(lms.Decoder().feed(b"\x99\x98"))
    assert (p.kind, p.raw) == ("garbage", b"\x99\x98")
    (p,) = problems(scip.ReplyDecoder(max_reply=100).feed(b"x" * 200))
    assert (p.kind, p.raw, p.detail) == ("overlong", b"x" * 64, "200 bytes without an end")


def test_telnet_counts_what_it_drops():
    dec = rfc2217.TelnetDecoder()
    (p,) = problems(dec.feed(b"\xff\xf0ok"))
    assert (p.kind, p.count, p.detail, p.raw) == ("stray", 2, "stray IAC SE", b"")
    assert dec.dropped == 2


def test_trace_decoders_report_lines_and_words():
    (p,) = problems(ts.TextDecoder().feed(b"no stamp here\n"))
    assert (p.kind, p.raw) == (ts.UNREADABLE, b"no stamp here") and p.detail
    dec = tb.WordDecoder()
    words = tb.encode_payloads(np.array([tb.time_payload(1 << 20), tb.stamp_payload(1, True, 1 << 20)], np.uint32))
    items = dec.feed(words[:-2] + words)  # the first stamp word loses its last two bytes
    (p,) = problems(items)
    assert (p.kind, p.count, p.raw) == ("broken_word", 1, b"")
    assert p.t_us is not None and type(p.t_us) is int


def test_checks_of_single_frames_say_what_they_expected():
    short = vel2d.decode(vel2d.build(0.1, 0.0, 0.0)[:27])
    assert (short.kind, short.detail) == ("length", vel2d.MSG_INSUFFICIENT)
    frame = bytearray(bc.build_setpoint(0.1, 0.0, 0.0, 1))
    frame[7] ^= 0x01
    p = bc.check_setpoint(bytes(frame))
    assert type(p) is Problem and p.kind == "checksum" and p.got == frame[7] and p.expected == frame[7] ^ 0x01


def test_no_module_defines_a_problem_type_of_its_own():
    root = Path(hilbench.__file__).parent
    own = [f"{path.relative_to(root)}:{m[1]}" for path in sorted(root.rglob("*.py"))
           for m in re.finditer(r"^\s*class (\w*Problem\w*|BadLine)\b", path.read_text(encoding="utf-8"), re.M)]
    assert own == ["protocols/problem.py:Problem"]
