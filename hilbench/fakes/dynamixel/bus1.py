"""The emulated devices of one Dynamixel Protocol 1.0 bus (AX, MX with 1.0 firmware) and its USB2AX adapter.

The bus decodes the line once (:class:`~hilbench.protocols.dynamixel_protocol1.Decoder1`)
and hands each instruction to the servos it addresses, as
:class:`~hilbench.fakes.dynamixel.bus.DynamixelBus` does for Protocol 2.0:

- PING, READ, WRITE, REG_WRITE/ACTION, RESET, SYNC_WRITE, BULK_READ (answered by
  MX servos only, in list order) with Status Return Level and Return Delay Time;
  nothing answers a broadcast, and a broadcast PING gets no reply (Protocol 1.0
  has none);
- ERR bits of Protocol 1.0: instruction, checksum (a unicast packet that fails
  its checksum), range, angle limit (a goal beyond the limits is clamped), and the
  servo's condition (input voltage outside its limits, overheating);
- with ``usb2ax`` (the default), the USB2AX adapter at ID 0xFD: its SYNC_READ
  (0x84) is answered with one status from ID 0xFD holding every listed servo's
  bytes in request order, all-0xFF for a servo that did not answer, as its
  firmware does (spec sheet ``servo_buses.md`` §2); it also answers PING and
  READ/WRITE of its own small table. Without it (a USB2Dynamixel), 0x84 goes
  unanswered.

:class:`Protocol1Bus` is also the base of Feetech's bus, whose framing is the same.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import ClassVar

from hilbench.fakes.servo_bus import ServoBusBase
from hilbench.protocols import dynamixel_protocol1 as p1
from hilbench.protocols.dynamixel import ErrorNumber
from hilbench.protocols.dynamixel_protocol1 import BROADCAST_ID, USB2AX_ID, Packet1
from hilbench.protocols.dynamixel_protocol1 import Instruction1 as I  # noqa: N814
from hilbench.protocols.problem import Problem

log = logging.getLogger(__name__)

#: Protocol 1.0 ERR bits for the servos' error numbers (Protocol 2.0 numbers, see TableServo).
P1_ERROR_BITS = {
    ErrorNumber.RESULT_FAIL: 0x40,
    ErrorNumber.INSTRUCTION_ERROR: 0x40,
    ErrorNumber.CRC_ERROR: 0x10,
    ErrorNumber.DATA_RANGE_ERROR: 0x08,
    ErrorNumber.DATA_LENGTH_ERROR: 0x08,
    ErrorNumber.DATA_LIMIT_ERROR: 0x02,
    ErrorNumber.ACCESS_ERROR: 0x08,
}
#: How long the USB2AX waits for each servo of its SYNC_READ (USART_TIMEOUT, 50 x 20 us).
USB2AX_TIMEOUT = 0.001


class Usb2ax:
    """The USB2AX adapter's own 18-byte table (model 16897, firmware 5, ID 0xFD, timeouts)."""

    name = "usb2ax"

    def __init__(self) -> None:
        self.mem = bytearray(18)
        self.mem[0:2] = p1.USB2AX_MODEL.to_bytes(2, "little")
        self.mem[2] = 5
        self.mem[3] = USB2AX_ID
        self.mem[4] = 50  # USART timeout, 20 us units
        self.mem[5] = 50  # SYNC_READ timeout per servo
        self.mem[6] = 8


class Protocol1Bus(ServoBusBase):
    """Emulated servos sharing one Protocol 1.0 line (see the module docstring)."""

    status_frame: ClassVar = staticmethod(p1.frame)
    protocol_type: ClassVar[int | None] = 1

    #: Every servo answers a broadcast PING (Feetech) or none does (Dynamixel Protocol 1.0).
    broadcast_ping = False
    #: A unicast instruction that fails its checksum gets a status with the checksum bit.
    reply_checksum_errors = True
    #: The Status Return Level from which a servo answers READ, and everything else.
    read_level = 1
    write_level = 2
    #: What RESET restores (0xFF: everything, the ID too, as a Protocol 1.0 servo does).
    reset_mode = 0xFF

    def __init__(
        self,
        servos: list,
        *,
        name: str = "dynamixel1",
        usb2ax: bool = True,
        inter_byte_timeout: float | None = 0.0015,
    ) -> None:
        super().__init__(servos, name=name)
        self.usb2ax = Usb2ax() if usb2ax else None
        self.inter_byte_timeout = inter_byte_timeout
        self.decoder = p1.Decoder1()
        self._last_t = 0.0
        self._handlers: dict[int, Callable[[Packet1, float, list], None]] = self.handlers()

    def handlers(self) -> dict[int, Callable[[Packet1, float, list], None]]:
        """Instruction code -> handler(packet, t, hearing servos)."""
        return {
            I.PING: self._ping,
            I.READ: self._read,
            I.WRITE: self._write,
            I.REG_WRITE: self._write,
            I.ACTION: self._action,
            I.RESET: self._reset,
            I.SYNC_WRITE: self._sync_write,
            I.BULK_READ: self._bulk_read,
            I.SYNC_READ: self._usb2ax_sync_read,
        }

    @staticmethod
    def instruction_name(code: int) -> str:
        return p1.INSTRUCTION_NAMES.get(code, f"0x{code:02x}")

    # ------------------------------------------------------------------ receiving

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        port = self.port
        t_first = t - len(data) * 10 / baud if port is not None and port.paced and baud else t
        dec = self.decoder
        if dec.pending and self.inter_byte_timeout is not None and t_first - self._last_t > self.inter_byte_timeout:
            dec.reset()  # a partial packet the line went quiet on: servos drop it
        self._last_t = t
        for item in dec.feed(data, t):
            if type(item) is Packet1:
                self._dispatch(item, t, baud)
            elif item.kind == "checksum":
                self._checksum_error(item, t, baud)

    def _dispatch(self, pkt: Packet1, t: float, baud: int | None) -> None:
        self.stats.requests[self.instruction_name(pkt.code)] += 1
        hearing = self._hearing(t, baud)
        if self.usb2ax is not None and pkt.id == USB2AX_ID and pkt.code != I.SYNC_READ:
            self._adapter(pkt, t)
            return
        handler = self._handlers.get(pkt.code)
        try:
            if handler is None:
                raise ValueError("unknown instruction")
            handler(pkt, t, hearing)
        except (ValueError, IndexError):  # a malformed or unknown instruction: an instruction error to a unicast
            self.stats.invalid_received += 1
            if pkt.id != BROADCAST_ID:
                self._send([(s, self.error_bits(s, ErrorNumber.INSTRUCTION_ERROR), b"", s.id)
                            for s in hearing if s.id == pkt.id and s.status_return_level >= 2], t)

    def _checksum_error(self, problem: Problem, t: float, baud: int | None) -> None:
        self.stats.crc_errors_received += 1
        raw = problem.raw
        if not self.reply_checksum_errors or len(raw) < 6:
            return
        self._send([(s, self.error_bits(s, ErrorNumber.CRC_ERROR), b"", s.id)
                    for s in self._hearing(t, baud) if s.id == raw[2] and s.status_return_level >= 2], t)

    # ------------------------------------------------------------------ sending

    def error_bits(self, s, number: int = 0) -> int:
        """The ERR byte of a status: the instruction's error plus the servo's condition."""
        return P1_ERROR_BITS.get(number, 0x40 if number else 0) | s.condition_bits()

    # ------------------------------------------------------------------ instructions

    def _ping(self, pkt: Packet1, t: float, hearing: list) -> None:
        if pkt.params:
            raise ValueError("PING takes no parameters")
        if pkt.id == BROADCAST_ID:
            if self.broadcast_ping:
                self._send([(s, self.error_bits(s), b"", s.id) for s in sorted(hearing, key=lambda s: s.id)], t)
            return
        self._send([(s, self.error_bits(s), b"", s.id) for s in hearing if s.id == pkt.id], t)  # even at level 0

    def _read(self, pkt: Packet1, t: float, hearing: list) -> None:
        address, length = pkt.params  # ValueError unless exactly two
        if pkt.id == BROADCAST_ID:
            return
        replies = []
        for s in hearing:
            if s.id == pkt.id and s.status_return_level >= self.read_level:
                err, data = s.read(address, length, t)
                replies.append((s, self.error_bits(s, err), data, s.id))
        self._send(replies, t)

    def _write(self, pkt: Packet1, t: float, hearing: list) -> None:
        p = pkt.params
        if len(p) < 2:
            raise ValueError("WRITE needs an address and data")
        address, data = p[0], p[1:]
        replies = []
        for s in hearing:
            if pkt.id in (s.id, BROADCAST_ID):
                reply_id_level = s.status_return_level
                op = s.write if pkt.code == I.WRITE else s.reg_write
                err = op(address, data, t)
                if pkt.id != BROADCAST_ID and reply_id_level >= self.write_level:
                    replies.append((s, self.error_bits(s, err), b"", s.id))
        self._send(replies, t)

    def _action(self, pkt: Packet1, t: float, hearing: list) -> None:
        replies = []
        for s in hearing:
            if pkt.id in (s.id, BROADCAST_ID):
                err = s.action(t)
                if pkt.id != BROADCAST_ID and s.status_return_level >= self.write_level:
                    replies.append((s, self.error_bits(s, err), b"", s.id))
        self._send(replies, t)

    def _reset(self, pkt: Packet1, t: float, hearing: list) -> None:
        targets = [s for s in hearing if pkt.id in (s.id, BROADCAST_ID)]
        if pkt.id != BROADCAST_ID:  # the status comes from the old ID, before the reset
            self._send([(s, self.error_bits(s), b"", s.id) for s in targets
                        if s.status_return_level >= self.write_level], t)
        for s in targets:
            s.factory_reset(self.reset_mode, t)

    def _sync_write(self, pkt: Packet1, t: float, hearing: list) -> None:
        p = pkt.params
        address, length = p[0], p[1]
        step = length + 1
        if length == 0 or (len(p) - 2) % step:
            raise ValueError("SYNC_WRITE entries do not fit its length")
        by_id = {s.id: s for s in hearing}
        for k in range(2, len(p), step):
            s = by_id.get(p[k])
            if s is not None:
                s.write(address, p[k + 1 : k + step], t)

    def _bulk_read(self, pkt: Packet1, t: float, hearing: list) -> None:
        p = pkt.params
        if not p or p[0] != 0 or (len(p) - 1) % 3:
            raise ValueError("BULK_READ entries are LEN, ID, ADDRESS")
        by_id = {s.id: s for s in hearing if not s.model.name.startswith("AX")}  # the AX has no BULK_READ
        seen = set()
        replies = []
        for k in range(1, len(p), 3):
            length, sid, address = p[k], p[k + 1], p[k + 2]
            s = by_id.get(sid)
            if sid in seen or s is None or s.status_return_level < 1:
                seen.add(sid)
                continue
            seen.add(sid)
            err, data = s.read(address, length, t)
            replies.append((s, self.error_bits(s, err), data, s.id))
        self._send(replies, t)

    # ------------------------------------------------------------------ the USB2AX adapter

    def _usb2ax_sync_read(self, pkt: Packet1, t: float, hearing: list) -> None:
        port = self.port
        if self.usb2ax is None or pkt.id not in (BROADCAST_ID, USB2AX_ID) or port is None:
            return  # servos ignore 0x84; only the adapter answers it
        p = pkt.params
        if len(p) < 2:
            self._adapter_status(0x08, b"", t)
            return
        address, length, ids = p[0], p[1], p[2:]
        n = len(ids)
        if not 1 <= length <= p1.USB2AX_MAX_LENGTH or n > p1.USB2AX_MAX_DEVICES or length * n > p1.USB2AX_MAX_DATA:
            self._adapter_status(0x08, b"", t)  # Range error, no data
            return
        by_id = {s.id: s for s in hearing}
        out = bytearray()
        missing = bytes((p1.USB2AX_MISSING,)) * length
        wire = 0.0  # the adapter's own bus time: a READ and a reply (or its timeout) per servo
        byte = 10 / (port.medium.baud or 1_000_000)
        stats = self.stats
        for sid in ids:
            s = by_id.get(sid)
            wire += 8 * byte
            if s is None or s.status_return_level < 1:
                out += missing
                wire += USB2AX_TIMEOUT
                continue
            faults = s.faults
            err, data = s.read(address, length, t)
            if faults.take_drop():
                stats.dropped_replies += 1
                out += missing
                wire += USB2AX_TIMEOUT
                continue
            if faults.take_corrupt():  # the adapter drops a reply whose checksum fails
                stats.corrupted_replies += 1
                out += missing
                wire += (6 + len(data)) * byte
                continue
            wire += s.return_delay + faults.delay + (6 + len(data)) * byte
            out += data if len(data) == length else missing
        stats.replies += 1
        port.transmit(p1.frame(USB2AX_ID, 0, bytes(out)), t=t, gap=wire if port.paced else 0.0)

    def _adapter_status(self, err: int, data: bytes, t: float) -> None:
        if self.port is not None:
            self.stats.replies += 1
            self.port.transmit(p1.frame(USB2AX_ID, err, data), t=t)

    def _adapter(self, pkt: Packet1, t: float) -> None:
        """PING, READ and WRITE of the adapter's own table (ID 0xFD)."""
        mem = self.usb2ax.mem
        p = pkt.params
        if pkt.code == I.PING:
            self._adapter_status(0, b"", t)
        elif pkt.code == I.READ and len(p) == 2:
            address, length = p
            if address + length > len(mem) or not length:
                self._adapter_status(0x08, b"", t)
            else:
                self._adapter_status(0, bytes(mem[address : address + length]), t)
        elif pkt.code == I.WRITE and len(p) >= 2:
            address, data = p[0], p[1:]
            if address < 4 or address + len(data) > len(mem):
                self._adapter_status(0x08, b"", t)
            else:
                mem[address : address + len(data)] = data
                self._adapter_status(0, b"", t)
        else:
            self._adapter_status(0x40, b"", t)


__all__ = ["P1_ERROR_BITS", "Protocol1Bus", "Usb2ax"]
