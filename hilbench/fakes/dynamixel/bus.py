"""The emulated devices of one Dynamixel RS-485 bus, as one party on a serial line.

Every real servo parses the line on its own; doing that twenty times over in
Python would cost twenty decodes per packet, so the bus decodes once and
hands each request to the devices it addresses. What the devices answer goes
back on the line in the order the protocol prescribes (ascending IDs for a
broadcast Ping, list order for Sync/Bulk reads, one combined packet for Fast
reads), each after its Return Delay Time when the line is paced.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from itertools import repeat
from typing import ClassVar

from hilbench.fakes.dynamixel.servo import Servo
from hilbench.fakes.servo_bus import ServoBusBase
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.dynamixel import BROADCAST_ID, ErrorNumber, InstructionPacket
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814
from hilbench.protocols.problem import Problem

log = logging.getLogger(__name__)

#: What happens to a Sync/Bulk read chain after a device that does not answer.
CHAIN_POLICIES = ("continue", "stall")
#: What a Fast read reply looks like when a listed device does not answer.
FAST_MISSING_POLICIES = ("truncate", "drop", "silent")


class DynamixelBus(ServoBusBase):
    """Emulated Dynamixel devices sharing one line.

    Policies for what the e-Manual leaves open: ``chain_policy`` (does a Sync/
    Bulk read chain go on after a silent device), ``fast_missing`` (the shape of
    a Fast read reply lacking a device), ``fast_read`` (per-ID override of
    whether a device answers Fast reads; by default X-series models do and
    MX(2.0) models, which the e-Manual does not list, stay silent).
    ``inter_byte_timeout`` drops a partial instruction when the line stays
    quiet longer than that (1.5 ms on real devices; None disables it), which
    is how devices recover from a corrupted LENGTH.
    """

    status_frame: ClassVar = staticmethod(dxl.status_packet)
    protocol_type: ClassVar[int | None] = 2
    checksum_size: ClassVar = 2

    def __init__(
        self,
        servos: list[Servo],
        *,
        name: str = "dynamixel",
        chain_policy: str = "continue",
        fast_missing: str = "truncate",
        fast_read: dict[int, bool] | None = None,
        strict_stuffing: bool = False,
        inter_byte_timeout: float | None = 0.0015,
        reply_crc_errors: bool = True,
    ) -> None:
        if chain_policy not in CHAIN_POLICIES:
            raise ValueError(f"chain_policy must be one of {CHAIN_POLICIES}")
        if fast_missing not in FAST_MISSING_POLICIES:
            raise ValueError(f"fast_missing must be one of {FAST_MISSING_POLICIES}")
        super().__init__(servos, name=name)
        self.chain_policy = chain_policy
        self.fast_missing = fast_missing
        self.fast_read = dict(fast_read or {})
        self.reply_crc_errors = reply_crc_errors
        self.decoder = dxl.Decoder(strict_stuffing=strict_stuffing, inter_byte_timeout=inter_byte_timeout)
        self._handlers: dict[int, Callable[[InstructionPacket, float, int | None, list[Servo]], None]] = {
            I.PING: self._ping,
            I.READ: self._read,
            I.WRITE: self._write,
            I.REG_WRITE: self._write,
            I.ACTION: self._simple,
            I.FACTORY_RESET: self._simple,
            I.REBOOT: self._simple,
            I.CLEAR: self._simple,
            I.BACKUP: self._simple,
            I.SYNC_READ: self._multi_read,
            I.BULK_READ: self._multi_read,
            I.FAST_SYNC_READ: self._fast_read,
            I.FAST_BULK_READ: self._fast_read,
            I.SYNC_WRITE: self._multi_write,
            I.BULK_WRITE: self._multi_write,
        }

    # ------------------------------------------------------------------ receiving

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        port = self.port
        # Paced lines deliver a chunk when its last byte is in; its first came earlier.
        t_first = t - len(data) * 10 / baud if port is not None and port.paced and baud else t
        for item in self.decoder.feed(data, t, t_first):
            if type(item) is InstructionPacket:
                self._dispatch(item, t, baud)
            elif type(item) is Problem and item.kind == "crc":
                self._crc_error(item, t, baud)

    def _dispatch(self, pkt: InstructionPacket, t: float, baud: int | None) -> None:
        self.stats.requests[pkt.name] += 1
        hearing = self._hearing(t, baud)
        problem = dxl.check_instruction(pkt)
        if problem:
            self.stats.invalid_received += 1
            if pkt.id != BROADCAST_ID:
                err = ErrorNumber.INSTRUCTION_ERROR if "unknown" in problem else ErrorNumber.DATA_LENGTH_ERROR
                for s in hearing:
                    if s.id == pkt.id and s.status_return_level >= 2:
                        self._send([(s, s.error_byte(err), b"", s.id)], t)
            return
        self._handlers[pkt.instruction](pkt, t, baud, hearing)

    def _crc_error(self, problem: Problem, t: float, baud: int | None) -> None:
        """A unicast instruction that failed its CRC check gets a CRC Error status."""
        raw = problem.raw
        self.stats.crc_errors_received += 1
        if not self.reply_crc_errors or len(raw) < 10 or raw[7] == dxl.STATUS:
            return
        for s in self._hearing(t, baud):
            if s.id == raw[4] and s.status_return_level >= 2:
                self._send([(s, s.error_byte(ErrorNumber.CRC_ERROR), b"", s.id)], t)

    # ------------------------------------------------------------------ sending

    @staticmethod
    def _answers(s: Servo, inst: int) -> bool:
        """Status Return Level: 0 = Ping only, 1 = Ping and reads, 2 = everything."""
        level = s.status_return_level
        if inst == I.PING:
            return True
        if inst in (I.READ, I.SYNC_READ, I.BULK_READ, I.FAST_SYNC_READ, I.FAST_BULK_READ):
            return level >= 1
        return level >= 2

    # ------------------------------------------------------------------ instructions

    def _targets(self, pkt: InstructionPacket, hearing: list[Servo]) -> tuple[list[Servo], list[Servo]]:
        """(devices that execute and reply, devices that execute silently via Secondary ID)."""
        if pkt.id == BROADCAST_ID:
            return [], hearing
        primary = [s for s in hearing if s.id == pkt.id]
        shadow = [s for s in hearing if s.secondary_id == pkt.id and s not in primary]
        return primary, shadow

    def _ping(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        if pkt.id == BROADCAST_ID:
            ordered = sorted(hearing, key=lambda s: s.id)
            self._send([(s, s.error_byte(), s.ping(), s.id) for s in ordered], t)
        else:
            self._send([(s, s.error_byte(), s.ping(), s.id) for s in hearing if s.id == pkt.id], t)

    def _read(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        if pkt.id == BROADCAST_ID:
            return  # a broadcast Read is not executed
        address, length = _u16s(pkt.params)
        replies = []
        for s in hearing:
            if s.id == pkt.id:
                err, data = s.read(address, length, t)
                if self._answers(s, I.READ):
                    replies.append((s, s.error_byte(err), data, s.id))
        self._send(replies, t)

    def _write(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        address = pkt.params[0] | pkt.params[1] << 8
        data = pkt.params[2:]
        primary, shadow = self._targets(pkt, hearing)
        replies = []
        for s in primary + shadow:
            reply_id = s.id  # an ID change answers from the old ID
            op = s.write if pkt.instruction == I.WRITE else s.reg_write
            err = op(address, data, t)
            if s in primary and self._answers(s, pkt.instruction):
                replies.append((s, s.error_byte(err), b"", reply_id))
        self._send(replies, t)

    def _simple(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        """Action, Factory Reset, Reboot, Clear, Backup: execute, answer a unicast."""
        primary, shadow = self._targets(pkt, hearing)
        inst = pkt.instruction
        replies = []
        for s in primary + shadow:
            reply_id = s.id
            if inst == I.ACTION:
                err = s.action(t)
            elif inst == I.REBOOT:
                err = s.reboot(t)
            elif inst == I.FACTORY_RESET:
                # From firmware 42 on, a broadcast reset of everything is ignored.
                if pkt.id == BROADCAST_ID and pkt.params[0] == 0xFF and s.firmware >= 42:
                    continue
                err = s.factory_reset(pkt.params[0], t)
            elif inst == I.CLEAR:
                err = s.clear(pkt.params, t)
            else:
                err = s.backup(pkt.params, t)
            if s in primary and self._answers(s, inst):
                replies.append((s, s.error_byte(err), b"", reply_id))
        self._send(replies, t)

    def _read_list(self, pkt: InstructionPacket) -> list[tuple[int, int, int]]:
        """(id, address, length) for each device a Sync/Bulk/Fast read lists, in order."""
        p = pkt.params
        if pkt.instruction in (I.SYNC_READ, I.FAST_SYNC_READ):
            address, length = _u16s(p)
            return [(i, address, length) for i in p[4:]]
        return [(p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8) for k in range(0, len(p), 5)]

    def _multi_read(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        by_id = {s.id: s for s in hearing}
        replies = []
        stall = self.chain_policy == "stall"
        p = pkt.params
        if pkt.instruction == I.SYNC_READ:  # one address and length for all: the hot path of control loops
            address, length = _u16s(p)
            wanted = zip(p[4:], repeat(address), repeat(length))
        else:
            wanted = self._read_list(pkt)
        for dxl_id, address, length in wanted:
            s = by_id.get(dxl_id)
            if s is None or s.status_return_level < 1:  # _answers() of a read
                if stall:
                    break
                continue
            err, data = s.read(address, length, t)
            replies.append((s, s.error_byte(err), data, dxl_id))
        self._send(replies, t)

    def _supports_fast(self, s: Servo) -> bool:
        return self.fast_read.get(s.id, s.model.fast_read)

    def _fast_read(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        by_id = {s.id: s for s in hearing}
        wanted = self._read_list(pkt)
        slices: list[tuple[int, int, bytes]] = []
        missing = False
        first: Servo | None = None
        delay = 0.0
        for dxl_id, address, length in wanted:
            s = by_id.get(dxl_id)
            if s is None or not self._supports_fast(s) or not self._answers(s, pkt.instruction):
                missing = True
                if self.fast_missing != "drop":
                    break
                continue
            if s.faults.take_drop():
                self.stats.dropped_replies += 1
                missing = True
                if self.fast_missing != "drop":
                    break
                continue
            err, data = s.read(address, length, t)
            if err:
                data = bytes(length)  # a slice keeps its size; ERR tells the host
            slices.append((s.id, s.error_byte(err), data))
            delay += s.faults.delay
            first = first or s
        if first is None or (missing and self.fast_missing == "silent"):
            return
        raw = dxl.build_fast_reply(slices)
        if missing and self.fast_missing == "truncate":
            # The first device announces the whole list's length; the rest never comes.
            full = 1 + sum(length + 4 for _, _, length in wanted)
            raw = raw[:5] + bytes((full & 0xFF, full >> 8)) + raw[7:]
        if any(self.servo(i).faults.take_corrupt() for i, _, _ in slices):
            raw = raw[:-2] + bytes((raw[-2] ^ 0xFF, raw[-1]))
            self.stats.corrupted_replies += 1
        port = self.port
        if port is not None:
            gap = (first.return_delay if port.paced else 0.0) + delay
            port.transmit(raw, t=t, gap=gap, baud=first.baud)
            self.stats.replies += 1

    def _multi_write(self, pkt: InstructionPacket, t: float, baud: int | None, hearing: list[Servo]) -> None:
        by_id: dict[int, list] = {}  # id -> the bound write_unanswered of each device answering to it
        for s in hearing:
            write = s.write_unanswered
            sid = s.id
            by_id.setdefault(sid, []).append(write)
            second = s.secondary_id
            if second is not None and second != sid:
                by_id.setdefault(second, []).append(write)
        p = pkt.params
        if pkt.instruction == I.SYNC_WRITE:
            address, length = _u16s(p)
            for k in range(4, len(p), length + 1):
                for write in by_id.get(p[k], ()):
                    write(address, p[k + 1 : k + 1 + length], t)
        else:
            k = 0
            while k < len(p):
                length = p[k + 3] | p[k + 4] << 8
                for write in by_id.get(p[k], ()):
                    write(p[k + 1] | p[k + 2] << 8, p[k + 5 : k + 5 + length], t)
                k += 5 + length


def _u16s(p: bytes) -> tuple[int, int]:
    """The two little-endian u16 at the start of Read/Sync Read parameters (address, length)."""
    return p[0] | p[1] << 8, p[2] | p[3] << 8
