"""The protocol decoders as rough-input targets (:mod:`hilbench.fuzzing`): how to drive each with bytes,
its fastest line, and clean traffic of its kind to mutate. Registered in ``pyproject.toml``."""

from __future__ import annotations

import random

from hilbench.fuzzing import Counting, FuzzTarget
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols import dynamixel_protocol1 as dxl1
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols import vel2d
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp_stream import StreamDecoder

#: A Dynamixel bus at 4.5 Mbaud (the fastest Baud Rate code the servos of both protocols share), 8N1.
DYNAMIXEL_LINE = 4_500_000 / 10
#: The rover board's UART at its fastest, 12.5 Mbit/s (STM32F767 USART at 108 MHz / 8), 8N1.
BOARD_LINE = 12_500_000 / 10


# --------------------------------------------------------------------------- Dynamixel 2.0


def dynamixel_traffic(rng: random.Random, size: int) -> bytes:
    """A servo bus's traffic: Sync Reads of present position with their replies, Sync Writes, Reads,
    Pings, now and then an error status or a device that stays silent."""
    out = bytearray()
    ids = list(range(1, rng.randrange(2, 21)))
    while len(out) < size:
        kind = rng.random()
        if kind < 0.5:
            out += dxl.instruction_packet_unstuffed(dxl.BROADCAST_ID, dxl.Instruction.SYNC_READ,
                                                    bytes((132, 0, 4, 0, *ids)))
            for i in ids:
                if rng.random() > 0.02:
                    out += dxl.status_packet(i, 0x80 if rng.random() < 0.01 else 0, rng.randbytes(4))
        elif kind < 0.8:
            out += dxl.instruction_packet_unstuffed(dxl.BROADCAST_ID, dxl.Instruction.SYNC_WRITE, bytes(
                (116, 0, 4, 0)) + b"".join(bytes((i,)) + rng.randbytes(4) for i in ids))
        elif kind < 0.95:
            i = rng.choice(ids)
            out += dxl.instruction_packet(i, dxl.Instruction.READ, bytes((146, 0, 1, 0)))
            out += dxl.status_packet(i, 0, rng.randbytes(1))
        else:
            i = rng.choice(ids)
            out += dxl.instruction_packet(i, dxl.Instruction.PING) + dxl.status_packet(i, 0, b"\x1e\x04\x2a")
    return bytes(out)


def _dynamixel() -> Counting:
    dec = dxl.Decoder()
    return Counting(dec.feed, dec.flush, lambda i: not isinstance(i, Problem), lambda: dec.bytes_skipped)


DYNAMIXEL = FuzzTarget("dynamixel", "Dynamixel Protocol 2.0 decoder", _dynamixel, DYNAMIXEL_LINE,
                          "4.5 Mbaud RS-485 bus", dynamixel_traffic)


# --------------------------------------------------------------------------- Dynamixel 1.0


def dynamixel1_traffic(rng: random.Random, size: int) -> bytes:
    """A Protocol 1.0 bus: Reads with their statuses, Writes, Sync Writes, Pings."""
    out = bytearray()
    while len(out) < size:
        i = rng.randrange(0, 0xFE)
        kind = rng.random()
        if kind < 0.5:
            out += dxl1.build(i, dxl1.Instruction1.READ, bytes((36, 2)))
            out += dxl1.build(i, 0, rng.randbytes(2))
        elif kind < 0.8:
            out += dxl1.build(dxl1.BROADCAST_ID, dxl1.Instruction1.SYNC_WRITE,
                              bytes((30, 2)) + b"".join(bytes((k,)) + rng.randbytes(2) for k in range(1, 7)))
        else:
            out += dxl1.build(i, dxl1.Instruction1.PING) + dxl1.build(i, 0)
    return bytes(out)


def _dynamixel1() -> Counting:
    dec = dxl1.Decoder1()
    return Counting(dec.feed, dec.flush, lambda i: isinstance(i, dxl1.Packet1), lambda: dec.bytes_skipped)


DYNAMIXEL1 = FuzzTarget("dynamixel1", "Dynamixel Protocol 1.0 decoder", _dynamixel1, DYNAMIXEL_LINE,
                           "4.5 Mbaud RS-485 bus", dynamixel1_traffic)


# --------------------------------------------------------------------------- Vel2d


def vel2d_traffic(rng: random.Random, size: int) -> bytes:
    """Velocity frames back to back, as a host streaming commands sends them."""
    frames = []
    while len(frames) * vel2d.FRAME_SIZE < size:
        frames.append(vel2d.build(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-3, 3)))
    return b"".join(frames)


class _Vel2dReader:
    """The board's receiver: idle-line framing on a continuous line, then the CRC check."""

    def __init__(self, baud: int = 12_500_000) -> None:
        self.framer = vel2d.IdleLineFramer(baud)
        self.t = 0.0
        self.ok = 0
        self.bad = 0

    def _check(self, chunks) -> None:
        for raw, _ in chunks:
            if isinstance(vel2d.decode(raw), vel2d.Velocity):
                self.ok += 1
            else:
                self.bad += len(raw)

    def feed(self, data: bytes) -> None:
        self._check(self.framer.feed(data, self.t))
        self.t += len(data) * self.framer.char_time

    def finish(self) -> None:
        self._check(self.framer.flush())

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.bad


VEL2D = FuzzTarget("vel2d", "Vel2d velocity frames (idle-line framing, CRC-32/MPEG-2)", _Vel2dReader,
                      BOARD_LINE, "12.5 Mbit/s UART", vel2d_traffic)


# --------------------------------------------------------------------------- trace stamps

NAMES = ["IDLE", "hal_fetch", "wheel_ctrl", "odometry", "pose_control", "tsink", "pid"]


def schedule(rng: random.Random, t: int = 0):
    """Stamps of a plausible FreeRTOS schedule, endlessly: ``(name index, µs, begin)``. IDLE runs between
    task slices; now and then a function scope inside a slice, or tsink preempting it."""
    while True:
        task = rng.randrange(1, 5)
        t += rng.randrange(20, 400)
        yield 0, t, False
        yield task, t, True
        k = rng.random()
        if k < 0.3:
            t += rng.randrange(1, 10)
            yield 6, t, True  # a function scope ("pid") inside the slice
            t += rng.randrange(1, 20)
            yield 6, t, False
        elif k < 0.4:
            t += rng.randrange(1, 10)
            yield task, t, False  # tsink preempts the slice
            yield 5, t, True
            t += rng.randrange(1, 10)
            yield 5, t, False
            yield task, t, True
        t += rng.randrange(5, 30)
        yield task, t, False
        yield 0, t, True


def text_traffic(rng: random.Random, size: int) -> bytes:
    """A board's text output: stamp lines in either dialect, a log line now and then, a run-time report."""
    out = bytearray()
    dialect = rng.choice(["branch", "thesis"])
    stamps = schedule(rng, rng.randrange(1 << 20))
    t = 0
    while len(out) < size:
        k = rng.random()
        if k < 0.989:
            name, t, begin = next(stamps)
            out += ts.format_stamp(NAMES[name], t, begin, dialect)
        elif k < 0.999:
            out += ts.format_log(t / 1e6, rng.choice(["INFO", "ERROR"]), f"[recv vel] [{rng.random():f}]")
        else:
            out += _report(rng, t)
    return bytes(out)


def binary_traffic(rng: random.Random, size: int, *, table: bool = True) -> bytes:
    """hilbench's binary stamp words with their name table, TIME, DROPS and CHECK words."""
    out = bytearray(tb.name_table(dict(enumerate(NAMES))) if table else b"")
    ins = tb.CheckInserter()
    payloads = [tb.control_payload(tb.Op.WINDOW_START, 1)]
    ins.restart()
    stamps = schedule(rng)
    hi = -1
    while len(out) + 4 * len(payloads) < size:
        name, t, begin = next(stamps)
        if t >> tb.HI_SHIFT != hi:
            hi = t >> tb.HI_SHIFT
            payloads.append(tb.time_payload(t))
        if rng.random() < 0.001:  # an overflow now and then: DROPS, then TIME to unwrap again
            payloads.append(tb.control_payload(tb.Op.DROPS, rng.randrange(1, 100)))
            payloads.append(tb.time_payload(t))
        payloads.append(tb.stamp_payload(name, begin, t))
    body = ins.add_list(payloads) + ins.close() + [tb.control_payload(tb.Op.WINDOW_STOP, 1)]
    return bytes(out + tb.encode_payloads(body))


def stream_traffic(rng: random.Random, size: int) -> bytes:
    """Text and binary on one UART as the board sends them in binary mode: windows of words after
    their name table, log lines between the words, a run-time report after each window."""
    out = bytearray()
    while len(out) < size:
        window = rng.randrange(min(16_384, max(64, size // 8)), min(131_072, max(128, size // 2)))
        out += tb.name_table(dict(enumerate(NAMES)))
        words = binary_traffic(rng, window, table=False)
        pos = 0
        while pos < len(words):
            n = 4 * rng.randrange(16, 512)
            out += words[pos : pos + n]
            pos += n
            if rng.random() < 0.2:
                out += ts.format_log(pos / 1e6, "INFO", f"[recv vel] [{rng.random():f} 0.0 0.0]")
        out += _report(rng, pos)
    return bytes(out)


def _report(rng: random.Random, t: int) -> bytes:
    """The run-time statistics block a board prints after a window."""
    rows = tuple(ts.RuntimeRow(n, rng.randrange(1, 10_000), 0) for n in NAMES[:6])
    tasks = tuple(ts.TaskRow(n, "B", 24, 400, k + 1) for k, n in enumerate(NAMES[:6]))
    return ts.format_report(ts.RuntimeReport(195_696, t // 50, rows, tasks, "output took", t, "%%", True))


def _units(item) -> int:
    """Good units of a decoded item: the stamps of a batch, one for any other good item, none for damage."""
    if type(item) is ts.StampBatch:
        return item.count
    return 0 if type(item) is Problem else 1


def _text() -> Counting:
    dec = ts.TextDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.parse_errors)


def _binary() -> Counting:
    dec = tb.WordDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.broken_words)


def _stream() -> Counting:
    dec = StreamDecoder()
    return Counting(dec.feed_batch, dec.flush, _units, lambda: dec.text.parse_errors + dec.words.broken_words)


TRACESTAMP_TEXT = FuzzTarget("tracestamp-text", "trace stamps as text (stamp lines, logs, reports)", _text,
                                BOARD_LINE, "12.5 Mbit/s UART", text_traffic)
TRACESTAMP_BINARY = FuzzTarget("tracestamp-binary", "binary trace stamp words", _binary, BOARD_LINE,
                                  "12.5 Mbit/s UART", binary_traffic)
TRACESTAMP_STREAM = FuzzTarget("tracestamp-stream", "text and binary stamps mixed on one UART", _stream,
                                  BOARD_LINE, "12.5 Mbit/s UART", stream_traffic)

__all__ = ["BOARD_LINE", "DYNAMIXEL", "DYNAMIXEL1", "DYNAMIXEL_LINE", "TRACESTAMP_BINARY", "TRACESTAMP_STREAM",
           "TRACESTAMP_TEXT", "VEL2D", "binary_traffic", "dynamixel1_traffic", "dynamixel_traffic", "stream_traffic",
           "text_traffic", "vel2d_traffic"]
