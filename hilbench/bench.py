"""A running bench: the endpoints and devices of a profile, wired together and started.

``Bench(profile).start()`` opens one pseudo-terminal per endpoint, puts the
profile's devices on a serial line behind it, and starts the line. The
manifest (:meth:`Bench.manifest`) tells other programs where everything is.
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
from hilbench.fakes.dynamixel.models import BAUD_TO_CODE, find_model
from hilbench.fakes.dynamixel.servo import Servo
from hilbench.profile import EndpointSpec, Profile, load_profile
from hilbench.transports.pty import PtyEndpoint
from hilbench.transports.serial_medium import SerialMedium
from hilbench.transports.tap_server import TapServer


@dataclass
class Endpoint:
    """A started endpoint: its spec, its pty and the line behind it."""

    spec: EndpointSpec
    pty: PtyEndpoint
    medium: SerialMedium
    bus: DynamixelBus
    tap: TapServer | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def path(self) -> str:
        """What a host program opens (the stable link if the profile gave one)."""
        return self.pty.client_path


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
        self.devices: dict[str, Servo] = {}
        self.started_at: float | None = None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Bench:
        """Open the endpoints and start every line; returns self."""
        if self.started_at is not None:
            return self
        t = time.monotonic()
        prof = self.profile
        try:
            for spec in prof.endpoints.values():
                link = spec.link
                if self.link_dir is not None:
                    link = str(self.link_dir / spec.name)
                pty = PtyEndpoint(spec.name, link=os.path.expanduser(link) if link else None)
                paced = spec.paced if self.paced is None else self.paced
                medium = SerialMedium(spec.name, spec.baud, paced=paced)
                servos = []
                fast_read = {}
                for dev in prof.devices:
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
                bus.attach(medium)
                medium.add_host(pty)
                server = None
                if self.tap:
                    server = TapServer(baud=spec.baud, protocol=spec.protocol,
                                       description=f"bench {prof.name}, endpoint {spec.name}")
                    medium.add_tap(server.feed)
                self.endpoints[spec.name] = Endpoint(spec, pty, medium, bus, server)
            for ep in self.endpoints.values():
                ep.medium.start()
        except Exception:
            self.stop()
            raise
        self.started_at = t
        return self

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
        """Stop every line and close every endpoint."""
        for ep in self.endpoints.values():
            ep.medium.close()
            ep.pty.close()
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

    def device(self, name_or_id: str | int, endpoint: str | None = None) -> Servo:
        """A device by profile name, or by its current ID on an endpoint."""
        if isinstance(name_or_id, str):
            return self.devices[name_or_id]
        return self.endpoint(endpoint).bus.servo(name_or_id)

    def now(self) -> float:
        """The bench's clock (the devices' ``t``)."""
        return time.monotonic()

    # ------------------------------------------------------------------ manifest

    def manifest(self) -> dict[str, Any]:
        """Where everything is: ``{"endpoints": [...], "devices": [...]}``."""
        eps = []
        for ep in self.endpoints.values():
            eps.append(
                {
                    "name": ep.name,
                    "type": ep.spec.type,
                    "path": ep.path,
                    "pty": ep.pty.path,
                    "link": str(ep.pty.link) if ep.pty.link else None,
                    "protocol": ep.spec.protocol,
                    "baud": ep.spec.baud,
                    "paced": ep.medium.paced,
                    "tap": ep.tap.url if ep.tap is not None else None,
                }
            )
        devs = []
        for dev in self.profile.devices:
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
        return {
            "profile": self.profile.path,
            "pid": os.getpid(),
            "endpoints": eps,
            "devices": devs,
        }

    def write_manifest(self, path: str | Path) -> None:
        """Write the manifest atomically (readers never see half a file)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.manifest(), indent=2) + "\n")
        tmp.replace(path)
