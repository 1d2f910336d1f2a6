"""Profiles from servo-bus captures: what every ID-addressed control-table bus shares (a kit).

A family's inferrer (Dynamixel Protocol 2.0 and 1.0, Feetech) supplies a
:class:`ServoDialect`: how its bytes decode into :class:`Request`,
:class:`Reply` and :class:`Damaged` items, its models, its baud rates and how
its replies are laid out. :class:`ServoBusSession` does the rest the same way
for every dialect:

- pairs each reply with the request that owes it (a unicast request one
  status, a Sync/Bulk Read one per listed ID in order, a combined Fast or
  USB2AX read one packet split into slices), counts what stays unanswered;
- keeps per ID what it was asked and what it answered: Ping replies, the
  first value of every range read (before any write to it), what was
  written, status errors, reply latency (captures with measured times);
- chooses each ID's model: a Ping reply or a read of the Model Number;
  else the models whose tables fit every address and length the host used
  (and every value it wrote), narrowed by a damaged Ping reply, by the
  models of IDs polled the same way, and for boards by the registers read
  every cycle being read-only; an ID no model fits becomes a generic
  control-table board of the registers the host touched (where the family
  has one);
- the initial state (first values read, EEPROM limits, Return Delay Time
  also from the measured latency, Status Return Level from which
  instructions got replies), the contradictions the capture holds, and the
  host's traffic pattern;
- the :class:`~hilbench.bench.capture_replay.SerialReplay` of ``--verify``.
"""

from __future__ import annotations

import collections
import statistics
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.capture_profile import (
    Hex,
    InferOptions,
    ProfileDraft,
    SourceFacts,
    Table,
    id_ranges,
)
from hilbench.bench.capture_replay import Exchange, Expected, SerialReplay, Splitter
from hilbench.protocols.control_table import Field, Model
from hilbench.transports.chunk import Chunk

#: Requests kept for ``--verify`` (a long capture replays its first ones).
MAX_EXCHANGES = 200_000
#: Latency samples kept per ID.
MAX_LATENCIES = 2048
#: Distinct ranges kept per ID (bounded memory on a capture of random garbage).
MAX_RANGES = 512
#: A request signature kept for the pattern (bounded).
MAX_SIGNATURES = 4096
#: Requests whose order is kept to tell the host's cycle (bounded).
MAX_SEQUENCE = 200_000
#: Steps of a cycle shown (a longer one is cut with its length).
CYCLE_STEPS = 6

#: Field keys that name a role in the tables that have no ``roles`` (the X/MX(2.0) tables).
_ROLE_KEYS = {
    "model_number": ("model_number",),
    "firmware": ("firmware_version", "firmware_major_version"),
    "id": ("id",),
    "baud": ("baud_rate",),
    "return_delay": ("return_delay_time",),
    "status_return_level": ("status_return_level", "response_status_level"),
    "torque_enable": ("torque_enable",),
    "present_position": ("present_position",),
    "present_voltage": ("present_input_voltage", "present_voltage"),
    "present_temperature": ("present_temperature",),
    "homing_offset": ("homing_offset",),
}
#: Read-only fields whose values say who the device is, not how it moves: compared by content.
_IDENTITY_ROLES = ("model_number", "firmware", "id")


def role_field(model: Model, role: str) -> Field | None:
    """The field of ``model`` playing ``role`` (its ``roles`` table, else the field keys tables use)."""
    f = model.role(role)
    if f is not None:
        return f
    for key in _ROLE_KEYS.get(role, ()):
        try:
            return model.field_named(key)
        except KeyError:
            continue
    return None


# ------------------------------------------------------------------------------------------- the items


@dataclass(frozen=True)
class Owed:
    """One status a request is owed: from ``id``, to a read of ``length`` bytes at ``address``, a Ping
    (``kind`` ``"ping"``) or an acknowledgement (``"ack"``)."""

    id: int
    kind: str
    address: int = 0
    length: int = 0


@dataclass
class Request:
    """A host request as a dialect decoded it."""

    t: float
    raw: bytes
    name: str
    target: int
    owed: list[Owed] = field(default_factory=list)
    #: What it reads, per ID (in answer order), and writes: (id, address, length) and (id, address, data).
    reads: list[tuple[int, int, int]] = field(default_factory=list)
    writes: list[tuple[int, int, bytes]] = field(default_factory=list)
    #: A broadcast Ping every device answers (Feetech), or none does (Dynamixel 1.0): then ``owed`` is empty.
    any_may_answer: bool = False
    #: One combined reply from this ID carries every owed read (a Fast read's FE, the USB2AX's FD).
    combined: int | None = None
    source: str = ""


@dataclass
class Reply:
    """A status packet: its sender, error byte, data and bytes."""

    t: float
    id: int
    error: int
    data: bytes
    raw: bytes
    source: str = ""


@dataclass
class Damaged:
    """A packet candidate that failed its check (CRC, checksum, length) or was cut short."""

    t: float
    raw: bytes
    kind: str


Item = Request | Reply | Damaged


class ServoDialect:
    """What one kind of servo bus is to the kit (a family's inferrer subclasses it)."""

    #: The instrument protocol of its traffic, and the profile ``protocol`` of its endpoint.
    traffic: str = ""
    family: str = ""
    #: A few words for the header ("Dynamixel Protocol 2.0").
    title: str = ""
    endpoint_name: str = "bus"
    #: Endpoint keys beyond type, protocol, baud and paced.
    endpoint_extra: dict[str, Any] = {}
    #: Baud rates the family's endpoint takes, and the one a capture without any gets.
    bauds: tuple[int, ...] = ()
    default_baud: int = 57_600
    #: The models a device of this bus may be, in order of preference when several fit.
    models: tuple[Model, ...] = ()
    #: Where the Model Number is (two bytes).
    model_address: int = 0
    #: Data bytes of a Ping reply (None: any).
    ping_length: int | None = None
    #: Bytes before a status's data, and of its check at the end.
    data_offset: int = 0
    check_size: int = 1
    #: Status Return Level needed for a read, and for an acknowledgement, to be answered.
    read_level: int = 1
    ack_level: int = 2
    #: Bytes per character on the wire (start, 8 data, stop).
    bits_per_byte: int = 10
    #: Return Delay Time unit (s).
    delay_unit: float = 2e-6
    #: Keys of a device entry the family takes for the horn's position, supply voltage and ambient temperature.
    position_key: str | None = "position"
    voltage_key: str | None = "supply_voltage"
    temperature_key: str | None = "ambient_temperature"

    def decoder(self) -> ItemDecoder:
        """A new decoder of this bus's bytes into items."""
        raise NotImplementedError

    def splitter(self) -> Splitter:
        """A new splitter of what a bench sends back into ``(id, raw status)`` (for ``--verify``)."""
        raise NotImplementedError

    def model_by_number(self, number: int) -> Model | None:
        """The model with this model number, if the family has its table."""
        return next((m for m in self.models if m.number == number), None)

    def model_name(self, number: int) -> str:
        """A name for a model number the family may have no table for."""
        m = self.model_by_number(number)
        return m.name if m else f"model {number}"

    def ping_data(self, reply: Reply) -> tuple[int, int | None] | None:
        """(model number, firmware) a Ping reply carries, if this bus's Ping replies carry them."""
        return None

    def damaged_ping(self, raw: bytes, dev_id: int) -> tuple[int, int | None] | None:
        """(model number, firmware) still readable in a damaged Ping reply from ``dev_id``, if it looks like one."""
        return None

    def split_combined(self, reply: Reply, request: Request) -> list[Reply]:
        """A combined reply's slices as plain replies (one per owed read it carries)."""
        return []

    def profile_model(self, model: Model) -> str:
        """The name a profile gives ``model``."""
        return model.name

    def fits_bus(self, model: Model) -> str | None:
        """Why ``model`` cannot sit on this bus (None: it can)."""
        return None

    def position_range(self, model: Model) -> tuple[int, int]:
        """The positions a device entry's ``position`` takes."""
        top = model.motion.position_max if model.motion else 4095
        return 0, top

    def custom_board(self, dev_id: int, number: int | None, firmware: int | None,
                     registers: list[dict[str, Any]]) -> Table | None:
        """A generic control-table device of ``registers`` (dicts: address, size, name, access, value), or None
        where the family has no such device."""
        return None


class ItemDecoder:
    """A dialect's decoder: chunks in, items out (the session answers what it owes, for buses whose requests
    and replies share one layout)."""

    def feed(self, chunk: Chunk, owes: Callable[[int, int], bool]) -> Iterable[Item]:
        """The chunk's items; a decoder that calls ``owes`` yields them lazily, so that each is classified after
        the session took in the ones before it."""
        raise NotImplementedError

    def flush(self) -> list[Item]:
        return []


# ------------------------------------------------------------------------------------------- per device


@dataclass
class ReadObs:
    """A range one ID was asked to read and answered."""

    count: int = 0
    first: bytes | None = None  # first value read before any write to the range
    first_t: float | None = None
    first_name: str = ""
    after_write: bytes | None = None  # first value read, when a write came first
    by_instruction: dict[str, bytes] = field(default_factory=dict)
    names: set[str] = field(default_factory=set)
    asked: int = 0


@dataclass
class WriteObs:
    count: int = 0
    first: bytes = b""
    last: bytes = b""
    names: set[str] = field(default_factory=set)


@dataclass
class DeviceObs:
    """Everything the capture shows of one ID."""

    id: int
    asked: int = 0
    answered: int = 0
    missed: int = 0
    unsolicited: int = 0
    pings: int = 0
    ping_answers: int = 0
    ping_data: tuple[int, int | None] | None = None
    damaged_ping: tuple[int, int | None] | None = None
    errors: int = 0
    first_error: int | None = None
    reads: dict[tuple[int, int], ReadObs] = field(default_factory=dict)
    writes: dict[tuple[int, int], WriteObs] = field(default_factory=dict)
    written: set[int] = field(default_factory=set)
    acks_answered: int = 0
    acks_missed: int = 0
    reads_answered: int = 0
    reads_missed: int = 0
    latencies: list[float] = field(default_factory=list)
    requested_by: collections.Counter = field(default_factory=collections.Counter)

    @property
    def silent(self) -> bool:
        return self.answered == 0 and self.unsolicited == 0

    @property
    def scanned_only(self) -> bool:
        """Asked nothing but Pings."""
        return not self.reads and not self.writes and set(self.requested_by) <= {"ping"}

    def accesses(self) -> set[tuple[int, int, str]]:
        return {(a, n, "r") for a, n in self.reads} | {(a, n, "w") for a, n in self.writes}


@dataclass
class Choice:
    """The model chosen for an ID, how, and the other candidates."""

    model: Model | None
    number: int | None = None
    firmware: int | None = None
    how: str = ""  # "ping", "read", "guess", "custom", "unknown"
    reasons: list[str] = field(default_factory=list)
    candidates: list[Model] = field(default_factory=list)


@dataclass
class _Pending:
    req: Request
    answered: list[bool]
    replies: list[Reply] = field(default_factory=list)
    t_last: float = 0.0
    kept: bool = True


@dataclass
class _Pattern:
    name: str
    address: int | None
    length: int | None
    ids: set[int] = field(default_factory=set)
    multi: bool = False
    count: int = 0
    first: float | None = None
    last: float | None = None
    answered: int = 0
    index: int = 0


# ------------------------------------------------------------------------------------------- the session


class ServoBusSession:
    """One capture of one servo bus (see the module docstring)."""

    def __init__(self, dialect: ServoDialect, facts: SourceFacts, options: InferOptions) -> None:
        self.dialect = dialect
        self.facts = facts
        self.options = options
        self.decoder = dialect.decoder()
        self.devices: dict[int, DeviceObs] = {}
        self.pending: _Pending | None = None
        self.exchanges: list[_Pending] = []
        self.dropped_exchanges = 0
        self.patterns: dict[tuple, _Pattern] = {}
        #: The requests' signatures in capture order (indices into ``patterns``' order), for the cycle.
        self.sequence: list[int] = []
        self.requests = 0
        self.replies = 0
        self.unsolicited = 0
        self.damaged: collections.Counter[str] = collections.Counter()
        self.broadcast_pings = 0
        self.gaps = 0

    # -------------------------------------------------------------- input

    def device(self, dev_id: int) -> DeviceObs:
        dev = self.devices.get(dev_id)
        if dev is None:
            dev = self.devices[dev_id] = DeviceObs(dev_id)
        return dev

    def owes(self, dev_id: int, length: int) -> bool:
        """Whether the pending request still owes a status from ``dev_id`` whose data is ``length`` bytes."""
        p = self.pending
        if p is None:
            return False
        if p.req.combined is not None:
            return dev_id == p.req.combined and not all(p.answered)
        for k, o in enumerate(p.req.owed):
            if not p.answered[k] and o.id == dev_id and (
                    length == (o.length if o.kind == "read" else 0) or o.kind == "ping"):
                return True
        return p.req.any_may_answer

    def feed(self, chunk: Chunk) -> None:
        if chunk.lost:
            self.gaps += 1
            self._close()
            return
        for item in self.decoder.feed(chunk, self.owes):
            self._item(item)

    def _item(self, item: Item) -> None:
        if isinstance(item, Request):
            self._request(item)
        elif isinstance(item, Reply):
            self._reply(item)
        else:
            self._damaged(item)

    def _request(self, req: Request) -> None:
        self._close()
        self.requests += 1
        if req.any_may_answer:
            self.broadcast_pings += 1
        for o in req.owed:
            dev = self.device(o.id)
            dev.asked += 1
            dev.requested_by[req.name] += 1
            if o.kind == "ping":
                dev.pings += 1
            elif o.kind == "read":
                ro = self._read_obs(dev, o.address, o.length)
                if ro is not None:
                    ro.asked += 1
        for dev_id, address, data in req.writes:
            dev = self.device(dev_id)
            if not req.owed:
                dev.requested_by[req.name] += 1
            key = (address, len(data))
            wo = dev.writes.get(key)
            if wo is None:
                if len(dev.writes) >= MAX_RANGES:
                    continue
                wo = dev.writes[key] = WriteObs(first=data)
            wo.count += 1
            wo.last = data
            wo.names.add(req.name)
            dev.written.update(range(address, address + len(data)))
        self._pattern(req)
        p = _Pending(req, [False] * (1 if req.combined is not None else len(req.owed)), t_last=req.t)
        if len(self.exchanges) < MAX_EXCHANGES:
            self.exchanges.append(p)
        else:
            p.kept = False
            self.dropped_exchanges += 1
        self.pending = p

    def _read_obs(self, dev: DeviceObs, address: int, length: int) -> ReadObs | None:
        ro = dev.reads.get((address, length))
        if ro is None and len(dev.reads) < MAX_RANGES:
            ro = dev.reads[(address, length)] = ReadObs()
        return ro

    def _pattern(self, req: Request) -> None:
        ranges = {(a, n) for _, a, n in req.reads} or {(a, len(d)) for _, a, d in req.writes}
        address, length = next(iter(ranges)) if len(ranges) == 1 else (None, None)
        ids = [i for i, _, _ in req.reads] or [i for i, _, _ in req.writes] or [o.id for o in req.owed]
        multi = req.target == 0xFE or len(set(ids)) > 1 or req.any_may_answer
        key = (req.name, address, length, tuple(ids) if multi else None)
        pat = self.patterns.get(key)
        if pat is None:
            if len(self.patterns) >= MAX_SIGNATURES:
                return
            pat = self.patterns[key] = _Pattern(req.name, address, length, multi=multi, index=len(self.patterns))
        if len(self.sequence) < MAX_SEQUENCE:
            self.sequence.append(pat.index)
        pat.ids.update(ids)
        pat.count += 1
        if pat.first is None:
            pat.first = req.t
        pat.last = req.t

    def _reply(self, rep: Reply) -> None:
        self.replies += 1
        p = self.pending
        if p is not None and p.req.combined is not None and rep.id == p.req.combined and not p.answered[0]:
            p.answered[0] = True
            p.replies.append(rep)
            for part in self.dialect.split_combined(rep, p.req):
                k = next((i for i, o in enumerate(p.req.owed) if o.id == part.id), None)
                if k is not None:
                    self._answer(p, p.req.owed[k], part, latency=False)
            return
        k = None
        if p is not None:
            k = next((i for i, o in enumerate(p.req.owed)
                      if not p.answered[i] and o.id == rep.id and self._fits(o, rep)), None)
            if k is None and p.req.any_may_answer:
                p.req.owed.append(Owed(rep.id, "ping"))
                p.answered.append(False)
                k = len(p.req.owed) - 1
                dev = self.device(rep.id)
                dev.asked += 1
                dev.pings += 1
                dev.requested_by[p.req.name] += 1
        if k is None:
            self.unsolicited += 1
            self.device(rep.id).unsolicited += 1
            return
        p.answered[k] = True
        p.replies.append(rep)
        self._answer(p, p.req.owed[k], rep, latency=True)

    def _fits(self, owed: Owed, rep: Reply) -> bool:
        """Whether ``rep`` can be the status ``owed`` (a status with an error carries no data)."""
        n = len(rep.data)
        if owed.kind == "read":
            return n == owed.length or (rep.error != 0 and n == 0)
        if owed.kind == "ack":
            return n == 0
        return self.dialect.ping_length is None or n in (0, self.dialect.ping_length)

    def _answer(self, p: _Pending, owed: Owed, rep: Reply, *, latency: bool) -> None:
        dev = self.device(owed.id)
        dev.answered += 1
        if rep.error:
            dev.errors += 1
            if dev.first_error is None:
                dev.first_error = rep.error
        if latency and self.facts.timestamps == "measured" and self.facts.baud:
            wire = len(rep.raw) * self.dialect.bits_per_byte / self.facts.baud
            lat = rep.t - p.t_last - wire
            if len(dev.latencies) < MAX_LATENCIES:
                dev.latencies.append(lat)
            p.t_last = rep.t
        if owed.kind == "ping":
            dev.ping_answers += 1
            data = self.dialect.ping_data(rep)
            if data is not None and dev.ping_data is None:
                dev.ping_data = data
        elif owed.kind == "ack":
            dev.acks_answered += 1
        else:
            dev.reads_answered += 1
            if rep.error or len(rep.data) != owed.length:
                return
            ro = self._read_obs(dev, owed.address, owed.length)
            if ro is None:
                return
            ro.count += 1
            ro.names.add(p.req.name)
            clean = not any(a in dev.written for a in range(owed.address, owed.address + owed.length))
            if clean:
                if ro.first is None:
                    ro.first, ro.first_t, ro.first_name = rep.data, rep.t, p.req.name
                ro.by_instruction.setdefault(p.req.name, rep.data)
            elif ro.after_write is None:
                ro.after_write = rep.data

    def _damaged(self, d: Damaged) -> None:
        self.damaged[d.kind] += 1
        p = self.pending
        if p is None or len(d.raw) < 6:
            return
        for k, o in enumerate(p.req.owed):
            if o.kind == "ping" and not p.answered[k]:
                guess = self.dialect.damaged_ping(d.raw, o.id)
                if guess is not None:
                    dev = self.device(o.id)
                    if dev.damaged_ping is None:
                        dev.damaged_ping = guess
                    return

    def _close(self) -> None:
        p, self.pending = self.pending, None
        if p is None:
            return
        if p.req.combined is not None:
            if not p.answered[0]:
                for o in p.req.owed:
                    self._missed(o)
            return
        for k, o in enumerate(p.req.owed):
            if not p.answered[k]:
                self._missed(o)

    def _missed(self, o: Owed) -> None:
        dev = self.device(o.id)
        dev.missed += 1
        if o.kind == "ack":
            dev.acks_missed += 1
        elif o.kind == "read":
            dev.reads_missed += 1

    # -------------------------------------------------------------- the draft

    def finish(self) -> ProfileDraft:
        for item in self.decoder.flush():
            self._item(item)
        self._close()
        return _Drafter(self).build()


def field_values(model: Model, address: int, data: bytes) -> list[tuple[Field, int | float]]:
    """The whole fields of ``model`` inside the range ``data`` was read from, with their values."""
    out = []
    end = address + len(data)
    for f in model.fields:
        if address <= f.address and f.address + f.size <= end:
            out.append((f, f.decode(data[f.address - address : f.address - address + f.size])))
    return out


def is_live(model: Model, f: Field) -> bool:
    """A read-only value that changes by itself (a position, a voltage, a sensor): compared by length only."""
    if f.access != "R":
        return False
    return not any(role_field(model, r) == f for r in _IDENTITY_ROLES) and "error" not in f.key


def misfit(model: Model, dev: DeviceObs) -> str | None:
    """Why ``model``'s table cannot be ``dev``'s (None: every range read and written fits it)."""
    for (address, length), _ in sorted(dev.reads.items()):
        why = _range_misfit(model, address, length)
        if why:
            return f"the read of {address}/{length}: {why}"
    for (address, length), wo in sorted(dev.writes.items()):
        why = _range_misfit(model, address, length)
        if why:
            return f"the write of {address}/{length}: {why}"
        pos = address
        while pos < address + length:
            f = model.field_at(pos)
            if f is None:
                return f"the write of {address}/{length}: no item starts at {pos}"
            if pos + f.size > address + length:
                return f"the write of {address}/{length} ends inside {f.name}"
            if f.access != "RW":
                return f"the write of {address}/{length}: {f.name} is read-only"
            for data in {wo.first, wo.last}:
                value = f.decode(data[pos - address : pos - address + f.size])
                if not f.in_range(value):
                    span = f"one of {f.allowed}" if f.allowed else f"{f.min}..{f.max}"
                    return f"{value} written to {f.name} is out of its range {span}"
            pos += f.size
    return None


def _range_misfit(model: Model, address: int, length: int) -> str | None:
    end = address + length
    if end > model.table_size:
        return f"runs past its table ({model.table_size} bytes)"
    if model.field_at(address) is None:
        return f"no item starts at {address}"
    last = model.covering(end - 1)
    if last is None or last.address + last.size != end:
        return f"ends inside or after an item ({end - 1})"
    return None


class _Drafter:
    """Turns a finished session into a :class:`ProfileDraft`."""

    def __init__(self, s: ServoBusSession) -> None:
        self.s = s
        self.d = s.dialect
        self.draft = ProfileDraft(description="")
        self.choices: dict[int, Choice] = {}
        self._masks: dict[tuple, bytes] = {}

    # -------------------------------------------------------------- models

    def _number_read(self, dev: DeviceObs) -> int | None:
        a = self.d.model_address
        for (address, length), ro in dev.reads.items():
            value = ro.first if ro.first is not None else ro.after_write
            if value is not None and address <= a and a + 2 <= address + length:
                raw = value[a - address : a - address + 2]
                number = int.from_bytes(raw, "little")
                if self.d.model_by_number(number) is None and self.d.model_by_number(int.from_bytes(raw, "big")):
                    number = int.from_bytes(raw, "big")  # a big-endian table (Feetech SCS)
                return number
        return None

    def _firmware_read(self, dev: DeviceObs, model: Model) -> int | None:
        f = role_field(model, "firmware")
        if f is None:
            return None
        for (address, length), ro in dev.reads.items():
            if ro.first is not None and address <= f.address and f.address + f.size <= address + length:
                return int(f.decode(ro.first[f.address - address : f.address - address + f.size]))
        return None

    def _known(self, dev: DeviceObs) -> Choice | None:
        if dev.ping_data is not None:
            number, firmware = dev.ping_data
            model = self.d.model_by_number(number)
            return Choice(model, number, firmware, "ping" if model else "custom",
                          [f"its Ping reply says model {number} ({self.d.model_name(number)}), firmware "
                           f"{firmware}" if firmware is not None else f"its Ping reply says model {number}"])
        number = self._number_read(dev)
        if number is not None:
            model = self.d.model_by_number(number)
            firmware = self._firmware_read(dev, model) if model else None
            return Choice(model, number, firmware, "read" if model else "custom",
                          [f"it read back model number {number} ({self.d.model_name(number)})"])
        return None

    def _guess(self, dev: DeviceObs, known: dict[int, Choice]) -> Choice:
        fitting, excluded = [], []
        for m in self.d.models:
            why = self.d.fits_bus(m) or misfit(m, dev)
            (excluded if why else fitting).append((m, why))
        candidates = [m for m, _ in fitting]
        used = ", ".join(f"{a}/{n}" for a, n in sorted(dev.reads)) or "nothing"
        wrote = ", ".join(f"{a}/{n}" for a, n in sorted(dev.writes))
        basis = f"no Ping reply or Model Number read; the host read {used}" + (f" and wrote {wrote}" if wrote else "")
        if not candidates:
            return Choice(None, how="custom", reasons=[basis, "no model's table fits them"])
        reasons = [basis]
        pick = None
        if dev.damaged_ping is not None:
            number, firmware = dev.damaged_ping
            m = self.d.model_by_number(number)
            if m in candidates:
                pick = m
                reasons.append(f"a damaged Ping reply (check failed) still reads model {number} ({m.name})")
        if pick is None:
            mine = dev.accesses()
            peers = collections.Counter()
            for other_id, ch in known.items():
                other = self.s.devices[other_id]
                theirs = other.accesses()
                if ch.model in candidates and mine and len(mine & theirs) * 2 >= len(mine | theirs):
                    peers[ch.model] += 1
            if peers:
                pick, n = max(peers.items(), key=lambda kv: (kv[1], -candidates.index(kv[0])))
                reasons.append(f"{n} other ID(s) polled the same way are {pick.name}")
        if pick is None and len(candidates) > 1:
            pick, why = self._board_like(dev, candidates)
            if why:
                reasons.append(why)
        if pick is None:
            pick = candidates[0]
        if len(candidates) > 1:
            others = [m.name for m in candidates if m is not pick]
            shown = ", ".join(others[:6]) + (f" and {len(others) - 6} more" if len(others) > 6 else "")
            reasons.append(f"also fits: {shown}")
        reasons += [f"not {m.name}: {why}" for m, why in excluded[:3]]
        if len(excluded) > 3:
            reasons.append(f"nor {len(excluded) - 3} other model(s)")
        firmware = None
        same = collections.Counter(ch.firmware for ch in known.values() if ch.model is pick and ch.firmware is not None)
        if same:
            firmware, n = same.most_common(1)[0]
            reasons.append(f"firmware {firmware}: that of {n} of the {sum(same.values())} other {pick.name}(s)")
        return Choice(pick, pick.number, firmware, "guess", reasons, candidates)

    def _board_like(self, dev: DeviceObs, candidates: list[Model]) -> tuple[Model | None, str]:
        """Among fitting models, the one whose read-only values are what the host polls (a sensor board read
        every cycle), or None when nothing is polled."""
        polled = [(a, n) for (a, n), ro in dev.reads.items() if ro.asked >= 3]
        if not polled:
            return None, ""

        def score(m: Model) -> tuple[float, int]:
            total = live = 0
            covered: set[int] = set()
            for a, n in polled:
                for f, _ in field_values(m, a, bytes(n)):
                    total += f.size
                    if is_live(m, f):
                        live += f.size
                        covered.add(f.address)
            data = {f.address for f in m.fields if is_live(m, f)}
            return (live / total if total else 0.0), (1 if data and data <= covered else 0)

        best = max(candidates, key=lambda m: (score(m), -candidates.index(m)))
        share, whole = score(best)
        if share <= 0:
            return None, ""
        what = "read every cycle are its read-only values" + (", all of them" if whole else "")
        return best, f"the ranges {', '.join(f'{a}/{n}' for a, n in polled)} {what}"

    def _choose(self) -> None:
        known: dict[int, Choice] = {}
        for dev_id, dev in self.s.devices.items():
            ch = self._known(dev)
            if ch is not None:
                known[dev_id] = ch
        for dev_id, dev in sorted(self.s.devices.items()):
            if dev.scanned_only and dev.silent:
                continue
            self.choices[dev_id] = known.get(dev_id) or (
                self._guess(dev, {k: v for k, v in known.items() if v.model is not None})
                if dev.reads or dev.writes else Choice(None, how="unknown",
                                                       reasons=["nothing but Pings, never answered"]))

    # -------------------------------------------------------------- values

    def _state(self, dev: DeviceObs, ch: Choice, table: Table, notes: list[str]) -> None:
        """Init values, position, voltage, temperature from the first values read; contradictions noted."""
        model = ch.model
        assert model is not None
        d, draft = self.d, self.draft
        init: dict[str, Any] = {}
        at_default: list[str] = []
        skipped: list[str] = []
        roles = {r: role_field(model, r) for r in ("id", "baud", "status_return_level", "return_delay",
                                                    "model_number", "firmware", "present_position",
                                                    "present_voltage", "present_temperature",
                                                    "homing_offset", "torque_enable")}
        live_values: dict[str, int | float] = {}
        first_by_field: dict[int, tuple[Field, int | float, str]] = {}
        for (address, _length), ro in sorted(dev.reads.items()):
            if ro.first is None:
                continue
            for f, value in field_values(model, address, ro.first):
                first_by_field.setdefault(f.address, (f, value, ro.first_name))
            if len(ro.by_instruction) > 1:
                self._by_instruction(dev, model, address, ro)
        read_keys = {f.key for (address, length) in dev.reads for f, _ in field_values(model, address,
                                                                                         bytes(length))}
        draft.read[dev.id] = sorted(read_keys)
        for f, value, _name in sorted(first_by_field.values(), key=lambda x: x[0].address):
            if f == roles["id"]:
                if value != dev.id:
                    draft.contradictions.append(f"ID {dev.id}: its ID register ({f.address}) reads {value}, "
                                                "another device's ID: not applied")
                continue
            if f == roles["baud"]:
                rate = model.baud_codes.get(int(value))
                if self.s.facts.baud and rate != self.s.facts.baud:
                    said = f"{rate} baud" if rate else "no rate this model knows"
                    draft.contradictions.append(f"ID {dev.id}: its Baud Rate register reads {value} ({said}), "
                                                f"not the {self.s.facts.baud} baud it was captured at: not applied")
                continue
            if f in (roles["model_number"], roles["firmware"]):
                continue
            if f == roles["present_position"]:
                live_values["position"] = value
                continue
            if f == roles["present_voltage"]:
                live_values["voltage"] = f.physical(value)
                continue
            if f == roles["present_temperature"]:
                live_values["temperature"] = value
                continue
            if f.access != "RW":
                continue
            if f == roles["torque_enable"] or f.key.startswith("goal_"):
                skipped.append(f"{f.key} {value}")
                continue
            if not f.in_range(value):
                draft.contradictions.append(f"ID {dev.id}: {f.name} reads {value}, outside the model's range "
                                            f"{f.min}..{f.max}: not applied")
                continue
            if value == f.default:
                at_default.append(f.key)
            else:
                init[f.key] = value
        srl = roles["status_return_level"]
        level = self._level(dev)
        if srl is not None and srl.key not in init and srl.address not in first_by_field and level is not None:
            lvl, why = level
            if lvl != srl.default:
                init[srl.key] = lvl
                notes.append(f"{srl.key} = {lvl}: {why}")

        elif srl is not None and srl.address in first_by_field and level is not None:
            read = first_by_field[srl.address][1]
            lvl, why = level
            if read != lvl and not (lvl >= d.ack_level and read >= d.ack_level):
                draft.contradictions.append(f"ID {dev.id}: {srl.name} reads {read}, but {why} (level {lvl})")
        rdt = roles["return_delay"]
        if rdt is not None and rdt.address not in first_by_field:
            estimate = self._delay(dev)
            if estimate is not None:
                value, why = estimate
                if value is not None and rdt.in_range(value):
                    if value != rdt.default:
                        init[rdt.key] = value
                    notes.append(f"{rdt.key} = {value}: {why}")
                else:
                    notes.append(f"{rdt.key} not set: {why}")
        if init:
            table.set("init", init)
        if at_default:
            notes.append(f"read back at the model's defaults: {', '.join(at_default)}")
        if skipped:
            notes.append(f"set by the host's software, left at power-on values: {', '.join(skipped)}")
        pos = live_values.get("position")
        if pos is not None and d.position_key:
            offset_f = roles["homing_offset"]
            offset = 0
            if offset_f is not None and offset_f.address in first_by_field:
                offset = int(first_by_field[offset_f.address][1])
            sign = model.motion.offset_sign if model.motion else 1
            actual = int(pos) - sign * offset
            lo, hi = d.position_range(model)
            if lo <= actual <= hi:
                table.set(d.position_key, actual, "the first Present Position read" +
                          (f", with its Homing Offset {offset}" if offset else ""))
            else:
                draft.contradictions.append(f"ID {dev.id}: the first Present Position read ({pos}) is no position "
                                            f"this servo can have ({lo}..{hi}): not applied")
        volts = live_values.get("voltage")
        if volts is not None and d.voltage_key and 0 < volts <= 30:
            table.set(d.voltage_key, round(float(volts), 1), "V, the first Present Voltage read")
        temp = live_values.get("temperature")
        if temp is not None and d.temperature_key and -40 <= temp <= 100:
            table.set(d.temperature_key, float(temp), "C, the first Present Temperature read")

    def _by_instruction(self, dev: DeviceObs, model: Model, address: int, ro: ReadObs) -> None:
        """One range read as different values by different instructions (not what moves by itself)."""
        seen: dict[int, tuple[str, int | float]] = {}
        for name, data in sorted(ro.by_instruction.items()):
            for f, value in field_values(model, address, data):
                if is_live(model, f):
                    continue
                if f.address in seen and seen[f.address][1] != value:
                    other, was = seen[f.address]
                    self.draft.contradictions.append(
                        f"ID {dev.id}: {f.name} ({f.address}) reads {was} by {other} but {value} by {name}")
                seen.setdefault(f.address, (name, value))

    def _level(self, dev: DeviceObs) -> tuple[int, str] | None:
        """Status Return Level from which instructions got replies."""
        d = self.d
        if dev.acks_answered:
            return max(d.ack_level, d.read_level), f"{dev.acks_answered} write(s) or other unicast instruction(s) " \
                                                   "were answered"
        if dev.acks_missed and dev.reads_answered:
            return d.read_level, f"{dev.acks_missed} unicast write(s) went unanswered while reads were answered"
        if dev.reads_missed and not dev.reads_answered and dev.ping_answers and d.read_level > 0:
            return d.read_level - 1, "Pings were answered, reads never"
        return None

    def _delay(self, dev: DeviceObs) -> tuple[int | None, str] | None:
        """Return Delay Time from the measured reply latency (captures with measured times)."""
        lat = sorted(dev.latencies)
        if len(lat) < 5:
            return None
        lo = lat[len(lat) // 10]
        hi = lat[len(lat) * 9 // 10]
        med = statistics.median(lat)
        unit = self.d.delay_unit
        if hi - lo > max(40e-6, 0.5 * abs(med)):
            return None, (f"replies took {1e6 * lo:.0f}..{1e6 * hi:.0f} us after their request (10th..90th "
                          "percentile), too scattered to tell a delay")
        if med > 254 * unit + 100e-6:
            return None, f"replies took {1e6 * med:.0f} us, more than any Return Delay Time: host or adapter latency"
        if hi <= 0:
            return 0, (f"replies came with their requests' end ({len(lat)} measured; the capture's times hold no "
                       "wire time for them: an unpaced line)")
        value = max(0, min(254, round(max(0.0, lo) / unit)))
        return value, f"replies came {1e6 * lo:.0f} us (10th percentile; median {1e6 * med:.0f} us) after their " \
                      "request's end, less wire time"

    # -------------------------------------------------------------- tables

    def _device_table(self, dev: DeviceObs, ch: Choice, silent: bool) -> Table:
        d = self.d
        notes: list[str] = []
        if ch.model is not None:
            table = Table()
            table.set("model", d.profile_model(ch.model))
            table.set("id", dev.id)
            if ch.firmware is not None:
                table.set("firmware", ch.firmware)
            self._state(dev, ch, table, notes)
        else:
            regs = self._registers(dev)
            table = d.custom_board(dev.id, ch.number, ch.firmware, regs) or Table()
            if not table.entries:  # (kept as a comment naming the ID: the user can give its model by hand)
                table.set("id", dev.id)
                table.disabled = True
                notes.append("the family has no generic control-table device: left out (give its model by hand)")
        if silent:
            table.set("faults", {"vanished": True}, "it never answered in the capture")
        head = [self._summary_line(dev, ch)]
        if ch.how in ("guess", "custom", "unknown"):
            head += [f"  {r}" for r in ch.reasons]
        head += [f"  {n}" for n in notes]
        table.comment = head
        return table

    def _registers(self, dev: DeviceObs) -> list[dict[str, Any]]:
        """The registers a custom board's host touched: every range cut at every other range's edges, in
        pieces of one, two or four bytes, each with the first value read (0 if none) and RW where written."""
        cuts: set[int] = set()
        covered: set[int] = set()
        for address, length in [*dev.reads, *dev.writes]:
            cuts.update((address, address + length))
            covered.update(range(address, address + length))
        regs: list[dict[str, Any]] = []
        order = sorted(covered)
        i = 0
        while i < len(order):
            start = order[i]
            size = 1
            while size < 4 and start + size in covered and start + size not in cuts:
                size += 1
            if size == 3:
                size = 2
            value = 0
            for (a, n), ro in dev.reads.items():
                data = ro.first if ro.first is not None else ro.after_write
                if data is not None and a <= start and start + size <= a + n:
                    value = int.from_bytes(data[start - a : start - a + size], "little")
                    break
            written = any(a <= start < a + n for a, n in dev.writes)
            regs.append({"address": start, "size": size, "access": "RW" if written else "R", "value": value})
            i += size
        return regs

    def _summary_line(self, dev: DeviceObs, ch: Choice) -> str:
        if dev.silent:
            what = f"ID {dev.id}: asked {dev.asked} time(s), never answered"
        else:
            what = f"ID {dev.id}: answered {dev.answered} of {dev.asked} request(s)"
            if dev.unsolicited:
                what += f" (+{dev.unsolicited} replies to damaged requests)"
        name = ch.model.name if ch.model else (self.d.model_name(ch.number) if ch.number is not None else "unknown")
        how = {"ping": "from its Ping reply", "read": "from its Model Number", "guess": "guessed",
               "custom": "no table fits: a generic control-table board", "unknown": "unknown"}[ch.how]
        line = f"{what}; {name} ({how})"
        if dev.errors:
            line += f"; {dev.errors} status(es) with an error, the first 0x{dev.first_error:02X}"
        return line

    # -------------------------------------------------------------- header

    def _seen(self, answered: list[int], silent: list[int], scanned: list[int]) -> None:
        s, draft = self.s, self.draft
        damaged = sum(s.damaged.values())
        kinds = ", ".join(f"{n} {k}" for k, n in s.damaged.most_common())
        draft.seen.append(f"{self.d.title} traffic: {s.requests} requests, {s.replies} replies"
                          + (f", {damaged} damaged packets ({kinds})" if damaged else ""))
        if answered:
            draft.seen.append(f"answered: ID {id_ranges(answered)} ({len(answered)})")
        if silent:
            asked = ", ".join(f"{i} ({s.devices[i].asked}x)" for i in silent[:12])
            draft.seen.append(f"asked but never answered: ID {asked}")
        if scanned:
            draft.seen.append(f"pinged only, never answered (a scan): ID {id_ranges(scanned)}")
        if s.broadcast_pings:
            draft.seen.append(f"{s.broadcast_pings} broadcast Ping(s)")
        by_model: dict[tuple[str, int | None, str], list[int]] = collections.defaultdict(list)
        for dev_id, ch in self.choices.items():
            if ch.how in ("ping", "read"):
                by_model[(ch.model.name if ch.model else self.d.model_name(ch.number or 0), ch.firmware,
                          ch.how)].append(dev_id)
        for (name, fw, how), ids in sorted(by_model.items(), key=lambda kv: kv[1][0]):
            src = "Ping replies" if how == "ping" else "Model Number reads"
            draft.seen.append(f"{name}" + (f", firmware {fw}" if fw is not None else "") +
                              f": ID {id_ranges(ids)} ({src})")
        if s.unsolicited:
            draft.unread.append(f"{s.unsolicited} replies answer requests the capture lost (damaged or cut): "
                                "kept only as signs of life")
        if damaged:
            draft.unread.append(f"{damaged} packet candidates failed their check or were cut short ({kinds})")
        if s.gaps:
            draft.unread.append(f"{s.gaps} gap(s) in the capture: requests around them lost their replies")

    def _cycle_lines(self, pats: list[_Pattern]) -> None:
        """The host's cycle: the request it sends most often (10 times or more) starts one; the sequences of
        requests from one start to the next, the commonest first, with their shares."""
        s = self.s
        if not pats or pats[0].count < 10:
            return
        head = pats[0]
        by_index = {p.index: p for p in pats}
        starts = [k for k, i in enumerate(s.sequence) if i == head.index]
        shapes: collections.Counter[tuple[int, ...]] = collections.Counter(
            tuple(s.sequence[a:b]) for a, b in zip(starts, starts[1:], strict=False))
        if not shapes:
            return

        def label(p: _Pattern) -> str:
            return p.name + (f" {p.address}/{p.length}" if p.address is not None else "")

        total = sum(shapes.values())
        span = s.facts.span
        lasted = (head.last - head.first) if head.last is not None and head.first is not None else 0.0
        rate = f", {(head.count - 1) / lasted:.1f}/s" if span and lasted > 0.2 * span else ""
        self.draft.pattern.append(f"the cycle: {head.count} starting with {label(head)}{rate}; "
                                  f"{len(shapes)} shape(s), the commonest:")
        for shape, n in shapes.most_common(3):
            steps = " -> ".join(label(by_index[i]) for i in shape[:CYCLE_STEPS])
            if len(shape) > CYCLE_STEPS:
                steps += f" -> ... ({len(shape)} requests)"
            self.draft.pattern.append(f"  {steps}: {n} of {total} ({100 * n / total:.0f} %)")

    def _pattern_lines(self) -> None:
        s = self.s
        span = self.s.facts.span
        pats = sorted(s.patterns.values(), key=lambda p: -p.count)
        self._cycle_lines(pats)
        for pat in pats[:14]:
            what = pat.name
            if pat.address is not None:
                what += f" {pat.address}/{pat.length}"
                fname = self._field_name(pat.ids, pat.address, pat.length)
                if fname:
                    what += f" ({fname})"
            ids = id_ranges(pat.ids) if pat.ids else "all"
            what += f" of ID {ids}" if pat.ids else " (broadcast)"
            line = f"{what}: {pat.count} time(s)"
            lasted = (pat.last - pat.first) if pat.last is not None and pat.first is not None else 0.0
            if span and pat.count >= 10 and lasted > 0.2 * span:
                line += f", {(pat.count - 1) / lasted:.1f}/s"
            elif span and pat.first is not None:
                t = pat.first - (s.facts.t_first or 0)
                line += f", at {t:.3f} s" if pat.count == 1 else f", from {t:.3f} s over {1e3 * lasted:.0f} ms"
            s_ids = [i for i in pat.ids if i in s.devices]
            if s_ids and all(s.devices[i].silent for i in s_ids) and pat.name not in ("sync_write", "bulk_write"):
                line += " (never answered)"
            self.draft.pattern.append(line)
        if len(pats) > 14:
            rest = sum(p.count for p in pats[14:])
            self.draft.pattern.append(f"... and {len(pats) - 14} other kinds of request ({rest} in all)")

    def _field_name(self, ids: Iterable[int], address: int, length: int) -> str:
        for dev_id in ids:
            ch = self.choices.get(dev_id)
            if ch is not None and ch.model is not None:
                names = [f.name for f, _ in field_values(ch.model, address, bytes(length))]
                if names:
                    return ", ".join(names[:3]) + (" ..." if len(names) > 3 else "")
        return ""

    # -------------------------------------------------------------- endpoint, replay

    def _endpoint(self) -> Table:
        s, d = self.s, self.d
        facts = s.facts
        table = Table()
        table.set("type", "pty")
        table.set("protocol", d.family)
        for key, value in d.endpoint_extra.items():
            table.set(key, value)
        baud, note = facts.baud, ""
        if baud and baud not in d.bauds:
            self.draft.contradictions.append(f"the capture's {baud} baud is no rate a {d.title} endpoint takes: "
                                             f"{d.default_baud} used")
            baud, note = d.default_baud, "not the capture's rate (see the header)"
        elif baud:
            note = "from --baud" if facts.baud_from == "--baud" else "from the capture"
        else:
            rates = self._baud_from_registers()
            if rates is not None:
                baud, why = rates
                note = "guessed, see the header"
                self.draft.guessed.append(f"baud {baud}: {why}")
            else:
                baud = d.default_baud
                note = "NOT IN THE CAPTURE: give --baud (this is the family's default)"
                self.draft.guessed.append(f"baud {baud}: the capture says no rate and no Baud Rate register was "
                                          "read; the family's default (give --baud)")
        table.set("baud", baud, note)
        if facts.timestamps == "measured":
            table.set("paced", True, "wire time at the baud rate plus each device's Return Delay Time")
        else:
            table.set("paced", False, "the capture has no measured times: wire time and delays unknown")
        self.endpoint_baud = baud
        return table

    def _endpoint_name(self) -> str:
        """The host's side's name in the capture (a bench's endpoint name), else the dialect's."""
        import re

        names = collections.Counter(p.req.source for p in self.s.exchanges[:1000])
        name = names.most_common(1)[0][0] if names else ""
        if re.fullmatch(r"[A-Za-z][A-Za-z0-9_-]{0,31}", name or "") and name != "bus":
            return name
        return self.d.endpoint_name

    def _baud_from_registers(self) -> tuple[int, str] | None:
        rates = collections.Counter()
        for dev_id, ch in self.choices.items():
            if ch.model is None:
                continue
            f = role_field(ch.model, "baud")
            if f is None:
                continue
            for (address, length), ro in self.s.devices[dev_id].reads.items():
                if ro.first is not None and address <= f.address < address + length:
                    rate = ch.model.baud_codes.get(int(f.decode(ro.first[f.address - address:
                                                                         f.address - address + f.size])))
                    if rate:
                        rates[rate] += 1
        if len(rates) == 1:
            rate, n = rates.most_common(1)[0]
            if rate in self.d.bauds:
                return rate, f"the Baud Rate register of {n} device(s) reads it"
        return None

    def _replay(self) -> SerialReplay:
        s, d = self.s, self.d
        baud = self.endpoint_baud
        byte_time = d.bits_per_byte / baud if baud else 0.0
        exchanges = []
        timed = s.facts.timestamps != "none"
        for k, p in enumerate(s.exchanges):
            expected = tuple(Expected(rep.id, rep.raw, self._mask(p.req, rep)) for rep in p.replies)
            wire = (len(p.req.raw) + sum(len(r.raw) for r in p.replies)) * byte_time
            t = p.req.t if timed else k * 1e-9
            exchanges.append(Exchange(t, p.req.raw, expected, self._label(p.req), wire))
        notes = []
        if s.dropped_exchanges:
            notes.append(f"only the first {len(exchanges)} requests are replayed ({s.dropped_exchanges} more)")
        if not timed:
            notes.append("the capture has no times: requests are replayed as fast as the bench answers")
        return SerialReplay(self.endpoint_name, exchanges, d.splitter, span=s.facts.span, notes=notes,
                            t0=s.facts.t_first if timed else None)

    def _label(self, req: Request) -> str:
        ranges = {(a, n) for _, a, n in req.reads}
        ids = sorted({i for i, _, _ in req.reads} or {o.id for o in req.owed})
        text = req.name
        if len(ranges) == 1:
            a, n = next(iter(ranges))
            text += f" {a}/{n}"
        if ids:
            text += f" of ID {id_ranges(ids)}"
        return f"{text} at {req.t:.6f} s" if self.s.facts.timestamps != "none" else text

    def _mask(self, req: Request, rep: Reply) -> bytes | None:
        """Which bytes of a captured reply the bench must reproduce: all but values that move by themselves (and
        the check over them)."""
        d = self.d
        if rep.id != req.target and req.combined is not None:
            return None  # a combined reply: slices of several devices, compared by length
        ch = self.choices.get(rep.id)
        owed = next((o for o in req.owed if o.id == rep.id), None)
        n = len(rep.raw)
        if owed is None or ch is None:
            return None
        if owed.kind != "read":
            return bytes([0xFF]) * n
        if ch.model is None:
            return None  # a custom board's values: length only
        key = (ch.model.name, owed.address, owed.length, n)
        mask = self._masks.get(key)
        if mask is None:
            buf = bytearray([0xFF]) * n
            moved = False
            for f, _ in field_values(ch.model, owed.address, bytes(owed.length)):
                if is_live(ch.model, f):
                    off = d.data_offset + f.address - owed.address
                    buf[off : off + f.size] = bytes(f.size)
                    moved = True
            if moved:
                buf[n - d.check_size :] = bytes(d.check_size)
            mask = self._masks[key] = bytes(buf)
        return mask

    # -------------------------------------------------------------- all of it

    def build(self) -> ProfileDraft:
        s, d, draft = self.s, self.d, self.draft
        self._choose()
        answered = sorted(i for i, dev in s.devices.items() if not dev.silent)
        silent = sorted(i for i, dev in s.devices.items() if dev.silent and not dev.scanned_only)
        scanned = sorted(i for i, dev in s.devices.items() if dev.silent and dev.scanned_only)
        self._seen(answered, silent, scanned)
        self.endpoint_name = self._endpoint_name()
        draft.endpoints[self.endpoint_name] = self._endpoint()
        tables: list[tuple[int, Table]] = []
        for dev_id in answered + silent:
            ch = self.choices.get(dev_id)
            if ch is None:
                continue
            dev = s.devices[dev_id]
            table = self._device_table(dev, ch, dev.silent)
            if dev.silent and not s.options.keep_silent:
                table.disabled = True
                table.comment.append("  (never answered: kept as a comment; --keep-silent makes it an absent "
                                     "device, or delete the # to bring it up)")
            if ch.how == "guess":
                draft.guessed.append(f"ID {dev_id}: {ch.model.name}: " + "; ".join(ch.reasons[1:]))
            elif ch.how == "custom":
                draft.guessed.append(f"ID {dev_id}: a generic control-table board: " + "; ".join(ch.reasons))
            for line in table.comment[1:]:
                if " = " in line and line.strip().split(" ")[0] in ("return_delay_time", "status_return_level",
                                                                     "response_status_level"):
                    draft.guessed.append(f"ID {dev_id}: {line.strip()}")
            tables.append((dev_id, table))
        draft.devices = _grouped(tables)
        names = sorted({t.get("model") for _, t in tables if t.get("model") and not t.disabled})
        n = sum(1 for _, t in tables if not t.disabled)
        draft.description = f"{d.title} bus from a capture: {n} device(s)" + (f" ({', '.join(names)})" if names
                                                                             else "")
        self._pattern_lines()
        draft.replay = self._replay()
        return draft


def _grouped(tables: list[tuple[int, Table]]) -> list[Table]:
    """Devices whose entries differ only in their ID share one entry (``ids = [...]``)."""
    out: list[Table] = []
    groups: dict[tuple, Table] = {}
    for dev_id, table in tables:
        rest = tuple((e.key, repr(e.value)) for e in table.entries if e.key != "id")
        key = (rest, table.disabled)
        g = groups.get(key)
        if g is not None and "name" not in table.as_dict():
            ids = g.get("ids") or [g.get("id")]
            g.set("ids", [*ids, dev_id])
            g.entries = [e for e in g.entries if e.key != "id"]
            # (keep the ids key where id was: second)
            g.entries.sort(key=lambda e: 0 if e.key == "model" else 1 if e.key == "ids" else 2)
            g.comment = _merged(g.comment, table.comment)
            continue
        groups[key] = table
        out.append(table)
    return out


def _merged(mine: list[str], theirs: list[str]) -> list[str]:
    """The comments of a group of devices: first lines that differ only in the ID become one line
    (``ID 1-6: ...``), the other lines once each."""
    import re

    head = re.compile(r"^ID ([\d, -]+): (.*)$")
    a, b = head.match(mine[0]) if mine else None, head.match(theirs[0]) if theirs else None
    out = list(mine)
    if a and b and a.group(2) == b.group(2):
        ids = [int(x) for part in a.group(1).split(", ") for x in _expand(part)] + \
              [int(x) for part in b.group(1).split(", ") for x in _expand(part)]
        out[0] = f"ID {id_ranges(ids)}: {a.group(2)}"
        rest = theirs[1:]
    else:
        rest = theirs
    out += [line for line in rest if line not in out]
    return out


def _expand(part: str) -> list[int]:
    lo, _, hi = part.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def hex_number(value: int) -> Hex:
    return Hex(value, 4)



class ServoBusInferrer:
    """An inferrer plug-in for servo buses: one :class:`ServoDialect` per traffic protocol it reads."""

    def __init__(self, title: str, dialects: Iterable[ServoDialect]) -> None:
        self.title = title
        self.dialects = {d.traffic: d for d in dialects}
        self.protocols = tuple(self.dialects)

    def session(self, facts: SourceFacts, options: InferOptions) -> ServoBusSession:
        return ServoBusSession(self.dialects[facts.protocol], facts, options)

    def __repr__(self) -> str:
        return f"ServoBusInferrer({self.title!r})"


class DecoderSplitter:
    """A :class:`~hilbench.bench.capture_replay.Splitter` over a servo bus's stream decoder: the items
    ``keep`` accepts (its status packets), as ``(id, raw)``."""

    def __init__(self, decoder: Any, keep: Callable[[Any], bool]) -> None:
        self.dec = decoder
        self.keep = keep

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        return [(i.id, i.raw) for i in self.dec.feed(data) if self.keep(i)]


__all__ = ["DecoderSplitter", "Choice", "Damaged", "DeviceObs", "ItemDecoder", "Owed", "Reply", "Request", "ServoBusInferrer",
           "ServoBusSession", "ServoDialect", "field_values", "hex_number", "is_live", "misfit", "role_field"]
