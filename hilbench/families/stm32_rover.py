"""The STM32 rover family: the mecanum rover's STM32F767 FreeRTOS board behind a UART (or UDP).

:data:`~hilbench.families.stm32_rover.BUS_KIND` is its UART (endpoint ``protocol = "vel2d"``: one board, which paces its own line),
:data:`~hilbench.families.stm32_rover.FAMILY` the board.

Profile schema (endpoint ``protocol = "vel2d"``, a pty or UDP)::

    [endpoints.rover]
    type = "pty"                   # or "udp" (bind, port, peer)
    protocol = "vel2d"
    baud = 115_200                 # the UART's rate: paces the board's output and its receiver

    [[devices]]
    model = "stm32f767-rover"
    name = "rover"
    preset = "freertos-50-30"
    caches = true
    output = "v3"                  # v1, v2, v3, binary
    dialect = "branch"             # "thesis" or "branch"
    window_ms = 1000
    flush_ms = 10
    seed = 0
    boot_banner = true
    tasks = { wheel_ctrl = { mean_us = 12.0, sd_us = 1.0 } }
    faults = { drop_rate = 0.0, corrupt_rate = 0.0, drop_next = 0, corrupt_next = 0 }
    agent = "127.0.0.1:8888"       # micro-ros presets: the XRCE client's agent ("HOST:PORT" or an
                                   # xrce-dds endpoint of this profile); see fakes/stm32_board/micro_ros.py
    micro_ros = { client_key = 0x60C93570, domain_id = 0, zero_after_session = false }
    body = "rover"                 # the world body the board drives (whichever door setpoints come through)
    odometry = { slip = 0.0, encoder_noise = 0.0 }   # share of wheel motion lost; counts of noise per cycle

An endpoint carries one board (a UART is point to point):
``bench.family("stm32-rover").board()`` (:class:`RoverBoards`). The board paces its own UART, so its medium delivers at
once. Control commands (``hilbench board``, :class:`hilbench.clients.stm32_rover.BoardClient`): status,
button, reset, fault, log, wait_report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hilbench.bench.bus import BusKind
from hilbench.bench.checks import Checker
from hilbench.bench.control import ControlError, ControlRequestError, client_waits
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.bench.knobs import check_fault_table, check_knobs
from hilbench.bench.world import check_odometry, refuse_second_driver
from hilbench.rules import FAULT_COUNT, PROBABILITY, Rule, RuleError

if TYPE_CHECKING:
    from hilbench.fakes.stm32_board import Board

#: Line rates a board endpoint accepts (bit/s); a pty does not care, the board paces its UART by it.
BOARD_BAUD_RANGE = (1200, 12_500_000)
#: The board's UART rate: a profile's ``baud``, and ``--baud`` of ``send-vel`` / ``teleop``.
BOARD_BAUD = Rule(int, *BOARD_BAUD_RANGE)
BOARD_MODELS = ("stm32f767-rover", "mecarover", "stm32-rover")
BOARD_KEYS = ("model", "name", "endpoint", "preset", "caches", "output", "dialect", "window_ms", "flush_ms", "seed",
              "boot_banner", "faults", "tasks", "agent", "micro_ros", "odometry")
MICRO_ROS_KEYS = ("client_key", "domain_id", "zero_after_session")
TIMING_KEYS = ("mean_us", "sd_us", "min_us", "max_us", "dist")
#: ``wait_report``: how long to wait (s), and after how many reports (``hilbench board wait-report`` too).
WAIT_TIMEOUT = Rule(float, 0, 3600)
REPORT_COUNT = Rule(int, 0, 2**31)
#: Fault knobs and their rules: a profile's ``faults`` table (all but ``stall``), ``hilbench board fault``
#: before it sends, and the bench's control channel when it receives (``stall`` in seconds).
FAULT_RULES: dict[str, Rule] = {"drop_rate": PROBABILITY, "corrupt_rate": PROBABILITY, "drop_next": FAULT_COUNT,
                                "corrupt_next": FAULT_COUNT, "stall": Rule(float, 0.0, 3600.0)}
#: The knobs a profile may set (``stall`` is live only).
BOARD_FAULT_RULES = {k: rule for k, rule in FAULT_RULES.items() if k != "stall"}


@dataclass
class BoardSpec(DeviceSpec):
    """An emulated STM32 rover board on a ``vel2d`` endpoint."""

    model: str = "stm32f767-rover"
    preset: str = "freertos-100-50"
    caches: bool = True
    output: str = "v1"
    dialect: str | None = None
    window_ms: float | None = None
    flush_ms: float = 10.0
    seed: int = 0
    boot_banner: bool = True
    faults: dict[str, float] = field(default_factory=dict)
    tasks: dict[str, dict[str, Any]] = field(default_factory=dict)
    agent: str | None = None
    micro_ros: dict[str, Any] = field(default_factory=dict)
    odometry: dict[str, float] = field(default_factory=dict)


def board_config(spec: BoardSpec, baud: int, port_type: str = "pty"):
    """The emulator configuration of a profile's board entry (behind a door of ``port_type``: a UDP door,
    which has no flow control, holds at most :data:`~hilbench.fakes.stm32_board.firmware.RX_FIFO` bytes;
    a pty door needs no bound: the line holds its writer back, as the real USB link does)."""
    from hilbench.fakes.stm32_board import BoardConfig, make_preset
    from hilbench.fakes.stm32_board.firmware import RX_FIFO

    preset = make_preset(spec.preset, spec.caches)
    for name, timing in spec.tasks.items():
        preset = preset.with_task_timing(name, **timing)
    return BoardConfig(preset, output=spec.output, baud=baud, dialect=spec.dialect, window_ms=spec.window_ms,
                       flush_ms=spec.flush_ms, seed=spec.seed, boot_banner=spec.boot_banner,
                       faults=dict(spec.faults), rx_fifo=RX_FIFO if port_type == "udp" else None,
                       encoder_noise=spec.odometry.get("encoder_noise", 0.0))


def check_fault_knobs(knobs: dict[str, Any]) -> dict[str, float]:
    """Fault knobs for a live board, checked against :data:`FAULT_RULES`; raises
    :class:`~hilbench.rules.RuleError` (a usage error) in one line. ``hilbench board`` checks before
    sending and the bench again when it receives, with these same rules."""
    return check_knobs(knobs, FAULT_RULES, error=RuleError)


class Vel2dBusKind(BusKind):
    """The rover board's UART (a pty) or its UDP door: one board per endpoint."""

    protocol = "vel2d"
    endpoint_types = ("pty", "udp")
    max_devices = 1
    one_device_reason = "a UART is point to point"
    tap_reader = "trace"

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int:
        return c.rule(115_200 if value is None else value, key, BOARD_BAUD)

    def paced(self, spec, requested: bool) -> bool:
        return False  # the board paces its own UART (full duplex), so its line delivers at once

    def describe_endpoint(self, endpoint) -> dict[str, Any]:
        return {"paced": True}  # at the UART's rate, by the board itself

    def summary(self, endpoint) -> str:
        board = next(iter(endpoint.devices.values()), None)
        if board is None or not hasattr(board, "config"):
            return f"{endpoint.spec.protocol}, {endpoint.spec.baud} baud, no board"
        b = board.config
        return (f"{endpoint.spec.protocol}, {endpoint.spec.baud} baud, board {board.name!r}: "
                f"{b.preset.name}{'' if b.preset.caches else ' no caches'}, output {b.output}")

    def device_at(self, endpoint, address: int):
        if not endpoint.devices:
            raise KeyError(f"endpoint {endpoint.name!r} has no board")
        return next(iter(endpoint.devices.values()))


class Stm32RoverFamily(DeviceFamily):
    """The emulated rover board, one per ``vel2d`` endpoint."""

    name = "stm32-rover"
    joins = ("vel2d",)
    device_keys = BOARD_KEYS
    models = BOARD_MODELS
    device_word = "board"
    control_commands = {
        "status": "what the board is doing (preset, output, counters, recent log)",
        "button": "press the user button (starts/stops a trace window)",
        "reset": "reboot the board",
        "fault": "turn fault knobs: drop_rate, corrupt_rate, drop_next, corrupt_next, stall",
        "log": "the board's recent log lines",
        "wait_report": "wait until the board printed another run-time report",
        "micro_ros": "the micro-ROS client's session, topics and counters; zeroed_next=N zeroes its next N datagrams",
    }

    # ------------------------------------------------------------------ profile

    def check_devices(self, c: Checker, key: str, dev: dict[str, Any], endpoint, profile) -> list[BoardSpec]:
        from hilbench.fakes.stm32_board.presets import OUTPUTS, make_preset, preset_names

        model = c.choice(dev.get("model", BOARD_MODELS[0]), f"{key}.model", BOARD_MODELS)
        preset = dev.get("preset", "freertos-100-50")
        if not isinstance(preset, str) or preset not in preset_names():
            c.fail(f"{key}.preset", f"expected one of {', '.join(preset_names())}, got {preset!r}")
        output = c.choice(dev.get("output", "v1"), f"{key}.output", OUTPUTS)
        dialect = dev.get("dialect")
        if dialect is not None:
            c.choice(dialect, f"{key}.dialect", ("thesis", "branch"))
        window = dev.get("window_ms")
        if window is not None:
            window = c.number(window, f"{key}.window_ms", 1, 3_600_000)
        name = dev.get("name", endpoint.name)
        if not isinstance(name, str) or not name:
            c.fail(f"{key}.name", f"expected a string, got {name!r}")
        faults = check_fault_table(c, f"{key}.faults", dev.get("faults", {}), BOARD_FAULT_RULES)
        tasks = c.table(dev.get("tasks", {}), f"{key}.tasks")
        base = make_preset(preset, dev.get("caches", True) is not False)
        known = {t.name for t in base.tasks} | {f.name for f in base.functions} | {"line_cost"}
        for tname, timing in tasks.items():
            where = f"{key}.tasks.{tname}"
            if tname not in known:
                c.fail(where, f"no such task or function in preset {preset!r} (expected one of: "
                              f"{', '.join(sorted(known))})")
            timing = c.table(timing, where)
            c.unknown(timing, where, TIMING_KEYS)
            for tk in ("mean_us", "sd_us", "min_us", "max_us"):
                if tk in timing:
                    c.number(timing[tk], f"{where}.{tk}", 0.0, 1e6)
            if "dist" in timing:
                c.choice(timing["dist"], f"{where}.dist", ("normal", "fixed"))
        return [BoardSpec(
            name=name,
            endpoint=endpoint.name,
            model=model,
            preset=preset,
            caches=c.boolean(dev.get("caches", True), f"{key}.caches"),
            output=output,
            dialect=dialect,
            window_ms=window,
            flush_ms=c.number(dev.get("flush_ms", 10.0), f"{key}.flush_ms", 1, 10_000),
            seed=c.integer(dev.get("seed", 0), f"{key}.seed", 0, 2**31),
            boot_banner=c.boolean(dev.get("boot_banner", True), f"{key}.boot_banner"),
            faults=dict(faults),
            tasks={k: dict(v) for k, v in tasks.items()},
            odometry=check_odometry(c, dev.get("odometry", {}), f"{key}.odometry"),
            **_check_micro_ros(c, key, dev, preset),
        )]

    def check_profile(self, c: Checker, profile) -> None:
        for spec in profile.devices_of(self.name):
            if spec.agent is not None and ":" not in spec.agent and spec.agent not in profile.endpoints:
                c.fail(f"{spec.where}.agent", f"no endpoint named {spec.agent!r} (expected \"HOST:PORT\" or an "
                                              "xrce-dds endpoint of this profile)")

    # ------------------------------------------------------------------ bench

    def build(self, bench, endpoint, devices: list[BoardSpec], t: float) -> None:
        from hilbench.fakes.stm32_board import Board

        for dev in devices:
            board = Board(board_config(dev, endpoint.spec.baud, endpoint.spec.type), name=dev.name)
            if dev.agent is not None:
                from hilbench.fakes.stm32_board.micro_ros import MicroRosClient

                virtual = bench.clock.virtual
                if virtual and ":" in dev.agent:
                    from hilbench.errors import UsageError

                    # (its replies would come at whatever virtual instant the loop reads them: not deterministic)
                    raise UsageError(f"{bench.profile.path}: {dev.where}.agent: a virtual-time bench needs its micro-ROS agent on the "
                                     f"bench's clock: name an xrce-dds endpoint of the profile, not {dev.agent!r}")
                net = (lambda name=dev.agent: bench.endpoints[name].medium) if virtual else None
                board.attach_client(MicroRosClient(_agent_address(bench, dev.agent), net=net, **dev.micro_ros))
            endpoint.add_device(dev.name, board)
            if dev.body is not None:  # the firmware's motion model moves its body, whichever door the setpoint took
                refuse_second_driver(bench.world.world, dev.body, dev.name)
                bench.world.world.drive(dev.body, board.body_motion, dev.odometry["slip"])

    def start(self, endpoint, devices: dict[str, Any], t: float) -> None:
        for board in devices.values():
            board.start(t)

    def stop(self, endpoint, devices: dict[str, Any]) -> None:
        for board in devices.values():
            board.stop()

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: BoardSpec, device, endpoint, profile) -> dict[str, Any]:
        extra: dict[str, Any] = {}
        if spec.agent is not None:
            extra["micro_ros"] = {"agent": spec.agent, **spec.micro_ros}
        return {
            "name": spec.name,
            "model": spec.model,
            "endpoint": spec.endpoint,
            "protocol": profile.endpoints[spec.endpoint].protocol,
            "preset": spec.preset,
            "caches": spec.caches,
            "output": spec.output,
            "baud": profile.endpoints[spec.endpoint].baud,
            **({"odometry": dict(spec.odometry)} if spec.body is not None else {}),
        } | extra | _rx_fifo(profile.endpoints[spec.endpoint].type, device)

    # ------------------------------------------------------------------ control channel

    def control(self, bench, board, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        if cmd == "status":
            return {"status": board.status()}
        if cmd == "button":
            board.press_button()
            board.settle()  # the reply shows the press's effect (sampling on/off)
            return {"status": board.status()}
        if cmd == "reset":
            board.reset()
            board.settle()
            return {"status": board.status()}
        if cmd == "fault":
            knobs = req.get("knobs", {})
            if not isinstance(knobs, dict):
                raise ControlRequestError("knobs: expected an object")
            try:
                return {"faults": board.set_faults(**check_fault_knobs(knobs))}
            except RuleError as exc:
                raise ControlRequestError(str(exc)) from None
        if cmd == "log":
            return {"log": board.status()["log"]}
        if cmd == "micro_ros":
            clients = [c for c in board.clients if hasattr(c, "client")]
            if not clients:
                raise ControlRequestError(f"board {board.name!r} has no micro-ROS client (set agent = \"HOST:PORT\")")
            zeroed = req.get("zeroed_next")
            if zeroed is not None:
                if isinstance(zeroed, bool) or not isinstance(zeroed, int) or not 0 <= zeroed <= 1000:
                    raise ControlRequestError(f"zeroed_next: expected an integer 0..1000, got {zeroed!r}")
                clients[0].client.zero_next(zeroed)
            return {"micro_ros": clients[0].status()}
        if cmd == "wait_report":
            timeout, start = req.get("timeout", 10.0), req.get("after")
            if not WAIT_TIMEOUT.ok(timeout):
                raise ControlRequestError(f"wait_report: timeout: expected {WAIT_TIMEOUT.expected} (s), got {timeout!r}")
            if start is not None and not REPORT_COUNT.ok(start):
                raise ControlRequestError(f"wait_report: after: expected {REPORT_COUNT.expected}, got {start!r}")
            start = len(board.reports) if start is None else start
            # (ends with its client: a client that gave up does not leave a waiting thread behind)
            if not client_waits(lambda: len(board.reports) > start, timeout):
                raise ControlError(f"no report within {timeout} s")
            rep = board.reports[-1]
            return {"report": rep._asdict(), "status": board.status()}
        raise ControlRequestError(f"unknown command {cmd!r}")

    def overflow(self, board, endpoint) -> dict[str, Any]:
        """A UDP door's receive FIFO: its size and the host writes it dropped (a pty door has none)."""
        fifo = _rx_fifo(endpoint.spec.type, board).get("rx_fifo")
        if fifo is None:
            return {}
        return {"limits": {"rx_fifo_bytes": fifo["bytes"]}, "rx_overruns": fifo["overruns"],
                "rx_overrun_bytes": fifo["overrun_bytes"]}


def _rx_fifo(port_type: str, board) -> dict[str, Any]:
    """A UDP door's receive FIFO and what it dropped, for the manifest (a pty door has none)."""
    if port_type != "udp":
        return {}
    from hilbench.fakes.stm32_board.firmware import RX_FIFO

    truth = board.truth if board is not None else None
    return {"rx_fifo": {"bytes": RX_FIFO, "overruns": truth.rx_overruns if truth else 0,
                        "overrun_bytes": truth.rx_overrun_bytes if truth else 0}}


def _check_micro_ros(c: Checker, key: str, dev: dict[str, Any], preset: str) -> dict[str, Any]:
    """``agent`` and ``micro_ros`` of a board entry (the XRCE client of the micro-ROS presets)."""
    agent = dev.get("agent")
    raw = c.table(dev.get("micro_ros", {}), f"{key}.micro_ros")
    if agent is None:
        if raw:
            c.fail(f"{key}.micro_ros", "only with agent = \"HOST:PORT\" (the micro-ROS client's agent)")
        return {}
    if not preset.startswith("micro-ros-"):
        c.fail(f"{key}.agent", f"only for the micro-ros-* presets (the micro-ROS firmware), not {preset!r}")
    if not isinstance(agent, str) or not agent:
        c.fail(f"{key}.agent", f"expected \"HOST:PORT\" or the name of an xrce-dds endpoint, got {agent!r}")
    if ":" in agent:
        c.address(agent, f"{key}.agent", '"HOST:PORT"')
    c.unknown(raw, f"{key}.micro_ros", MICRO_ROS_KEYS)
    opts: dict[str, Any] = {}
    if "client_key" in raw:
        opts["client_key"] = c.integer(raw["client_key"], f"{key}.micro_ros.client_key", 1, 0xFFFFFFFF)
    if "domain_id" in raw:
        opts["domain_id"] = c.integer(raw["domain_id"], f"{key}.micro_ros.domain_id", 0, 232)
    if "zero_after_session" in raw:
        opts["zero_after_session"] = c.boolean(raw["zero_after_session"], f"{key}.micro_ros.zero_after_session")
    return {"agent": agent, "micro_ros": opts}


def _agent_address(bench, agent: str):
    """``(host, port)`` of ``agent``: a HOST:PORT, or a callable finding an endpoint of the bench when it starts."""
    if ":" in agent:
        from hilbench.transports.udp import parse_address

        return parse_address(agent)

    def find() -> tuple[str, int]:
        ep = bench.endpoints.get(agent)
        if ep is None or getattr(ep.port, "address", None) is None:
            from hilbench.errors import BenchError

            raise BenchError(f"agent {agent!r}: no UDP endpoint of that name in this bench")
        return tuple(ep.port.address)

    return find


class RoverBoards(FamilyAccess):
    """The rover boards of a running bench: ``bench.family("stm32-rover")``."""

    family_name = "stm32-rover"

    def board(self, name: str | None = None) -> Board:
        """A board by profile name, or the only one."""
        return self.device(name)


Stm32RoverFamily.access = RoverBoards


#: The bus kind this module registers (entry point ``hilbench.bus_kinds``).
BUS_KIND = Vel2dBusKind()
#: The device family this module registers (entry point ``hilbench.families``).
FAMILY = Stm32RoverFamily()

__all__ = ["BOARD_BAUD", "BOARD_MODELS", "BUS_KIND", "FAMILY", "FAULT_RULES", "BoardSpec",
           "RoverBoards", "Stm32RoverFamily", "Vel2dBusKind", "board_config", "check_fault_knobs"]
