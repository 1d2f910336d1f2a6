"""``hilbench demo``: a bench from a profile, driven by the official SDK, shown live.

The demo starts the profile's devices behind a pseudo-terminal and runs a
control loop against that pty with the unmodified ``dynamixel-sdk``, the way a
robot's own control software would: torque on, then every cycle a Sync Read
of Present Position and a Sync Write of Goal Position along a sine wave, and
now and then a Sync Read of voltage and temperature. The table shows what the
SDK reads back.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import dynamixel_sdk as sdk
from rich import box
from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from hilbench.bench import Bench
from hilbench.dxl_client import open_port
from hilbench.profile import DEFAULT_PROFILE, load_profile

POSITION = 132
GOAL = 116
VOLT_TEMP = 144  # Present Input Voltage (2) + Present Temperature (1)


@dataclass
class ServoView:
    id: int
    model: str
    goal: int = 0
    position: int | None = None
    voltage: float | None = None
    temperature: int | None = None


@dataclass
class DemoResult:
    """What the control loop saw; ``hilbench demo`` prints it at the end."""

    cycles: int = 0
    seconds: float = 0.0
    failed_reads: int = 0
    servos: dict[int, ServoView] = field(default_factory=dict)
    line_bytes: int = 0

    @property
    def rate(self) -> float:
        return self.cycles / self.seconds if self.seconds else 0.0


def _render(result: DemoResult, elapsed: float, title: str, line_rate: float) -> Group:
    """Two servos per row, so twenty fit an 80x24 terminal with the status line."""
    table = Table(title=title, box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False, header_style="bold")
    for _ in range(2):
        for col in ("ID", "model", "goal", "pos", "V", "C"):
            table.add_column(col, justify="right")
    views = list(result.servos.values())
    half = (len(views) + 1) // 2

    def cells(v: ServoView | None) -> list[str]:
        if v is None:
            return [""] * 6
        return [
            str(v.id),
            v.model.replace("(2.0)", ""),
            str(v.goal),
            "-" if v.position is None else str(v.position),
            "-" if v.voltage is None else f"{v.voltage:.1f}",
            "-" if v.temperature is None else str(v.temperature),
        ]

    for k in range(half):
        right = views[k + half] if k + half < len(views) else None
        table.add_row(*cells(views[k]), *cells(right))
    rate = result.cycles / elapsed if elapsed else 0.0
    bps = result.line_bytes / max(elapsed, 1e-9)
    status = Text(
        f"{elapsed:4.1f} s: {result.cycles} cycles ({rate:4.0f}/s), line {bps / 1000:5.1f} kB/s "
        f"({bps / line_rate:4.0%} busy), {result.failed_reads} failed reads",
        style="green" if result.failed_reads == 0 else "yellow",
    )
    return Group(table, status)


def run_demo(
    profile: str = DEFAULT_PROFILE,
    seconds: float = 10.0,
    *,
    console: Console | None = None,
    amplitude: int = 400,
    period: float = 2.0,
    paced: bool = True,
) -> DemoResult:
    """Run the demo for ``seconds`` (0 = until Ctrl-C); returns what the control loop saw."""
    console = console or Console()
    prof = load_profile(profile)
    result = DemoResult()
    with Bench(prof, paced=paced) as bench:
        ep = next(iter(bench.endpoints.values()))
        servos = sorted(
            (s for s in ep.bus.servos if s.is_servo), key=lambda s: s.id
        )
        for s in servos:
            result.servos[s.id] = ServoView(s.id, s.model.name)
        ids = [s.id for s in servos]
        console.print(f"[bold]hilbench demo[/]: profile {prof.name} - {prof.description}")
        console.print(f"  bus {ep.name} on {ep.path} at {ep.spec.baud} baud, {len(ids)} servos")
        ph = sdk.PacketHandler(2.0)
        with open_port(ep.path, ep.spec.baud) as port:
            torque = sdk.GroupSyncWrite(port, ph, 64, 1)
            for i in ids:
                torque.addParam(i, [1])
            torque.txPacket()
            reader = sdk.GroupSyncRead(port, ph, POSITION, 4)
            vt = sdk.GroupSyncRead(port, ph, VOLT_TEMP, 3)
            for i in ids:
                reader.addParam(i)
                vt.addParam(i)
            writer = sdk.GroupSyncWrite(port, ph, GOAL, 4)
            start = time.monotonic()
            bytes0 = ep.medium.stats.bytes
            last_draw = 0.0
            timing = "paced at wire speed" if ep.medium.paced else "unpaced"
            title = f"{prof.name}: SDK Sync Read / Sync Write, {timing}"
            rate = ep.spec.baud / 10  # bytes/s at 8N1
            with Live(_render(result, 0.0, title, rate), console=console, refresh_per_second=10,
                      auto_refresh=False) as live:
                try:
                    while True:
                        now = time.monotonic()
                        elapsed = now - start
                        if seconds and elapsed >= seconds:
                            break
                        if reader.txRxPacket() == sdk.COMM_SUCCESS:
                            for i in ids:
                                result.servos[i].position = reader.getData(i, POSITION, 4)
                        else:
                            result.failed_reads += 1
                        writer.clearParam()
                        for k, i in enumerate(ids):
                            goal = int(2048 + amplitude * math.sin(2 * math.pi * elapsed / period + k * 0.3))
                            result.servos[i].goal = goal
                            writer.addParam(i, list(goal.to_bytes(4, "little")))
                        writer.txPacket()
                        result.cycles += 1
                        if result.cycles % 50 == 1 and vt.txRxPacket() == sdk.COMM_SUCCESS:
                            for i in ids:
                                result.servos[i].voltage = vt.getData(i, VOLT_TEMP, 2) / 10
                                result.servos[i].temperature = vt.getData(i, VOLT_TEMP + 2, 1)
                        if now - last_draw >= 0.1:  # the screen refreshes at most 10 times a second
                            result.line_bytes = ep.medium.stats.bytes - bytes0
                            live.update(_render(result, elapsed, title, rate), refresh=True)
                            last_draw = now
                except KeyboardInterrupt:
                    pass
                result.seconds = time.monotonic() - start
                result.line_bytes = ep.medium.stats.bytes - bytes0
                live.update(_render(result, result.seconds, title, rate), refresh=True)
            torque.clearParam()
            for i in ids:
                torque.addParam(i, [0])
            torque.txPacket()
    return result
