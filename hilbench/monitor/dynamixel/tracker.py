"""Turning Dynamixel Protocol 2.0 traffic into device and bus state (no I/O).

:class:`BusTracker` is fed bytes with their bus time (``feed(t, source,
data)``) or already decoded items (``feed_items``). It pairs every status
packet with the latest instruction that expects replies (spec sheet §1.7 step
5): a unicast instruction is owed one status by its ID, Sync/Bulk Read one per
listed ID in list order, a Fast Sync/Bulk Read one combined packet (ID FE)
that is split with the request's lengths (§2.3, §2.4). When the next
instruction arrives, whoever still owes a reply gets a miss.

Liveness follows the thesis bus monitor (§8.4) and goes further:

- a device is disconnected when it has missed more than ``miss_limit`` (4)
  consecutive replies, i.e. on the 5th; any status from it brings it back;
- a request left unanswered for ``reply_timeout`` seconds counts as missed even
  if the master sends nothing more, and a device that owes a reply and has
  said nothing for ``silence`` seconds is disconnected too;
- an unanswered unicast Ping of an ID never heard from is not a miss (a scan
  for devices is not a failure); a broadcast Ping owes nothing.

Control-table values come from what passes: Read, Sync/Bulk (Fast) Read
replies at the requested address, Write/Sync Write/Bulk Write data from the
instructions (a unicast Write only once its status reports success). Model
and firmware come from Ping replies or reads of the Model Number.

Speed: the monitor must keep up with a 4.5 Mbaud line many times over. Nine
packets in ten are plain replies to the pending Sync Read; :meth:`BusTracker.feed`
lets the decoder store those straight into the request's bookkeeping
(:class:`~hilbench.protocols.dynamixel.ReplySlots`, see ``_arm``), so they never
become items, and settles their latencies per batch. A reply that comes as an
item still costs a handful of operations, a repeating request one dictionary
lookup; everything only a person looks at (names, units, percentiles, rates,
per-device counts) is computed on demand. Tests prove both ways give the same
state.
"""

from __future__ import annotations

from typing import ClassVar

from hilbench.monitor.servo_bus.bus_state import ANY_PING, DATA, NODATA, PING, Period, ServoBusState
from hilbench.monitor.servo_bus.bus_state import COMBINED as FAST
from hilbench.monitor.servo_bus.devices import CONNECTED, OBS_LIMIT, READ, WRITTEN, DeviceState
from hilbench.protocols import dynamixel as dxl
from hilbench.protocols.dynamixel import (
    BROADCAST_ID,
    INSTRUCTION_NAMES,
    MAX_LENGTH,
    Decoder,
    InstructionPacket,
    ReplySlots,
    StatusPacket,
    describe_error,
    describe_hardware_error,
)
from hilbench.protocols.dynamixel import Instruction as I  # noqa: N814
from hilbench.protocols.problem import Problem

# What a request expects back (bus_state): FAST is one combined Fast-read packet (ID FE) with a slice per ID.

#: Control-table addresses whose values change what the monitor believes.
MODEL_NUMBER, FIRMWARE_BOARD, FIRMWARE, STATUS_RETURN_LEVEL, HARDWARE_ERROR = 0, 2, 6, 68, 70
#: The XL-320 (a Protocol 2.0 servo with its own table) keeps Status Return Level at 17, the error at 50.
XL320_STATUS_RETURN_LEVEL, XL320_HARDWARE_ERROR = 17, 50
_SPECIAL = (MODEL_NUMBER, MODEL_NUMBER + 1, FIRMWARE_BOARD, FIRMWARE, XL320_STATUS_RETURN_LEVEL,
            XL320_HARDWARE_ERROR, STATUS_RETURN_LEVEL, HARDWARE_ERROR)
#: Instructions answered by a plain status when unicast (at Status Return Level 2).
_NODATA_INSTRUCTIONS = frozenset({I.WRITE, I.REG_WRITE, I.ACTION, I.FACTORY_RESET, I.REBOOT, I.CLEAR, I.BACKUP})
#: Multi-device reads; the most frequent one of these is the bus's main cycle.
_CYCLE_INSTRUCTIONS = frozenset({I.SYNC_READ, I.BULK_READ, I.FAST_SYNC_READ, I.FAST_BULK_READ})
#: Instructions that carry data to remember (plain ints: compared per packet).
_WRITES = frozenset({int(I.WRITE), int(I.REG_WRITE), int(I.SYNC_WRITE), int(I.BULK_WRITE)})
_SYNC_WRITE, _REBOOT, _FACTORY_RESET = int(I.SYNC_WRITE), int(I.REBOOT), int(I.FACTORY_RESET)
#: Distinct repeating requests remembered (folded into the devices when full: bounded memory).
GROUP_CACHE = 4096


def _crc_text(raw: bytes) -> str:
    """Log text of a candidate that failed its CRC, with a guess at what it was."""
    guess = ""
    if len(raw) >= 8:
        if raw[7] == 0x55:
            guess = f", status from ID {raw[4]}?"
        else:
            guess = f", {INSTRUCTION_NAMES.get(raw[7], 'instruction')} to ID {raw[4]}?"
    return f"mismatched checksum ({len(raw)} bytes{guess})"


def _covers_special(address: int, length: int) -> bool:
    return address <= HARDWARE_ERROR and any(address <= a < address + length for a in _SPECIAL)


class Expectation(Period):
    """Who owes what for one distinct request; built once and reused while the request repeats.

    It is the device's :class:`~hilbench.monitor.servo_bus.devices.RequestGroup` for
    that request: it counts the requests, keeps each device's newest plain
    reply, and accumulates the request's period (the main cycle's rate).
    """

    __slots__ = (
        "kind",
        "instruction",
        "ids",
        "index",
        "devices",
        "ranges",
        "lengths",
        "sizes",
        "special",
        "fast",
        "cycle",
        "last",
        "last_t",
        "slot_index",
        "slot_epoch",
        "last_at",
    )

    def __init__(self, kind: int, instruction: int, entries: list[tuple[int, int, int]], devices: list[DeviceState]):
        super().__init__()
        self.kind = kind
        self.instruction = instruction
        self.ids = tuple(e[0] for e in entries)
        self.index = {dev_id: k for k, dev_id in enumerate(self.ids)}
        self.devices = devices
        self.ranges = tuple((e[1], e[2]) for e in entries)
        self.lengths = tuple(e[2] for e in entries)
        #: Wire size of each plain reply (data + 11 bytes), for the decoder's reply slots.
        self.sizes = tuple(e[2] + 11 for e in entries)
        self.special = tuple(kind != DATA or _covers_special(e[1], e[2]) for e in entries)
        #: Replies may take the tracker's fast path (plain data, nothing to interpret).
        self.fast = kind == DATA and not any(self.special)
        #: A multi-device read: candidate for the bus's main cycle.
        self.cycle = instruction in _CYCLE_INSTRUCTIONS
        #: Newest plain reply per entry (its data and bus time), set by the fast paths.
        self.last: list[bytes | None] = [None] * len(entries)
        self.last_at: list[float] = [0.0] * len(entries)
        #: The reply slots of the connected devices, as of BusTracker._epoch == slot_epoch (see _arm).
        self.slot_index: dict[int, int] = {}
        self.slot_epoch = -1

    @property
    def name(self) -> str:
        return INSTRUCTION_NAMES.get(self.instruction, f"0x{self.instruction:02x}")

    def observation(self, k: int) -> tuple[int, bytes, float, int] | None:
        data = self.last[k]
        return None if data is None else (self.ranges[k][0], data, self.last_at[k], READ)

    def clear(self, k: int) -> None:
        self.last[k] = None


class WriteGroup:
    """A repeating Sync Write (same address, length and IDs): counted once per packet.

    Only the newest packet's parameters are kept; each device's data is cut
    out of them when someone looks (:meth:`observation`).
    """

    __slots__ = ("address", "length", "devices", "count", "params", "t", "cleared")

    def __init__(self, address: int, length: int, devices: list[DeviceState]) -> None:
        self.address = address
        self.length = length
        self.devices = devices
        self.count = 0
        self.params = b""
        self.t = 0.0
        self.cleared: set[int] = set()

    def observation(self, k: int) -> tuple[int, bytes, float, int] | None:
        if not self.params or k in self.cleared:
            return None
        start = 4 + k * (self.length + 1) + 1
        return self.address, self.params[start : start + self.length], self.t, WRITTEN

    def clear(self, k: int) -> None:
        self.cleared.add(k)


class BusTracker(ServoBusState):
    """Device and bus state of one Dynamixel Protocol 2.0 bus, from its bytes.

    ``baud`` is the line rate (for the bus load; None if unknown).
    ``timestamps`` says whether the times fed are real (False for raw captures
    without times: latencies, rates and time rules are then skipped).
    ``max_length`` is the decoder's LENGTH cap (1024, the SDK's; 65535 counts
    candidates exactly as the spec sheet's capture statistics do).
    ``silence`` (seconds, None or 0 to disable) and ``reply_timeout`` are the
    time rules described in the module docstring.
    """

    protocol = "dynamixel"
    problem_names: ClassVar = {"crc": "crc", "bad_length": "bad_length", "truncated": "truncated",
                               "stuffing": "stuffing"}
    crc_problem: ClassVar = "crc"

    def __init__(
        self,
        *,
        baud: int | None = None,
        timestamps: bool = True,
        miss_limit: int = 4,
        silence: float | None = 1.0,
        reply_timeout: float = 0.1,
        max_length: int = MAX_LENGTH,
        log_capacity: int = 1000,
    ) -> None:
        super().__init__(instruction_names=INSTRUCTION_NAMES, device_class=DeviceState, baud=baud,
                         timestamps=timestamps, miss_limit=miss_limit, silence=silence,
                         reply_timeout=reply_timeout, log_capacity=log_capacity)
        self.max_length = max_length
        self.items = 0  # packets and problems seen
        self.problem_items = 0
        self.expectations: dict[bytes, Expectation] = {}
        self.write_groups: dict[bytes, WriteGroup] = {}
        #: Every multi-device read request seen, by its parameters (for the main cycle).
        self.cycles: dict[bytes, Expectation] = {}
        self._exp: Expectation | None = None
        self._exp_t = 0.0
        #: Replies the decoders may store straight into the pending request (see _arm).
        self._slots = ReplySlots()
        self._scan_t = 0.0
        self._answered = bytearray()
        self._pending_write: tuple[int, bytes] | None = None
        self._orphans: list[int] = []

    # ------------------------------------------------------------------ input

    def _new_decoder(self) -> Decoder:
        return Decoder(max_length=self.max_length)

    def _decode(self, dec: Decoder, data: bytes, t: float) -> None:
        self._scan_t = t
        self._consume(dec.scan(data, t, slots=self._arm()))

    def _pending_since(self) -> float | None:
        return self._exp_t if self._exp is not None else None

    def finish(self) -> None:
        """End of the source: flush the decoders, count replies still owed as missed, log orphans."""
        super().finish()
        self._flush_orphans(self.t_last or 0.0)

    def feed_items(self, items: list) -> None:
        """Decoded packets and problems in bus order (from :class:`~hilbench.protocols.dynamixel.Decoder`)."""
        self._consume(items)

    def _consume(self, items) -> None:
        """Every item in order; replies the decoder put in the reply slots are settled in bulk."""
        n = 0
        timed = self.timestamps
        exp = self._exp
        answered = self._answered
        exp_t = self._exp_t
        fast = exp is not None and exp.fast
        if fast:
            index_get, devices, lengths, last, last_at = exp.index.get, exp.devices, exp.lengths, exp.last, exp.last_at
        status = StatusPacket
        instruction = InstructionPacket
        fills = self._slots.fills
        for item in items:
            n += 1
            cls = item.__class__
            if cls is status:
                if fast:
                    # Fast path: a healthy device answers the pending plain (Sync/Bulk) Read.
                    pid, err, data, _, t = item
                    idx = index_get(pid)
                    if idx is not None and not answered[idx]:
                        answered[idx] = 1
                        dev = devices[idx]
                        if err or len(data) != lengths[idx]:
                            self._reply(item, exp, idx, dev)
                            continue
                        if dev.health:
                            if dev.state is not CONNECTED:
                                self._reply(item, exp, idx, dev)  # it comes back: logged there
                                continue
                            dev.consecutive = dev.health = 0  # a reply ends its streak of misses
                        last[idx] = data
                        last_at[idx] = t
                        if timed:
                            dev.lat.append(t - exp_t)
                        continue
                self._status(item)
            elif cls is instruction:
                if fills:
                    self._settle_fills()
                self._instruction(item)
                self._arm()
                exp = self._exp
                answered = self._answered
                exp_t = self._exp_t
                fast = exp is not None and exp.fast
                if fast:
                    index_get, devices, lengths, last, last_at = (
                        exp.index.get, exp.devices, exp.lengths, exp.last, exp.last_at
                    )
            else:
                self._problem(item)
        self.items += n
        if fills:
            self._settle_fills()

    def _arm(self) -> ReplySlots:
        """Point the reply slots at the pending request: the replies its fast path would take.

        Those are plain replies (ERR 0, the requested length) to a plain
        (Sync/Bulk) Read from connected devices: for them the fast path only
        stores the data and the latency and clears a streak of misses, so the
        decoder may store the data itself and :meth:`_settle_fills` does the
        rest. Replies from devices not connected (whose return is logged) and
        every other packet come as items. Which devices are connected changes
        rarely, so the slot index is cached per request and state epoch.
        """
        slots = self._slots
        exp = self._exp
        if exp is None or not exp.fast:
            slots.clear()
            return slots
        if exp.slot_epoch != self._epoch:
            exp.slot_epoch = self._epoch
            exp.slot_index = {i: k for i, k in exp.index.items() if exp.devices[k].state is CONNECTED}
        slots.point(exp.slot_index, exp.sizes, self._answered, exp.last, exp.last_at)
        return slots

    def _settle_fills(self) -> None:
        """What the fast path does besides storing the data, for the replies the decoder slotted.

        Called before the next instruction and at the end of each feed: until
        then a slotted device may still show the ``health`` of its last miss,
        which only ``_orphan`` reads, to the same effect.
        """
        fills = self._slots.fills
        self.items += len(fills)
        devices = self._exp.devices
        if self.timestamps:
            lat = self._scan_t - self._exp_t  # every reply of one scan has the scan's time
            for k in fills:
                dev = devices[k]
                if dev.health:
                    dev.consecutive = dev.health = 0  # a reply ends its streak of misses
                dev.lat.append(lat)
        else:
            for k in fills:
                dev = devices[k]
                if dev.health:
                    dev.consecutive = dev.health = 0
        fills.clear()

    # ------------------------------------------------------------------ devices

    def replies(self, dev: DeviceState) -> int:
        """Status packets from ``dev`` so far.

        Counted without per-packet work: every request that owed the device a
        reply was answered, missed, or is still open; statuses nobody asked
        for come on top.
        """
        expected = dev.direct_expected
        for group, _ in dev.groups:
            if isinstance(group, Expectation):
                expected += group.count
        pending = 0
        exp = self._exp
        if exp is not None:
            idx = exp.index.get(dev.id)
            if idx is not None and exp.devices[idx] is dev and not self._answered[idx]:
                pending = 1
        return expected - dev.misses - pending + dev.extra_replies

    @property
    def statuses(self) -> int:
        """Status packets seen (a combined Fast-read reply counts once)."""
        return self.items - self.problem_items - sum(self.counts)

    # ------------------------------------------------------------------ instructions

    def _instruction(self, pkt: InstructionPacket) -> None:
        _, inst, params, raw, t = pkt
        self.counts[inst] += 1
        if self._exp is not None:
            if self._answered.find(0) >= 0:
                self._close(t)
            else:  # everyone answered: nothing to count
                self._exp = None
                self._pending_write = None
        if self._orphans:
            self._flush_orphans(t)
        exp = self.expectations.get(raw)
        if exp is None:
            if inst == _SYNC_WRITE and pkt.id == BROADCAST_ID and self._sync_write(params, t):
                return
            problem = dxl.check_instruction(pkt)
            if problem:
                self.invalid_instructions += 1
                self.log.add(t, "invalid_instruction", "invalid instruction packet: {}", pkt.id, problem)
                return
            if inst in _WRITES:
                self._write(pkt, t)
                return
            exp = self._expectation(pkt)
            if exp is None:
                return
            if inst in (_REBOOT, _FACTORY_RESET):
                self._pending_write = (inst, b"")
        exp.count += 1  # a request to each listed device (DeviceState.requests)
        if exp.cycle:
            if exp.last_t is not None and self.timestamps:
                exp.add_interval(t - exp.last_t)
            exp.last_t = t
        self.requests_expecting_replies += 1
        self._exp = exp
        self._exp_t = t
        self._answered = bytearray(len(exp.ids))

    def _sync_write(self, p: bytes, t: float) -> bool:
        """A valid repeating Sync Write costs one dictionary lookup; False if it needs the general path."""
        n = len(p)
        if n < 4:
            return False
        address, length = p[0] | p[1] << 8, p[2] | p[3] << 8
        step = length + 1
        if (n - 4) % step or _covers_special(address, length):
            return False
        key = p[:4] + p[4::step]
        group = self.write_groups.get(key)
        if group is None:
            if BROADCAST_ID in key[4:]:
                return False
            if len(self.write_groups) >= GROUP_CACHE:
                self._forget_groups()
            devices = [self.device(i, t) for i in key[4:]]
            group = self.write_groups[key] = WriteGroup(address, length, devices)
            for k, dev in enumerate(devices):
                dev.groups.append((group, k))
        group.count += 1
        group.params = p
        group.t = t
        if group.cleared:
            group.cleared = set()
        return True

    def _expectation(self, pkt: InstructionPacket) -> Expectation | None:
        """Build (and cache) what a valid request expects; None if it expects nothing."""
        inst, pid, p = pkt.instruction, pkt.id, pkt.params
        broadcast = pid == BROADCAST_ID
        if inst == I.PING:
            if broadcast:
                return Expectation(ANY_PING, inst, [], [])
            # A Ping may look for a device that is not there: it joins the bus on its first reply.
            dev = self.devices.get(pid) or DeviceState(pid, pkt.t)
            dev.direct_requests += 1
            dev.direct_expected += 1
            return Expectation(PING, inst, [(pid, 0, 3)], [dev])
        if inst == I.READ:
            if broadcast:
                return None  # a broadcast Read is not executed (spec §2.2)
            kind, entries = DATA, [(pid, p[0] | p[1] << 8, p[2] | p[3] << 8)]
        elif inst in (I.SYNC_READ, I.FAST_SYNC_READ):
            address, length = p[0] | p[1] << 8, p[2] | p[3] << 8
            kind, entries = (DATA if inst == I.SYNC_READ else FAST), [(i, address, length) for i in p[4:]]
        elif inst in (I.BULK_READ, I.FAST_BULK_READ):
            entries = [(p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8) for k in range(0, len(p), 5)]
            kind = DATA if inst == I.BULK_READ else FAST
        elif inst in _NODATA_INSTRUCTIONS:
            if broadcast:
                if inst in (I.REBOOT, I.FACTORY_RESET):
                    for dev in self.devices.values():
                        self._rebooted(dev, inst)
                return None
            dev = self.device(pid, pkt.t)
            dev.direct_requests += 1
            if dev.status_return_level is not None and dev.status_return_level < 2:
                if inst in (I.REBOOT, I.FACTORY_RESET):
                    self._rebooted(dev, inst)
                return None  # this device does not answer such instructions
            dev.direct_expected += 1
            # Not cached: whether it is answered depends on the device's Status Return Level.
            return Expectation(NODATA, inst, [(pid, 0, 0)], [dev])
        else:
            return None
        if len(self.expectations) >= GROUP_CACHE:
            self._forget_groups()
        devices = [self.device(e[0], pkt.t) for e in entries]
        exp = self.expectations[pkt.raw] = Expectation(kind, inst, entries, devices)
        for k, dev in enumerate(devices):
            dev.groups.append((exp, k))
        if inst in _CYCLE_INSTRUCTIONS:
            self.cycles.setdefault(bytes((inst,)) + p, exp)
        return exp

    def _forget_groups(self) -> None:
        """Fold the cached request groups into their devices and drop them (bounded memory)."""
        exps = set(self.expectations.values())
        for dev in self.devices.values():
            kept = []
            for group, k in dev.groups:
                if group is self._exp:
                    kept.append((group, k))
                    continue
                dev.direct_requests += group.count
                if isinstance(group, Expectation):
                    dev.direct_expected += group.count
                seen = group.observation(k)
                if seen is not None:
                    address, data, t, how = seen
                    dev.obs[(address, len(data))] = (data, t, how)
                    if how == READ and (dev.seen_t is None or t > dev.seen_t):
                        dev.seen_t = t
            dev.groups = kept
        main = self.main_cycle()
        self.expectations = {raw: e for raw, e in self.expectations.items() if e is self._exp}
        self.write_groups.clear()
        # the main cycle keeps its statistics; its requests now live in its devices' counters
        self.cycles = {key: e for key, e in self.cycles.items() if e is main or e not in exps}
        if main is not None and main is not self._exp:
            main.count = 0

    def _write(self, pkt: InstructionPacket, t: float) -> None:
        """Write / Reg Write / Sync Write / Bulk Write: remember the data written."""
        inst, pid, p = pkt.instruction, pkt.id, pkt.params
        if inst in (I.WRITE, I.REG_WRITE):
            address, data = p[0] | p[1] << 8, p[2:]
            if pid == BROADCAST_ID:
                if inst == I.WRITE:
                    for dev in self.devices.values():
                        self._store(dev, address, data, t, WRITTEN)
                return
            dev = self.device(pid, t)
            dev.direct_requests += 1
            if dev.status_return_level is None or dev.status_return_level >= 2:
                # Remember the data once the status reports success (a refused write changes nothing).
                dev.direct_expected += 1
                exp = Expectation(NODATA, inst, [(pid, 0, 0)], [dev])
                exp.count = 1
                self.requests_expecting_replies += 1
                self._exp, self._exp_t, self._answered = exp, t, bytearray(1)
                self._pending_write = (address, data) if inst == I.WRITE else None
            elif inst == I.WRITE:
                self._store(dev, address, data, t, WRITTEN)
            return
        if inst == I.SYNC_WRITE:
            address, length = p[0] | p[1] << 8, p[2] | p[3] << 8
            step = length + 1
            if _covers_special(address, length):
                for k in range(4, len(p), step):
                    dev = self.device(p[k], t)
                    dev.direct_requests += 1
                    self._store(dev, address, p[k + 1 : k + step], t, WRITTEN)
                return
            self._sync_write(p, t)
            return
        k = 0  # Bulk Write
        while k < len(p):
            dev_id, address, length = p[k], p[k + 1] | p[k + 2] << 8, p[k + 3] | p[k + 4] << 8
            dev = self.device(dev_id, t)
            dev.direct_requests += 1
            self._store(dev, address, p[k + 5 : k + 5 + length], t, WRITTEN)
            k += 5 + length

    def _store(self, dev: DeviceState, address: int, data: bytes, t: float, how: int) -> None:
        """Remember ``data`` at ``address`` and act on the items that change what the monitor believes."""
        length = len(data)
        if not length or address + length > 0x10000:
            return
        obs = dev.obs
        obs[(address, length)] = (data, t, how)
        if len(obs) > OBS_LIMIT:
            dev.compact()
        if not _covers_special(address, length):
            return
        end = address + length
        if address <= MODEL_NUMBER and end >= MODEL_NUMBER + 2 and how == READ:
            number = data[MODEL_NUMBER - address] | data[MODEL_NUMBER + 1 - address] << 8
            self._identify(dev, number, None, "read")
        model = dev.model_info
        fw = model.firmware_address if model is not None else FIRMWARE
        if address <= fw < end and how == READ:
            dev.firmware = data[fw - address]
        servo = model is None or model.kind == "servo"
        roles = model.roles if model is not None else None
        srl = roles.get("status_return_level", -1) if roles else STATUS_RETURN_LEVEL
        hw = roles.get("hardware_error", -1) if roles else HARDWARE_ERROR
        if address <= srl < end and servo:
            dev.status_return_level = data[srl - address]
        if address <= hw < end and how == READ and servo:
            bits = data[hw - address]
            if bits and bits != dev.hardware_error:
                names = ", ".join(describe_hardware_error(bits)) or f"bits 0x{bits:02x}"
                self.log.add(t, "hardware_error", f"ID {dev.id} hardware error: {names}", dev.id)
            dev.hardware_error = bits

    @staticmethod
    def _identify(dev: DeviceState, number: int, firmware: int | None, how: str, t: float | None = None) -> None:
        """Model (and firmware) from a Ping reply or a Model Number read; a Ping also tells the ID."""
        dev.model = number
        dev.model_from = how
        if firmware is not None:
            dev.firmware = firmware
        if how == "ping" and t is not None:
            # what a Ping reply carries is the control table's bytes 0-1, the firmware byte, and the ID
            model = dev.model_info
            obs = dev.obs
            obs[(MODEL_NUMBER, 2)] = (number.to_bytes(2, "little"), t, READ)
            if firmware is not None:
                obs[(model.firmware_address if model else FIRMWARE, 1)] = (bytes((firmware,)), t, READ)
            if model is not None and dev.id <= 0xFF:
                obs[(model.id_address, 1)] = (bytes((dev.id,)), t, READ)

    def _rebooted(self, dev: DeviceState, inst: int) -> None:
        """After Reboot the RAM items (64 on) are back to defaults; after Factory Reset everything is."""
        keep = 64 if inst == I.REBOOT else 0
        for key in [k for k in dev.obs if k[0] + k[1] > keep]:
            del dev.obs[key]
        for group, k in dev.groups:
            seen = group.observation(k)
            if seen is not None and seen[0] + len(seen[1]) > keep:
                group.clear(k)
        dev.hardware_error = None
        if inst == I.FACTORY_RESET:
            dev.status_return_level = None

    def _close(self, t: float) -> None:
        """The pending request is over: whoever did not answer missed a reply."""
        exp = self._exp
        answered = self._answered
        self._exp = None
        self._pending_write = None
        if exp is not None:
            self._misses(exp.kind, exp.devices, answered, self._exp_t, t,
                         INSTRUCTION_NAMES.get(exp.instruction, "request"))

    # ------------------------------------------------------------------ statuses

    def _status(self, st: StatusPacket) -> None:
        """Every status the fast path did not take."""
        exp = self._exp
        if exp is not None:
            if exp.kind == FAST:
                if st.id == BROADCAST_ID and not any(self._answered):
                    self._fast_reply(st, exp)
                    return
            elif exp.kind == ANY_PING:
                if len(st.data) == 3 and st.id <= dxl.MAX_ID:
                    dev = self.device(st.id, st.t)
                    dev.extra_replies += 1
                    self._alive(dev, st.t)
                    self._error_byte(dev, st, exp)
                    self._identify(dev, st.data[0] | st.data[1] << 8, st.data[2], "ping", st.t)
                    return
            else:
                idx = exp.index.get(st.id)
                if idx is not None and not self._answered[idx]:
                    self._answered[idx] = 1
                    self._reply(st, exp, idx, exp.devices[idx])
                    return
        self._orphan(st)

    def _reply(self, st: StatusPacket, exp: Expectation, idx: int, dev: DeviceState) -> None:
        """A status that answers entry ``idx`` of the pending request (the general path)."""
        t = st.t
        if dev.id not in self.devices:
            self.devices[dev.id] = dev  # a pinged device answered
        self._alive(dev, t)
        if self.timestamps:
            dev.lat.append(t - self._exp_t)
        if not self._error_byte(dev, st, exp):
            return  # an error status carries no valid data
        kind = exp.kind
        if kind == DATA:
            address, length = exp.ranges[idx]
            if len(st.data) != length:
                self._bad_length(st, exp, idx)
            elif exp.fast:
                exp.last[idx] = st.data
                exp.last_at[idx] = t
            else:
                self._store(dev, address, st.data, t, READ)
        elif kind == PING:
            if len(st.data) != 3:
                self.bad_replies += 1
                self.log.add(t, "bad_reply", f"ID {dev.id} ping reply has {len(st.data)} data bytes, not 3", dev.id)
                return
            self._identify(dev, st.data[0] | st.data[1] << 8, st.data[2], "ping", t)
        elif kind == NODATA:
            pending = self._pending_write
            if pending is not None:
                if exp.instruction == I.WRITE:
                    self._store(dev, pending[0], pending[1], t, WRITTEN)
                elif exp.instruction in (I.REBOOT, I.FACTORY_RESET):
                    self._rebooted(dev, exp.instruction)

    def _error_byte(self, dev: DeviceState, st: StatusPacket, exp: Expectation | None) -> bool:
        """Alert bit and error number of a status; False if the error number voids its data."""
        err = st.error
        alert = bool(err & dxl.ALERT_BIT)
        if alert != dev.alert:
            dev.alert = alert
            if alert:
                known = f": {', '.join(dev.hardware_error_bits)}" if dev.hardware_error else ""
                self.log.add(st.t, "alert", f"ID {dev.id} raised the Alert bit (hardware error{known})", dev.id)
        dev.last_error = err
        if err & 0x7F:
            dev.error_statuses += 1
            what = exp.name if exp is not None else "a request"
            self.log.add(st.t, "error_status", f"ID {dev.id} status packet has an error: "
                                               f"{describe_error(err)} (reply to {what})", dev.id)
            return False
        return True

    def _bad_length(self, st: StatusPacket, exp: Expectation, idx: int) -> None:
        self.bad_replies += 1
        address, length = exp.ranges[idx]
        self.log.add(st.t, "bad_reply", f"ID {st.id} replied {len(st.data)} bytes to a read of {length} "
                                        f"at {address}", st.id)

    def _fast_reply(self, st: StatusPacket, exp: Expectation) -> None:
        """Split the combined Fast Sync/Bulk Read reply and treat each slice as one device's status."""
        t = st.t
        slices = dxl.split_fast_reply(st.raw, list(exp.lengths))
        answered = self._answered
        for k, sl in enumerate(slices):
            if k >= len(exp.ids) or sl.id != exp.ids[k]:
                self.bad_replies += 1
                self.log.add(t, "bad_reply", f"fast read reply slice {k + 1} is from ID {sl.id}, "
                                             f"expected ID {exp.ids[k] if k < len(exp.ids) else '-'}")
                break
            answered[k] = 1
            dev = exp.devices[k]
            if not sl.crc_ok:
                dev.crc_errors += 1
                self.log.add(t, "crc", f"ID {dev.id} fast read slice has a mismatched checksum", dev.id)
            self._alive(dev, t)
            if self.timestamps:
                dev.lat.append(t - self._exp_t)
            if self._error_byte(dev, StatusPacket(sl.id, sl.error, sl.data, st.raw, t), exp):
                self._store(dev, exp.ranges[k][0], sl.data, t, READ)

    def _orphan(self, st: StatusPacket) -> None:
        """A valid status nobody asked for: proof of life, but its data cannot be placed."""
        self.unexpected += 1
        pid, err, _, _, t = st
        if pid <= dxl.MAX_ID:
            dev = self.devices.get(pid) or self.device(pid, t)
            dev.extra_replies += 1
            if dev.health:
                self._alive(dev, t)
            else:
                dev.seen_t = t
            if err or dev.alert:
                self._error_byte(dev, st, None)
        self._orphans.append(pid)
        if len(self._orphans) > 64:
            self._flush_orphans(t)

    def _flush_orphans(self, t: float) -> None:
        ids = self._orphans
        if not ids:
            return
        self._orphans = []
        distinct = sorted(set(ids))
        shown = ", ".join(str(i) for i in distinct[:8]) + (", ..." if len(distinct) > 8 else "")
        what = "status packet" if len(ids) == 1 else f"{len(ids)} status packets"
        self.log.add(t, "unexpected_status", f"{what} without a matching request (ID {shown})")

    # ------------------------------------------------------------------ problems

    def _problem(self, pr: Problem) -> None:
        self.problem_items += 1
        kind, raw, t = pr.kind, pr.raw, pr.t
        if kind == "crc":
            if len(raw) >= 8 and raw[7] == 0x55:
                exp = self._exp
                if exp is not None:
                    idx = exp.index.get(raw[4])
                    if idx is not None:
                        exp.devices[idx].crc_errors += 1  # most likely its reply, damaged
            self.log.add(t, "crc", _crc_text, None, raw)
        elif kind == "bad_length":
            self.log.add(t, "bad_length", "invalid packet length ({})", None, pr.detail)
        elif kind == "truncated":
            self.log.add(t, "truncated", "truncated packet ({} bytes, {})", None, len(raw), pr.detail)
        else:
            self.log.add(t, "invalid_instruction", "{}: {}", None, kind, pr.detail)
