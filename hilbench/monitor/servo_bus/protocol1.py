"""Turning Protocol 1.0-framed traffic (Dynamixel 1.0 with a USB2AX, Feetech) into device and bus state.

:class:`Bus1Tracker` is fed bytes with their bus time, like the Protocol 2.0
tracker, and offers the same state to the summary and the dashboard (devices
with their counters, latencies and control-table observations, the main
cycle, the error log, packet counts and rates). A :class:`Dialect` says what
the bytes mean on this bus: Dynamixel Protocol 1.0 (SYNC_READ 0x84 answered
by the USB2AX at ID 0xFD in one status, all-0xFF for a servo that did not
answer; BULK_READ 0x92; no reply to a broadcast PING) or Feetech (SYNC_READ
0x82 answered by each servo in turn; every servo answers a broadcast PING;
the model number at address 3).

Instruction and status packets share one layout in Protocol 1.0, so the
tracker tells them apart by what is owed: a packet from an ID that owes a
reply, with the length that reply must have, is that reply; a packet whose
code is no instruction is a status nobody asked for; anything else is an
instruction. That works on a bench's tap and on a raw dump of a real bus.

Pairing and liveness follow the Protocol 2.0 tracker: each request expects
its replies in order; the next instruction (or ``reply_timeout`` of quiet)
counts what is still owed as missed; a device is disconnected after more
than ``miss_limit`` consecutive misses or ``silence`` seconds owing a reply;
any reply brings it back. An unanswered PING of an ID never heard from is a
scan, not a miss.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar

from hilbench.monitor.servo_bus.bus_state import ANY_PING, DATA, NODATA, PING, Period, ServoBusState
from hilbench.monitor.servo_bus.bus_state import COMBINED as USB2AX
from hilbench.monitor.servo_bus.devices import READ, WRITTEN, DeviceState
from hilbench.protocols.dynamixel_protocol1 import BROADCAST_ID, USB2AX_ID, Decoder1, Packet1
from hilbench.protocols.problem import Problem

# what a pending request expects (bus_state): USB2AX is the adapter's one combined reply to SYNC_READ 0x84
#: Distinct multi-device read requests remembered for the main cycle (bounded memory).
CYCLE_CACHE = 1024


@dataclass(frozen=True)
class Dialect:
    """What Protocol 1.0-framed bytes mean on one kind of bus."""

    protocol: str
    instruction_names: dict[int, str]
    describe_error: Callable[[int], str]
    device_class: type[DeviceState]
    #: Instruction codes.
    ping: int = 0x01
    read: int = 0x02
    write: int = 0x03
    reg_write: int = 0x04
    action: int = 0x05
    reset: int = 0x06
    sync_write: int = 0x83
    sync_read: int | None = None  # per-servo replies (Feetech 0x82)
    usb2ax_sync_read: int | None = None  # one reply from the USB2AX (0x84)
    bulk_read: int | None = None
    broadcast_ping_answered: bool = False
    #: Control-table addresses the tracker interprets.
    model_address: int = 0
    firmware_address: int = 2
    status_return_level_address: int = 16
    #: Status Return Level from which READ, and every other instruction, is answered.
    read_level: int = 1
    write_level: int = 2
    #: Model numbers a table may store big-endian (Feetech SCS).
    big_endian_models: frozenset[int] = field(default_factory=frozenset)


class Cycle(Period):
    """A repeating multi-device read (the bus's control cycle candidates): its count and period."""

    __slots__ = ("name", "ids", "ranges")

    def __init__(self, name: str, entries: list[tuple[int, int, int]]) -> None:
        super().__init__()
        self.name = name
        self.ids = tuple(e[0] for e in entries)
        self.ranges = tuple((e[1], e[2]) for e in entries)


class _Pending:
    __slots__ = ("kind", "code", "entries", "devices", "answered", "t")

    def __init__(self, kind: int, code: int, entries: list[tuple[int, int, int]], devices: list[DeviceState],
                 t: float) -> None:
        self.kind = kind
        self.code = code
        self.entries = entries
        self.devices = devices
        self.answered = bytearray(len(entries))
        self.t = t


class Bus1Tracker(ServoBusState):
    """Device and bus state of one Protocol 1.0-framed bus (see the module docstring)."""

    problem_names: ClassVar = {"checksum": "crc", "bad_length": "bad_length", "truncated": "truncated"}
    crc_problem: ClassVar = "checksum"

    def __init__(
        self,
        dialect: Dialect,
        *,
        baud: int | None = None,
        timestamps: bool = True,
        miss_limit: int = 4,
        silence: float | None = 1.0,
        reply_timeout: float = 0.1,
        log_capacity: int = 1000,
    ) -> None:
        super().__init__(instruction_names=dict(dialect.instruction_names), device_class=dialect.device_class,
                         baud=baud, timestamps=timestamps, miss_limit=miss_limit, silence=silence,
                         reply_timeout=reply_timeout, log_capacity=log_capacity)
        self.dialect = dialect
        self.protocol = dialect.protocol
        self.describe_error = dialect.describe_error
        self.statuses = 0
        self.cycles: dict[bytes, Cycle] = {}
        self._pending: _Pending | None = None

    # ------------------------------------------------------------------ input

    def _new_decoder(self) -> Decoder1:
        return Decoder1()

    def _decode(self, dec: Decoder1, data: bytes, t: float) -> None:
        self.feed_items(dec.feed(data, t))

    def _pending_since(self) -> float | None:
        return self._pending.t if self._pending is not None else None

    def feed_items(self, items: list) -> None:
        """Decoded packets and problems in bus order."""
        for item in items:
            if type(item) is Packet1:
                if self._is_status(item):
                    self.statuses += 1
                    self._status(item)
                else:
                    self._instruction(item)
            else:
                self._problem(item)

    # ------------------------------------------------------------------ telling packets apart

    def _is_status(self, pkt: Packet1) -> bool:
        if pkt.code not in self.instruction_names:
            return True  # no such instruction: a status (most often ERR 0)
        p = self._pending
        if p is None:
            return False
        n = len(pkt.params)
        if p.kind == USB2AX:
            return pkt.id == USB2AX_ID and n == sum(e[2] for e in p.entries)
        if p.kind == ANY_PING:
            return n == 0
        for k, (dev_id, _, length) in enumerate(p.entries):
            if dev_id == pkt.id and not p.answered[k]:
                return n == length
        return False

    # ------------------------------------------------------------------ devices

    def _alive(self, dev: DeviceState, t: float) -> None:
        dev.extra_replies += 1  # replies seen (this tracker counts them directly)
        super()._alive(dev, t)

    def replies(self, dev: DeviceState) -> int:
        """Status packets from ``dev`` (its share of a USB2AX reply counts as one)."""
        return dev.extra_replies

    # ------------------------------------------------------------------ instructions

    def _instruction(self, pkt: Packet1) -> None:
        d = self.dialect
        code, pid, p, t = pkt.code, pkt.id, pkt.params, pkt.t
        self.counts[code] += 1
        if self._pending is not None:
            self._close(t)
        broadcast = pid == BROADCAST_ID
        try:
            if code == d.ping:
                if broadcast:
                    if d.broadcast_ping_answered:
                        self._expect(ANY_PING, code, [], t)
                    return
                self._expect(PING, code, [(pid, 0, 0)], t)
            elif code == d.read:
                address, length = p  # exactly two parameters
                if not broadcast:
                    self._expect(DATA, code, [(pid, address, length)], t)
            elif code in (d.write, d.reg_write):
                if len(p) < 2:
                    raise ValueError("no data")
                self._expect_status(code, pid, t)  # at the level before the write (it may change it)
                if code == d.write:
                    for dev in (list(self.devices.values()) if broadcast else [self.device(pid, t)]):
                        self._store(dev, p[0], p[1:], t, WRITTEN)
            elif code in (d.action, d.reset):
                self._expect_status(code, pid, t)
                if code == d.reset:
                    for dev in (list(self.devices.values()) if broadcast else [self.device(pid, t)]):
                        dev.obs.clear()
            elif code == d.sync_write:
                address, length = p[0], p[1]
                step = length + 1
                if not length or (len(p) - 2) % step:
                    raise ValueError("entries do not fit the length")
                for k in range(2, len(p), step):
                    dev = self.device(p[k], t)
                    dev.direct_requests += 1
                    self._store(dev, address, p[k + 1 : k + step], t, WRITTEN)
            elif code in (d.sync_read, d.usb2ax_sync_read):
                if not broadcast and not (code == d.usb2ax_sync_read and pid == USB2AX_ID):
                    return
                address, length, ids = p[0], p[1], p[2:]
                entries = [(i, address, length) for i in ids]
                self._expect(USB2AX if code == d.usb2ax_sync_read else DATA, code, entries, t, cycle=p)
            elif code == d.bulk_read:
                if not p or p[0] != 0 or (len(p) - 1) % 3:
                    raise ValueError("entries are LEN, ID, ADDRESS")
                seen: set[int] = set()
                entries = []
                for k in range(1, len(p), 3):
                    if p[k + 1] not in seen:
                        seen.add(p[k + 1])
                        entries.append((p[k + 1], p[k + 2], p[k]))
                self._expect(DATA, code, entries, t, cycle=p)
            else:
                raise ValueError(f"unknown instruction 0x{code:02x}")
        except (ValueError, IndexError) as exc:
            self.invalid_instructions += 1
            self.log.add(t, "invalid_instruction", "invalid instruction packet to ID {}: {}", pid, pid, str(exc))

    def _expect_status(self, code: int, pid: int, t: float) -> None:
        if pid == BROADCAST_ID:
            return
        dev = self.device(pid, t)
        if dev.status_return_level is not None and dev.status_return_level < self.dialect.write_level:
            dev.direct_requests += 1
            return
        self._expect(NODATA, code, [(pid, 0, 0)], t)

    def _expect(self, kind: int, code: int, entries: list[tuple[int, int, int]], t: float,
                cycle: bytes | None = None) -> None:
        if kind == PING:
            dev = self.devices.get(entries[0][0]) or self.dialect.device_class(entries[0][0], t)
        devices = [self.device(e[0], t) for e in entries] if kind != PING else [dev]
        for dev in devices:
            dev.direct_requests += 1
            dev.direct_expected += 1
        self.requests_expecting_replies += 1 if entries or kind == ANY_PING else 0
        self._pending = _Pending(kind, code, entries, devices, t)
        if cycle is not None and len(entries) > 1:
            key = bytes((code,)) + cycle
            c = self.cycles.get(key)
            if c is None:
                if len(self.cycles) >= CYCLE_CACHE:
                    main = self.main_cycle()
                    self.cycles = {k: v for k, v in self.cycles.items() if v is main}
                c = self.cycles[key] = Cycle(self.instruction_names.get(code, f"0x{code:02x}"), entries)
            c.count += 1
            if c.last_t is not None and self.timestamps:
                c.add_interval(t - c.last_t)
            c.last_t = t

    def _close(self, t: float) -> None:
        """The pending request is over: whoever did not answer missed a reply."""
        p, self._pending = self._pending, None
        if p is None:
            return
        self._misses(p.kind, p.devices, p.answered, p.t, t, self.instruction_names.get(p.code, "a request"))

    # ------------------------------------------------------------------ statuses

    def _status(self, st: Packet1) -> None:
        p = self._pending
        t = st.t
        if p is None:
            self._orphan(st)
            return
        if p.kind == USB2AX:
            self._usb2ax_reply(st, p)
            return
        if p.kind == ANY_PING:
            if st.id <= 0xFD:
                dev = self.device(st.id, t)
                dev.direct_requests += 1
                dev.direct_expected += 1
                self._alive(dev, t)
                self._error_byte(dev, st.code, p)
            return
        for k, (dev_id, address, length) in enumerate(p.entries):
            if dev_id == st.id and not p.answered[k]:
                p.answered[k] = 1
                dev = p.devices[k]
                if dev.id not in self.devices:
                    self.devices[dev.id] = dev  # a pinged device answered
                self._alive(dev, t)
                if self.timestamps:
                    dev.lat.append(t - p.t)
                self._error_byte(dev, st.code, p)
                if p.kind == DATA:
                    if len(st.params) != length:
                        self.bad_replies += 1
                        self.log.add(t, "bad_reply", f"ID {dev.id} replied {len(st.params)} bytes to a read of "
                                                     f"{length} at {address}", dev.id)
                    else:
                        self._store(dev, address, st.params, t, READ)
                if p.answered.find(0) < 0:
                    self._pending = None
                return
        self._orphan(st)

    def _usb2ax_reply(self, st: Packet1, p: _Pending) -> None:
        """Split the adapter's one status into each servo's bytes; all-0xFF means it did not answer."""
        t = st.t
        data = st.params
        pos = 0
        for k, (_, address, length) in enumerate(p.entries):
            dev = p.devices[k]
            chunk = data[pos : pos + length]
            pos += length
            p.answered[k] = 1
            if chunk.count(0xFF) == length:
                self._missed(dev, p.t, t, self.instruction_names.get(p.code, "a request"))
                continue
            self._alive(dev, t)
            if self.timestamps:
                dev.lat.append(t - p.t)
            self._store(dev, address, chunk, t, READ)
        self._pending = None

    def _error_byte(self, dev: DeviceState, err: int, p: _Pending | None) -> None:
        dev.last_error = err
        if err:
            dev.error_statuses += 1
            what = self.instruction_names.get(p.code, "a request") if p is not None else "a request"
            self.log.add(p.t if p is not None else (self.t_last or 0.0), "error_status",
                         f"ID {dev.id} status packet has an error: {self.describe_error(err)} (reply to {what})",
                         dev.id)

    def _orphan(self, st: Packet1) -> None:
        self.unexpected += 1
        if st.id <= 0xFD:
            dev = self.device(st.id, st.t)
            if dev.health:
                self._alive(dev, st.t)
            else:
                dev.seen_t = st.t
                dev.extra_replies += 1
        self.log.add(st.t, "unexpected_status", "status packet without a matching request (ID {})", st.id, st.id)

    def _store(self, dev: DeviceState, address: int, data: bytes, t: float, how: int) -> None:
        """Remember observed bytes; model, firmware and Status Return Level change what the tracker believes."""
        if not data:
            return
        d = self.dialect
        dev.obs[(address, len(data))] = (bytes(data), t, how)
        if len(dev.obs) > 256:
            dev.compact()
        end = address + len(data)
        ma = d.model_address
        if how == READ and address <= ma and end >= ma + 2:
            lo, hi = data[ma - address], data[ma + 1 - address]
            number = lo | hi << 8
            if number not in dev.models_by_number and (hi | lo << 8) in d.big_endian_models:
                number = hi | lo << 8
            dev.model = number
            dev.model_from = "read"
        if how == READ and address <= d.firmware_address < end:
            dev.firmware = data[d.firmware_address - address]
        if address <= d.status_return_level_address < end:
            dev.status_return_level = data[d.status_return_level_address - address]

    # ------------------------------------------------------------------ problems

    def _problem(self, pr: Problem) -> None:
        kind, raw, t = pr.kind, pr.raw, pr.t
        if kind == "checksum":
            p = self._pending
            if p is not None and len(raw) > 2:
                for k, (dev_id, _, _) in enumerate(p.entries):
                    if dev_id == raw[2] and not p.answered[k]:
                        p.devices[k].crc_errors += 1
                        break
            self.log.add(t, "crc", f"mismatched checksum ({len(raw)} bytes, ID {raw[2] if len(raw) > 2 else '?'})")
        elif kind == "bad_length":
            self.log.add(t, "bad_length", "invalid packet length")
        else:
            self.log.add(t, "truncated", "truncated packet ({} bytes)", None, len(raw))


__all__ = ["Bus1Tracker", "Cycle", "Dialect"]
