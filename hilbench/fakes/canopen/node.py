"""A CANopen node (CiA 301) on an emulated CAN bus: NMT, heartbeat, SDO server, EMCY, node guarding.

What a real node does and this one does too:

- after power-up or a reset it sends its boot-up message (``0x700+n [1] 00``)
  once, enters PRE-OPERATIONAL by itself (OPERATIONAL at once with
  ``autostart``, as self-starting firmware does), and produces heartbeats at
  the period of object 0x1017 (0: none). Writing 0x1017 takes effect at once:
  the next heartbeat follows the new period from the moment of the write;
- NMT commands on 0x000 (addressed to it or to all): start, stop,
  pre-operational, reset node (every object back to its default, the
  application restarted) and reset communication (objects 0x1000-0x1FFF);
- SDO server on 0x600+n / 0x580+n in PRE-OPERATIONAL and OPERATIONAL
  (:class:`~hilbench.fakes.canopen.sdo_server.SdoServer`); in STOPPED only
  NMT and heartbeat work;
- EMCY on 0x080+n when an error appears (error code, error register 0x1001,
  five vendor bytes), kept in the pre-defined error field 0x1003, and an
  error-reset EMCY (code 0) when the last one clears;
- node guarding: a remote frame on 0x700+n is answered with the state and a
  toggle bit while the heartbeat is off;
- its own controller's error passive and bus-off states raise EMCY 0x8120
  and 0x8140 (recovered from bus off).

Everything runs in the bus's thread (``on_frame`` and timers through the
device port), so no locks are needed. Timers are absolute deadlines (no
drift); a generation number cancels the ones a change made stale.
Fault knobs: ``heartbeat_stop``, ``silent`` (sends nothing at all),
``sdo_abort`` (answer every SDO request with that abort code).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from hilbench.fakes.canopen.dictionary import ObjectDictionary
from hilbench.fakes.canopen.sdo_server import SdoServer
from hilbench.protocols import canopen as co
from hilbench.protocols import canopen_od as od
from hilbench.protocols.can_frame import CanFrame, data_frame
from hilbench.transports.clock import WALL

log = logging.getLogger(__name__)

#: Entries kept in the pre-defined error field 0x1003.
ERROR_HISTORY = 8


class CanopenNode:
    """One CANopen node; subclasses add the application (PDOs) in the ``on_*`` hooks."""

    def __init__(self, name: str, node_id: int, entries: list[od.Entry], *, autostart: bool = False,
                 boot_delay: float = 0.02) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id must be 1..127, got {node_id}")
        self.name = name
        self.node_id = node_id
        self.od = ObjectDictionary(entries, node_id)
        self.sdo = SdoServer(self.od)
        self.autostart = autostart
        self.boot_delay = boot_delay
        self.state = co.BOOTUP
        self.port: Any = None
        self.faults: dict[str, Any] = {"heartbeat_stop": False, "silent": False, "sdo_abort": 0}
        self.active_errors: dict[int, int] = {}  # EMCY code -> error register bits
        self.emcy_sent = 0
        self.heartbeats = 0
        self.bootups = 0
        self.nmt_commands = 0
        self.frames_sent = 0
        self.bus_state = "active"
        self._guard_toggle = 0
        self._gen = {"heartbeat": 0, "boot": 0}
        self._started = False
        self.od.on_write(0x1017, self._write_heartbeat)
        self.od.on_write(0x1003, self._write_error_field)
        self.od.on_read(0x1001, lambda i, s: None)

    # ------------------------------------------------------------------ wiring

    def attach(self, medium: Any) -> None:
        """Join a :class:`~hilbench.transports.can_medium.CanMedium`."""
        self.port = medium.add_device(self)

    def now(self) -> float:
        """The bus's time (its bench's clock; the wall clock before the node is attached)."""
        return self.port.now() if self.port is not None else WALL.now()

    def start(self, t: float | None = None) -> None:
        """Power up: boot-up message after the boot delay, then heartbeats."""
        self._started = True
        self._boot(self.now() if t is None else t)

    def stop(self) -> None:
        """Power off: nothing more is sent (timers become stale)."""
        self._started = False
        for key in self._gen:
            self._gen[key] += 1

    def call_at(self, t: float, fn: Callable[[], None], timer: str | None = None) -> None:
        """Run ``fn`` at ``t`` in the bus thread; with ``timer``, only unless that timer was restarted since."""
        if timer is None:
            self.port.call_at(t, fn)
            return
        gen = self._gen.setdefault(timer, 0)

        def run() -> None:
            if self._gen.get(timer) == gen and self._started:
                fn()

        self.port.call_at(t, run)

    def restart_timer(self, timer: str) -> None:
        """Make every pending run of ``timer`` stale."""
        self._gen[timer] = self._gen.get(timer, 0) + 1

    def send(self, can_id: int, data: bytes) -> None:
        """Transmit a data frame (unless the node is silenced by a fault knob or its controller is bus-off)."""
        if self.faults["silent"] or not self._started:
            return
        self.frames_sent += 1
        self.port.send(data_frame(can_id, data))

    # ------------------------------------------------------------------ NMT

    @property
    def state_name(self) -> str:
        return co.state_name(self.state)

    def _boot(self, t: float) -> None:
        self.restart_timer("boot")
        self.restart_timer("heartbeat")
        self.state = co.BOOTUP
        self.on_state(co.BOOTUP, t)
        self.call_at(t + self.boot_delay, lambda: self._booted(t + self.boot_delay), timer="boot")

    def _booted(self, t: float) -> None:
        self.bootups += 1
        self.send(0x700 + self.node_id, bytes([co.BOOTUP]))
        self.set_state(co.OPERATIONAL if self.autostart else co.PRE_OPERATIONAL, t)
        self._schedule_heartbeat(t)

    def set_state(self, state: int, t: float) -> None:
        """Enter an NMT state (the application hears it through :meth:`on_state`)."""
        if state == self.state:
            return
        self.state = state
        self.on_state(state, t)

    def reset(self, t: float | None = None, *, communication_only: bool = False) -> None:
        """NMT reset node (or reset communication): defaults back, boot-up again."""
        t = self.now() if t is None else t
        if communication_only:
            self.od.reset(0x1000, 0x1FFF)
        else:
            self.od.reset()
            self.active_errors.clear()
            self.on_reset(t)
        self.sdo.reset()
        self._boot(t)

    def _nmt(self, data: bytes, t: float) -> None:
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        self.nmt_commands += 1
        command = data[0]
        if self.state == co.BOOTUP and command not in (co.NMT_RESET_NODE, co.NMT_RESET_COMMUNICATION):
            return  # still initialising
        if command == co.NMT_START:
            self.set_state(co.OPERATIONAL, t)
        elif command == co.NMT_STOP:
            self.set_state(co.STOPPED, t)
        elif command == co.NMT_PRE_OPERATIONAL:
            self.set_state(co.PRE_OPERATIONAL, t)
        elif command == co.NMT_RESET_NODE:
            self.reset(t)
        elif command == co.NMT_RESET_COMMUNICATION:
            self.reset(t, communication_only=True)

    # ------------------------------------------------------------------ heartbeat and guarding

    @property
    def heartbeat_ms(self) -> int:
        return int(self.od[(0x1017, 0)])

    def _schedule_heartbeat(self, t: float) -> None:
        self.restart_timer("heartbeat")
        period = self.heartbeat_ms / 1000
        if period > 0 and self.state != co.BOOTUP:
            self.call_at(t + period, lambda: self._heartbeat(t + period), timer="heartbeat")

    def _heartbeat(self, t: float) -> None:
        if not self.faults["heartbeat_stop"]:
            self.heartbeats += 1
            self.send(0x700 + self.node_id, bytes([self.state]))
        period = self.heartbeat_ms / 1000
        if period > 0:
            nxt = t + period
            now = self.now()
            if nxt < now - period:  # far behind (a stalled machine): skip the backlog instead of bursting
                nxt = now + period
            self.call_at(nxt, lambda: self._heartbeat(nxt), timer="heartbeat")

    def _write_heartbeat(self, index: int, subindex: int, value: Any) -> int | None:
        # The new period applies from now: the heartbeat "follows a change at once".
        self.od[(0x1017, 0)] = value
        self._schedule_heartbeat(self.now())
        return None

    def _guard(self) -> None:
        if self.heartbeat_ms:
            return  # node guarding is answered only while the heartbeat is off
        self.send(0x700 + self.node_id, bytes([(self._guard_toggle << 7) | self.state]))
        self._guard_toggle ^= 1

    # ------------------------------------------------------------------ EMCY

    @property
    def error_register(self) -> int:
        reg = 0
        for bits in self.active_errors.values():
            reg |= bits
        return reg | (co.REG_GENERIC if reg else 0)

    def raise_error(self, code: int, register_bits: int = co.REG_GENERIC, data: bytes = bytes(5)) -> None:
        """An error appears: EMCY (if the node may send one now), 0x1001 and the 0x1003 history updated."""
        self.active_errors[code] = register_bits
        self._emcy(code, data)

    def clear_error(self, code: int) -> None:
        """An error went away; when none is left, the error-reset EMCY (code 0) is sent."""
        if self.active_errors.pop(code, None) is not None and not self.active_errors:
            self._emcy(co.ERR_RESET)
        self.od[(0x1001, 0)] = self.error_register

    def _emcy(self, code: int, data: bytes = bytes(5)) -> None:
        reg = self.error_register
        self.od[(0x1001, 0)] = reg
        if code:
            count = min(int(self.od[(0x1003, 0)]) + 1, ERROR_HISTORY)
            for i in range(count, 1, -1):
                self.od[(0x1003, i)] = self.od[(0x1003, i - 1)]
            self.od[(0x1003, 1)] = code | (int.from_bytes(data[:2].ljust(2, b"\0"), "little") << 16)
            self.od[(0x1003, 0)] = count
        if self.state in (co.PRE_OPERATIONAL, co.OPERATIONAL):  # EMCY is not sent in STOPPED (CiA 301)
            self.emcy_sent += 1
            self.send(0x080 + self.node_id, co.emcy_frame(code, reg, data))

    def emcy(self, code: int, register_bits: int = co.REG_MANUFACTURER, data: bytes = bytes(5)) -> None:
        """Send one EMCY without keeping the error active (an event, not a state)."""
        self.active_errors[code] = register_bits
        self._emcy(code, data)
        self.active_errors.pop(code, None)
        self.od[(0x1001, 0)] = self.error_register

    def _write_error_field(self, index: int, subindex: int, value: Any) -> int | None:
        if subindex == 0 and value != 0:
            return 0x06090030  # only 0 (clear the history) may be written
        for i in range(1, ERROR_HISTORY + 1):
            self.od[(0x1003, i)] = 0
        return None

    def on_bus_state(self, state: str, t: float) -> None:
        """The medium reports this node's controller state (error passive, bus-off, recovered)."""
        self.bus_state = state
        if state == "passive":
            self.raise_error(co.ERR_CAN_PASSIVE, co.REG_COMMUNICATION)
        elif state == "active":
            self.clear_error(co.ERR_CAN_PASSIVE)
        elif state == "recovered":
            self.active_errors.pop(co.ERR_CAN_PASSIVE, None)
            self.raise_error(co.ERR_BUS_OFF_RECOVERED, co.REG_COMMUNICATION)
            self.clear_error(co.ERR_BUS_OFF_RECOVERED)
            self.bus_state = "active"

    # ------------------------------------------------------------------ frames

    def on_frame(self, frame: CanFrame, t: float) -> None:
        """Frames on the bus: NMT, SDO requests, node guarding; the rest goes to :meth:`on_app_frame`."""
        if frame.error or frame.extended or not self._started:
            return
        n = self.node_id
        cid = frame.can_id
        if cid == co.NMT_ID:
            self._nmt(frame.data, t)
            return
        if self.state == co.BOOTUP:
            return
        if cid == 0x700 + n and frame.remote:
            self._guard()
            return
        if cid == 0x600 + n and not frame.remote:
            if self.state == co.STOPPED:
                return
            self.sdo.forced_abort = int(self.faults.get("sdo_abort") or 0)
            response = self.sdo.request(frame.data)
            if response is not None:
                self.send(0x580 + n, response)
            return
        self.on_app_frame(frame, t)

    # ------------------------------------------------------------------ application hooks

    def on_state(self, state: int, t: float) -> None:
        """The NMT state changed (``BOOTUP`` while initialising)."""

    def on_reset(self, t: float) -> None:
        """Reset node: the application starts over."""

    def on_app_frame(self, frame: CanFrame, t: float) -> None:
        """A frame that is not NMT, SDO or guarding (PDOs, SYNC, other nodes' traffic)."""

    def status(self) -> dict[str, Any]:
        """What the node is doing (the control channel's ``status``)."""
        return {
            "name": self.name, "node_id": self.node_id, "nmt_state": self.state_name,
            "heartbeat_ms": self.heartbeat_ms, "heartbeats": self.heartbeats, "bootups": self.bootups,
            "error_register": self.error_register,
            "active_errors": {f"0x{c:04X}": co.emcy_text(c) for c in self.active_errors},
            "emcy_sent": self.emcy_sent, "sdo": {"uploads": self.sdo.uploads, "downloads": self.sdo.downloads,
                                                  "aborts_sent": self.sdo.aborts_sent},
            "bus_state": self.bus_state, "frames_sent": self.frames_sent, "faults": dict(self.faults),
        }


__all__ = ["CanopenNode"]
