"""The CAN monitor's state machine: frames in (with times), bus and CANopen state out. No I/O.

:class:`CanTracker` is fed chunks of 16-byte SocketCAN records (what every
CAN source yields, :mod:`hilbench.protocols.can_frame`) and keeps:

- per identifier: count, rate, period and jitter (standard deviation of the
  intervals), largest gap, last data, length changes, the decoded signals
  (with a DBC or EDS decoder) and decode failures;
- the bus: frames, bits (exact, stuffed) and load over the last second and
  at its peak, error frames by class, frames lost before the monitor;
- CANopen, by node (from the predefined connection set): NMT state from
  boot-up and heartbeat messages, heartbeat period (from an SDO access to
  0x1017, else measured) and misses (a gap longer than 1.5 periods; a node
  silent for that long is ``lost`` until it is heard again), boot-ups, EMCY
  messages with their meaning, SDO transfers (expedited, segmented, aborts
  with their meaning), NMT commands;
- an event log (bounded) for the dashboard and the summary.

Garbage never raises: a record that is not a whole frame is counted in
``dropped_bytes``; a frame a decoder chokes on counts as a decode error.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field
from typing import Any

from hilbench.monitor.can.decoders import Decoder
from hilbench.monitor.can.sdo import SdoFollower, SdoTransfer
from hilbench.protocols import can_frame as cf
from hilbench.protocols import canopen as co
from hilbench.protocols.can_frame import CanFrame

#: A heartbeat gap longer than this many periods is a miss (and the node is lost while it lasts).
MISS_FACTOR = 1.5
#: Seconds of history for the "now" rates and the bus load.
RECENT = 1.0
MAX_EVENTS = 2000
MAX_TRANSFERS = 500
MAX_IDS = 4096


class Welford:
    """Running mean and standard deviation (Welford), plus min and max."""

    __slots__ = ("n", "mean", "m2", "min", "max")

    def __init__(self) -> None:
        self.n = 0
        self.mean = 0.0
        self.m2 = 0.0
        self.min = math.inf
        self.max = -math.inf

    def add(self, x: float) -> None:
        self.n += 1
        d = x - self.mean
        self.mean += d / self.n
        self.m2 += d * (x - self.mean)
        self.min = min(self.min, x)
        self.max = max(self.max, x)

    @property
    def std(self) -> float:
        return math.sqrt(self.m2 / (self.n - 1)) if self.n > 1 else 0.0


@dataclass
class IdStats:
    """What is known about one identifier."""

    can_id: int
    extended: bool
    label: str
    count: int = 0
    first: float | None = None
    last: float | None = None
    intervals: Welford = field(default_factory=Welford)
    data: bytes = b""
    dlc: int = 0
    dlc_changes: int = 0
    remote: int = 0
    sources: collections.Counter = field(default_factory=collections.Counter)
    name: str | None = None
    signals: dict[str, Any] = field(default_factory=dict)
    decode_errors: int = 0
    last_decode_error: str = ""

    @property
    def key(self) -> str:
        return f"0x{self.can_id:08X}" if self.extended else f"0x{self.can_id:03X}"

    def rate(self) -> float | None:
        if self.count < 2 or self.first is None or self.last is None or self.last <= self.first:
            return None
        return (self.count - 1) / (self.last - self.first)


@dataclass
class NodeState:
    """A CANopen node as the bus shows it."""

    node_id: int
    state: int | None = None
    heartbeats: int = 0
    last_heartbeat: float | None = None
    intervals: Welford = field(default_factory=Welford)
    recent_gaps: collections.deque = field(default_factory=lambda: collections.deque(maxlen=5))
    configured_ms: int | None = None  # from an SDO access to 0x1017
    period_changed: float | None = None  # when that access changed it (gaps count from there)
    misses: int = 0
    lost: bool = False
    losses: int = 0
    bootups: int = 0
    emcy: int = 0
    last_emcy: dict[str, Any] | None = None
    error_register: int = 0
    sdo_uploads: int = 0
    sdo_downloads: int = 0
    sdo_aborts: int = 0
    guarding: int = 0

    @property
    def state_name(self) -> str:
        if self.lost:
            return "LOST"
        return co.state_name(self.state) if self.state is not None else "?"

    def period(self) -> float | None:
        """The heartbeat period in seconds: configured if seen, else measured (None if neither)."""
        if self.configured_ms:
            return self.configured_ms / 1000
        if len(self.recent_gaps) >= 2:
            # The median of the last few gaps: a miss does not move it, a new period takes over in 3 beats.
            gaps = sorted(self.recent_gaps)
            return gaps[len(gaps) // 2] or None
        return None


@dataclass
class Event:
    """One line of the event log."""

    t: float
    kind: str  # nmt, bootup, heartbeat, emcy, sdo, error-frame, dropped, decode
    node: int | None
    text: str
    level: str = "info"  # info, warn, error


class CanTracker:
    """See the module docstring. ``baud`` is the bitrate (for bus load); ``decoders`` name and decode frames."""

    protocol = "can"

    def __init__(self, *, baud: int | None = None, timestamps: bool = True, decoders: list[Decoder] | None = None,
                 canopen: bool = True, miss_factor: float = MISS_FACTOR) -> None:
        self.baud = baud
        self.timestamps = timestamps
        self.decoders = list(decoders or [])
        self.canopen = canopen
        self.miss_factor = miss_factor
        self.t0: float | None = None
        self.t_last: float | None = None
        self.bytes = 0
        self.frames = 0
        self.data_frames = 0
        self.error_frames = 0
        self.remote_frames = 0
        self.extended_frames = 0
        self.bits = 0
        self.dropped_bytes = 0
        self.lost_frames = 0
        self.error_classes: collections.Counter = collections.Counter()
        self.ids: dict[tuple[int, bool], IdStats] = {}
        self.ids_dropped = 0
        self.nodes: dict[int, NodeState] = {}
        self.sdo: dict[int, SdoFollower] = {}
        self.transfers: collections.deque[SdoTransfer] = collections.deque(maxlen=MAX_TRANSFERS)
        self.transfer_count = 0
        self.events: collections.deque[Event] = collections.deque(maxlen=MAX_EVENTS)
        self.event_counts: collections.Counter = collections.Counter()
        self.nmt_commands = 0
        self._recent: collections.deque[tuple[float, int, int]] = collections.deque()  # (t, bits, frames)
        self._recent_bits = 0
        self.peak_load = 0.0
        self.peak_fps = 0.0

    # ------------------------------------------------------------------ feeding

    def feed(self, t: float, source: str, data: bytes) -> None:
        """SocketCAN frame records ``source`` put on the bus at ``t`` (a torn tail is counted, not fatal)."""
        frames, rest = cf.split(data)
        self.bytes += len(data)
        if rest:
            self.dropped_bytes += rest
            self._event(t, "dropped", None, f"{rest} bytes that are not a whole CAN frame record", "warn")
        for frame in frames:
            self.frame(t, source, frame)

    def gap(self, t: float, source: str, nbytes: int) -> None:
        """``nbytes`` of ``source``'s records were lost before the monitor."""
        n = max(1, nbytes // cf.FRAME_SIZE)
        self.lost_frames += n
        self._event(t, "dropped", None, f"{n} frames from {source} lost before the monitor", "warn")

    def flush(self, t: float | None = None) -> None:
        """Frames are whole: nothing is ever partial."""

    def finish(self) -> None:
        """The source ended: judge the silence up to its last frame."""
        if self.t_last is not None:
            self.tick(self.t_last)

    def tick(self, t: float) -> None:
        """Time passes: heartbeat silence turns nodes lost."""
        if not self.timestamps:
            return
        for node in self.nodes.values():
            period = node.period()
            if period is None or node.last_heartbeat is None or node.lost:
                continue
            since = max(node.last_heartbeat, node.period_changed or node.last_heartbeat)
            if t - since > self.miss_factor * period:
                node.lost = True
                node.losses += 1
                self._event(t, "heartbeat", node.node_id, f"node {node.node_id}: no heartbeat for "
                                                          f"{(t - since) * 1000:.0f} ms "
                                                          f"(period {period * 1000:.0f} ms): lost", "error")

    # ------------------------------------------------------------------ one frame

    def frame(self, t: float, source: str, frame: CanFrame) -> None:
        """One frame (or error frame) at ``t``."""
        if self.t0 is None:
            self.t0 = t
        if self.t_last is None or t > self.t_last:
            self.t_last = t
        self.frames += 1
        bits = cf.frame_bits(frame)
        self.bits += bits
        self._count_recent(t, bits)
        if frame.error:
            self.error_frames += 1
            for name in cf.error_class_names(frame.can_id):
                self.error_classes[name] += 1
            tec = frame.data[6] if frame.can_id & cf.CAN_ERR_CNT else None
            extra = f" (TEC {tec})" if tec is not None else ""
            self._event(t, "error-frame", None, f"error frame: {', '.join(cf.error_class_names(frame.can_id))}"
                                                f"{extra}", "error")
            return
        if frame.remote:
            self.remote_frames += 1
        else:
            self.data_frames += 1
        if frame.extended:
            self.extended_frames += 1
        stats = self._id(frame)
        if stats is not None:
            self._update_id(stats, t, source, frame)
        if self.canopen and not frame.extended:
            self._canopen(t, frame)

    def _count_recent(self, t: float, bits: int) -> None:
        recent = self._recent
        recent.append((t, bits, 1))
        self._recent_bits += bits
        while recent and recent[0][0] < t - RECENT:
            self._recent_bits -= recent.popleft()[1]
        if self.timestamps and self.t0 is not None and t - self.t0 >= RECENT:
            if self.baud:
                self.peak_load = max(self.peak_load, self._recent_bits / (self.baud * RECENT))
            self.peak_fps = max(self.peak_fps, len(recent) / RECENT)

    def _id(self, frame: CanFrame) -> IdStats | None:
        key = (frame.can_id, frame.extended)
        stats = self.ids.get(key)
        if stats is None:
            if len(self.ids) >= MAX_IDS:
                self.ids_dropped += 1
                return None
            stats = self.ids[key] = IdStats(frame.can_id, frame.extended, self._label(frame))
            for dec in self.decoders:
                name = dec.name(frame)
                if name:
                    stats.name = name
                    break
        return stats

    def _label(self, frame: CanFrame) -> str:
        if not self.canopen or frame.extended:
            return ""
        cob = co.classify(frame.can_id)
        if cob.function == "other":
            return ""
        names = {"NMT-EC": "heartbeat", "SDO-TX": "SDO response", "SDO-RX": "SDO request"}
        what = names.get(cob.function, cob.function)
        return f"{what} node {cob.node}" if cob.node else what

    def _update_id(self, stats: IdStats, t: float, source: str, frame: CanFrame) -> None:
        if stats.last is not None and self.timestamps:
            stats.intervals.add(t - stats.last)
        if stats.first is None:
            stats.first = t
        stats.last = t
        stats.count += 1
        stats.sources[source] += 1
        if frame.remote:
            stats.remote += 1
            return
        if stats.count > 1 and frame.length != stats.dlc:
            stats.dlc_changes += 1
        stats.data = frame.data
        stats.dlc = frame.length
        for dec in self.decoders:
            try:
                values = dec.decode(frame)
            except Exception as exc:  # a decoder's complaint is a finding about the frame, not a crash
                stats.decode_errors += 1
                stats.last_decode_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                if stats.decode_errors == 1:
                    self._event(t, "decode", None, f"{stats.name or stats.key}: cannot decode "
                                                   f"{frame.data.hex(' ').upper()}: {stats.last_decode_error}", "warn")
                continue
            if values is not None:
                stats.signals = values
                break

    # ------------------------------------------------------------------ CANopen

    def _node(self, node_id: int) -> NodeState:
        node = self.nodes.get(node_id)
        if node is None:
            node = self.nodes[node_id] = NodeState(node_id)
        return node

    def _canopen(self, t: float, frame: CanFrame) -> None:
        cid = frame.can_id
        data = frame.data
        if cid == co.NMT_ID:
            if len(data) >= 2:
                self.nmt_commands += 1
                what = co.NMT_COMMANDS.get(data[0], f"command 0x{data[0]:02X}")
                target = f"node {data[1]}" if data[1] else "all nodes"
                self._event(t, "nmt", data[1] or None, f"NMT {what} -> {target}")
            return
        cob = co.classify(cid)
        if not cob.node:
            return
        fn = cob.function
        if fn == "NMT-EC":
            node = self._node(cob.node)
            if frame.remote:
                node.guarding += 1
                return
            if not data:
                return
            self._heartbeat(node, t, data[0] & 0x7F)
        elif fn == "EMCY" and data:
            node = self._node(cob.node)
            code = int.from_bytes(data[:2].ljust(2, b"\0"), "little")
            reg = data[2] if len(data) > 2 else 0
            node.emcy += 1
            node.error_register = reg
            vendor = bytes(data[3:8]).hex(" ").upper()
            node.last_emcy = {"t": t, "code": f"0x{code:04X}", "text": co.emcy_text(code), "register": reg,
                              "data": vendor}
            level = "info" if code == 0 else "error"
            self._event(t, "emcy", cob.node, f"node {cob.node} EMCY 0x{code:04X} {co.emcy_text(code)} "
                                             f"(register 0x{reg:02X}, data {vendor or '-'})", level)
        elif fn in ("SDO-RX", "SDO-TX") and not frame.remote:
            follower = self.sdo.get(cob.node)
            if follower is None:
                follower = self.sdo[cob.node] = SdoFollower(cob.node)
            done = follower.request(data, t) if fn == "SDO-RX" else follower.response(data, t)
            if done is not None:
                self._transfer(done, t)

    def _heartbeat(self, node: NodeState, t: float, state: int) -> None:
        if state == co.BOOTUP:
            node.bootups += 1
            node.state = state
            node.lost = False
            node.last_heartbeat = t
            self._event(t, "bootup", node.node_id, f"node {node.node_id} boot-up")
            return
        period = node.period()
        if node.last_heartbeat is not None and self.timestamps:
            gap = t - max(node.last_heartbeat, node.period_changed or node.last_heartbeat)
            if period and gap > self.miss_factor * period:
                missed = max(1, round(gap / period) - 1)
                node.misses += missed
                self._event(t, "heartbeat", node.node_id, f"node {node.node_id}: {missed} heartbeat(s) missed "
                                                          f"(gap {gap * 1000:.0f} ms, period {period * 1000:.0f} ms)",
                            "warn")
            elif node.state not in (None, co.BOOTUP) and node.period_changed is None:
                node.intervals.add(gap)
            if node.state not in (None, co.BOOTUP) and node.period_changed is None:
                node.recent_gaps.append(gap)
            node.period_changed = None
        if node.lost:
            self._event(t, "heartbeat", node.node_id, f"node {node.node_id} heard again")
            node.lost = False
        if node.state is not None and node.state != state and node.state != co.BOOTUP:
            self._event(t, "nmt", node.node_id, f"node {node.node_id}: {co.state_name(node.state)} -> "
                                                f"{co.state_name(state)}")
        node.state = state
        node.heartbeats += 1
        node.last_heartbeat = t

    def _transfer(self, tr: SdoTransfer, t: float) -> None:
        self.transfers.append(tr)
        self.transfer_count += 1
        node = self._node(tr.node)
        name = self.object_name(tr.node, tr.index, tr.subindex)
        where = f"0x{tr.index:04X}:{tr.subindex:02X}" + (f" {name}" if name else "")
        if tr.abort:
            node.sdo_aborts += 1
            self._event(t, "sdo", tr.node, f"node {tr.node} SDO {tr.direction} {where} aborted by {tr.aborted_by}: "
                                           f"0x{tr.abort:08X} {co.abort_text(tr.abort)}", "warn")
            return
        if tr.upload:
            node.sdo_uploads += 1
        else:
            node.sdo_downloads += 1
        value = tr.value()
        if (tr.index, tr.subindex) == (0x1017, 0) and isinstance(value, int):
            if node.configured_ms != value:
                node.intervals = Welford()  # a new period: measure it afresh
                node.recent_gaps.clear()
                node.period_changed = t
            node.configured_ms = value
        shown = repr(value) if value is not None else f"{tr.size} bytes"
        self._event(t, "sdo", tr.node, f"node {tr.node} SDO {tr.direction} {where} = {shown} ({tr.kind})")

    def object_name(self, node: int, index: int, subindex: int) -> str | None:
        for dec in self.decoders:
            name = dec.object_name(node, index, subindex)
            if name:
                return name
        return None

    # ------------------------------------------------------------------ events and figures

    def _event(self, t: float, kind: str, node: int | None, text: str, level: str = "info") -> None:
        self.events.append(Event(t, kind, node, text, level))
        self.event_counts[kind] += 1

    def recent(self, now: float | None = None) -> tuple[float, int, int] | None:
        """``(seconds, bits, frames)`` of the last second up to ``now`` (None without times)."""
        if not self.timestamps or self.t_last is None:
            return None
        now = self.t_last if now is None else now
        bits = frames = 0
        for t, b, n in self._recent:
            if now - RECENT < t <= now:
                bits += b
                frames += n
        return RECENT, bits, frames

    def load(self, now: float | None = None) -> float | None:
        """Bus load over the last second (None without a bitrate or times)."""
        r = self.recent(now)
        if r is None or not self.baud:
            return None
        return r[1] / (self.baud * r[0])

    def duration(self) -> float | None:
        if not self.timestamps or self.t0 is None or self.t_last is None:
            return None
        return self.t_last - self.t0

    def mean_load(self) -> float | None:
        d = self.duration()
        if not d or not self.baud:
            return None
        return self.bits / (self.baud * d)


__all__ = ["CanTracker", "Event", "IdStats", "NodeState", "Welford"]
