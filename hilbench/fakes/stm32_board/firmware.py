"""The rover firmware as tasks on the emulated kernel: control loop, recv_vel, tsink, profiling, button.

One :class:`Firmware` is one boot of the board. It builds the task set of its
preset (spec §2.2) on a :class:`~hilbench.fakes.stm32_board.kernel.Kernel`,
wires the output path chosen by the configuration (§3.4), frames received
bytes as the UART does (§1.4) and keeps the robot's control data flow
(:mod:`~hilbench.fakes.mecanum_robot`). Times are µs since boot.

Output paths:

- ``v1`` (thesis): hook stamps go to a 512-record ring; ``profile`` wakes every
  ``flush_ms`` and prints what is there (so hook stamps arrive late and out of
  order); scope stamps (micro-ROS callbacks) are formatted and written by the
  caller inside the measured interval. The button toggles sampling; ``ref`` is
  latched at the press; the report closes with ``profiled for``.
- ``v2`` (micro-ROS head): hook and scope stamps in the 512-record ring, flushed
  every 10 ticks; ``in/out``; ``ref`` = first stamp; ``output took``.
- ``v3`` (FreeRTOS head): tasks ``btn`` and ``rt_stats`` replace ``profile``; the
  button opens a fixed window (1000 ms) recording into a 32,768-record array;
  ``rt_stats`` dumps it afterwards, then the report.
- ``binary``: the hooks write one word per stamp straight into the ring, which
  drops (and counts) what does not fit; ``profile`` sends the name table and
  the window's control words, then the report.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from dataclasses import replace

import numpy as np

from hilbench.fakes.mecanum_robot import Robot
from hilbench.fakes.stm32_board.kernel import (
    CALL,
    DELAY,
    DELAY_UNTIL,
    FSTAMP,
    NOTIFY,
    RUN,
    WAIT,
    Durations,
    Kernel,
    Periodic,
    Task,
)
from hilbench.fakes.stm32_board.presets import (
    RUNTIME_UNIT_US,
    SYSTEM_CLOCK_HZ,
    BoardConfig,
    Preset,
    TaskSpec,
    Timing,
)
from hilbench.fakes.stm32_board.sink import (
    RING_SIZE,
    BinaryWriter,
    OutputFaults,
    RecordBuffer,
    Ring,
    Truth,
    Wire,
)
from hilbench.protocols import tracestamp as ts
from hilbench.protocols import tracestamp_binary as tb
from hilbench.protocols import vel2d
from hilbench.protocols.problem import Problem
from hilbench.protocols.tracestamp import RuntimeReport, RuntimeRow, TaskRow

DEBOUNCE_MS = {"v1": 100.0, "v2": 50.0, "v3": 50.0, "binary": 50.0}
RECORD_RING = 512
BINARY_MIN_CHUNK = 256
RECORD_ARRAY = 32_768
LOG_HISTORY = 200
#: The receive FIFO of the board's UDP door: host bytes not yet on the UART that it holds (the size of the
#: firmware's ring buffer, spec §3.4: 73 frames, 17.8 ms at 1,152,000 baud). A datagram that does not fit
#: is dropped whole and counted, as a UART drops what its FIFO cannot hold and the board counts it.
RX_FIFO = RING_SIZE
#: Received frames waiting for recv_vel. The firmware has one DMA buffer that the next frame overwrites
#: (spec §1.4, a race not emulated): every frame is kept, up to this many while recv_vel is busy (writing
#: its log line into a full ring, under a flood); a frame beyond is lost and counted (``frames_lost``).
RX_PENDING = 64
CYCLES_PER_US = SYSTEM_CLOCK_HZ / 1_000_000


def stamp_us(t: np.ndarray, ref: float) -> np.ndarray:
    """Whole µs from ``ref`` to the virtual times ``t`` as the firmware prints them (spec §3.3): both on
    the 216 MHz DWT cycle grid, the cycle difference truncated to µs. Snapping to cycles first also makes
    the result independent of how a time was summed: T + isr + switch may come out a hair below a whole
    µs in one summation order and not in another, and the fast path and the exact path sum differently."""
    return ((np.rint(t * CYCLES_PER_US) - round(ref * CYCLES_PER_US)) // CYCLES_PER_US).astype(np.int64)


def elapsed_us(t: float, ref: float) -> int:
    """:func:`stamp_us` for one time."""
    return int((round(t * CYCLES_PER_US) - round(ref * CYCLES_PER_US)) // CYCLES_PER_US)


def task_set(preset: Preset, output: str) -> list[TaskSpec]:
    """The preset's tasks as the chosen firmware variant creates them (V3 has btn and rt_stats)."""
    tasks = list(preset.tasks)
    if output != "v3":
        return tasks
    out = []
    num = 0
    for t in tasks:
        if t.kind == "profile":
            num += 1
            out.append(TaskSpec("btn", "btn", 24, num, 70, Timing(2.0)))
            num += 1
            out.append(replace(t, name="rt_stats", kind="profile", number=num, stack_hwm=380))
            continue
        num += 1
        out.append(replace(t, number=num))
    return out


class Firmware:
    """One boot of the board; see the module docstring."""

    def __init__(self, config: BoardConfig, *, boot_count: int = 1, seed: int | None = None) -> None:
        self.cfg = config
        self.preset = p = config.preset
        self.output = config.output
        self.dialect = config.edge_dialect
        self.boot_count = boot_count
        seed = config.seed if seed is None else seed
        self.kernel = k = Kernel(p.tick_hz, isr_us=p.isr_us, switch_us=p.switch_us)
        self.truth = Truth()
        self.ring = Ring()
        self.wire = Wire(config.baud)
        self.faults = OutputFaults(seed=seed + 7919)
        for key, value in config.faults.items():
            setattr(self.faults, key, value)
        self.framer = vel2d.IdleLineFramer(config.baud)
        self.rx_pending: deque[tuple[bytes, float]] = deque()
        self.crc_err = 0
        self.log: deque[ts.LogMessage] = deque(maxlen=LOG_HISTORY)
        self.frames: deque[tuple[float, vel2d.Velocity | Problem]] = deque(maxlen=LOG_HISTORY)
        self.reports: list[RuntimeReport] = []
        # Sampling state.
        self.sampling = False
        self.window = 0
        self.ref: float | None = None
        self.window_start = 0.0
        self.window_stop = 0.0
        self.first_stamp: float | None = None
        self.last_press = -math.inf
        self.binary = BinaryWriter(self.ring, self.truth)
        self.records = RecordBuffer(RECORD_ARRAY if self.output == "v3" else RECORD_RING,
                                    "array" if self.output == "v3" else "ring")
        self.poll_ticks = max(1, round(p.tick_hz / 1000))  # 1 ms
        self.line_cost = Durations(p.line_cost, seed * 1000 + 1)
        self.window_ms = config.window_ms if config.window_ms is not None else (1000.0 if self.output == "v3"
                                                                                 else None)
        # Tasks and stamp names: tasks in creation order, then scope (function) names.
        specs = task_set(p, self.output)
        self.names: list[str] = [s.name for s in specs] + [f.name for f in p.functions]
        if len(self.names) > tb.MAX_STAMP_ID + 1:
            raise ValueError("too many stamp names for the binary format")
        self.names_b = [n.encode() for n in self.names]
        self.tasks: dict[str, Task] = {}
        self.specs: dict[str, TaskSpec] = {s.name: s for s in specs}
        for i, spec in enumerate(specs):
            task = Task(spec.name, spec.priority, spec.number, i, spec.stack_hwm)
            task.durations = Durations(spec.timing, seed * 1000 + 17 * (i + 1))
            self.tasks[spec.name] = task
            gen = self._behaviour(spec, task)
            k.add_task(task, gen, idle=spec.kind == "idle")
            if spec.kind == "idle":
                k._make_ready(task)
        self.fn_ids = {f.name: len(specs) + j for j, f in enumerate(p.functions)}
        self.fn_durations = {f.name: Durations(f.timing, seed * 1000 + 991 + j) for j, f in enumerate(p.functions)}
        wheel_us = 1e6 * self._period_ticks("wheel") / p.tick_hz
        pose_us = 1e6 * self._period_ticks("pose") / p.tick_hz
        # (the micro-ROS build's odometry runs per encoder message, spec §2.2: it loses no delta)
        self.robot = Robot(pose_us, wheel_us, first_cycle_us=pose_us, encoder_noise=config.encoder_noise,
                           seed=config.seed + boot_count, every_delta=p.rtos == "micro-ros")
        k.start()
        if config.boot_banner:
            self.log_line("INFO", f"[main] hilbench emulated {p.rtos} board, boot {boot_count}, "
                                  f"{p.wheel_hz:g}|{p.pose_hz:g} Hz, output {self.output}", immediate=True)
        for spec in specs:
            if spec.kind == "sporadic":
                self._schedule_sporadic(self.tasks[spec.name], spec.rate_hz, seed)

    # ------------------------------------------------------------------ helpers

    def _period_ticks(self, which: str) -> int:
        p = self.preset
        hz = p.wheel_hz if which == "wheel" else p.pose_hz
        return max(1, round(p.tick_hz / hz))

    @property
    def now(self) -> float:
        return self.kernel.now

    def run_until(self, t_us: float) -> None:
        self.kernel.run_until(t_us)
        self.sync()

    def rtc(self, t_us: float) -> float:
        return t_us / 1e6

    def log_line(self, level: str, message: str, immediate: bool = False) -> bytes:
        line = ts.format_log(self.rtc(self.kernel.now), level, message)
        self.log.append(ts.LogMessage(line[:8].decode(), level, message))
        if immediate:  # boot messages before the scheduler has anything else to do
            self.ring.write(line)
        return line

    # ------------------------------------------------------------------ stamps into the output path

    def sync(self) -> None:
        """Hand the stamps the kernel recorded to the output path. Binary words go into the ring, so
        this runs before any ring operation (:meth:`sync_ring`); text paths buffer records apart from
        the ring, so they need it only before the records are read, at the window's edges and at the
        end of a :meth:`run_until`."""
        k = self.kernel
        if not k.has_stamps:
            return
        if self.output == "binary":
            chunks = [k.take_stamps()]
        else:
            chunks = [c for c in k.take_chunks() if len(c[0])]
            if not chunks:
                return
        if self.first_stamp is None:
            self.first_stamp = float(chunks[0][0][0])
            if self.output in ("v2", "v3"):
                self.ref = self.first_stamp
        truth = self.truth
        for t, ids, b in chunks:
            truth.stamps_recorded += len(t)
            if self.output == "binary":
                self.binary.write(stamp_us(t, self.ref), ids, b)
            else:
                truth.records_lost += self.records.push(t, ids, b)

    def sync_ring(self) -> None:
        """:meth:`sync` where the ring's content depends on it (binary words)."""
        if self.output == "binary":
            self.sync()

    def try_write(self, data: bytes) -> bool:
        self.sync_ring()
        return self.ring.write(data)

    def write_blocking(self, task: Task, data: bytes):
        """Write ``data`` into the ring, sleeping 1 ms at a time while it does not fit (a generator)."""
        while True:
            ok = yield (CALL, lambda k: self.try_write(data))
            if ok:
                return
            # Retries are periodic while the line still does not fit (space only returns when a DMA ends).
            task.fast = Periodic(self.poll_ticks, task.durations, lambda: len(data) > self.ring.free, relative=True)
            yield (DELAY, self.poll_ticks)
            task.fast = None
            yield (RUN, task.durations.draw())

    def write_log(self, task: Task, level: str, message: str):
        yield (RUN, self.line_cost.draw())
        line = self.log_line(level, message)
        yield from self.write_blocking(task, line)

    # ------------------------------------------------------------------ tsink and DMA

    def start_dma(self, k: Kernel, min_bytes: int = 1) -> int:
        self.sync_ring()
        if k.now < self.faults.stall_until_us or self.ring.used < min_bytes:
            return 0
        n = self.ring.dma_chunk()
        if n == 0:
            return 0
        data = self.ring.start(n)
        self.truth.dma_transfers += 1
        sent = self._apply_faults(data)
        self.wire.send(k.now, sent)
        self.truth.bytes_to_wire += len(sent)
        k.at(k.now + n * self.wire.byte_us, self._dma_done)
        return n

    def _dma_done(self, k: Kernel) -> None:
        self.sync_ring()
        self.ring.complete()
        k.notify_from_isr(self.tasks["tsink"])

    def _apply_faults(self, data: bytes) -> bytes:
        f = self.faults
        if not f.active:
            return data
        a = np.frombuffer(data, np.uint8).copy()
        keep = np.ones(len(a), bool)
        if f.corrupt_next:
            n = min(f.corrupt_next, len(a))
            a[:n] ^= 0x01 << f.rng.integers(0, 8, n).astype(np.uint8)
            f.corrupt_next -= n
            self.truth.bytes_corrupted_fault += n
        if f.corrupt_rate:
            hit = f.rng.random(len(a)) < f.corrupt_rate
            a[hit] ^= (0x01 << f.rng.integers(0, 8, int(hit.sum()))).astype(np.uint8)
            self.truth.bytes_corrupted_fault += int(hit.sum())
        if f.drop_next:
            n = min(f.drop_next, len(a))
            keep[:n] = False
            f.drop_next -= n
        if f.drop_rate:
            keep &= f.rng.random(len(a)) >= f.drop_rate
        self.truth.bytes_dropped_fault += int((~keep).sum())
        return a[keep].tobytes()

    def _tsink(self, task: Task):
        # Polling an empty ring is periodic until someone writes into it.
        poll = Periodic(self.poll_ticks, task.durations,
                        lambda: self.ring.used == 0 and not (self.output == "binary" and self.sampling), relative=True)
        after_tx = False
        binary = self.output == "binary"
        while True:
            yield (RUN, task.durations.draw())
            # Binary words: after a transfer, send again at once only if a worthwhile chunk is waiting,
            # else at the next poll; otherwise tsink's own switch stamps would keep it sending 16-byte
            # chunks (hilbench's choice for the binary variant; the text variants send what is there).
            need = BINARY_MIN_CHUNK if binary and after_tx else 1
            n = yield (CALL, lambda k, need=need: self.start_dma(k, need))
            if n:
                task.fast = None
                after_tx = True
                yield (WAIT,)
            else:
                after_tx = False
                task.fast = poll
                yield (DELAY, self.poll_ticks)

    # ------------------------------------------------------------------ behaviours

    def _behaviour(self, spec: TaskSpec, task: Task):
        kind = spec.kind
        if kind == "periodic":
            task.fast = Periodic(spec.period_ticks, task.durations)
            return self._periodic(task, spec.period_ticks)
        if kind == "tsink":
            return self._tsink(task)
        if kind == "recv_vel":
            return self._recv_vel(task)
        if kind == "profile":
            if self.output == "v3":
                return self._rt_stats(task)
            if self.output == "binary":
                return self._binary_reporter(task)
            return self._flusher(task)
        if kind == "btn":
            return self._btn(task)
        if kind == "uros":
            return self._uros(task)
        if kind == "sporadic":
            return self._sporadic(task)
        if kind == "timer":
            return self._blocked_forever()
        return None  # idle

    def _periodic(self, task: Task, period: int):
        yield (DELAY_UNTIL, period)
        while True:
            yield (RUN, task.durations.draw())
            yield (DELAY_UNTIL, task.wake_tick + period)

    def _blocked_forever(self):
        yield (WAIT,)

    def _sporadic(self, task: Task):
        while True:
            yield (WAIT,)
            yield (RUN, task.durations.draw())

    def _schedule_sporadic(self, task: Task, rate_hz: float, seed: int) -> None:
        rng = np.random.default_rng(seed * 31 + task.number)

        def fire(k: Kernel) -> None:
            k.notify_from_isr(task)
            k.at(k.now + rng.exponential(1e6 / rate_hz), fire)

        self.kernel.at(rng.exponential(1e6 / rate_hz), fire)

    def _scope(self, task: Task, name: str):
        """A scope stamp around one callback (micro-ROS), as the output path records it."""
        sid = self.fn_ids[name]
        d = self.fn_durations[name]
        if self.output == "v1":
            # Formatted by the caller and written straight into the sink, inside the measured interval.
            t0 = self.kernel.now
            if self.sampling:
                yield (RUN, self.line_cost.draw())
                yield from self.write_blocking(task, self._fmt_one(sid, t0, True))
            yield (RUN, d.draw())
            if self.sampling:
                t1 = self.kernel.now
                yield (RUN, self.line_cost.draw())
                yield from self.write_blocking(task, self._fmt_one(sid, t1, False))
            return
        yield (FSTAMP, sid, True)
        yield (RUN, d.draw())
        yield (FSTAMP, sid, False)

    def _fmt_one(self, sid: int, t: float, begin: bool) -> bytes:
        self.truth.stamps_recorded += 1
        self.truth.stamps_sent += 1
        self.truth.lines_written += 1
        return ts.format_stamp(self.names[sid], max(0, elapsed_us(t, self.ref or 0.0)), begin, self.dialect)

    def _uros(self, task: Task):
        """The micro-ROS executor: spins every tick; rcl timers fire the callbacks, skipping missed periods."""
        wheel = 1e6 / self.preset.wheel_hz
        pose = 1e6 / self.preset.pose_hz
        next_wheel, next_pose = wheel, pose
        while True:
            yield (RUN, task.durations.draw())
            now = self.kernel.now
            if now >= next_wheel:
                next_wheel += wheel * (1 + math.floor((now - next_wheel) / wheel))
                yield from self._scope(task, "w_ctrl")
                yield from self._scope(task, "odom")
            now = self.kernel.now
            if now >= next_pose:
                next_pose += pose * (1 + math.floor((now - next_pose) / pose))
                yield from self._scope(task, "p_ctrl")
            yield (DELAY, 1)

    # ------------------------------------------------------------------ velocity frames

    def uart_rx(self, data: bytes, t_us: float) -> None:
        """Bytes from the host start arriving at ``t_us`` (on the wire back to back)."""
        if "recv_vel" not in self.tasks:
            # The micro-ROS build takes setpoints over XRCE-DDS and never arms UART3's receiver.
            self.truth.rx_bytes_ignored += len(data)
            return
        t_us = max(t_us, self.kernel.now)
        fifo = self.cfg.rx_fifo
        if fifo is not None:
            # Bytes still waiting for the wire when these arrive (they go out back to back, 10 bits each).
            waiting = (self.framer.line_free_at - t_us / 1e6) * self.cfg.baud / 10
            if waiting + len(data) > fifo:
                self.truth.rx_overruns += 1
                self.truth.rx_overrun_bytes += len(data)
                return
        for raw, t_end in self.framer.feed(data, t_us / 1e6):
            self.kernel.at(t_end * 1e6, lambda k, raw=raw: self._rx_event(k, raw))
        deadline = self.framer.idle_deadline()
        if deadline is not None:
            self.kernel.at(deadline * 1e6 + 1e-3, self._rx_idle_check)

    def _rx_idle_check(self, k: Kernel) -> None:
        for raw, _ in self.framer.poll(k.now / 1e6):
            self._rx_event(k, raw)

    def _rx_event(self, k: Kernel, raw: bytes) -> None:
        if len(self.rx_pending) >= RX_PENDING:
            self.truth.frames_lost += 1
            return
        self.rx_pending.append((raw, k.now))
        k.notify_from_isr(self.tasks["recv_vel"])

    def _recv_vel(self, task: Task):
        while True:
            yield (WAIT,)
            while self.rx_pending:
                raw, t_rx = self.rx_pending.popleft()
                yield (RUN, task.durations.draw())
                result = vel2d.decode(raw)
                self.frames.append((t_rx, result))
                if isinstance(result, Problem):
                    if result.kind == "crc":
                        self.crc_err += 1
                        self.truth.frames_crc_error += 1
                    else:
                        self.truth.frames_length_error += 1
                    yield from self.write_log(task, "ERROR", result.detail)  # the firmware's message
                    continue
                self.truth.frames_ok += 1
                vx, vy, wz = result.firmware_units()
                if not self.robot.push_setpoint(self.kernel.now, vx, vy, wz):
                    self.truth.setpoints_dropped += 1
                yield from self.write_log(task, "INFO", f"[recv vel] [{vx:f} {vy:f} {wz:f}]")

    # ------------------------------------------------------------------ sampling window

    def press_button(self, t_us: float) -> None:
        """The user button (EXTI13 rising edge) at ``t_us``, debounced."""
        self.kernel.at(t_us, self._button_isr)

    def _button_isr(self, k: Kernel) -> None:
        if (k.now - self.last_press) < DEBOUNCE_MS[self.output] * 1e3:
            return
        self.last_press = k.now
        if self.output == "v3":
            k.notify_from_isr(self.tasks["btn"])
            return
        if not self.sampling and not self._reporting:
            if self.output == "binary":
                k.notify_from_isr(self.tasks["profile"])  # it sends the name table, then starts sampling
                return
            self._start_sampling(k)
            k.notify_from_isr(self.tasks["profile"])
        elif self.sampling:
            self._stop_sampling(k)
            if self.output == "binary":
                k.notify_from_isr(self.tasks["profile"])

    _reporting = False

    def _start_sampling(self, k: Kernel) -> None:
        self.sync()
        self.window += 1
        self.records.clear()
        k.ctx_switches = 0
        self.first_stamp = None
        self.ref = k.now if self.output in ("v1", "binary") else None
        self.window_start = k.now
        self.sampling = True
        k.sampling = True
        if self.window_ms is not None and self.output != "v3":
            k.at(k.now + self.window_ms * 1e3, self._auto_stop)

    def _auto_stop(self, k: Kernel) -> None:
        if self.sampling:
            self._stop_sampling(k)
            if self.output == "binary":
                k.notify_from_isr(self.tasks["profile"])

    def _stop_sampling(self, k: Kernel) -> None:
        self.sampling = False
        k.sampling = False
        self.window_stop = k.now
        self.sync()

    def _flusher(self, task: Task):
        """V1/V2: print the record ring every ``flush_ms`` while sampling, then the rest and the report."""
        flush = max(1, round(self.cfg.flush_ms * self.preset.tick_hz / 1000))
        while True:
            yield (WAIT,)
            self._reporting = True
            next_flush = self.kernel.tick + flush
            while True:
                yield (DELAY_UNTIL, next_flush)
                next_flush += flush
                yield from self._print_records(task)
                if not self.sampling:
                    break
            yield from self._print_records(task)
            yield from self._print_report(task)
            self._reporting = False

    def _print_records(self, task: Task):
        """Format and write the buffered records.

        Lines are formatted in batches of as many as fit into the ring's free space: the batch
        costs the sum of its lines' formatting times (one long computation, which the control
        tasks interleave with at every tick) and is written at its end. The real task writes each
        line as soon as it is formatted, so bytes enter the ring up to one batch later here; when
        nothing fits, it waits in 1 ms steps as the sink makes writers do.
        """
        self.sync()
        t, ids, b = self.records.take()
        if not len(t):
            return
        t_us = np.maximum(stamp_us(t, self.ref), 0)
        lines = ts.format_stamps(self.names_b, ids, t_us, b, self.dialect)
        ends = list(itertools.accumulate(map(len, lines)))
        i = 0
        n = len(lines)
        while i < n:
            free = yield (CALL, lambda k: self.ring.free)
            base = ends[i - 1] if i else 0
            m = bisect.bisect_right(ends, base + free, lo=i) - i
            if m == 0:  # not even one line fits: format it, then wait for space
                yield (RUN, self.line_cost.draw())
                yield from self.write_blocking(task, lines[i])
                m = 1
            else:
                yield (RUN, float(self.line_cost.peek(m).sum()))
                self.line_cost.consume(m)
                chunk = b"".join(lines[i : i + m])
                ok = yield (CALL, lambda k, chunk=chunk: self.try_write(chunk))
                if not ok:  # someone else wrote meanwhile: line by line, waiting as needed
                    for line in lines[i : i + m]:
                        yield from self.write_blocking(task, line)
            i += m
            self.truth.stamps_sent += m
            self.truth.lines_written += m

    def _btn(self, task: Task):
        window_ticks = max(1, round(self.window_ms * self.preset.tick_hz / 1000))
        while True:
            yield (WAIT,)
            if self.sampling or self._reporting:
                continue
            yield (RUN, task.durations.draw())
            self._reporting = True
            yield (CALL, self._start_sampling)
            yield (DELAY, window_ticks)
            yield (CALL, self._stop_sampling)
            yield (NOTIFY, self.tasks["rt_stats"])

    def _rt_stats(self, task: Task):
        """V3: dump the record array after the window, then the report."""
        while True:
            yield (WAIT,)
            yield from self._print_records(task)
            yield from self._print_report(task)
            self._reporting = False

    def _binary_reporter(self, task: Task):
        """Binary: name table and WINDOW_START before sampling; DROPS/CHECK/WINDOW_STOP and the report after."""
        while True:
            yield (WAIT,)
            if self.sampling:
                continue
            self._reporting = True
            names = {i: n for i, n in enumerate(self.names)}
            for line in tb.name_table(names).splitlines(keepends=True):
                yield (RUN, self.line_cost.draw())
                yield from self.write_blocking(task, line)
            yield (CALL, self._start_sampling)
            yield from self.write_blocking(task, self.binary.start(self.window))
            while self.sampling:
                yield (WAIT,)
            yield (CALL, lambda k: self.sync())
            t_stop = elapsed_us(self.window_stop, self.ref)
            yield from self.write_blocking(task, self.binary.stop(t_stop))
            yield from self._print_report(task)
            self._reporting = False

    # ------------------------------------------------------------------ report

    def runtime_report(self, reporter: Task | None = None, closing_us: int | None = None) -> RuntimeReport:
        """The statistics block as the firmware would print it now (spec §3.7)."""
        k = self.kernel
        now = k.now
        rows = []
        order = self._list_order(reporter)
        units = []
        for t in order:
            u = t.runtime_units
            if t is k.current:
                u += math.floor(now / RUNTIME_UNIT_US) - math.floor(t.in_at / RUNTIME_UNIT_US)
            units.append(u)
        pcts = ts.runtime_percentages(units)
        for t, u, pct in zip(order, units, pcts, strict=True):
            rows.append(RuntimeRow(t.name, u, pct))
        tasks = []
        for t in order:
            if t is reporter:
                state = "X"
            elif t is k.idle or t.state in ("ready", "running"):
                state = "R"
            elif t.waiting and t.name in ("recv_vel", "btn", "rt_stats", "profile"):
                state = "S"
            else:
                state = "B"
            tasks.append(TaskRow(t.name, state, t.priority, t.stack_hwm, t.number))
        closing = "profiled for" if self.output == "v1" else "output took"
        pct_header = "%" if self.preset.rtos == "micro-ros" else "%%"
        return RuntimeReport(self.preset.free_heap, k.ctx_switches, tuple(rows), tuple(tasks), closing, closing_us,
                             pct_header, True)

    def _list_order(self, reporter: Task | None) -> list[Task]:
        """uxTaskGetSystemState's order: ready lists from the top priority, then delayed, then waiting."""
        k = self.kernel
        ready = sorted((t for t in k.tasks if t.state in ("ready", "running") or t is reporter),
                       key=lambda t: -t.priority)
        delayed = [e[2] for e in k.delayed if e[2] not in ready]
        rest = [t for t in k.tasks if t not in ready and t not in delayed]
        return ready + delayed + rest

    def _print_report(self, task: Task):
        if self.output == "v1":  # thesis: the sampling duration, framed by separators
            report = self.runtime_report(task, elapsed_us(self.window_stop, self.window_start))
            lines = ts.format_report(report).splitlines(keepends=True)
            last = None
        else:  # branch heads: from the first stamp to the end of the report, known only at the end
            report = self.runtime_report(task, 0)
            lines = ts.format_report(report).splitlines(keepends=True)
            lines, last = lines[:-1], lines[-1]
        for line in lines:
            yield (RUN, self.line_cost.draw())
            yield from self.write_blocking(task, line)
        if last is not None:
            start = self.first_stamp if self.first_stamp is not None else self.window_start
            report = report._replace(closing_us=elapsed_us(self.kernel.now, start))
            yield from self.write_blocking(task, ts.format_report(report).splitlines(keepends=True)[-1])
        self.reports.append(report)
