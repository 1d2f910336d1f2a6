"""Profiles from CAN captures of CANopen nodes: the CANopen family's inferrer plug-in.

The ``hilbench.inferrers`` entry point ``canopen`` (:data:`INFERRER`) reads
``can`` traffic (python-can logs, candump, hilbench captures of a CAN bus)
and tells, per node of the predefined connection set: its boot-ups, its
heartbeat (period and NMT states), its TPDOs (identifier, period, the last
payload), the SDO transfers the host made with it (uploads and their values,
downloads), its EMCY messages; for the bus: the host's NMT commands, SYNC,
RPDOs, and identifiers outside CANopen's predefined set. Each node becomes a
``recorded-node`` (:mod:`hilbench.families.canopen_recorded`): on the bench it
boots, beats and sends its PDOs at the captured periods, and answers the
captured SDO uploads with the captured bytes. ``--verify`` replays the host's
frames (:class:`~hilbench.bench.capture_replay.FrameReplay`): SDO responses
and node-guarding replies by content (by length where the capture shows a
value change), heartbeats and PDOs by period and length.
"""

from __future__ import annotations

import collections
import statistics
from dataclasses import dataclass, field
from typing import Any

from hilbench.bench.capture_profile import (
    Commented,
    Hex,
    InferOptions,
    ProfileDraft,
    SourceFacts,
    Table,
    id_ranges,
)
from hilbench.bench.capture_replay import Exchange, Expected, FrameReplay, Stream
from hilbench.families.canopen_recorded import MAX_OBJECT, RECORDED
from hilbench.monitor.can.sdo import MAX_KEPT, SdoFollower, SdoTransfer
from hilbench.protocols import can_frame as cf
from hilbench.protocols import canopen as co
from hilbench.protocols.can_frame import CanFrame
from hilbench.transports.chunk import Chunk

#: Host frames kept for ``--verify`` (a long capture replays its first ones).
MAX_EXCHANGES = 100_000
#: Frame times kept per identifier (for periods).
MAX_TIMES = 10_000
#: The bitrates an emulated CAN bus takes (:class:`hilbench.bench.can_bus.CanBus`).
MIN_BITRATE, MAX_BITRATE = 10_000, 1_000_000
#: Identifiers tracked (bounded memory on garbage).
MAX_IDS = 2048
DEFAULT_BITRATE = 500_000
_TPDO = {0x180, 0x280, 0x380, 0x480}


@dataclass
class IdObs:
    """Frames of one identifier: times, payloads, lengths."""

    can_id: int
    times: list[float] = field(default_factory=list)
    count: int = 0
    first: bytes = b""
    last: bytes = b""
    payloads: set[bytes] = field(default_factory=set)
    lengths: set[int] = field(default_factory=set)
    #: Intervals between frames (s), none across a restart.
    intervals: list[float] = field(default_factory=list)
    #: Where the next interval counts from (the last frame, or a restart; None: nowhere).
    since: float | None = None

    def add(self, t: float, data: bytes) -> None:
        if not self.count:
            self.first = data
        self.count += 1
        self.last = data
        self.lengths.add(len(data))
        if len(self.payloads) < 64:
            self.payloads.add(data)
        if len(self.times) < MAX_TIMES:
            self.times.append(t)
            if self.since is not None and t > self.since:
                self.intervals.append(t - self.since)
        self.since = t

    def restart(self, t: float) -> None:
        """The sender restarted at ``t`` (a boot-up): its timer counts from there, not from its last frame."""
        self.since = t

    def period(self) -> float | None:
        """The median interval (s), None with fewer than two intervals."""
        if len(self.intervals) < 2:
            return None
        return statistics.median(self.intervals)


@dataclass
class NodeObs:
    """What the capture shows of one node."""

    node: int
    bootups: list[float] = field(default_factory=list)
    heartbeat: IdObs = field(default_factory=lambda: IdObs(0))
    states: collections.Counter = field(default_factory=collections.Counter)
    first_state: int | None = None
    first_operational: float | None = None
    tpdos: dict[int, IdObs] = field(default_factory=dict)
    uploads: dict[tuple[int, int], list[SdoTransfer]] = field(default_factory=dict)
    downloads: dict[tuple[int, int], list[SdoTransfer]] = field(default_factory=dict)
    aborts: list[SdoTransfer] = field(default_factory=list)
    emcy: list[tuple[float, int, int, bytes]] = field(default_factory=list)
    asked: int = 0
    answered: int = 0

    @property
    def silent(self) -> bool:
        return not (self.bootups or self.heartbeat.count or self.tpdos or self.answered or self.emcy)


class _Pending:
    """A host frame and the reply frames the capture shows to it."""

    __slots__ = ("t", "frame", "reply_id", "replies", "label")

    def __init__(self, t: float, frame: CanFrame, reply_id: int | None, label: str) -> None:
        self.t = t
        self.frame = frame
        self.reply_id = reply_id
        self.replies: list[bytes] = []
        self.label = label


class CanopenSession:
    """One CAN capture (see the module docstring)."""

    def __init__(self, facts: SourceFacts, options: InferOptions) -> None:
        self.facts = facts
        self.options = options
        self.nodes: dict[int, NodeObs] = {}
        self.sdo: dict[int, SdoFollower] = {}
        self.other: dict[int, IdObs] = {}
        self.rpdos: dict[int, IdObs] = {}
        self.sync = IdObs(co.SYNC_ID)
        self.nmt: list[tuple[float, int, int]] = []
        self.frames = 0
        self.errors = 0
        self.remote = 0
        self.dropped_bytes = 0
        self.extended = 0
        self.exchanges: list[_Pending] = []
        self.dropped_exchanges = 0
        self.open: dict[int, _Pending] = {}  # reply identifier -> the host frame waiting for it

    def node(self, n: int) -> NodeObs:
        obs = self.nodes.get(n)
        if obs is None:
            obs = self.nodes[n] = NodeObs(n)
            obs.heartbeat = IdObs(0x700 + n)
        return obs

    # -------------------------------------------------------------- input

    def feed(self, chunk: Chunk) -> None:
        if chunk.lost:
            self.dropped_bytes += chunk.lost
            return
        frames, rest = cf.split(chunk.data)
        self.dropped_bytes += rest
        for frame in frames:
            self._frame(chunk.t, frame)

    def _host(self, t: float, frame: CanFrame, reply_id: int | None, label: str) -> None:
        p = _Pending(t, frame, reply_id, label)
        if len(self.exchanges) < MAX_EXCHANGES:
            self.exchanges.append(p)
        else:
            self.dropped_exchanges += 1
        if reply_id is not None:
            self.open[reply_id] = p

    def _reply(self, frame: CanFrame) -> None:
        p = self.open.pop(frame.can_id, None)
        if p is not None:
            p.replies.append(bytes(frame.data))

    def _frame(self, t: float, frame: CanFrame) -> None:
        self.frames += 1
        if frame.error:
            self.errors += 1
            return
        if frame.extended:
            self.extended += 1
            self._other(t, frame)
            return
        function, n = co.classify(frame.can_id)
        data = bytes(frame.data)
        if function == "NMT":
            if len(data) >= 2:
                self.nmt.append((t, data[0], data[1]))
            self._host(t, frame, None, f"NMT {co.NMT_COMMANDS.get(data[0], hex(data[0]))}")
        elif function == "SYNC":
            self.sync.add(t, data)
            self._host(t, frame, None, "SYNC")
        elif function in ("TIME", "LSS"):
            self._host(t, frame, co.LSS_SLAVE_ID if frame.can_id == co.LSS_MASTER_ID else None, function)
            if frame.can_id == co.LSS_SLAVE_ID:
                self._reply(frame)
        elif function == "NMT-EC":
            obs = self.node(n)
            if frame.remote:
                self.remote += 1
                obs.asked += 1
                self._host(t, frame, frame.can_id, f"node guarding of node {n}")
            elif data:
                if frame.can_id in self.open:
                    obs.answered += 1
                    self._reply(frame)
                state = data[0] & 0x7F
                if state == co.BOOTUP:
                    obs.bootups.append(t)
                    obs.heartbeat.restart(t)  # the heartbeat timer starts with the boot-up
                    for ido in obs.tpdos.values():
                        ido.since = None  # PDOs start again with the next NMT start
                else:
                    if obs.first_state is None:
                        obs.first_state = state
                    if state == co.OPERATIONAL and obs.first_operational is None:
                        obs.first_operational = t
                    obs.states[state] += 1
                    obs.heartbeat.add(t, data)
        elif function in ("TPDO1", "TPDO2", "TPDO3", "TPDO4"):
            obs = self.node(n)
            ido = obs.tpdos.get(frame.can_id)
            if ido is None:
                ido = obs.tpdos[frame.can_id] = IdObs(frame.can_id)
            ido.add(t, data)
        elif function.startswith("RPDO"):
            ido = self.rpdos.get(frame.can_id)
            if ido is None and len(self.rpdos) < MAX_IDS:
                ido = self.rpdos[frame.can_id] = IdObs(frame.can_id)
            if ido is not None:
                ido.add(t, data)
            self._host(t, frame, None, f"{function} 0x{frame.can_id:03X}")
        elif function == "SDO-RX":
            obs = self.node(n)
            obs.asked += 1
            follower = self.sdo.setdefault(n, SdoFollower(n))
            done = follower.request(data, t)
            if done is not None:
                self._transfer(done)
            self._host(t, frame, 0x580 + n, f"SDO request to node {n} ({_sdo_text(data)})")
        elif function == "SDO-TX":
            obs = self.node(n)
            obs.answered += 1
            self._reply(frame)
            follower = self.sdo.setdefault(n, SdoFollower(n))
            done = follower.response(data, t)
            if done is not None:
                self._transfer(done)
        elif function == "EMCY":
            obs = self.node(n)
            if len(data) >= 3:
                obs.emcy.append((t, int.from_bytes(data[:2], "little"), data[2], data[3:8]))
        else:
            self._other(t, frame)

    def _other(self, t: float, frame: CanFrame) -> None:
        ido = self.other.get(frame.can_id)
        if ido is None and len(self.other) < MAX_IDS:
            ido = self.other[frame.can_id] = IdObs(frame.can_id)
        if ido is not None:
            ido.add(t, bytes(frame.data))

    def _transfer(self, tr: SdoTransfer) -> None:
        obs = self.node(tr.node)
        if tr.abort:
            obs.aborts.append(tr)
            return
        book = obs.uploads if tr.upload else obs.downloads
        book.setdefault((tr.index, tr.subindex), []).append(tr)

    # -------------------------------------------------------------- the draft

    def finish(self) -> ProfileDraft:
        return _Drafter(self).build()


def _sdo_text(data: bytes) -> str:
    data = bytes(data[:8]).ljust(8, b"\0")
    cs = co.specifier(data[0])
    if cs in (co.CCS_INITIATE_UPLOAD, co.CCS_INITIATE_DOWNLOAD):
        _cmd, index, sub, _payload = co.parse_initiate(data)
        return f"{'upload' if cs == co.CCS_INITIATE_UPLOAD else 'download'} 0x{index:04X} sub {sub}"
    return {co.CCS_UPLOAD_SEGMENT: "upload segment", co.CCS_DOWNLOAD_SEGMENT: "download segment",
            co.CCS_ABORT: "abort"}.get(cs, f"command 0x{data[0]:02X}")


def _ms(seconds: float) -> int:
    return max(1, round(seconds * 1000))


class _Drafter:
    def __init__(self, s: CanopenSession) -> None:
        self.s = s
        self.draft = ProfileDraft(description="")
        self.live: dict[int, set[tuple[int, int]]] = {}

    def _objects(self, obs: NodeObs, notes: list[str]) -> list[dict[str, Any]]:
        objects = []
        varying = self.live.setdefault(obs.node, set())
        keys = sorted(set(obs.uploads) | set(obs.downloads))
        for key in keys:
            index, sub = key
            ups = obs.uploads.get(key, [])
            downs = obs.downloads.get(key, [])
            first_down = downs[0].t_start if downs else None
            before = [u for u in ups if first_down is None or u.t_start < first_down]
            source = before[0] if before else (downs[0] if downs else ups[0])
            data = bytes(source.data[:MAX_OBJECT])
            if not data:
                continue
            if source.received > len(source.data):
                notes.append(f"0x{index:04X} sub {sub}: {source.received} bytes, only the first {MAX_KEPT} kept")
            values = {bytes(u.data) for u in before}
            if len(values) > 1:
                varying.add(key)
            entry: dict[str, Any] = {"index": Hex(index, 4), "subindex": sub, "data": data.hex(" ")}
            if downs:
                entry["access"] = "rw"
            value = source.value()
            note = repr(value) if isinstance(value, str) else (f"0x{value:X}" if value > 9 else str(value)) \
                if value is not None else ""
            if key in varying:
                note = (note + ": " if note else "") + "the first of several values"
            objects.append(Commented(entry, note))
        return objects

    def _node_table(self, obs: NodeObs) -> Table:
        s = self.s
        t = Table()
        notes: list[str] = []
        t.set("model", RECORDED)
        t.set("name", f"node{obs.node}")
        t.set("node_id", obs.node)
        period = obs.heartbeat.period()
        hb_up = obs.uploads.get((0x1017, 0))
        if hb_up and len(hb_up[0].data) == 2:
            t.set("heartbeat_ms", int.from_bytes(hb_up[0].data, "little"), "its 0x1017 as uploaded")
        elif period is not None:
            t.set("heartbeat_ms", _ms(period), f"measured over {obs.heartbeat.count} heartbeats")
        else:
            t.set("heartbeat_ms", 0, "no heartbeat in the capture" if not obs.heartbeat.count else
                  "too few heartbeats to tell a period")
        became = obs.first_operational
        started = any(cmd == co.NMT_START and target in (0, obs.node) and (became is None or t0 <= became)
                      for t0, cmd, target in s.nmt)
        operational = obs.first_state == co.OPERATIONAL
        if operational and not started:
            t.set("autostart", True, "OPERATIONAL from its first heartbeat without an NMT start")
        else:
            why = "the host's NMT start (replayed by --verify) makes it OPERATIONAL" if started else \
                "never OPERATIONAL in the capture" if obs.first_state is not None else "no NMT state seen"
            t.set("autostart", False, why)
        tpdos = []
        for cob, ido in sorted(obs.tpdos.items()):
            p = ido.period()
            if p is None:
                notes.append(f"PDO 0x{cob:03X}: {ido.count} frame(s), too few for a period: not sent")
                continue
            tpdos.append(Commented({"cob_id": Hex(cob, 3), "period_ms": _ms(p), "data": ido.last.hex(" ")},
                                   f"{ido.count} frames, {len(ido.payloads)}{'+' if len(ido.payloads) >= 64 else ''}"
                                   " payload(s)"))
        if tpdos:
            t.set("tpdos", tpdos, "sent in OPERATIONAL at the measured periods, with the last payloads")
        objects = self._objects(obs, notes)
        if objects:
            t.set("objects", objects, "as the host's SDO uploads returned them")
        if obs.silent:
            t.set("faults", {"silent": True}, "it never answered in the capture")
        head = [self._summary(obs)]
        head += [f"  {n}" for n in notes]
        if obs.emcy:
            codes = ", ".join(f"0x{c:04X} ({co.emcy_text(c)})" for _, c, _, _ in obs.emcy[:4])
            head.append(f"  EMCY seen (not sent by the bench): {codes}")
        t.comment = head
        return t

    def _summary(self, obs: NodeObs) -> str:
        if obs.silent:
            return f"node {obs.node}: asked {obs.asked} time(s), never answered"
        parts = [f"node {obs.node}:"]
        if obs.bootups:
            parts.append(f"{len(obs.bootups)} boot-up(s),")
        if obs.heartbeat.count:
            states = ", ".join(f"{co.state_name(st)} {n}x" for st, n in obs.states.most_common())
            parts.append(f"{obs.heartbeat.count} heartbeats ({states}),")
        if obs.tpdos:
            parts.append(f"{len(obs.tpdos)} PDO identifier(s),")
        ups = sum(len(v) for v in obs.uploads.values())
        downs = sum(len(v) for v in obs.downloads.values())
        if ups or downs or obs.aborts:
            parts.append(f"SDO {ups} upload(s), {downs} download(s), {len(obs.aborts)} abort(s),")
        return " ".join(parts).rstrip(",")

    def _seen(self) -> None:
        s, draft = self.s, self.draft
        draft.seen.append(f"CAN traffic: {s.frames} frames" + (f", {s.errors} error frames" if s.errors else "")
                          + (f", {s.extended} with extended identifiers" if s.extended else ""))
        live = sorted(n for n, o in s.nodes.items() if not o.silent)
        silent = sorted(n for n, o in s.nodes.items() if o.silent)
        if live:
            draft.seen.append(f"CANopen nodes: {id_ranges(live)}")
        if silent:
            draft.seen.append(f"asked but never answering: node {id_ranges(silent)}")
        for n in live:
            o = s.nodes[n]
            p = o.heartbeat.period()
            line = f"node {n}: " + (f"heartbeat every {1e3 * p:.1f} ms" if p else "no steady heartbeat")
            if o.bootups:
                line += f", boot-up at {o.bootups[0] - (s.facts.t_first or 0):.3f} s"
            for cob, ido in sorted(o.tpdos.items()):
                pp = ido.period()
                line += f"; PDO 0x{cob:03X} " + (f"every {1e3 * pp:.1f} ms" if pp else f"{ido.count}x")
            draft.seen.append(line)
            for (index, sub), trs in sorted(o.uploads.items()):
                value = trs[0].value()
                shown = f"{value:#x}" if isinstance(value, int) else repr(value) if value is not None else \
                    bytes(trs[0].data).hex(" ")
                varies = " (changed later)" if (index, sub) in self.live.get(n, set()) else ""
                draft.seen.append(f"  SDO upload 0x{index:04X} sub {sub}: {shown}{varies}")
            for tr in o.aborts[:5]:
                draft.seen.append(f"  SDO {tr.direction} 0x{tr.index:04X} sub {tr.subindex} aborted by the "
                                  f"{tr.aborted_by}: 0x{tr.abort:08X} ({co.abort_text(tr.abort)})")
            for t, code, reg, _data in o.emcy[:5]:
                draft.seen.append(f"  EMCY 0x{code:04X} ({co.emcy_text(code)}), error register 0x{reg:02X}, at "
                                  f"{t - (s.facts.t_first or 0):.3f} s")
        for cob, ido in sorted(s.other.items())[:10]:
            p = ido.period()
            draft.unread.append(f"identifier 0x{cob:X}: {ido.count} frame(s)" +
                                (f" every {1e3 * p:.1f} ms" if p else "") +
                                ", outside CANopen's predefined set: not emulated")
        if s.dropped_bytes:
            draft.unread.append(f"{s.dropped_bytes} bytes were no whole frame record")

    def _pattern(self) -> None:
        s, out = self.s, self.draft.pattern
        for t, command, target in s.nmt[:10]:
            who = "all nodes" if target == 0 else f"node {target}"
            out.append(f"NMT {co.NMT_COMMANDS.get(command, hex(command))} to {who} at "
                       f"{t - (s.facts.t_first or 0):.3f} s")
        if len(s.nmt) > 10:
            out.append(f"... {len(s.nmt) - 10} more NMT commands")
        if s.sync.count:
            p = s.sync.period()
            out.append(f"SYNC: {s.sync.count} frames" + (f", every {1e3 * p:.1f} ms" if p else ""))
        for cob, ido in sorted(s.rpdos.items()):
            p = ido.period()
            out.append(f"RPDO 0x{cob:03X}: {ido.count} frames" + (f", every {1e3 * p:.1f} ms" if p else ""))
        for n, o in sorted(s.nodes.items()):
            ups = sum(len(v) for v in o.uploads.values())
            downs = sum(len(v) for v in o.downloads.values())
            if ups or downs:
                out.append(f"SDO with node {n}: {ups} upload(s) of {len(o.uploads)} object(s), {downs} "
                           f"download(s) of {len(o.downloads)}")

    def _endpoint(self) -> Table:
        facts = self.s.facts
        t = Table()
        t.set("type", "can")
        t.set("protocol", "can")
        if facts.baud and not MIN_BITRATE <= facts.baud <= MAX_BITRATE:  # as the servo buses treat a rate they lack
            t.set("bitrate", DEFAULT_BITRATE, "not the capture's rate (see the header)")
            self.draft.contradictions.append(f"the capture's {facts.baud} bit/s is no CAN bitrate (an emulated bus "
                                             f"runs at {MIN_BITRATE}..{MAX_BITRATE}): {DEFAULT_BITRATE} used")
        elif facts.baud:
            t.set("bitrate", facts.baud, "from --baud" if facts.baud_from == "--baud" else "from the capture")
        else:
            t.set("bitrate", DEFAULT_BITRATE, "NOT IN THE CAPTURE: give --baud (a common rate)")
            self.draft.guessed.append(f"bitrate {DEFAULT_BITRATE}: the capture says none (give --baud)")
        t.set("paced", True, "arbitration and bit time")
        t.set("socketcand", {"port": 0, "channel": "can0"}, "port 0: any free port (the manifest says which)")
        t.set("slcan", True)
        return t

    def _replay(self) -> FrameReplay:
        s = self.s
        exchanges = []
        for p in s.exchanges:
            expected = []
            for data in p.replies[:1]:
                mask = None
                if p.reply_id is not None and 0x580 <= p.reply_id < 0x600:
                    node = p.reply_id - 0x580
                    mask = self._sdo_mask(node, data)
                elif data:
                    mask = bytes([0x7F]) + bytes([0xFF]) * (len(data) - 1)  # a guarding reply's toggle bit
                expected.append(Expected(p.reply_id, data, mask))
            exchanges.append(Exchange(p.t, cf.pack(p.frame), tuple(expected), p.label, 0.0))
        streams = []
        for n, o in sorted(s.nodes.items()):
            if o.silent:
                continue
            p = o.heartbeat.period()
            if p is not None:
                streams.append(Stream(0x700 + n, p, 1, None, f"node {n}'s heartbeat"))
            for cob, ido in sorted(o.tpdos.items()):
                pp = ido.period()
                if pp is not None and len(ido.lengths) == 1:
                    const = next(iter(ido.payloads)) if len(ido.payloads) == 1 else None
                    streams.append(Stream(cob, pp, next(iter(ido.lengths)), const, f"PDO 0x{cob:03X}"))
        notes = []
        if s.dropped_exchanges:
            notes.append(f"only the first {len(exchanges)} host frames are replayed ({s.dropped_exchanges} more)")
        # Nodes already running when the host's first frame came: the bench's boot first (its boot delay), so
        # that first frame finds them as the capture did.
        first = s.exchanges[0].t if s.exchanges else None
        up = [n for n, o in s.nodes.items() if not o.silent and first is not None
              and (not o.bootups or o.bootups[0] > first)]

        def ready(bench: Any) -> bool:
            nodes = bench.family("canopen")
            return all(nodes.node(n).state != co.BOOTUP for n in up)

        return FrameReplay("can", exchanges, streams, span=s.facts.span, notes=notes, t0=s.facts.t_first,
                           ready=ready if up else None)

    def _sdo_mask(self, node: int, data: bytes) -> bytes:
        """An SDO response compared whole, but for the value of an object the capture shows changing."""
        data = bytes(data)
        if len(data) == 8 and co.specifier(data[0]) == co.SCS_INITIATE_UPLOAD:
            _cmd, index, sub, _payload = co.parse_initiate(data)
            if (index, sub) in self.live.get(node, set()):
                return bytes([0xFF] * 4 + [0] * 4)
        if len(data) == 8 and co.specifier(data[0]) == co.SCS_UPLOAD_SEGMENT:
            return bytes([0xFF] + [0] * 7)  # a segment's bytes: compared by length (which object is not said)
        return bytes([0xFF]) * len(data)

    def build(self) -> ProfileDraft:
        s, draft = self.s, self.draft
        draft.endpoints["can"] = self._endpoint()
        for _n, obs in sorted(s.nodes.items()):
            t = self._node_table(obs)
            if obs.silent and not s.options.keep_silent:
                t.disabled = True
                t.comment.append("  (never answered: kept as a comment; --keep-silent makes it a silent node)")
            draft.devices.append(t)
        self._seen()
        self._pattern()
        live = [n for n, o in s.nodes.items() if not o.silent]
        draft.description = f"CAN bus from a capture: CANopen node(s) {id_ranges(live)}" if live else \
            "CAN bus from a capture: no CANopen node answered"
        draft.replay = self._replay()
        return draft


class CanopenInferrer:
    """CANopen nodes from CAN traffic."""

    title = "CANopen nodes on a CAN bus"
    protocols = ("can",)

    def session(self, facts: SourceFacts, options: InferOptions) -> CanopenSession:
        return CanopenSession(facts, options)


#: The ``hilbench.inferrers`` plug-in.
INFERRER = CanopenInferrer()

__all__ = ["INFERRER", "CanopenInferrer", "CanopenSession"]
