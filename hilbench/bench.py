"""A running bench: the endpoints and devices of a profile, wired together and started.

``Bench(profile).start()`` opens each endpoint (a pseudo-terminal, or a UDP
socket on 127.0.0.1), puts the profile's devices on a serial line behind it,
and starts the line. Which devices an endpoint carries depends on its
protocol: a ``dynamixel`` endpoint gets a bus of emulated servos, a ``vel2d``
endpoint one emulated STM32 rover board (:data:`DEVICE_FACTORIES`). Every
endpoint's traffic passes one :class:`SerialMedium`, so taps (monitor,
recorder) attach the same way everywhere. The manifest (:meth:`Bench.manifest`)
tells other programs where everything is.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hilbench.fakes.dynamixel.bus import DynamixelBus
from hilbench.fakes.dynamixel.servo import Servo
from hilbench.fakes.stm32_board import Board, BoardConfig, make_preset
from hilbench.profile import BoardSpec, DeviceSpec, EndpointSpec, Profile, load_profile
from hilbench.protocols.dynamixel_models import BAUD_TO_CODE, find_model
from hilbench.transports.pty import PtyEndpoint
from hilbench.transports.serial_medium import SerialMedium
from hilbench.transports.tap_server import TapServer
from hilbench.transports.udp import UdpEndpoint


@dataclass
class Endpoint:
    """A started endpoint: its spec, its host port (pty or UDP socket) and the line behind it.

    ``bus`` is the Dynamixel bus of a ``dynamixel`` endpoint (else None);
    ``board`` the emulated board of a ``vel2d`` endpoint (else None).
    """

    spec: EndpointSpec
    pty: PtyEndpoint | None
    medium: SerialMedium
    bus: DynamixelBus | None = None
    board: Board | None = None
    udp: UdpEndpoint | None = None
    tap: TapServer | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def path(self) -> str:
        """What a host program opens: the pty (or its stable link), or ``udp://127.0.0.1:PORT``."""
        if self.udp is not None:
            return self.udp.url
        return self.pty.client_path

    @property
    def host_port(self) -> PtyEndpoint | UdpEndpoint:
        return self.udp if self.udp is not None else self.pty


class Bench:
    """The devices of a profile behind real pseudo-terminals.

    ``paced`` overrides every endpoint's ``paced`` setting; ``link_dir`` puts a
    stable symlink named after each endpoint into that directory. ``tap``
    serves each line's traffic on 127.0.0.1 (a TCP tap server, listed as
    ``tap`` in the manifest) for monitors and recorders in other processes.
    """

    def __init__(
        self,
        profile: Profile | str | Path,
        *,
        paced: bool | None = None,
        link_dir: str | Path | None = None,
        tap: bool = False,
    ) -> None:
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        self.paced = paced
        self.tap = tap
        self.link_dir = Path(link_dir) if link_dir else None
        self.endpoints: dict[str, Endpoint] = {}
        self.devices: dict[str, Servo | Board] = {}
        self.started_at: float | None = None
        self.control = None  # a ControlServer once serve_control() ran

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Bench:
        """Open the endpoints and start every line; returns self."""
        if self.started_at is not None:
            return self
        t = time.monotonic()
        prof = self.profile
        try:
            for spec in prof.endpoints.values():
                paced = spec.paced if self.paced is None else self.paced
                if spec.type == "udp":
                    host: PtyEndpoint | UdpEndpoint = UdpEndpoint(spec.name, spec.bind, spec.port, spec.peer)
                else:
                    link = spec.link
                    if self.link_dir is not None:
                        link = str(self.link_dir / spec.name)
                    host = PtyEndpoint(spec.name, link=os.path.expanduser(link) if link else None)
                # A board paces its own UART (full duplex), so its line delivers at once.
                medium = SerialMedium(spec.name, spec.baud, paced=paced and spec.protocol == "dynamixel")
                ep = Endpoint(spec, host if isinstance(host, PtyEndpoint) else None, medium,
                              udp=host if isinstance(host, UdpEndpoint) else None)
                self.endpoints[spec.name] = ep
                DEVICE_FACTORIES[spec.protocol](self, ep, t)
                medium.add_host(host)
                if self.tap:
                    ep.tap = TapServer(baud=spec.baud, protocol=spec.protocol,
                                       description=f"bench {prof.name}, endpoint {spec.name}")
                    medium.add_tap(ep.tap.feed)
            for ep in self.endpoints.values():
                ep.medium.start()
            for ep in self.endpoints.values():
                if ep.board is not None:
                    ep.board.start(t)
        except Exception:
            self.stop()
            raise
        self.started_at = t
        return self

    def _start_dynamixel(self, ep: Endpoint, t: float) -> None:
        spec = ep.spec
        servos = []
        fast_read = {}
        for dev in self.profile.servos:
            if dev.endpoint != spec.name:
                continue
            servo = self._make_servo(dev, spec, t)
            servos.append(servo)
            self.devices[dev.name] = servo
            if dev.fast_read is not None:
                fast_read[dev.id] = dev.fast_read
        bus = DynamixelBus(
            servos,
            name=f"{spec.name}-devices",
            chain_policy=spec.chain_policy,
            fast_missing=spec.fast_missing,
            fast_read=fast_read,
            strict_stuffing=spec.strict_stuffing,
        )
        bus.attach(ep.medium)
        ep.bus = bus

    def _start_board(self, ep: Endpoint, t: float) -> None:
        for dev in self.profile.boards:
            if dev.endpoint != ep.spec.name:
                continue
            board = Board(board_config(dev, ep.spec.baud), name=dev.name)
            board.attach(ep.medium)
            ep.board = board
            self.devices[dev.name] = board

    def _make_servo(self, dev, spec: EndpointSpec, t: float) -> Servo:
        model = find_model(dev.model)
        init = dict(dev.init)
        if model.kind == "servo":
            init.setdefault("baud_rate", BAUD_TO_CODE[spec.baud])
        servo = Servo(
            model,
            dev.id,
            name=dev.name,
            initial=init,
            position=dev.position,
            supply_voltage=dev.supply_voltage or self.profile.supply_voltage,
            ambient_temperature=dev.ambient_temperature or self.profile.ambient_temperature,
            firmware=dev.firmware,
            board_baud=spec.baud,
            t=t,
            seed=dev.faults.get("seed", 0),
        )
        f = dev.faults
        for key in ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay"):
            if key in f:
                setattr(servo.faults, key, f[key])
        if f.get("vanished"):
            servo.vanish(t, math.inf)
        if f.get("hardware_error"):
            servo.raise_hardware_error(f["hardware_error"], t, sticky=True)
        return servo

    def stop(self) -> None:
        """Stop every board, line and control server; close every endpoint."""
        if self.control is not None:
            self.control.close()
            self.control = None
        for ep in self.endpoints.values():
            if ep.board is not None:
                ep.board.stop()
            ep.medium.close()
            ep.host_port.close()
            if ep.tap is not None:
                ep.tap.close()
        self.started_at = None

    def __enter__(self) -> Bench:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # ------------------------------------------------------------------ access

    def endpoint(self, name: str | None = None) -> Endpoint:
        """An endpoint by name (or the only one)."""
        if name is None:
            if len(self.endpoints) != 1:
                raise KeyError(f"bench has endpoints {list(self.endpoints)}; name one")
            return next(iter(self.endpoints.values()))
        return self.endpoints[name]

    def device(self, name_or_id: str | int, endpoint: str | None = None) -> Servo | Board:
        """A device by profile name (a servo or a board), or a servo by its current ID on an endpoint."""
        if isinstance(name_or_id, str):
            return self.devices[name_or_id]
        return self.endpoint(endpoint).bus.servo(name_or_id)

    def board(self, name: str | None = None) -> Board:
        """An emulated board by name (or the only one)."""
        boards = {n: d for n, d in self.devices.items() if isinstance(d, Board)}
        if name is None:
            if len(boards) != 1:
                raise KeyError(f"bench has boards {list(boards)}; name one")
            return next(iter(boards.values()))
        return boards[name]

    def serve_control(self, host: str = "127.0.0.1", port: int = 0):
        """Start the control channel (button, reset, faults for other processes); listed in the manifest."""
        from hilbench.control import ControlServer

        if self.control is None:
            self.control = ControlServer(self, host, port)
        return self.control

    def now(self) -> float:
        """The bench's clock (the devices' ``t``)."""
        return time.monotonic()

    # ------------------------------------------------------------------ manifest

    def manifest(self) -> dict[str, Any]:
        """Where everything is: ``{"endpoints": [...], "devices": [...]}``."""
        eps = []
        for ep in self.endpoints.values():
            entry = {
                "name": ep.name,
                "type": ep.spec.type,
                "path": ep.path,
                "pty": ep.pty.path if ep.pty else None,
                "link": str(ep.pty.link) if ep.pty and ep.pty.link else None,
                "protocol": ep.spec.protocol,
                "baud": ep.spec.baud,
                "paced": ep.medium.paced if ep.board is None else True,
                "tap": ep.tap.url if ep.tap is not None else None,
            }
            if ep.udp is not None:
                entry["address"] = list(ep.udp.address)
            eps.append(entry)
        devs = []
        for dev in self.profile.boards:
            devs.append({
                "name": dev.name,
                "model": dev.model,
                "endpoint": dev.endpoint,
                "protocol": "vel2d",
                "preset": dev.preset,
                "caches": dev.caches,
                "output": dev.output,
                "baud": self.profile.endpoints[dev.endpoint].baud,
            })
        for dev in self.profile.servos:
            servo = self.devices.get(dev.name)
            devs.append(
                {
                    "name": dev.name,
                    "model": dev.model,
                    "model_number": servo.model.number if servo else find_model(dev.model).number,
                    "firmware": servo.firmware if servo else dev.firmware,
                    "endpoint": dev.endpoint,
                    "id": dev.id,
                    "protocol": self.profile.endpoints[dev.endpoint].protocol,
                }
            )
        out = {
            "profile": self.profile.path,
            "pid": os.getpid(),
            "endpoints": eps,
            "devices": devs,
        }
        if self.control is not None:
            out["control"] = self.control.address_text
        return out

    def write_manifest(self, path: str | Path) -> None:
        """Write the manifest atomically (readers never see half a file)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.manifest(), indent=2) + "\n")
        tmp.replace(path)


def board_config(spec: BoardSpec, baud: int) -> BoardConfig:
    """The emulator configuration of a profile's board entry."""
    preset = make_preset(spec.preset, spec.caches)
    for name, timing in spec.tasks.items():
        preset = preset.with_task_timing(name, **timing)
    return BoardConfig(preset, output=spec.output, baud=baud, dialect=spec.dialect, window_ms=spec.window_ms,
                       flush_ms=spec.flush_ms, seed=spec.seed, boot_banner=spec.boot_banner,
                       faults=dict(spec.faults))


#: How each endpoint protocol's devices are made and attached to the endpoint's line.
DEVICE_FACTORIES = {"dynamixel": Bench._start_dynamixel, "vel2d": Bench._start_board}

__all__ = ["DEVICE_FACTORIES", "Bench", "BoardSpec", "DeviceSpec", "Endpoint", "board_config"]
