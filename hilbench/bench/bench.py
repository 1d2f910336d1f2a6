"""A running bench: the endpoints and devices of a profile, wired together and started.

``Bench(profile).start()`` opens each endpoint's host port (the registered
class of its ``type``: a pseudo-terminal, a UDP or TCP socket on 127.0.0.1,
...), puts a medium of the kind its bus kind needs behind it (a serial line, a
CAN bus, ...), lets the bus kind make what the devices share (``endpoint.bus``)
and each device family present on the endpoint build its devices onto it, and
starts everything. Taps (monitor, recorder) attach to the medium the same way
for every bus. The manifest (:meth:`Bench.manifest`) tells other programs where
everything is. Nothing here knows a bus kind or device family by name: see
:mod:`hilbench.registry`, :class:`~hilbench.bench.bus.BusKind` and
:class:`~hilbench.bench.family.DeviceFamily`.
"""

from __future__ import annotations

import inspect
import os
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hilbench import registry
from hilbench.bench.bus import BusKind
from hilbench.bench.family import DeviceFamily, DeviceSpec, FamilyAccess
from hilbench.bench.profile import EndpointSpec, Profile, load_profile
from hilbench.bench.world import BenchWorld, build_world
from hilbench.errors import BenchError, UsageError
from hilbench.transports.clock import WALL, VirtualClock, WallClock
from hilbench.transports.listener import BindError
from hilbench.transports.medium import medium_timing
from hilbench.transports.tap_server import TapServer
from hilbench.transports.virtual_loop import MODES, VirtualLoop


class Endpoint:
    """A started endpoint: its spec, its host port, the medium behind it, its bus and the devices on it.

    ``port`` is the host port (what a host program opens, :attr:`path`);
    ``medium`` carries the traffic (taps attach here); ``bus_kind`` is the
    :class:`~hilbench.bench.bus.BusKind` of its protocol and ``bus`` what its
    devices share (the object that decodes a servo line once for every servo;
    None where they share only the medium); ``devices`` maps device names to
    the objects their families built, ``specs`` to their profile entries (in
    profile order); ``tap`` is its traffic tap server (or None) and
    ``services`` its network servers. Nothing else is grown on it: a family's
    own lookups are on ``bench.family(NAME)``.
    """

    def __init__(self, spec: EndpointSpec, port: Any, medium: Any, bus_kind: BusKind,
                 specs: list[DeviceSpec] | None = None) -> None:
        self.spec = spec
        self.port = port
        self.medium = medium
        self.bus_kind = bus_kind
        self.bus: Any = None
        self.specs: dict[str, DeviceSpec] = {s.name: s for s in specs or ()}
        self.devices: dict[str, Any] = {}
        self.tap: TapServer | None = None
        #: Running servers of this endpoint by server name (``--serve``), listed in its manifest entry.
        self.services: dict[str, Any] = {}

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def path(self) -> str:
        """What a host program opens: the pty (or its stable link), or the socket's URL."""
        return self.port.client_path

    @property
    def host_port(self) -> Any:
        return self.port

    def add_device(self, name: str, device: Any) -> None:
        """Put a device a family built on this endpoint's bus (:meth:`BusKind.join`) and list it under its
        profile name."""
        self.bus_kind.join(self, device, self.specs.get(name))
        self.devices[name] = device

    def families(self) -> list[str]:
        """The families of the devices on this endpoint, in profile order."""
        return list(dict.fromkeys(s.family for s in self.specs.values()))

    def devices_of(self, family: str) -> dict[str, Any]:
        """The devices of one family on this endpoint (name -> device), in profile order."""
        return {n: self.devices[n] for n, s in self.specs.items() if s.family == family and n in self.devices}

    def device(self, name: str | None = None) -> Any:
        """A device on this endpoint by profile name, or its only one; KeyError naming them."""
        if name is None:
            if len(self.devices) != 1:
                raise KeyError(f"endpoint {self.name!r} has devices {list(self.devices)}; name one")
            return next(iter(self.devices.values()))
        if name not in self.devices:
            raise KeyError(f"endpoint {self.name!r} has no device {name!r} (devices: {list(self.devices)})")
        return self.devices[name]

    def __repr__(self) -> str:
        return f"Endpoint({self.name!r}, {self.spec.protocol}, {self.path})"



def _bind_reason(exc: OSError) -> str:
    """Why a server's socket could not listen, without its own "cannot listen on" (a host name that does not
    resolve has a negative errno: its text, not "Unknown error -2")."""
    return exc.reason if isinstance(exc, BindError) else (exc.strerror or str(exc))

class Bench:
    """The devices of a profile behind real host ports.

    ``paced`` overrides every endpoint's ``paced`` setting; ``link_dir`` puts a
    stable symlink named after each pty endpoint into that directory. ``tap``
    serves each medium's traffic on 127.0.0.1 (a TCP tap server, listed as
    ``tap`` in the manifest) for monitors and recorders in other processes.
    ``serve`` names servers (:mod:`hilbench.bench.server`, e.g. ``"rfc2217"``)
    that make every endpoint they can serve reachable over the network; they,
    the taps and the control channel listen on ``bind`` (default 127.0.0.1).

    ``virtual_time`` (True, ``"hold"`` or ``"free"``) runs the bench on a
    :class:`~hilbench.transports.clock.VirtualClock`: one
    :class:`~hilbench.transports.virtual_loop.VirtualLoop` thread runs every medium and device timer, and
    time jumps from event to event (``"hold"``, the default: only when ``bench.clock.run_for(s)`` asks;
    ``"free"``: on its own). A virtual bench is paced. ``virtual_epoch`` pins the Unix time of its start
    (stamps then repeat from run to run); ``seed`` seeds what would otherwise be random (a bus's fault
    draws), so two runs of the same inputs do the same. A virtual bench also shares its clock with clients
    under ``hilbench run`` (:mod:`hilbench.bench.lockstep`; the manifest's ``clock`` entry);
    ``lockstep_stall`` is how many wall seconds a client thread that never waits holds the clock before
    time follows the wall clock (None: for ever).
    """

    def __init__(
        self,
        profile: Profile | str | Path,
        *,
        paced: bool | None = None,
        link_dir: str | Path | None = None,
        tap: bool = False,
        serve: tuple[str, ...] | list[str] = (),
        bind: str = "127.0.0.1",
        virtual_time: bool | str = False,
        virtual_epoch: float | None = None,
        seed: int = 0,
        lockstep_stall: float | None = 1.0,
    ) -> None:
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        if virtual_time and paced is False:
            raise UsageError("virtual time is paced: --unpaced and --virtual-time do not go together")
        self.paced = paced
        self.tap = tap
        self.serve = tuple(serve)
        self.bind = bind
        self.link_dir = Path(link_dir) if link_dir else None
        #: The one clock every medium, port and device of this bench reads (DESIGN §12).
        self.clock: WallClock = WALL
        #: What runs the bench in virtual time (None on the wall clock).
        self.loop: VirtualLoop | None = None
        self.seed = seed
        self.lockstep_stall = lockstep_stall
        if virtual_time:
            mode = "hold" if virtual_time is True else str(virtual_time)
            if mode not in MODES:
                raise UsageError(f"virtual time must be one of {', '.join(MODES)}, got {virtual_time!r}")
            self.paced = True
            self.clock = VirtualClock(epoch=virtual_epoch)
            self.loop = VirtualLoop(self.clock, mode=mode, name=self.profile.name)
        self.endpoints: dict[str, Endpoint] = {}
        self.devices: dict[str, Any] = {}
        self.started_at: float | None = None
        self._stopped = False
        self.control = None  # a ControlServer once serve_control() ran
        self.services: dict[str, Any] = {}  #: name -> object with close() and describe(): listed in the manifest
        self._manifest_token: str | None = None  # names this bench's manifests (see hilbench.bench.manifest)
        self._manifests: dict[Path, Any] = {}  # path -> ManifestClaim
        self._access: dict[str, FamilyAccess] = {}  # family name -> what family() returns
        self._world: BenchWorld | None = None

    # ------------------------------------------------------------------ lifecycle

    def start(self, on_endpoint: Callable[[Endpoint], Any] | None = None) -> Bench:
        """Open the endpoints and start every medium and device; returns self.

        ``on_endpoint(ep)`` is called for each endpoint once its medium exists and before anything
        runs, e.g. to tap the medium from the first byte (a monitor that must see RTPS discovery).
        """
        if self.started_at is not None:
            return self
        if self._stopped:
            raise BenchError("this bench was stopped and its ports are closed: start a new Bench")
        t = self.clock.now()
        prof = self.profile
        self._world = BenchWorld(self, build_world(prof, t, self.clock))
        try:
            for spec in prof.endpoints.values():
                bus_kind = registry.bus_kinds.get(spec.protocol)
                try:
                    port = registry.host_ports.get(spec.type).open(spec.name, spec.port_options,
                                                                   link_dir=self.link_dir)
                except BindError as exc:  # a UDP/TCP port's own keys, unless the port named another
                    raise self._bind_error(exc, spec.name, exc.key or ("port" if exc.port_taken else "bind")) \
                        from None
                paced = spec.paced if self.paced is None else self.paced
                try:
                    medium = self._medium(bus_kind, spec, paced)
                except Exception:
                    port.close()
                    raise
                medium.protocol = spec.protocol
                specs = prof.devices_on(spec.name)
                ep = Endpoint(spec, port, medium, bus_kind, specs)
                self.endpoints[spec.name] = ep
                try:
                    ep.bus = bus_kind.open(self, ep)
                    for family in ep.families():  # each family builds its own devices, in profile order
                        registry.families.get(family).build(self, ep, [s for s in specs if s.family == family], t)
                except BindError as exc:
                    raise self._bind_error(exc, spec.name, exc.key) from None
                self.devices.update(ep.devices)
                medium.add_host(port)
                if self.tap:
                    # the medium's protocol: what its traffic is, as the bus kind may have refined it
                    # (a Protocol 1.0 Dynamixel bus carries "dynamixel1")
                    try:
                        ep.tap = TapServer(host=self.bind, baud=spec.baud, protocol=medium.protocol or spec.protocol,
                                           description=f"bench {prof.name}, endpoint {spec.name}",
                                           clock=self.clock)
                    except OSError as exc:  # (on a free port: only the bind address can be wrong)
                        reason = _bind_reason(exc)
                        raise self._bind_error(BindError((self.bind, 0), reason, exc.errno, "traffic tap (TCP port)"),
                                               spec.name, None) from None
                    medium.add_tap(ep.tap.feed)
            self._start_servers()
            if on_endpoint is not None:
                for ep in self.endpoints.values():
                    on_endpoint(ep)
            for ep in self.endpoints.values():
                if self.loop is not None:
                    self.loop.add(ep.medium)
                else:
                    ep.medium.start()
            if self.loop is not None:
                self._start_lockstep()
                self.loop.start()
            for ep in self.endpoints.values():
                ep.bus_kind.start(ep, t)
                for family in ep.families():
                    registry.families.get(family).start(ep, ep.devices_of(family), t)
            if self._world.world.bodies:  # (a world without bodies has nothing to step: movers are functions of time)
                self._world.world.start()
        except Exception:
            self.stop()
            raise
        self.started_at = t
        return self

    def _start_lockstep(self) -> None:
        """The clock page clients under ``hilbench run`` share (listed in the manifest as ``clock``)."""
        from hilbench.bench.lockstep import Lockstep

        assert self.loop is not None and isinstance(self.clock, VirtualClock)
        ptys = [(ep.name, ep.port) for ep in self.endpoints.values()
                if getattr(ep.port, "rdev", None) is not None and hasattr(ep.port, "bytes_in")]
        clock = self.clock
        self.loop.lockstep = self.services["clock"] = Lockstep(
            ptys, vnow_ns=round(clock.now() * 1e9), origin_ns=round(clock.origin * 1e9),
            epoch_ns=round(clock.epoch * 1e9), stall=self.lockstep_stall, holding=self._holding,
            refuses=self._refuses, channels=clock.channels)
        for medium in self.loop.media:
            if hasattr(medium, "vt_defer_input"):  # (serial lines: clients' writes are sent when they all wait)
                medium.vt_defer_input()

    def _refuses(self, port: Any) -> bool:
        """Whether a medium leaves ``port``'s bytes unread on purpose (a serial line holding its writer back)."""
        assert self.loop is not None
        return any(medium.vt_refuses(port) for medium in self.loop.media if hasattr(medium, "vt_refuses"))

    def _holding(self) -> bool:
        """Whether a service has a lockstep client's request in hand (the port-state server's modem-port-state requests)."""
        return any(service.holding() for service in list(self.services.values()) if hasattr(service, "holding"))

    def _medium(self, bus_kind: BusKind, spec: EndpointSpec, paced: bool) -> Any:
        """The medium of an endpoint, on the bench's clock (a medium class without ``clock=`` gets the wall
        clock, its default)."""
        cls = registry.media.get(bus_kind.medium)
        kwargs: dict[str, Any] = {"paced": bus_kind.paced(spec, paced)}
        if self.clock is not WALL:
            kwargs["clock"] = self.clock
        if self.loop is not None and "seed" in inspect.signature(cls).parameters:
            kwargs["seed"] = self.seeded(f"medium:{spec.name}")
        return cls(spec.name, spec.baud, **kwargs)

    def seeded(self, name: str) -> int:
        """A seed for one part of the bench, derived from the bench's ``seed`` and the part's name (the same
        in every run, different for every part)."""
        return random.Random(f"{self.seed}:{name}").getrandbits(32)

    def _bind_error(self, exc: BindError, endpoint: str | None, key: str | None) -> BindError:
        """``exc`` in one line that names the profile, the endpoint, the address and the key to change."""
        host, port = exc.address
        where = f"{self.profile.path}: endpoint {endpoint!r}: " if endpoint else f"{self.profile.path}: "
        text = f"{where}cannot listen on {exc.what} {host}:{port}: {exc.reason}"
        if exc.port_taken:
            text += " (another bench or program has it)"
        if endpoint and key:
            example = "0 (any free port)" if key.endswith("port") else "VALUE"
            text += f"; change endpoints.{endpoint}.{key} in the profile, or --set {endpoint}.{key}={example}"
        elif not exc.port_taken:
            text += f"; {host} is the bench's bind address (--bind): give one of this machine's addresses"
        exc.key = key
        return exc.with_message(text)

    def _start_servers(self) -> None:
        for name in self.serve:
            server = registry.servers.get(name)
            served = [ep for ep in self.endpoints.values() if server.serves(ep)]
            if not served:
                raise UsageError(f"bench {self.profile.name!r} has no endpoint {name} can serve "
                                 f"({server.help or name})")
            for ep in served:
                try:
                    ep.services[name] = server.start(self, ep, self.bind)
                except BindError as exc:  # (servers listen on a free port of the bench's --bind address)
                    exc.what = f"{name} server (TCP port)"
                    raise self._bind_error(exc, ep.name, None) from None

    def stop(self) -> None:
        """Stop every device, medium and service; close every endpoint (once: stopping again does nothing)."""
        if self._stopped:
            return
        self._stopped = True
        if self.loop is not None:
            self.loop.close()  # (first: nothing runs while the rest is taken apart)
        if self.control is not None:
            self.control.close()
            self.control = None
        for service in self.services.values():
            service.close()
        self.services.clear()
        if self._world is not None:
            self._world.world.stop()
            self._world.close()  # (its records end complete at their names)
        for ep in self.endpoints.values():
            for family in ep.families():
                registry.families.get(family).stop(ep, ep.devices_of(family))
            ep.bus_kind.stop(ep)
            ep.medium.close()
            for service in ep.services.values():  # after the medium: its thread waits on their sockets
                service.close()
            ep.services.clear()
            ep.port.close()
            if ep.tap is not None:
                ep.tap.close()
        self.started_at = None

    def __enter__(self) -> Bench:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ access

    def endpoint(self, name: str | None = None) -> Endpoint:
        """An endpoint by name (or the only one)."""
        if name is None:
            if len(self.endpoints) != 1:
                raise KeyError(f"bench has endpoints {list(self.endpoints)}; name one")
            return next(iter(self.endpoints.values()))
        return self.endpoints[name]

    def device(self, name_or_address: str | int, endpoint: str | None = None) -> Any:
        """A device by profile name, or by its address on an endpoint (a servo's current ID, a node id)."""
        if isinstance(name_or_address, str):
            return self.devices[name_or_address]
        ep = self.endpoint(endpoint)
        return ep.bus_kind.device_at(ep, name_or_address)

    @property
    def world(self) -> BenchWorld:
        """The bench's world (the truth: bodies, their poses, recorders); see :mod:`hilbench.bench.world`.
        BenchError before the bench started."""
        if self._world is None:
            raise BenchError(f"bench {self.profile.name!r} has not started: its world does not exist yet")
        return self._world

    def family(self, name: str) -> FamilyAccess:
        """A family's devices on this bench with its typed lookups: ``bench.family("stm32-rover").board()``,
        ``bench.family("canopen").node(2)`` (its :attr:`DeviceFamily.access`). UsageError when the bench has no
        device of that family."""
        access = self._access.get(name)
        if access is None:
            family = registry.families.get(name)  # (UsageError naming the known ones)
            present = list(dict.fromkeys(s.family for s in self.profile.devices))
            if name not in present:
                raise UsageError(f"bench {self.profile.name!r} has no device of family {name!r} "
                                 f"(families: {', '.join(present) or 'none'})")
            access = self._access[name] = family.access(self, family)
        return access

    def family_of(self, device_name: str) -> DeviceFamily:
        """The family that built a device."""
        for ep in self.endpoints.values():
            spec = ep.specs.get(device_name)
            if spec is not None and device_name in ep.devices:
                return registry.families.get(spec.family)
        raise KeyError(device_name)

    def serve_control(self, host: str | None = None, port: int = 0):
        """Start the control channel (family commands for other processes) on ``host`` (default: the
        bench's ``bind``); listed in the manifest."""
        from hilbench.bench.control import ControlServer

        if self.control is None:
            try:
                self.control = ControlServer(self, host or self.bind, port)
            except OSError as exc:
                reason = _bind_reason(exc)
                raise self._bind_error(BindError((host or self.bind, port), reason, exc.errno,
                                                 "control channel (TCP port)"), None, None) from None
        return self.control

    @property
    def has_control_commands(self) -> bool:
        """Whether any device or bus on this bench answers control commands (``emulate`` then serves the
        channel)."""
        return any(ep.bus_kind.control_commands or any(self.family_of(n).control_commands for n in ep.devices)
                   for ep in self.endpoints.values())

    def now(self) -> float:
        """The bench's clock (the devices' ``t``)."""
        return self.clock.now()

    # ------------------------------------------------------------------ manifest

    def manifest(self) -> dict[str, Any]:
        """Where everything is: ``{"endpoints": [...], "devices": [...]}``."""
        eps = []
        for ep in self.endpoints.values():
            entry = {
                "name": ep.name,
                "type": ep.spec.type,
                **ep.port.describe(),
                "protocol": ep.spec.protocol,
                "baud": ep.spec.baud,
                "paced": ep.medium.paced,
                **medium_timing(ep.medium),  # scheduling, cpu_latency
                "tap": ep.tap.url if ep.tap is not None else None,
            }
            if ep.tap is not None:
                entry["tap_limits"] = ep.tap.limits()
            entry.update(ep.bus_kind.describe_endpoint(ep))
            for service in ep.services.values():
                entry.update(service.describe())
            eps.append(entry)
        devs = []
        for spec in self.profile.devices:
            ep = self.endpoints.get(spec.endpoint)
            family = registry.families.get(spec.family)
            entry = family.describe_device(spec, self.devices.get(spec.name), ep, self.profile)
            if spec.body is not None:
                entry["body"] = spec.body
            if spec.mount is not None:
                entry["pose"] = dict(zip(("x", "y", "theta"), spec.mount, strict=True))
            devs.append({**entry, "family": spec.family})
        out: dict[str, Any] = {
            "name": self.profile.name,
            "profile": self.profile.path,
            "pid": os.getpid(),
            "endpoints": eps,
            "devices": devs,
        }
        if self.profile.overrides:  # --set: the profile file alone is not this bench
            out["set"] = dict(self.profile.overrides)
        if self.control is not None:
            out["control"] = self.control.address_text
            out["control_limits"] = self.control.limits()
        for name, service in self.services.items():
            out[name] = service.describe()
        return out

    def write_manifest(self, path: str | Path):
        """Write the manifest atomically to ``path``; returns the :class:`~hilbench.bench.manifest.ManifestClaim`.

        Never replaces a file hilbench did not write, nor a running bench's manifest (one-line
        :class:`~hilbench.errors.HilbenchError`); takes over a stale one (``claim.took_over`` is its pid);
        rewrites this bench's own.
        """
        from hilbench.bench.manifest import new_token, write_manifest

        if self._manifest_token is None:
            self._manifest_token = new_token()
        claim = write_manifest(path, self.manifest(), token=self._manifest_token)
        self._manifests[Path(path)] = claim
        return claim

    def check_manifest_path(self, path: str | Path) -> int | None:
        """Raise if the manifest could not be written to ``path`` (before starting); the pid of a stale one."""
        from hilbench.bench.manifest import check_path

        return check_path(path, self._manifest_token)

    def remove_manifest(self, path: str | Path | None = None) -> None:
        """Remove the manifest(s) this bench wrote, each only while it is still this bench's."""
        from hilbench.bench.manifest import remove_manifest

        for p in [Path(path)] if path is not None else list(self._manifests):
            remove_manifest(self._manifests.pop(p, None))


__all__ = ["Bench", "Endpoint"]
