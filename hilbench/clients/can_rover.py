"""A host-side client of the rover board on CAN: NMT start, velocity setpoints every 50 ms, odometry back.

Works on any python-can bus (socketcand, SLCAN, SocketCAN, a real adapter,
``bench.endpoint("can").port.open_bus()`` in the bench's process)::

    import can
    from hilbench.clients.can_rover import RoverCanClient

    bus = can.Bus(interface="socketcand", host="127.0.0.1", port=PORT, channel="can0")
    with RoverCanClient(bus, node_id=2) as rover:
        rover.start()                      # NMT start: PDOs flow
        rover.drive(0.2, 0.0, 0.0)         # repeated every 50 ms with counter and checksum until changed
        time.sleep(2)
        rover.drive(0, 0, 0)
        print(rover.pose())                # (x m, y m, theta rad) from the board's odometry PDO

One thread receives (the odometry, velocity, status PDOs and heartbeats) and
one sends the setpoint on absolute deadlines, so the 50 ms repeat does not
drift. The layout comes from :mod:`hilbench.protocols.board_can`.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

from hilbench.protocols import board_can as bc
from hilbench.protocols import canopen as co

SETPOINT_PERIOD = 0.05


class RoverCanClient:
    """Drives the rover board over a python-can bus (which it does not own unless ``own_bus``)."""

    def __init__(self, bus: Any, node_id: int = 2, *, period: float = SETPOINT_PERIOD, own_bus: bool = False) -> None:
        self.bus = bus
        self.node_id = node_id
        self.period = period
        self.own_bus = own_bus
        self.latest: dict[str, dict[str, float]] = {}
        self.times: dict[str, float] = {}
        self.nmt_state: int | None = None
        self.heartbeats = 0
        self.bootups = 0
        self.emcy: list[tuple[int, int]] = []
        self.sent = 0
        self._setpoint: tuple[float, float, float] | None = None
        self._counter = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._ids = {p.cob_id(node_id): p.key for p in bc.PDOS if p.kind == "tpdo"}
        self._rx = threading.Thread(target=self._receive, name="rover-can-rx", daemon=True)
        self._tx = threading.Thread(target=self._transmit, name="rover-can-tx", daemon=True)
        self._rx.start()
        self._tx.start()

    # ------------------------------------------------------------------ commands

    def nmt(self, command: int) -> None:
        """Send an NMT command to this node."""
        import can

        self.bus.send(can.Message(arbitration_id=co.NMT_ID, data=co.nmt_command(command, self.node_id),
                                  is_extended_id=False))

    def start(self) -> None:
        """NMT start: the node goes OPERATIONAL and its PDOs flow."""
        self.nmt(co.NMT_START)

    def drive(self, vx: float, vy: float = 0.0, omega: float = 0.0) -> None:
        """Command a velocity (m/s, m/s, rad/s); it is repeated every period until changed or :meth:`halt`.

        ValueError for a value the setpoint PDO cannot carry (NaN, infinite, beyond +-32.767)."""
        for name, value in (("vx", vx), ("vy", vy), ("omega", omega)):
            if not (math.isfinite(value) and -32.768 <= value <= 32.767):
                raise ValueError(f"{name}: expected a number -32.768..32.767 (the setpoint PDO's range), got {value}")
        with self._cond:
            self._setpoint = (vx, vy, omega)
            self._cond.notify_all()

    def halt(self) -> None:
        """Stop sending setpoints (the board stops by its setpoint timeout)."""
        with self._cond:
            self._setpoint = None

    # ------------------------------------------------------------------ what the board says

    def pose(self) -> tuple[float, float, float] | None:
        """The last odometry pose (m, m, rad), or None before the first."""
        odo = self.latest.get("odometry")
        return (odo["x"], odo["y"], odo["theta"]) if odo else None

    def wait_for(self, key: str, after: float | None = None, timeout: float = 2.0) -> dict[str, float]:
        """The next PDO ``key`` (``odometry``, ``encoders``, ``velocity``, ``status``) received after ``after``."""
        after = time.monotonic() if after is None else after
        deadline = time.monotonic() + timeout
        with self._cond:
            while self.times.get(key, -1.0) <= after:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no {key} PDO from node {self.node_id} within {timeout} s")
                self._cond.wait(left)
            return dict(self.latest[key])

    # ------------------------------------------------------------------ threads

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.1)
            except Exception:
                return
            if msg is None or msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            cid = msg.arbitration_id
            key = self._ids.get(cid)
            now = time.monotonic()
            with self._cond:
                if key is not None:
                    try:
                        self.latest[key] = bc.decode(key, bytes(msg.data))
                    except ValueError:
                        continue
                    self.times[key] = now
                    self._cond.notify_all()
                elif cid == 0x700 + self.node_id and msg.data:
                    self.nmt_state = msg.data[0] & 0x7F
                    if self.nmt_state == co.BOOTUP:
                        self.bootups += 1
                    else:
                        self.heartbeats += 1
                    self._cond.notify_all()
                elif cid == 0x080 + self.node_id and len(msg.data) >= 3:
                    self.emcy.append((int.from_bytes(msg.data[:2], "little"), msg.data[2]))

    def _transmit(self) -> None:
        import can

        next_t = time.monotonic()
        while not self._stop.is_set():
            with self._cond:
                while self._setpoint is None and not self._stop.is_set():
                    self._cond.wait(0.2)
                    next_t = time.monotonic()
                setpoint = self._setpoint
            if setpoint is None:
                continue
            data = bc.build_setpoint(*setpoint, self._counter)
            self._counter = (self._counter + 1) % 256
            try:
                self.bus.send(can.Message(arbitration_id=bc.SETPOINT.cob_id(self.node_id), data=data,
                                          is_extended_id=False))
                self.sent += 1
            except Exception:
                pass  # a full transmit queue: the board's watchdog will say so
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay < -self.period:
                next_t = time.monotonic()  # far behind: do not burst
            elif delay > 0:
                self._stop.wait(delay)

    def close(self) -> None:
        """Stop both threads (and shut the bus down if this client owns it)."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._tx.join(timeout=2)
        self._rx.join(timeout=2)
        if self.own_bus:
            self.bus.shutdown()

    def __enter__(self) -> RoverCanClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["RoverCanClient"]
