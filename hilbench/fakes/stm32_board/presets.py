"""Calibration data for the emulated rover board, from the thesis tables (spec sheet §4).

A preset is data: the task set (names, priorities, creation numbers, stack
high-water marks), release rules (periods, event rates) and execution-time
distributions, per RTOS build (FreeRTOS or micro-ROS), controller rate pair
and cache setting. Profiles pick a preset by name and may override any task's
timing (``tasks = { wheel_ctrl = { mean_us = 12.0 } }``).

Where the numbers come from (means are µs per slice, as the tables report):

- FreeRTOS, caches on: Table 9 (100|50 Hz) — hal_fetch 6.61, wheel_ctrl 10.69,
  odometry 6.84, pose_control 9.88, tsink 3.01; profile 487.57 per slice at
  ≈ 100 flushes/s, i.e. ≈ 12 µs per formatted stamp line. Caches off: Table 8 —
  21.91, 37.77, 24.01, 32.46, 9.36, profile ≈ 43 µs per line. The 50|30 tables
  (6, 7) agree within a few percent. The 1000, 5000|2000 and 10000|5000 Hz runs
  have no tables; their listings (38, 39) show the same cached slice lengths,
  so those presets reuse Tables 8/9.
- micro-ROS: Tables 4/5 (100|50) and 2/3 (50|30). ``uros`` is one executor
  task that spins every tick (≈ 75 µs per spin cached, XRCE-DDS overhead) and
  runs the callbacks ``w_ctrl`` (wheel rate, 103.59 µs cached), ``p_ctrl``
  (pose rate, 75.16) and ``odom`` (per encoder message, i.e. wheel rate, 3.74)
  as function stamps; the network tasks (EthIf, tcpip_thread, EthLink) are
  released by traffic at the rates the tables imply.
- Distributions: the tables give means only. hilbench uses a normal
  distribution with a standard deviation of 8 % of the mean, clipped to
  [0.6, 1.8] x mean; the listings' slices (hal_fetch 6-7, wheel_ctrl 10-11 µs
  with an occasional 12) fit this. Profiles can set ``sd_us``, ``min_us``,
  ``max_us`` or ``dist = "fixed"``.
- Tick rate: 1 kHz up to 1000 Hz control; 10 kHz for 5000|2000 (periods 2 and
  5 ticks) and 10000|5000 (1 and 2 ticks), the smallest tick that makes the
  periods whole ticks (the thesis does not state the value).
- Report columns (stack high-water marks, free heap) are listing 37's and
  listing 36's values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

#: TIM13 run-time counter: 108 MHz / 10001 → one unit ≈ 92.6 µs (spec §2.1).
RUNTIME_UNIT_US = 10001 / 108.0
SYSTEM_CLOCK_HZ = 216_000_000

RATE_PAIRS: dict[str, tuple[float, float | None]] = {
    "50-30": (50.0, 30.3),
    "100-50": (100.0, 50.0),
    "1000": (1000.0, 500.0),
    "5000-2000": (5000.0, 2000.0),
    "10000-5000": (10000.0, 5000.0),
}


@dataclass(frozen=True)
class Timing:
    """An execution-time distribution in µs: normal(mean, sd) clipped to [min, max], or fixed."""

    mean_us: float
    sd_us: float | None = None
    min_us: float | None = None
    max_us: float | None = None
    dist: str = "normal"

    def resolved(self) -> Timing:
        sd = self.sd_us if self.sd_us is not None else 0.08 * self.mean_us
        lo = self.min_us if self.min_us is not None else 0.6 * self.mean_us
        hi = self.max_us if self.max_us is not None else 1.8 * self.mean_us
        return Timing(self.mean_us, sd, lo, hi, self.dist)


@dataclass(frozen=True)
class TaskSpec:
    """One FreeRTOS task of the firmware.

    ``kind``: ``periodic`` (vTaskDelayUntil every ``period_ticks``), ``tsink``,
    ``profile`` (V1/V2 flusher and reporter), ``btn`` (V3 window task),
    ``recv_vel``, ``sporadic`` (released by traffic, Poisson at ``rate_hz``),
    ``uros`` (micro-ROS executor), ``idle``, ``timer`` (Tmr Svc: blocked).
    """

    name: str
    kind: str
    priority: int
    number: int
    stack_hwm: int
    timing: Timing = Timing(1.0)
    period_ticks: int = 0
    rate_hz: float = 0.0
    role: str = ""  # control role for periodic tasks: hal_fetch, wheel_ctrl, odometry, pose_control


@dataclass(frozen=True)
class FunctionSpec:
    """A scope stamp inside a task (micro-ROS callbacks): ``every`` = wheel or pose rate."""

    name: str
    task: str
    every: str
    timing: Timing


@dataclass(frozen=True)
class Preset:
    """Everything the board's timing depends on."""

    name: str
    rtos: str
    caches: bool
    wheel_hz: float
    pose_hz: float
    tick_hz: int
    tasks: tuple[TaskSpec, ...]
    functions: tuple[FunctionSpec, ...] = ()
    #: CPU µs to format one stamp line into the sink (V1/V2 profiling task).
    line_cost: Timing = Timing(12.0)
    #: Kernel overheads: tick ISR and one context switch (µs).
    isr_us: float = 0.6
    switch_us: float = 0.4
    free_heap: int = 195_696
    notes: str = ""
    source: str = ""

    def task(self, name: str) -> TaskSpec:
        for t in self.tasks:
            if t.name == name:
                return t
        raise KeyError(name)

    @property
    def tick_us(self) -> float:
        return 1e6 / self.tick_hz

    def with_task_timing(self, name: str, **fields) -> Preset:
        """A copy with one task's (or function's, or ``line_cost``'s) timing changed."""
        if name == "line_cost":
            return replace(self, line_cost=replace(self.line_cost, **fields))
        if any(f.name == name for f in self.functions):
            funcs = tuple(replace(f, timing=replace(f.timing, **fields)) if f.name == name else f
                          for f in self.functions)
            return replace(self, functions=funcs)
        self.task(name)
        tasks = tuple(replace(t, timing=replace(t.timing, **fields)) if t.name == name else t for t in self.tasks)
        return replace(self, tasks=tasks)


@dataclass(frozen=True)
class _Calib:
    hal: float
    wheel: float
    odo: float
    pose: float
    tsink: float
    line: float
    isr: float
    switch: float


_FREERTOS = {True: _Calib(6.61, 10.69, 6.84, 9.88, 3.01, 12.0, 0.6, 0.4),
             False: _Calib(21.91, 37.77, 24.01, 32.46, 9.36, 43.0, 1.8, 1.2)}


def _ticks(hz: float, tick_hz: int) -> int:
    # pdMS_TO_TICKS-style: whole ticks; 30.3 Hz pose at 1 kHz is 33 ms as on the branch.
    return max(1, round(tick_hz / hz))


def _tick_rate(wheel_hz: float) -> int:
    return 1000 if wheel_hz <= 1000 else 10_000


def freertos(rates: str, caches: bool = True) -> Preset:
    """The FreeRTOS build (Tables 6-9; V1 flusher task named ``profile`` as in the thesis)."""
    wheel_hz, pose_hz = RATE_PAIRS[rates]
    tick = _tick_rate(wheel_hz)
    c = _FREERTOS[caches]
    wp, pp = _ticks(wheel_hz, tick), _ticks(pose_hz, tick)
    tasks = (
        TaskSpec("tsink", "tsink", 32, 1, 483, Timing(c.tsink)),
        TaskSpec("hal_fetch", "periodic", 24, 2, 443, Timing(c.hal), wp, role="hal_fetch"),
        TaskSpec("recv_vel", "recv_vel", 24, 3, 441, Timing(4.0 if caches else 12.0)),
        TaskSpec("pose_control", "periodic", 24, 4, 410, Timing(c.pose), pp, role="pose_control"),
        TaskSpec("wheel_ctrl", "periodic", 24, 5, 420, Timing(c.wheel), wp, role="wheel_ctrl"),
        TaskSpec("odometry", "periodic", 24, 6, 416, Timing(c.odo), pp, role="odometry"),
        TaskSpec("profile", "profile", 24, 7, 900, Timing(2.0 if caches else 6.0)),
        TaskSpec("IDLE", "idle", 0, 8, 108),
        TaskSpec("Tmr Svc", "timer", 2, 9, 223),
    )
    table = {("50-30", True): "Table 7", ("50-30", False): "Table 6", ("100-50", True): "Table 9",
             ("100-50", False): "Table 8"}.get((rates, caches), "Tables 8/9 timing, listings 38/39 rates")
    return Preset(
        name=f"freertos-{rates}", rtos="freertos", caches=caches, wheel_hz=wheel_hz, pose_hz=pose_hz, tick_hz=tick,
        tasks=tasks, line_cost=Timing(c.line), isr_us=c.isr, switch_us=c.switch, free_heap=195_696,
        source=table,
    )


_UROS = {
    # cached / uncached: spin, w_ctrl, p_ctrl, odom, tsink, EthIf, tcpip, EthLink, line cost
    True: (74.6, 103.59, 75.16, 3.74, 3.43, 18.81, 28.25, 128.88, 12.0),
    False: (157.0, 307.53, 322.41, 9.92, 8.80, 51.53, 71.13, 110.25, 43.0),
}


def micro_ros(rates: str, caches: bool = True) -> Preset:
    """The micro-ROS build (Tables 2-5): one executor task with function stamps, plus the network stack."""
    wheel_hz, pose_hz = RATE_PAIRS[rates]
    if rates == "50-30":
        pose_hz = 33.3  # micro-ROS uses 20 / 30 ms
    spin, w, p, o, ts, ethif, tcpip, ethlink, line = _UROS[caches]
    tick = 1000
    tasks = (
        TaskSpec("tsink", "tsink", 32, 1, 475, Timing(ts)),
        TaskSpec("profile", "profile", 24, 2, 892, Timing(2.0 if caches else 6.0)),
        TaskSpec("uros", "uros", 24, 3, 2548, Timing(spin), 1),
        TaskSpec("IDLE", "idle", 0, 4, 108),
        TaskSpec("Tmr Svc", "timer", 2, 5, 223),
        TaskSpec("tcpip_thread", "sporadic", 24, 6, 180, Timing(tcpip), rate_hz=199.0),
        TaskSpec("EthIf", "sporadic", 48, 7, 17, Timing(ethif), rate_hz=196.0),
        TaskSpec("EthLink", "periodic", 16, 8, 193, Timing(ethlink), 100),
    )
    functions = (
        FunctionSpec("w_ctrl", "uros", "wheel", Timing(w)),
        FunctionSpec("p_ctrl", "uros", "pose", Timing(p)),
        FunctionSpec("odom", "uros", "wheel", Timing(o)),
    )
    table = {("50-30", True): "Table 3", ("50-30", False): "Table 2", ("100-50", True): "Table 5",
             ("100-50", False): "Table 4"}.get((rates, caches), "Tables 4/5 timing")
    return Preset(
        name=f"micro-ros-{rates}", rtos="micro-ros", caches=caches, wheel_hz=wheel_hz, pose_hz=pose_hz,
        tick_hz=tick, tasks=tasks, functions=functions, line_cost=Timing(line),
        isr_us=0.6 if caches else 1.8, switch_us=0.4 if caches else 1.2, free_heap=4_688, source=table,
        notes="rates are targets: the executor spins every tick after its work, so 1000 Hz yields ~930 Hz",
    )


def preset_names() -> list[str]:
    """All preset names (each exists with caches on and off)."""
    return [f"freertos-{r}" for r in RATE_PAIRS] + [f"micro-ros-{r}" for r in ("50-30", "100-50", "1000")]


def make_preset(name: str, caches: bool = True) -> Preset:
    """A preset by name, e.g. ``"freertos-10000-5000"``; raises KeyError with the known names."""
    if name.startswith("freertos-") and name[9:] in RATE_PAIRS:
        return freertos(name[9:], caches)
    if name.startswith("micro-ros-") and name[10:] in ("50-30", "100-50", "1000"):
        return micro_ros(name[10:], caches)
    raise KeyError(f"unknown preset {name!r} (known: {', '.join(preset_names())})")


@dataclass
class BoardConfig:
    """How one emulated board runs: preset, output path, link, window, seed and faults.

    ``output`` picks the trace path of spec §3.4: ``v1`` (thesis: hook stamps
    in a 512-record ring flushed by ``profile``, ``1/0`` edges, button toggles),
    ``v2`` (micro-ROS head: ring flushed every 10 ticks, ``in/out``), ``v3``
    (FreeRTOS head: 32,768-record array, fixed window, dump afterwards) or
    ``binary`` (hilbench's compact words written by the hooks themselves,
    docs/formats/tracestamp-binary.md).
    """

    preset: Preset
    output: str = "v1"
    baud: int = 115_200
    dialect: str | None = None  # default: thesis for v1, branch otherwise
    window_ms: float | None = None  # fixed window length (v3: 1000 ms); None: the button toggles
    flush_ms: float = 10.0
    seed: int = 0
    boot_banner: bool = True
    faults: dict[str, float] = field(default_factory=dict)
    #: Bytes a door without flow control (UDP) holds for the UART: beyond, a write is dropped and counted
    #: (``Truth.rx_overruns``). None: unbounded (a pty door, whose writer the line holds back while the UART
    #: has more than half of HOST_FIFO to take in, as the real USB link does: :meth:`Board.input_backlog`).
    rx_fifo: int | None = None
    #: Encoder noise (standard deviation in counts per wheel per pose cycle while it turns): see
    #: :class:`~hilbench.fakes.mecanum_robot.Robot`.
    encoder_noise: float = 0.0

    @property
    def edge_dialect(self) -> str:
        if self.dialect:
            return self.dialect
        return "thesis" if self.output == "v1" else "branch"


OUTPUTS = ("v1", "v2", "v3", "binary")


def default_window_ms(output: str) -> float | None:
    return 1000.0 if output == "v3" else None


def runtime_units(t_us: float) -> int:
    """The TIM13 run-time counter value at ``t_us`` after scheduler start."""
    return math.floor(t_us / RUNTIME_UNIT_US)
