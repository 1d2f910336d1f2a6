"""What every servo-bus tracker shares: input bookkeeping, liveness, misses and the bus figures (no I/O).

The Protocol 2.0 tracker (:class:`~hilbench.monitor.dynamixel.tracker.BusTracker`)
and the Protocol 1.0-framed one (:class:`~hilbench.monitor.servo_bus.protocol1.Bus1Tracker`)
decode and pair packets their own way; both then apply the same rules to the
devices (a reply proves a device is there; more than ``miss_limit``
consecutive misses, or ``silence`` seconds owing a reply, disconnects it; an
unanswered Ping of a device never heard from is a scan, not a miss) and offer
the summary and the dashboard the same figures. Those rules and figures live
here once, in :class:`ServoBusState`.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, ClassVar

from hilbench.monitor.errorlog import ErrorLog
from hilbench.monitor.servo_bus.devices import CONNECTED, DISCONNECTED, UNKNOWN, DeviceState

# What a pending request expects back.
DATA = 1  # one status per listed ID, carrying data for (address, length)
PING = 2  # one status from the pinged ID
NODATA = 3  # one status without data (write, action, reboot, ...)
COMBINED = 4  # one combined status with a slice per listed ID (Fast Sync/Bulk Read, the USB2AX's SYNC_READ)
ANY_PING = 5  # broadcast Ping: any device may answer, nobody owes a reply

#: Bus-time spacing and span of the history the "per second" figures use.
HISTORY_STEP = 0.1
HISTORY_SPAN = 5.0


class Period:
    """How often a repeating request came: its count and the running statistics of its period."""

    __slots__ = ("count", "last_t", "iv_n", "iv_mean", "iv_m2", "iv_min", "iv_max")

    def __init__(self) -> None:
        self.count = 0
        self.last_t: float | None = None
        self.iv_n = 0
        self.iv_mean = 0.0
        self.iv_m2 = 0.0
        self.iv_min = math.inf
        self.iv_max = 0.0

    def add_interval(self, dt: float) -> None:
        """Welford's running mean and variance of the period."""
        self.iv_n += 1
        delta = dt - self.iv_mean
        self.iv_mean += delta / self.iv_n
        self.iv_m2 += delta * (dt - self.iv_mean)
        if dt < self.iv_min:
            self.iv_min = dt
        if dt > self.iv_max:
            self.iv_max = dt

    @property
    def jitter(self) -> float:
        """Standard deviation of the period (seconds)."""
        return math.sqrt(self.iv_m2 / (self.iv_n - 1)) if self.iv_n > 1 else 0.0


class ServoBusState:
    """Device and bus state of one servo bus; a tracker subclass decodes and pairs its packets.

    A subclass provides :meth:`_new_decoder`, :meth:`_decode` (feed one
    source's bytes through its decoder), :meth:`_pending_since` and
    :meth:`_close` (the request that owes replies), a ``statuses`` count,
    ``cycles`` (its multi-device reads, each with a ``count``) and the class
    attributes below.
    """

    protocol: str
    #: Decoder problem counters -> the names :meth:`problems` reports them under, in report order.
    problem_names: ClassVar[dict[str, str]]
    #: The decoder's counter of candidates that failed their checksum.
    crc_problem: ClassVar[str]
    statuses: int
    cycles: dict[bytes, Any]

    def __init__(
        self,
        *,
        instruction_names: dict[int, str],
        device_class: type[DeviceState],
        baud: int | None,
        timestamps: bool,
        miss_limit: int,
        silence: float | None,
        reply_timeout: float,
        log_capacity: int,
    ) -> None:
        self.instruction_names = instruction_names
        self.device_class = device_class
        self.baud = baud
        self.timestamps = timestamps
        self.miss_limit = miss_limit
        self.silence = silence or None
        self.reply_timeout = reply_timeout
        self.devices: dict[int, DeviceState] = {}
        self.log = ErrorLog(log_capacity)
        self.log.timed = timestamps
        self.decoders: dict[str, Any] = {}
        #: Instruction packets by instruction code.
        self.counts = [0] * 256
        self.bytes = 0
        self.bytes_by_source: dict[str, int] = {}
        self.t0: float | None = None
        self.t_last: float | None = None
        self.unanswered = 0
        self.unexpected = 0
        self.bad_replies = 0
        self.invalid_instructions = 0
        self.dropped_input = 0
        self.requests_expecting_replies = 0
        self.history: deque[tuple[float, int, tuple[int, ...]]] = deque()
        self._epoch = 0  # counts device state changes (connected / disconnected)
        self._last_tick = -math.inf

    # ------------------------------------------------------------------ what a tracker provides

    def _new_decoder(self) -> Any:
        raise NotImplementedError

    def _decode(self, dec: Any, data: bytes, t: float) -> None:
        raise NotImplementedError

    def _pending_since(self) -> float | None:
        """Bus time of the request that still owes replies, or None."""
        raise NotImplementedError

    def _close(self, t: float) -> None:
        raise NotImplementedError

    def feed_items(self, items: list) -> None:
        """Decoded packets and problems in bus order."""
        raise NotImplementedError

    # ------------------------------------------------------------------ input

    def feed(self, t: float, source: str, data: bytes) -> None:
        """Bytes ``data`` that ``source`` put on the bus, complete at bus time ``t``."""
        if self.t0 is None:
            self.t0 = self.log.t0 = t
        self.t_last = t
        n = len(data)
        self.bytes += n
        by_source = self.bytes_by_source
        by_source[source] = by_source.get(source, 0) + n
        dec = self.decoders.get(source)
        if dec is None:
            dec = self.decoders[source] = self._new_decoder()
        self._decode(dec, data, t)
        if self.timestamps and t - self._last_tick >= HISTORY_STEP / 2:
            self.tick(t)

    def gap(self, t: float, source: str, nbytes: int) -> None:
        """``nbytes`` from ``source`` were lost before reaching the monitor (a slow consumer)."""
        self.dropped_input += nbytes
        self.log.add(t, "dropped_input", f"monitor input lost {nbytes} bytes from {source}")
        dec = self.decoders.get(source)
        if dec is not None:
            self.feed_items(dec.flush(t))

    def flush(self, t: float | None = None) -> None:
        """The line went idle (or the stream ended): report partial packets as truncated."""
        t = self.t_last if t is None else t
        for dec in self.decoders.values():
            if dec.pending:
                self.feed_items(dec.flush(t or 0.0))

    def finish(self) -> None:
        """End of the source: flush the decoders and count replies still owed as missed."""
        self.flush()
        if self._pending_since() is not None:
            self._close(self.t_last or 0.0)

    def tick(self, t: float) -> None:
        """Advance bus time without data: reply timeout, silence rule, rate history."""
        self._last_tick = t
        since = self._pending_since()
        if since is not None and t - since > self.reply_timeout:
            self._close(t)
        if self.silence is not None:
            for dev in self.devices.values():
                if dev.consecutive and dev.state is not DISCONNECTED and t - dev.owed_since > self.silence:
                    self._disconnect(dev, t, f"silent for {t - dev.owed_since:.1f} s")
        hist = self.history
        if not hist or t - hist[-1][0] >= HISTORY_STEP:
            hist.append((t, self.bytes, (self.statuses, *self.counts)))
            while hist and t - hist[0][0] > HISTORY_SPAN:
                hist.popleft()
        for dev in self.devices.values():
            if len(dev.lat) > 4 * 1024:
                dev.fold_latency()

    # ------------------------------------------------------------------ devices

    def device(self, dev_id: int, t: float | None = None) -> DeviceState:
        """The state of ``dev_id``, created on first mention."""
        dev = self.devices.get(dev_id)
        if dev is None:
            dev = self.devices[dev_id] = self.device_class(dev_id, t)
        return dev

    def _alive(self, dev: DeviceState, t: float) -> None:
        """Any status from a device proves it is there."""
        dev.seen_t = t
        dev.consecutive = 0
        dev.health = 0
        if dev.state is not CONNECTED:
            if dev.state is DISCONNECTED:
                self.log.add(t, "reconnected", f"ID {dev.id} reconnected", dev.id)
            dev.state = CONNECTED
            dev.ever_replied = True
            self._epoch += 1

    def _disconnect(self, dev: DeviceState, t: float, why: str) -> None:
        dev.state = DISCONNECTED
        dev.health = 1
        self._epoch += 1
        dev.disconnects += 1
        what = f"never answered ({why})" if not dev.ever_replied else why
        self.log.add(t, "disconnected", f"ID {dev.id} disconnected: {what}", dev.id)

    def _misses(self, kind: int, devices: list[DeviceState], answered: bytearray, since: float, t: float,
                what: str) -> None:
        """A request sent at ``since`` is over at ``t``: each device that did not answer missed it.

        An unanswered Ping of a device never heard from is a scan, not a miss.
        """
        idx = answered.find(0)
        while idx >= 0:
            dev = devices[idx]
            idx = answered.find(0, idx + 1)
            if kind == PING and not dev.ever_replied:
                dev.direct_expected -= 1  # looking for a device that is not there is not a failure
                continue
            self._missed(dev, since, t, what)

    def _missed(self, dev: DeviceState, since: float, t: float, what: str) -> None:
        """``dev`` missed its reply to ``what`` sent at ``since``; too many in a row disconnect it at ``t``."""
        if dev.id not in self.devices:
            self.devices[dev.id] = dev
        dev.misses += 1
        dev.consecutive += 1
        dev.health = 1
        self.unanswered += 1
        if dev.consecutive == 1:
            dev.owed_since = since
            if dev.state is not DISCONNECTED:
                self.log.add(since, "missed_reply", "ID {} missed its reply to {}", dev.id, dev.id, what)
        if dev.consecutive > self.miss_limit and dev.state is not DISCONNECTED:
            self._disconnect(dev, t, f"{dev.consecutive} consecutive missed replies")

    # ------------------------------------------------------------------ bus figures

    @property
    def crc_errors(self) -> int:
        """Packet candidates that failed their checksum or LENGTH check."""
        crc = self.crc_problem
        return sum(d.problems[crc] + d.problems["bad_length"] for d in self.decoders.values())

    def problems(self) -> dict[str, int]:
        """Decode problems by kind, over every source, plus bytes outside valid packets."""
        names = self.problem_names
        out = dict.fromkeys(names.values(), 0)
        skipped = 0
        for d in self.decoders.values():
            for k, v in d.problems.items():
                name = names.get(k, k)
                out[name] = out.get(name, 0) + v
            skipped += d.bytes_skipped
        out["garbage_bytes"] = skipped
        return out

    def packet_counts(self) -> dict[str, int]:
        """Packets by snake_case instruction name (every known name, zeros included)."""
        names = self.instruction_names
        out = {name: self.counts[code] for code, name in names.items()}
        out["status"] = self.statuses
        unknown = sum(c for code, c in enumerate(self.counts) if code not in names)
        if unknown:
            out["unknown"] = unknown
        return out

    @property
    def duration(self) -> float:
        """Bus time between the first and the last data (0 without timestamps)."""
        if self.t0 is None or self.t_last is None or not self.timestamps:
            return 0.0
        return self.t_last - self.t0

    def main_cycle(self) -> Any:
        """The most frequent multi-device read request: the bus's control cycle (None before one)."""
        best = None
        for c in self.cycles.values():
            if best is None or c.count > best.count:
                best = c
        return best

    def recent(self, window: float = 1.0) -> tuple[float, int, dict[str, int]] | None:
        """(seconds, bytes, packets by name) over about the last ``window`` s of bus time, or None."""
        hist = self.history
        if not hist or self.t_last is None:
            return None
        t_now = self.t_last
        ref = hist[0]
        for entry in hist:
            if t_now - entry[0] >= window:
                ref = entry
            else:
                break
        span = t_now - ref[0]
        if span <= 0:
            return None
        now = (self.statuses, *self.counts)
        delta = [a - b for a, b in zip(now, ref[2], strict=True)]
        packets = {name: delta[code + 1] for code, name in self.instruction_names.items() if delta[code + 1]}
        if delta[0]:
            packets["status"] = delta[0]
        return span, self.bytes - ref[1], packets

    def state_counts(self) -> dict[str, int]:
        """Devices by state (connected, disconnected, unknown)."""
        out = {CONNECTED: 0, DISCONNECTED: 0, UNKNOWN: 0}
        for dev in self.devices.values():
            out[dev.state] += 1
        return out

    def models(self) -> dict[str, list[DeviceState]]:
        """Devices grouped by model name (``<unknown>`` for devices never identified), sorted by ID."""
        groups: dict[str, list[DeviceState]] = {}
        for dev_id in sorted(self.devices):
            dev = self.devices[dev_id]
            groups.setdefault(dev.model_name, []).append(dev)
        return dict(sorted(groups.items(), key=lambda kv: (kv[0] == "<unknown>", kv[0])))


__all__ = ["ANY_PING", "COMBINED", "DATA", "HISTORY_SPAN", "HISTORY_STEP", "NODATA", "PING", "Period", "ServoBusState"]
