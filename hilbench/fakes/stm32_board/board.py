"""The emulated STM32F767 rover board: firmware in virtual time, paced onto a real line.

Two ways to run it:

- **Offline** (tests, benchmarks, scripts): ``board.run_for(seconds)`` simulates
  as fast as the host allows; ``board.receive(frame)``, ``board.press_button()``
  and ``board.take_output()`` work in virtual time.
- **Live** (``Bench``, ``hilbench emulate``): :meth:`Board.attach` joins a
  :class:`~hilbench.transports.serial_medium.SerialMedium` as a device. A
  thread keeps the virtual clock a few milliseconds ahead of the wall clock
  and hands each piece of output to the line stamped with the wall time its
  last byte leaves the UART, so taps, monitors and clients see the board's
  real timing. Bytes from the host enter the simulation at the virtual time
  they arrived (at most the lookahead late when the simulation is ahead).

Virtual time is µs since the board's first boot; a reset starts a new boot
(new scheduler, empty buffers) at the current virtual time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from hilbench.fakes.mecanum_robot import RobotState
from hilbench.fakes.stm32_board.firmware import Firmware
from hilbench.fakes.stm32_board.presets import BoardConfig, make_preset
from hilbench.fakes.stm32_board.sink import Truth
from hilbench.protocols.tracestamp import LogMessage, RuntimeReport
from hilbench.transports.clock import WALL, WallClock

log = logging.getLogger(__name__)

#: Live operation: how far the simulation runs ahead of the wall clock, and how often it steps.
LOOKAHEAD_US = 2000.0
STEP_S = 0.001
FAULT_KEYS = ("drop_rate", "corrupt_rate", "drop_next", "corrupt_next")


def _mm(pose: tuple[float, float, float]) -> tuple[float, float, float]:
    """A pose in metres (the world's unit) in the firmware's units: mm, mm, rad."""
    return pose[0] * 1000.0, pose[1] * 1000.0, pose[2]


class Board:
    """One emulated rover board. ``name`` is its device name on a line; see the module docstring."""

    def __init__(self, config: BoardConfig | None = None, name: str = "rover") -> None:
        self.config = config or BoardConfig(make_preset("freertos-100-50"))
        self.name = name
        self.boots = 1
        self.boot_offset = 0.0  # virtual µs at which the current boot started
        self.fw = Firmware(self.config, boot_count=1)
        self.lock = threading.RLock()
        self.history_truth: list[Truth] = []
        # Live operation.
        self.port = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self.wall0: float | None = None
        self.lag_us = 0.0
        self.on_output: Callable[[bytes, float], None] | None = None
        self.rx_baud_mismatch = 0
        #: Peripherals that run beside the firmware while the board is live (e.g. the micro-ROS client):
        #: objects with start(board), stop() and reset(), see :meth:`attach_client`.
        self.clients: list[Any] = []

    @property
    def clock(self) -> WallClock:
        """The line's clock (its bench's) once attached; the wall clock before."""
        return self.port.clock if self.port is not None else WALL

    def attach_client(self, client: Any) -> None:
        """Add a peripheral started and stopped with the live board and told about resets."""
        self.clients.append(client)

    # ------------------------------------------------------------------ time

    @property
    def now_us(self) -> float:
        """Virtual time (µs since the first boot)."""
        return self.boot_offset + self.fw.now

    def run_until(self, t_us: float) -> None:
        with self.lock:
            self.fw.run_until(t_us - self.boot_offset)

    def run_for(self, seconds: float) -> None:
        """Simulate ``seconds`` of board time as fast as possible."""
        self.run_until(self.now_us + seconds * 1e6)

    # ------------------------------------------------------------------ inputs

    def receive(self, data: bytes, at_us: float | None = None) -> None:
        """Bytes from the host whose first byte reaches the UART at ``at_us`` (default: now)."""
        with self.lock:
            t = self.now_us if at_us is None else at_us
            self.fw.uart_rx(bytes(data), t - self.boot_offset)

    def press_button(self, at_us: float | None = None) -> None:
        """Press the user button (B1): starts or stops sampling, as the firmware variant does."""
        with self.lock:
            t = self.now_us if at_us is None else at_us
            self.fw.press_button(t - self.boot_offset)
        self._wake.set()

    def settle(self, us: float = 5000.0, timeout: float = 2.0) -> None:
        """Let ``us`` of virtual time pass: offline by simulating it, live by waiting for the thread."""
        target = self.now_us + us
        if self.clock.virtual and self.port is not None and self.wall0 is not None:
            loop = getattr(self.clock, "loop", None)
            if loop is not None and loop.mode == "hold" and not loop.in_loop():
                loop.run_until(self.wall0 + target / 1e6 + STEP_S, timeout)
                return
        if self._thread is None and not (self.clock.virtual and self.port is not None and self.wall0 is not None):
            self.run_until(target)
            return
        deadline = time.monotonic() + timeout  # wall-clock: how long the caller waits for the thread
        while self.now_us < target and time.monotonic() < deadline:  # wall-clock
            self._wake.set()
            time.sleep(0.001)  # wall-clock: the caller waits for the live thread

    def reset(self) -> None:
        """Reset the board: a new boot of the firmware at the current virtual time; unsent output is lost."""
        with self.lock:
            now = self.now_us
            self.history_truth.append(self.fw.truth)
            self.boots += 1
            old_wire = self.fw.wire
            self.fw = Firmware(self.config, boot_count=self.boots, seed=self.config.seed + self.boots)
            # Keep what the old UART had already shifted out; the rest dies with the reset.
            self.fw.wire.busy_until = max(0.0, old_wire.busy_until - now)
            self._carry = old_wire.take(now - self.boot_offset)[0]
            self.boot_offset = now
        self._wake.set()
        for client in self.clients:
            client.reset()

    _carry = b""

    def set_faults(self, **knobs: float) -> dict[str, float]:
        """Turn output fault knobs: ``drop_rate``, ``corrupt_rate`` (per byte), ``drop_next``,
        ``corrupt_next`` (counts), ``stall`` (seconds the sink stops sending); returns the new values."""
        with self.lock:
            f = self.fw.faults
            for key, value in knobs.items():
                if key == "stall":
                    f.stall_until_us = self.fw.now + float(value) * 1e6
                elif key in FAULT_KEYS:
                    setattr(f, key, type(getattr(f, key))(value))
                else:
                    raise KeyError(f"unknown fault knob {key!r} (expected one of: {', '.join(FAULT_KEYS)}, stall)")
            return {k: getattr(f, k) for k in FAULT_KEYS} | {"stall_until_us": f.stall_until_us}

    # ------------------------------------------------------------------ outputs

    def take_output(self, until_us: float | None = None) -> bytes:
        """Wire bytes fully sent by ``until_us`` (default: now), in order; offline use."""
        with self.lock:
            carry, self._carry = self._carry, b""
            if until_us is None:
                until_us = self.now_us
            data, _ = self.fw.wire.take(until_us - self.boot_offset)
            return carry + data

    @property
    def truth(self) -> Truth:
        """Counters of the current boot (what was recorded, sent, dropped, lost)."""
        return self.fw.truth

    @property
    def log(self) -> list[LogMessage]:
        """The log lines the firmware printed (most recent boot, last 200)."""
        with self.lock:
            return list(self.fw.log)

    @property
    def reports(self) -> list[RuntimeReport]:
        with self.lock:
            return list(self.fw.reports)

    @property
    def sampling(self) -> bool:
        return self.fw.sampling

    @property
    def reporting(self) -> bool:
        """True from a window's start until its report has been written."""
        return self.fw.sampling or self.fw._reporting

    def robot_state(self) -> RobotState:
        with self.lock:
            return self.fw.robot.state(self.fw.now)

    def body_motion(self, t: float) -> tuple[int, float, float, float, float, float, float]:
        """What the wheels did up to bench clock time ``t``, for its world body (a world driver,
        :meth:`hilbench.fakes.world.World.drive`): (epoch, x, y, theta of the motion since this boot's start
        in metres and radians, and the body-frame velocity vx, vy, omega now). The robot model is advanced no
        further than the firmware ran, so a setpoint the firmware has yet to receive is not overtaken; a reset
        starts a new epoch (a new robot model)."""
        if self.wall0 is None:
            return 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        with self.lock:
            fw = self.fw
            t_us = min((t - self.wall0) * 1e6 - self.boot_offset, fw.now)
            fw.robot.advance(t_us)
            return (self.boots, *fw.robot.motion_at(t_us), *fw.robot.body_velocity())

    def status(self) -> dict[str, Any]:
        """A JSON-able summary: time, counters, robot, faults, last log lines."""
        with self.lock:
            fw = self.fw
            st = fw.robot.state(fw.now)
            return {
                "name": self.name,
                "preset": self.config.preset.name,
                "caches": self.config.preset.caches,
                "output": self.config.output,
                "baud": self.config.baud,
                "boots": self.boots,
                "now_us": self.now_us,
                "sampling": fw.sampling,
                "reporting": fw.sampling or fw._reporting,
                "window": fw.window,
                "crc_err": fw.crc_err,
                "truth": asdict(fw.truth),
                "ctx_switches": fw.kernel.ctx_switches,
                "robot": {"setpoint": st.setpoint, "command": st.command, "wheels": st.wheels, "duty": st.duty,
                          "pose": st.pose, "pose_cycles": st.pose_cycles,
                          "wheel_angles": list(fw.robot.wheel_angle),
                          "measured": _mm(fw.robot.measured_at(fw.now))},
                "faults": {k: getattr(fw.faults, k) for k in FAULT_KEYS},
                "log": [f"{x.clock} [{x.level}]: {x.message}" for x in list(fw.log)[-20:]],
                "lag_us": self.lag_us,
                "fast_ticks": fw.kernel.fast_ticks,
                "exact_ticks": fw.kernel.exact_ticks,
                "rx_baud_mismatch": self.rx_baud_mismatch,
            }

    # ------------------------------------------------------------------ live operation

    def attach(self, medium) -> None:
        """Join a serial line as a device named ``<name>-board`` (the host port keeps the endpoint's
        name, so taps tell the two directions apart); host bytes arrive at :meth:`on_bytes`."""
        self.port = medium.add_device(_LineParty(self, f"{self.name}-board"))

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        """Host bytes from the line, received at monotonic time ``t`` (the chunk's last byte)."""
        if self.wall0 is None:
            return
        if baud is not None and baud != self.config.baud:
            # A host at another baud rate: the UART sees framing garbage, as on the real link.
            self.rx_baud_mismatch += len(data)
            data = bytes(b ^ 0xA5 for b in data)
        t_first = t - len(data) * 10 / self.config.baud if baud else t
        self.receive(data, (t_first - self.wall0) * 1e6)
        self._wake.set()

    def input_backlog(self, now: float) -> float:
        """Seconds (from monotonic ``now``) until the UART has taken in every host byte handed to it: the
        line holds the host back while this is long (a pty door: over the real USB link its writer waits)."""
        if self.wall0 is None:
            return 0.0
        free_s = self.fw.framer.line_free_at  # seconds of the current boot (-inf: nothing received)
        return self.wall0 + self.boot_offset / 1e6 + free_s - now

    def start(self, wall0: float | None = None) -> None:
        """Start the live thread; virtual time 0 (or the current virtual time) is now."""
        if self._thread is not None:
            return
        self.wall0 = (wall0 if wall0 is not None else self.clock.now()) - self.now_us / 1e6
        self._stop.clear()
        if self.clock.virtual and self.port is not None:
            # In virtual time the bench's loop runs the board: the thread's steps become loop timers.
            self._vt_sent = self.now_us
            self._vt_epoch = getattr(self, "_vt_epoch", 0) + 1
            epoch = self._vt_epoch
            self.port.call_at(self.clock.now(), lambda: self._vt_step(epoch))
        else:
            self._thread = threading.Thread(target=self._run, name=f"board-{self.name}", daemon=True)
            self._thread.start()
        for client in self.clients:
            client.start(self)

    def stop(self) -> None:
        for client in self.clients:
            client.stop()
        self._vt_epoch = getattr(self, "_vt_epoch", 0) + 1  # (ends the loop timers of virtual time)
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def _run(self) -> None:
        sent_until = self.now_us
        now = self.clock.now
        while not self._stop.is_set():
            sent_until = self._step(now(), sent_until)
            self._wake.wait(STEP_S)
            self._wake.clear()

    def _vt_step(self, epoch: int) -> None:
        """One step in virtual time (a timer of the bench's loop, every :data:`STEP_S`)."""
        if epoch != self._vt_epoch:
            return  # stopped (or restarted) since
        now = self.clock.now()
        self._vt_sent = self._step(now, self._vt_sent)
        self.port.call_at(now + STEP_S, lambda: self._vt_step(epoch))

    def _step(self, wall: float, sent_until: float) -> float:
        """Run the firmware to ``LOOKAHEAD_US`` past clock time ``wall`` and hand the line what its UART
        has sent by one step later; returns the new ``sent_until``."""
        v_now = (wall - self.wall0) * 1e6
        target = v_now + LOOKAHEAD_US
        try:
            with self.lock:
                if self.now_us < target:
                    self.fw.run_until(target - self.boot_offset)
                self.lag_us = max(0.0, v_now - self.now_us)
                horizon = v_now + STEP_S * 1e6
                carry, self._carry = self._carry, b""
                data, t_last = self.fw.wire.take(horizon - self.boot_offset)
                t_last += self.boot_offset
            data = carry + data
            if data:
                t_wall = self.wall0 + max(t_last, sent_until) / 1e6
                sent_until = max(t_last, sent_until)
                if self.port is not None:
                    self.port.transmit(data, t=t_wall)
                if self.on_output is not None:
                    self.on_output(data, t_wall)
        except Exception:  # keep the board alive; the failure is logged
            log.exception("board %s failed", self.name)
        return sent_until


class _LineParty:
    """The board as a party on a serial line, under its own name."""

    def __init__(self, board: Board, name: str) -> None:
        self.board = board
        self.name = name

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        self.board.on_bytes(data, t, baud)

    def input_backlog(self, now: float) -> float:
        return self.board.input_backlog(now)
