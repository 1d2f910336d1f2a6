"""An emulated CAN bus: arbitration by identifier, bit-time pacing, error frames, bus-off and bus load.

Parties are in-process devices (``on_frame(frame, t)``; they send through the
:class:`CanDevicePort` :meth:`CanMedium.add_device` returns) and CAN host ports
(:mod:`hilbench.transports.can_port`: socketcand, SLCAN, SocketCAN and
python-can ``virtual`` doors), whose every client is a sender of its own. A
frame reaches every party but its sender (as SocketCAN does with
``CAN_RAW_RECV_OWN_MSGS`` off), and every tap as ``(t, sender, 16 bytes of
struct can_frame)`` (:mod:`hilbench.protocols.can_frame`).

Timing. Unpaced (the default), a frame is delivered when it is sent. Paced,
the bus models a real one: each sender has a transmit queue (FIFO, like a
SocketCAN qdisc); whenever the bus falls idle the queue heads arbitrate and
the lowest identifier wins (:func:`~hilbench.protocols.can_frame.arbitration_key`);
the winner occupies the bus for its exact stuffed bit count plus the
interframe space at the bitrate, and is delivered when its last bit is on
the wire. Queueing delay, arbitration order and bus load then come out as on
the real bus.

Faults (:meth:`CanMedium.set_faults`). ``error_rate`` destroys that share of
transmission attempts and ``error_next`` the next N: receivers signal an error
frame (reported to every party as a SocketCAN error frame), the sender's
transmit error counter (TEC) rises by 8 and the controller retransmits, as
CAN controllers do. A successful transmission lowers the TEC by 1. At TEC 128
the sender is error passive, above 255 it is bus-off: its queue is dropped
and it sends nothing until it recovers after 128 x 11 recessive bits
(``auto_recover``), when its TEC is 0 again. :meth:`CanMedium.force_bus_off`
puts one sender there at once. Devices with ``on_bus_state(state, t)`` hear
their own controller's state changes (``active``, ``passive``, ``bus-off``,
``recovered``).
"""

from __future__ import annotations

import collections
import logging
import random
import threading
from dataclasses import dataclass, field
from typing import Any, Protocol

from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import CanFrame
from hilbench.rules import FAULT_COUNT, PROBABILITY, SWITCH
from hilbench.transports.clock import WALL, Waiter, WallClock, wait
from hilbench.transports.line_load import is_unpaced
from hilbench.transports.medium import DevicePort
from hilbench.transports.medium_loop import LoopMedium

log = logging.getLogger(__name__)

DEFAULT_BITRATE = 500_000
#: Recessive bit sequences a bus-off controller must see before it may transmit again.
BUS_OFF_RECOVERY_BITS = 128 * 11
ERROR_PASSIVE = 128
BUS_OFF = 256
#: Frames a sender's transmit queue holds (paced); beyond, new frames are dropped and counted.
TX_QUEUE_LIMIT = 4096
#: Seconds of history the bus load figure covers.
LOAD_WINDOW = 1.0
#: The bus load history sums bits per slot of this many seconds: an unpaced bus flooded with 40 000 frames a
#: second kept a record per frame for 10 s (30 MB, and the allocator kept it after the flood).
LOAD_SLOT = 0.001

#: The bus's fault knobs and their rules (the CANopen family checks profiles and control commands with them).
FAULT_RULES = {"error_rate": PROBABILITY, "error_next": FAULT_COUNT, "auto_recover": SWITCH}


def _none() -> None:
    return None


class CanDevice(Protocol):
    """An in-process party on a CAN medium."""

    name: str

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """A frame (or an error frame) another party put on the bus, complete at time ``t``."""


class CanDevicePort(DevicePort):
    """What a device holds to send frames on its CAN medium."""

    def send(self, frame: CanFrame, t: float | None = None) -> None:
        """Queue ``frame`` for transmission (not before ``t``); thread-safe."""
        self._medium.send(self.name, frame, t)

    def transmit(self, data: bytes, t: float | None = None, gap: float = 0.0, baud: int | None = None) -> float:
        """Send frames given as 16-byte SocketCAN records (the generic :class:`DevicePort` form)."""
        frames, _ = cf.split(data)
        at = None if t is None else t + gap
        for frame in frames:
            self._medium.send(self.name, frame, at)
        return self._medium.clock.now() if at is None else at

    @property
    def state(self) -> str:
        """This device's controller state: ``active``, ``passive`` or ``bus-off``."""
        return self._medium.controller_state(self.name)


@dataclass
class CanMediumStats:
    """Counters of the bus."""

    frames: int = 0
    error_frames: int = 0
    bits: int = 0
    attempts_failed: int = 0
    dropped_bus_off: int = 0
    dropped_queue_full: int = 0
    callback_errors: int = 0
    by_source: dict[str, int] = field(default_factory=dict)


class CanMedium(LoopMedium):
    """One CAN bus at ``baud`` bit/s (default 500 kbit/s); see the module docstring."""

    kind = "can"
    thread_prefix = "can"

    def __init__(self, name: str, baud: int | None = None, *, paced: bool = False, seed: int | None = None,
                 clock: WallClock = WALL) -> None:
        super().__init__(name, baud or DEFAULT_BITRATE, paced=paced, clock=clock)
        self.stats = CanMediumStats()
        self.rng = random.Random(seed)
        self.faults: dict[str, Any] = {"error_rate": 0.0, "error_next": 0, "auto_recover": True}
        self.tec: dict[str, int] = {}
        self._bus_off: set[str] = set()
        self._queues: dict[str, collections.deque[CanFrame]] = {}
        self._busy_until = 0.0
        self._arbitrating = False
        self._load: collections.deque[list[int]] = collections.deque()  # [slot number, bits], oldest first
        self._load_bits = 0

    @property
    def bitrate(self) -> int:
        return int(self.baud or DEFAULT_BITRATE)

    @property
    def wall_offset(self) -> float:
        """Unix time minus bus time: the clock's one mapping, so wire stamps never jump."""
        return self.clock.wall(0.0)

    def wall(self, t: float) -> float:
        """Unix time of bus time ``t`` (what socketcand stamps frames with)."""
        return self.clock.wall(t)

    # ------------------------------------------------------------------ wiring

    def add_device(self, device: Any) -> CanDevicePort:
        """Attach an in-process device (``on_frame``); it sends through the returned port."""
        with self._lock:
            self._devices.append(device)
        return CanDevicePort(self, device.name)

    def add_host(self, port: Any, *, listen_only: bool = False) -> None:
        """Attach a CAN host port (``filenos``, ``read_frames``, ``write_frames``, ``flush``, ``poll``)."""
        super().add_host(port, listen_only=listen_only)
        attach = getattr(port, "attach", None)
        if attach is not None:
            attach(self)
        self._wake()

    # ------------------------------------------------------------------ faults and state

    def set_faults(self, **knobs: Any) -> dict[str, Any]:
        """Turn fault knobs (``error_rate`` 0..1, ``error_next`` N, ``auto_recover``); returns them all."""
        for key, value in knobs.items():
            rule = FAULT_RULES.get(key)
            if rule is None:
                raise ValueError(f"unknown bus fault {key!r} (expected one of: {', '.join(FAULT_RULES)})")
            if key == "auto_recover":
                value = bool(value)
            elif not rule.any_number().ok(value):  # (Python callers may give a count as a float)
                raise ValueError(f"bus fault {key}: expected {rule.expected}, got {value!r}")
            with self._lock:
                self.faults[key] = value
        return dict(self.faults)

    def controller_state(self, source: str) -> str:
        """``active``, ``passive`` or ``bus-off`` for a sender's controller."""
        if source in self._bus_off:
            return "bus-off"
        return "passive" if self.tec.get(source, 0) >= ERROR_PASSIVE else "active"

    def force_bus_off(self, source: str) -> None:
        """Put ``source``'s controller into bus-off now (as after 32 failed attempts)."""
        self.call_at(None, lambda: self._enter_bus_off(source, self._now()))

    def recover(self, source: str) -> None:
        """Restart a bus-off controller now (what ``ip link set canX type can restart`` does)."""
        self.call_at(None, lambda: self._recover(source, self._now()))

    def load(self, window: float = LOAD_WINDOW, now: float | None = None) -> float:
        """Share of the last ``window`` seconds the bus was busy (bits sent / bits possible)."""
        now = self._now() if now is None else now
        first = (now - window) / LOAD_SLOT  # (a slot counts if it began after the window did: one slot off at most)
        with self._lock:
            bits = sum(b for slot, b in self._load if slot > first)
        return bits / (self.bitrate * window)

    def status(self) -> dict[str, Any]:
        """The bus's figures for the manifest and the control channel (safe from any thread)."""
        s = self.stats
        tec, off = dict(self.tec), set(self._bus_off)  # copies: the bus thread changes them
        load = self.load()
        unpaced = is_unpaced(load)  # more bits than the bitrate carries: no load to speak of
        return {"bitrate": self.bitrate, "paced": self.paced, "frames": s.frames, "error_frames": s.error_frames,
                "failed_attempts": s.attempts_failed, "dropped_bus_off": s.dropped_bus_off,
                "dropped_queue_full": s.dropped_queue_full, "load": None if unpaced else round(load, 4),
                "unpaced": unpaced,
                "faults": dict(self.faults),
                "controllers": {src: {"tec": tec.get(src, 0),
                                      "state": "bus-off" if src in off else
                                      "passive" if tec.get(src, 0) >= ERROR_PASSIVE else "active"}
                                for src in sorted(set(tec) | off)}}

    # ------------------------------------------------------------------ sending

    def send(self, source: str, frame: CanFrame, t: float | None = None) -> None:
        """Put ``frame`` from ``source`` on the bus (not before ``t``); thread-safe."""
        in_thread = threading.get_ident() == self._ident
        if t is None and in_thread:
            self._submit(source, frame, self._now())
            return
        with self._lock:
            at = self._now() if t is None else t
            self._push(at, lambda: self._submit(source, frame, max(at, self._now())))
        if not in_thread:
            self._wake()

    def transmit(self, source: str, data: bytes, *, t: float | None = None, gap: float = 0.0,
                 baud: int | None = None) -> float:
        """Send 16-byte SocketCAN records (the generic medium form); returns when they were queued."""
        frames, _ = cf.split(bytes(data))
        at = None if t is None else t + gap
        for frame in frames:
            self.send(source, frame, at)
        return self._now() if at is None else at

    def _submit(self, source: str, frame: CanFrame, now: float) -> None:
        if source in self._bus_off:
            self.stats.dropped_bus_off += 1
            return
        if not self.paced:
            self._attempt_unpaced(source, frame, now)
            return
        queue = self._queues.get(source)
        if queue is None:
            queue = self._queues[source] = collections.deque()
        if len(queue) >= TX_QUEUE_LIMIT:
            self.stats.dropped_queue_full += 1
            return
        queue.append(frame)
        if not self._arbitrating:
            self._arbitrating = True
            start = max(now, self._busy_until)
            with self._lock:
                self._push(start, lambda: self._arbitrate(start))

    def _fails(self) -> bool:
        """Whether the fault knobs destroy this transmission attempt (called in the bus thread)."""
        f = self.faults
        if f["error_next"] > 0:
            f["error_next"] -= 1
            return True
        rate = f["error_rate"]
        return rate > 0 and self.rng.random() < rate

    def _attempt_unpaced(self, source: str, frame: CanFrame, now: float) -> None:
        bits = cf.frame_bits(frame)
        while self._fails():
            self._count_bits(now, bits // 2 + cf.ERROR_FRAME_BITS)
            self._error(source, now)
            if source in self._bus_off:
                self.stats.dropped_bus_off += 1
                return
        self._count_bits(now, bits)
        self._success(source)
        self._deliver(source, frame, now)

    def _arbitrate(self, t: float) -> None:
        """Contention at bus time ``t`` (the end of the previous frame, or when a frame found the bus idle)."""
        start = max(t, self._busy_until)
        best = None
        for src, queue in self._queues.items():
            if queue and src not in self._bus_off:
                key = cf.arbitration_key(queue[0])
                if best is None or key < best[0]:
                    best = (key, src)
        if best is None:
            self._arbitrating = False
            return
        source = best[1]
        frame = self._queues[source][0]
        bits = cf.frame_bits(frame)
        if self._fails():
            # Receivers flag the error somewhere in the frame; the sender retries after the error frame.
            used = self.rng.randint(14, max(14, bits - cf.TRAILER_BITS)) + cf.ERROR_FRAME_BITS
            end = start + used / self.bitrate
            self._busy_until = end
            self._count_bits(end, used)

            def failed() -> None:
                self._error(source, end)
                self._arbitrate(end)

            with self._lock:
                self._push(end, failed)
            return
        self._queues[source].popleft()
        end = start + bits / self.bitrate
        self._busy_until = end
        self._count_bits(end, bits)

        def done() -> None:
            self._success(source)
            self._deliver(source, frame, end)
            self._arbitrate(end)

        with self._lock:
            self._push(end, done)

    def _count_bits(self, t: float, bits: int) -> None:
        self.stats.bits += bits
        slot = int(t / LOAD_SLOT)
        with self._lock:
            load = self._load
            if load and load[-1][0] == slot:
                load[-1][1] += bits
                return
            load.append([slot, bits])
            oldest = slot - int(10 * LOAD_WINDOW / LOAD_SLOT)
            while load[0][0] < oldest:
                load.popleft()

    # ------------------------------------------------------------------ error confinement

    def _success(self, source: str) -> None:
        tec = self.tec.get(source, 0)
        if tec:
            self.tec[source] = tec - 1
            if tec == ERROR_PASSIVE:  # back below the passive threshold
                self._state_change(source, "active", self._now())

    def _error(self, source: str, t: float) -> None:
        self.stats.attempts_failed += 1
        before = self.tec.get(source, 0)
        tec = self.tec[source] = before + 8
        data = bytearray(8)
        data[2] = cf.CAN_ERR_PROT_TX
        data[3] = cf.CAN_ERR_PROT_LOC_CRC_SEQ
        data[6] = min(tec, 255)
        self._deliver_error(cf.CAN_ERR_PROT | cf.CAN_ERR_BUSERROR | cf.CAN_ERR_CNT, bytes(data), t)
        if tec >= BUS_OFF:
            self._enter_bus_off(source, t)
        elif before < ERROR_PASSIVE <= tec:
            data = bytearray(8)
            data[1] = cf.CAN_ERR_CRTL_TX_PASSIVE
            data[6] = tec
            self._deliver_error(cf.CAN_ERR_CRTL | cf.CAN_ERR_CNT, bytes(data), t)
            self._state_change(source, "passive", t)

    def _enter_bus_off(self, source: str, t: float) -> None:
        if source in self._bus_off:
            return
        self._bus_off.add(source)
        self.tec[source] = max(self.tec.get(source, 0), BUS_OFF)
        queue = self._queues.get(source)
        if queue:
            self.stats.dropped_bus_off += len(queue)
            queue.clear()
        self._deliver_error(cf.CAN_ERR_BUSOFF, bytes(8), t)
        self._state_change(source, "bus-off", t)
        if self.faults["auto_recover"]:
            at = t + BUS_OFF_RECOVERY_BITS / self.bitrate
            with self._lock:
                self._push(at, lambda: self._recover(source, at))

    def _recover(self, source: str, t: float) -> None:
        if source not in self._bus_off:
            return
        self._bus_off.discard(source)
        self.tec[source] = 0
        self._deliver_error(cf.CAN_ERR_RESTARTED, bytes(8), t)
        self._state_change(source, "recovered", t)

    def _state_change(self, source: str, state: str, t: float) -> None:
        for device in self._devices:
            if device.name == source:
                handler = getattr(device, "on_bus_state", None)
                if handler is not None:
                    try:
                        handler(state, t)
                    except Exception:
                        self.stats.callback_errors += 1
                        log.exception("device %s failed on bus state %s", device.name, state)

    # ------------------------------------------------------------------ delivery

    def _deliver_error(self, error_class: int, data: bytes, t: float) -> None:
        self.stats.error_frames += 1
        self._deliver("bus", cf.error_frame(error_class, data), t)

    def _deliver(self, source: str, frame: CanFrame, t: float) -> None:
        stats = self.stats
        if not frame.error:
            stats.frames += 1
            stats.by_source[source] = stats.by_source.get(source, 0) + 1
        for port, _listen_only in self._hosts:
            try:
                port.write_frame(t, source, frame)
            except Exception:
                stats.callback_errors += 1
                log.exception("host port %s failed on a frame", getattr(port, "name", port))
        for device in self._devices:
            if device.name != source:
                try:
                    device.on_frame(frame, t)
                except Exception:  # one faulty device must not stop the bus
                    stats.callback_errors += 1
                    log.exception("device %s failed on frame %s", device.name, frame)
        if self._taps:
            record = cf.pack(frame)
            for tap in self._taps:
                try:
                    tap(t, source, record)
                except Exception:
                    stats.callback_errors += 1
                    log.exception("tap failed")

    # ------------------------------------------------------------------ running (timers, thread: LoopMedium)

    def wake(self) -> None:
        """Make the bus thread look at its host ports again (a port opened a door)."""
        self._wake()

    def _run(self) -> None:
        waker = self._waker
        waiter = Waiter() if self.paced else wait  # a paced bus keeps its frames' times
        while not self._stop.is_set():
            with self._lock:
                deadline = self._events[0][0] if self._events else None
                hosts = list(self._hosts)
            fds = [waker.fd]
            for port, _ in hosts:
                fds.extend(port.filenos())
                for d in (port.deadline(), getattr(port, "wall_deadline", _none)()):  # (one time base on the wall clock)
                    if d is not None and (deadline is None or d < deadline):
                        deadline = d
            # No leave_cpu (see Waiter and SerialMedium._run): it keeps a SCHED_FIFO line's polling from
            # holding back the tty worker its pty write woke on the same CPU; this thread runs under the
            # normal scheduler, whose wake-up preemption lets the worker in. Measured (an SLCAN listener at
            # 1 Mbit/s, bursts of 20 frames, three runs each): passing it after rounds whose doors wrote made
            # the fastest tenth of frames 8-35 us later and moved the median and p90 no more than the
            # loaded machine's noise did.
            ready = waiter(fds, deadline)
            now = self._now()
            if ready:
                if waker.fd in ready:
                    waker.drain()
            for port, listen_only in hosts:
                self._take(port, listen_only, now, bool(ready) and any(fd in ready for fd in port.filenos()), True)
            self._run_due()
            self._flush_hosts(hosts)

    def _take(self, port, listen_only: bool, now: float, read: bool, poll: bool) -> None:
        """What a host port's doors received (``read``: its descriptors are ready) and what their timers made
        (``poll``), onto the bus; a door that fails is counted and logged, and the bus goes on."""
        try:
            frames = port.read_frames(now) if read else []
            if poll:
                frames += port.poll(now)
        except Exception:
            self.stats.callback_errors += 1
            log.exception("host port %s failed", getattr(port, "name", port))
            return
        if not listen_only:
            for src, frame in frames:
                self._submit(src, frame, now)

    def _flush_hosts(self, hosts) -> None:
        for port, _ in hosts:
            try:
                port.flush()
            except Exception:
                self.stats.callback_errors += 1
                log.exception("host port %s failed to flush", getattr(port, "name", port))

    # ------------------------------------------------------------------ virtual time (a VirtualLoop runs it)

    def vt_deadline(self) -> float | None:
        times = [d for port, _ in list(self._hosts) if (d := port.deadline()) is not None]
        return min(times) if times else None

    def vt_fds(self) -> list[int]:
        fds = [self._waker.fd]
        for port, _ in list(self._hosts):
            fds.extend(port.filenos())
        return fds

    def vt_read(self, ready: list[int], now: float) -> bool:
        got = super().vt_read(ready, now)
        for port, listen_only in list(self._hosts):
            if any(fd in ready for fd in port.filenos()):
                got = True
                self._take(port, listen_only, now, True, False)
        return got

    def vt_poll(self, now: float) -> None:
        for port, listen_only in list(self._hosts):
            self._take(port, listen_only, now, False, True)

    def vt_flush(self) -> None:
        self._flush_hosts(list(self._hosts))


__all__ = ["DEFAULT_BITRATE", "CanMediumStats", "CanDevice", "CanDevicePort", "CanMedium"]
