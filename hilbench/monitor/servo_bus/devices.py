"""What the monitor knows about one device on the bus.

:class:`DeviceState` is updated by the tracker for every packet, so it holds
raw facts only (counters, times, the bytes of each observation) and leaves
decoding and formatting to the moment someone looks: :meth:`DeviceState.fields`
turns the observations into control-table values with units, marked as read
back, written, or the model's default.

Repeating requests (the Sync Read of every control cycle, the Sync Write of
goal positions) are :class:`RequestGroup` s: the tracker counts them once per
packet and keeps their newest reply or data there, and each device reads its
own share from the groups it belongs to. That keeps the per-packet work of a
20-servo cycle independent of the number of servos where it can be.
"""

from __future__ import annotations

import math
from typing import ClassVar, NamedTuple, Protocol

from hilbench.protocols.dynamixel import describe_hardware_error
from hilbench.protocols.dynamixel_models import MODEL_NAMES, MODELS_BY_NUMBER, MX106_2, Field, Model

#: Device states.
UNKNOWN = "unknown"  # addressed, no verdict yet
CONNECTED = "connected"
DISCONNECTED = "disconnected"

#: How a value became known.
READ = 1  # a status packet carried it
WRITTEN = 2  # an instruction wrote it (and the write was not refused)
HOW_NAMES = {0: "default", READ: "read", WRITTEN: "written"}

#: Latency samples kept for the percentile (the newest ones).
LATENCY_WINDOW = 1024
#: Distinct observed ranges kept per device before they are merged into runs (bounded memory).
OBS_LIMIT = 256


def model_name(number: int | None) -> str:
    """Model name for a model number; ``"<unknown>"`` when there is none."""
    if number is None:
        return "<unknown>"
    return MODEL_NAMES.get(number) or f"model {number}"


class RequestGroup(Protocol):
    """A repeating request: counted once per packet instead of once per listed device."""

    #: Packets of this request so far.
    count: int

    def observation(self, k: int) -> tuple[int, bytes, float, int] | None:
        """(address, data, t, how) of the newest data for the request's ``k``-th device, if any."""

    def clear(self, k: int) -> None:
        """Forget the ``k``-th device's data (it rebooted)."""


class FieldValue(NamedTuple):
    """One control-table field of a device as the monitor knows it."""

    field: Field
    raw: int | float | None  # None: neither observed nor a known default
    how: str  # "read", "written" or "default"
    t: float | None  # bus time of the observation (None for defaults)

    @property
    def observed(self) -> bool:
        return self.how != "default"

    @property
    def value(self) -> int | float | None:
        """The value in the field's unit (``raw * scale``)."""
        if self.raw is None:
            return None
        return self.field.physical(self.raw) if self.field.scale != 1.0 else self.raw

    def text(self) -> str:
        """The value with its unit, e.g. ``184.4 deg (2098)``, ``14.0 V``, ``38 C``."""
        f, raw = self.field, self.raw
        if raw is None:
            return "-"
        if f.is_float:
            return f"{raw:.4g} {f.unit}".rstrip()
        if f.unit and f.scale != 1.0:
            return f"{f.physical(raw):.4g} {f.unit} ({raw})"
        if f.unit:
            return f"{raw} {f.unit}"
        if f.address == 70 and raw and f.name == "Hardware Error Status":
            return f"{raw} ({', '.join(describe_hardware_error(int(raw)))})"
        return str(raw)


class DeviceState:
    """Counters, identity and observations of one bus device (plain slots, updated in the hot path).

    ``health`` is 0 exactly while the device is connected and owes no reply;
    the tracker's fast path checks only that.
    """

    __slots__ = (
        "id",
        "model",
        "firmware",
        "model_from",
        "state",
        "health",
        "ever_replied",
        "first_t",
        "seen_t",
        "owed_since",
        "direct_requests",
        "direct_expected",
        "extra_replies",
        "groups",
        "misses",
        "consecutive",
        "disconnects",
        "crc_errors",
        "error_statuses",
        "last_error",
        "alert",
        "hardware_error",
        "status_return_level",
        "obs",
        "lat",
        "lat_n",
        "lat_sum",
        "lat_min",
        "lat_max",
    )

    #: The model catalogue of the bus (a Feetech or Protocol 1.0 bus brings its own): tables by
    #: model number, names of model numbers, and the layout that names ranges of unknown models.
    models_by_number: ClassVar[dict[int, Model]] = MODELS_BY_NUMBER
    model_names: ClassVar[dict[int, str]] = MODEL_NAMES
    fallback_layout: ClassVar[Model] = MX106_2

    def __init__(self, dev_id: int, t: float | None = None) -> None:
        self.id = dev_id
        self.model: int | None = None
        self.firmware: int | None = None
        self.model_from: str | None = None  # "ping" or "read"
        self.state = UNKNOWN
        self.health = 1
        self.ever_replied = False
        self.first_t = t
        self.seen_t: float | None = None  # bus time of the last status handled outside the groups
        self.owed_since: float | None = None  # first unanswered request of the current miss streak
        self.direct_requests = 0  # requests not counted by a group
        self.direct_expected = 0  # of those, the ones that owe a reply
        self.extra_replies = 0  # statuses nobody (or no open request) asked for
        #: (group, index of this device in it) for every repeating request listing the device.
        self.groups: list[tuple[RequestGroup, int]] = []
        self.misses = 0
        self.consecutive = 0
        self.disconnects = 0
        self.crc_errors = 0
        self.error_statuses = 0
        self.last_error = 0
        self.alert = False
        self.hardware_error: int | None = None
        self.status_return_level: int | None = None
        #: (address, length) -> (data, t, how): ranges seen outside the groups.
        self.obs: dict[tuple[int, int], tuple[bytes, float, int]] = {}
        #: Latency samples not yet folded into the aggregates below.
        self.lat: list[float] = []
        self.lat_n = 0
        self.lat_sum = 0.0
        self.lat_min = math.inf
        self.lat_max = 0.0

    # ------------------------------------------------------------------ derived facts

    @property
    def model_info(self) -> Model | None:
        """The model's table, if its number is known to hilbench."""
        return self.models_by_number.get(self.model) if self.model is not None else None

    @property
    def model_name(self) -> str:
        if self.model is None:
            return "<unknown>"
        return self.model_names.get(self.model) or f"model {self.model}"

    @property
    def never_answered(self) -> bool:
        return not self.ever_replied

    @property
    def requests(self) -> int:
        """Instructions addressed to the device (unicast, or listing it)."""
        return self.direct_requests + sum(g.count for g, _ in self.groups)

    @property
    def last_seen(self) -> float | None:
        """Bus time of the newest status from the device."""
        best = self.seen_t
        for group, k in self.groups:
            seen = group.observation(k)
            if seen is not None and seen[3] == READ and (best is None or seen[2] > best):
                best = seen[2]
        return best

    @property
    def hardware_error_bits(self) -> list[str]:
        return describe_hardware_error(self.hardware_error or 0)

    def fold_latency(self) -> None:
        """Fold older samples into min/mean/max, keeping the newest window for the percentile."""
        lat = self.lat
        if len(lat) <= LATENCY_WINDOW:
            return
        old = lat[:-LATENCY_WINDOW]
        self.lat_n += len(old)
        self.lat_sum += sum(old)
        self.lat_min = min(self.lat_min, min(old))
        self.lat_max = max(self.lat_max, max(old))
        del lat[:-LATENCY_WINDOW]

    def latency(self) -> dict[str, float] | None:
        """Request-to-reply latency in seconds: ``n``, ``min``, ``mean``, ``p99``, ``max``.

        min/mean/max cover every reply; p99 covers the newest
        :data:`LATENCY_WINDOW` replies. None before the first timed reply.
        """
        self.fold_latency()
        lat = self.lat
        n = self.lat_n + len(lat)
        if not n:
            return None
        window = sorted(lat)
        if window:
            p99 = window[max(0, math.ceil(0.99 * len(window)) - 1)]
            lo, hi = min(self.lat_min, window[0]), max(self.lat_max, window[-1])
        else:
            p99, lo, hi = self.lat_max, self.lat_min, self.lat_max
        return {"n": n, "min": lo, "mean": (self.lat_sum + sum(lat)) / n, "p99": p99, "max": hi}

    # ------------------------------------------------------------------ control table

    def observations(self) -> list[tuple[int, bytes, float, int]]:
        """Every range seen on the bus, oldest first: (address, data, t, how)."""
        out = [(address, data, t, how) for (address, _), (data, t, how) in self.obs.items()]
        for group, k in self.groups:
            seen = group.observation(k)
            if seen is not None:
                out.append(seen)
        out.sort(key=lambda o: o[2])
        return out

    def compact(self) -> None:
        """Merge the observed ranges into runs of bytes seen the same way at the same time.

        Keeps memory bounded when traffic touches many different ranges; what
        :meth:`fields` shows does not change.
        """
        obs = [(a, d, t, how) for (a, _), (d, t, how) in self.obs.items()]
        obs.sort(key=lambda o: o[2])
        latest: dict[int, tuple[int, float, int]] = {}
        for address, data, t, how in obs:
            for k, b in enumerate(data):
                latest[address + k] = (b, t, how)
        runs: dict[tuple[int, int], tuple[bytes, float, int]] = {}
        start = None
        buf = bytearray()
        key = None
        for a in sorted(latest):
            b, t, how = latest[a]
            if start is not None and a == start + len(buf) and (t, how) == key:
                buf.append(b)
                continue
            if start is not None:
                runs[(start, len(buf))] = (bytes(buf), key[0], key[1])
            start, buf, key = a, bytearray((b,)), (t, how)
        if start is not None:
            runs[(start, len(buf))] = (bytes(buf), key[0], key[1])
        self.obs = runs

    def table(self) -> tuple[bytearray, bytearray, dict[int, float]]:
        """The control table as observed: (bytes, how per byte, bus time per observed byte).

        Bytes never observed hold the model's defaults (zeros for an unknown model).
        """
        obs = self.observations()
        size = max((address + len(data) for address, data, _, _ in obs), default=0)
        model = self.model_info
        if model is not None:
            size = max(size, model.table_size)
        mem = bytearray(size)
        how = bytearray(size)
        when: dict[int, float] = {}
        if model is not None:
            mem[: model.table_size] = model.defaults()
        for address, data, t, kind in obs:
            end = address + len(data)
            mem[address:end] = data
            how[address:end] = bytes((kind,)) * len(data)
            for a in range(address, end):
                when[a] = t
        return mem, how, when

    def fields(self, *, observed_only: bool = False) -> list[FieldValue]:
        """Every field of the device's model with its value, how it is known and when.

        A field counts as observed when all its bytes were seen; otherwise its
        default shows (for a known model). For an unknown model the X/MX(2.0)
        layout names the observed ranges, and fields never seen are left out.
        """
        model = self.model_info
        layout = model or self.fallback_layout
        mem, how, when = self.table()
        out = []
        for f in layout.fields:
            end = f.address + f.size
            if end <= len(how) and all(how[f.address : end]):
                newest = max(range(f.address, end), key=when.__getitem__)
                out.append(FieldValue(f, f.decode(bytes(mem[f.address : end])), HOW_NAMES[how[newest]], when[newest]))
            elif model is not None and not observed_only:
                out.append(FieldValue(f, f.default, "default", None))
        return out

    def __repr__(self) -> str:
        return f"DeviceState(id={self.id}, model={self.model_name}, state={self.state})"
