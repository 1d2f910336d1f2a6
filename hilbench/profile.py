"""Bench profiles: TOML files describing endpoints (what a host opens) and devices (what answers).

A profile is read with tomllib and checked completely before anything starts;
every mistake becomes one :class:`ProfileError` line naming the file, the key
and what was expected. Example::

    schema = 1
    description = "a small arm"

    [endpoints.arm]
    type = "pty"                 # the port a host program opens
    protocol = "dynamixel"
    baud = 1_000_000
    paced = false                # true: model wire time and Return Delay Time

    [[devices]]
    model = "XM430-W350"
    ids = [1, 2, 3]              # or id = 1 for one device
    endpoint = "arm"

An endpoint's ``protocol`` decides what its devices are: ``dynamixel``
endpoints carry servos (:class:`DeviceSpec`), ``vel2d`` endpoints carry one
emulated STM32 rover board (:class:`BoardSpec`, see ``profiles/mecarover.toml``),
on a pty or on UDP (``type = "udp"``, bound to 127.0.0.1 by default).
"""

from __future__ import annotations

import importlib.resources
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilbench.fakes.dynamixel.bus import CHAIN_POLICIES, FAST_MISSING_POLICIES
from hilbench.protocols.dynamixel_models import BAUD_CODES, find_model, model_names
from hilbench.transports.udp import parse_address

SCHEMA = 1
DEFAULT_PROFILE = "wolfgang"
ENDPOINT_TYPES = ("pty", "udp")
PROTOCOLS = ("dynamixel", "vel2d")
#: Line rates a board endpoint accepts (bit/s); a pty does not care, the board paces its UART by it.
BOARD_BAUD_RANGE = (1200, 12_500_000)
BOARD_MODELS = ("stm32f767-rover", "mecarover", "stm32-rover")
BOARD_KEYS = ("model", "name", "endpoint", "preset", "caches", "output", "dialect", "window_ms", "flush_ms", "seed",
              "boot_banner", "faults", "tasks")
BOARD_FAULT_KEYS = ("drop_rate", "corrupt_rate", "drop_next", "corrupt_next")
TIMING_KEYS = ("mean_us", "sd_us", "min_us", "max_us", "dist")
#: Rates the official SDK can open (spec §7.1) that are also Dynamixel baud codes.
DYNAMIXEL_BAUDS = tuple(sorted(set(BAUD_CODES.values()) - {4_500_000}))
FAULT_KEYS = ("drop_rate", "drop_next", "corrupt_rate", "corrupt_next", "delay", "vanished", "hardware_error",
              "seed")
DEVICE_KEYS = ("model", "id", "ids", "name", "endpoint", "firmware", "init", "faults", "position",
               "supply_voltage", "ambient_temperature", "fast_read")


class ProfileError(ValueError):
    """A profile that cannot be used; ``str()`` is one line: ``file: key: problem``."""


@dataclass
class EndpointSpec:
    """One endpoint of a profile."""

    name: str
    type: str
    protocol: str
    baud: int
    paced: bool = False
    link: str | None = None
    chain_policy: str = "continue"
    fast_missing: str = "truncate"
    strict_stuffing: bool = False
    bind: str = "127.0.0.1"  # udp: local address
    port: int = 0  # udp: local port (0: any free port, see the manifest)
    peer: str | None = None  # udp: "host:port" that always receives the output stream


@dataclass
class BoardSpec:
    """An emulated STM32 rover board on a ``vel2d`` endpoint."""

    name: str
    endpoint: str
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


@dataclass
class DeviceSpec:
    """One device of a profile (``ids = [...]`` entries are expanded to one spec per ID)."""

    name: str
    model: str
    id: int
    endpoint: str
    firmware: int | None = None
    init: dict[str, int | float] = field(default_factory=dict)
    faults: dict[str, Any] = field(default_factory=dict)
    position: float | None = None
    supply_voltage: float | None = None
    ambient_temperature: float | None = None
    fast_read: bool | None = None


@dataclass
class Profile:
    """A checked profile."""

    path: str
    name: str
    description: str
    endpoints: dict[str, EndpointSpec]
    devices: list[DeviceSpec | BoardSpec]
    supply_voltage: float = 12.0
    ambient_temperature: float = 30.0

    @property
    def servos(self) -> list[DeviceSpec]:
        """The Dynamixel devices."""
        return [d for d in self.devices if isinstance(d, DeviceSpec)]

    @property
    def boards(self) -> list[BoardSpec]:
        """The emulated boards."""
        return [d for d in self.devices if isinstance(d, BoardSpec)]


def bundled_profiles() -> dict[str, Path]:
    """Profiles shipped with hilbench (the repository's ``profiles/``), by name."""
    root = importlib.resources.files("hilbench.profiles")
    return {Path(p.name).stem: Path(str(p)) for p in root.iterdir() if p.name.endswith(".toml")}


def resolve(name_or_path: str | Path) -> Path:
    """A profile path from a file path or the name of a bundled profile."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise ProfileError(f"{p}: no such profile file")
        return p
    bundled = bundled_profiles()
    if str(name_or_path) in bundled:
        return bundled[str(name_or_path)]
    raise ProfileError(f"{name_or_path}: no such profile (bundled: {', '.join(sorted(bundled))})")


def load_profile(name_or_path: str | Path = DEFAULT_PROFILE) -> Profile:
    """Read and check a profile; raises :class:`ProfileError` with one line on any mistake."""
    path = resolve(name_or_path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ProfileError(f"{path}: cannot read: {exc.strerror}") from None
    return parse_profile(data, str(path))


def parse_profile(data: dict[str, Any], path: str = "<profile>") -> Profile:
    """Check a profile already read into a dict."""
    c = _Checker(path)
    schema = data.get("schema")
    if schema != SCHEMA:
        c.fail("schema", f"expected {SCHEMA}, got {schema!r}")
    c.unknown(data, "", ("schema", "description", "endpoints", "devices", "defaults"))
    defaults = c.table(data.get("defaults", {}), "defaults")
    c.unknown(defaults, "defaults", ("supply_voltage", "ambient_temperature"))
    supply = c.number(defaults.get("supply_voltage", 12.0), "defaults.supply_voltage", 0, 50)
    ambient = c.number(defaults.get("ambient_temperature", 30.0), "defaults.ambient_temperature", -40, 100)
    endpoints = {}
    raw_eps = c.table(data.get("endpoints"), "endpoints")
    if not raw_eps:
        c.fail("endpoints", "expected at least one [endpoints.NAME] table")
    for name, ep in raw_eps.items():
        endpoints[name] = _endpoint(c, name, ep)
    devices = []
    raw_devs = data.get("devices", [])
    if not isinstance(raw_devs, list):
        c.fail("devices", "expected an array of tables ([[devices]])")
    taken: dict[tuple[str, int], str] = {}
    names: set[str] = set()
    for i, dev in enumerate(raw_devs):
        where = f"devices[{i}]"
        dev = c.table(dev, where)
        ep_name = dev.get("endpoint")
        if ep_name is None and len(endpoints) == 1:
            ep_name = next(iter(endpoints))
        if ep_name in endpoints and endpoints[ep_name].protocol == "vel2d":
            board = _board(c, where, dev, endpoints)
            if any(isinstance(d, BoardSpec) and d.endpoint == board.endpoint for d in devices):
                c.fail(f"{where}.endpoint", f"endpoint {board.endpoint!r} already has a board (a UART is "
                                            "point to point)")
            if board.name in names:
                c.fail(f"{where}.name", f"device name {board.name!r} is used twice")
            names.add(board.name)
            devices.append(board)
            continue
        for spec in _devices(c, where, dev, endpoints):
            where = f"devices[{i}]"
            owner = taken.get((spec.endpoint, spec.id))
            if owner is not None:
                c.fail(f"{where}.id", f"ID {spec.id} is already used on endpoint {spec.endpoint!r} by {owner}")
            taken[(spec.endpoint, spec.id)] = where
            if spec.name in names:
                c.fail(f"{where}.name", f"device name {spec.name!r} is used twice")
            names.add(spec.name)
            devices.append(spec)
    return Profile(
        path=path,
        name=Path(path).stem,
        description=str(data.get("description", "")),
        endpoints=endpoints,
        devices=devices,
        supply_voltage=supply,
        ambient_temperature=ambient,
    )


class _Checker:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> None:
        raise ProfileError(f"{self.path}: {key}: {message}")

    def table(self, value: Any, key: str) -> dict[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(key, f"expected a table, got {type(value).__name__}")
        return value

    def unknown(self, table: dict[str, Any], prefix: str, allowed: tuple[str, ...]) -> None:
        for key in table:
            if key not in allowed:
                where = f"{prefix}.{key}" if prefix else key
                self.fail(where, f"unknown key (expected one of: {', '.join(allowed)})")

    def integer(self, value: Any, key: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer {lo}..{hi}, got {value!r}")
        if not lo <= value <= hi:
            self.fail(key, f"expected an integer {lo}..{hi}, got {value}")
        return value

    def number(self, value: Any, key: str, lo: float, hi: float) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, f"expected a number {lo}..{hi}, got {value!r}")
        if not lo <= value <= hi:
            self.fail(key, f"expected a number {lo}..{hi}, got {value}")
        return float(value)

    def boolean(self, value: Any, key: str) -> bool:
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {value!r}")
        return value

    def choice(self, value: Any, key: str, choices: tuple[str, ...]) -> str:
        if value not in choices:
            self.fail(key, f"expected one of {', '.join(map(str, choices))}, got {value!r}")
        return value


def _endpoint(c: _Checker, name: str, ep: Any) -> EndpointSpec:
    key = f"endpoints.{name}"
    ep = c.table(ep, key)
    c.unknown(ep, key, ("type", "protocol", "baud", "paced", "link", "chain_policy", "fast_missing",
                        "strict_stuffing", "bind", "port", "peer"))
    kind = c.choice(ep.get("type", "pty"), f"{key}.type", ENDPOINT_TYPES)
    protocol = c.choice(ep.get("protocol", "dynamixel"), f"{key}.protocol", PROTOCOLS)
    if protocol == "dynamixel":
        baud = ep.get("baud", 57_600)
        if baud not in DYNAMIXEL_BAUDS:
            c.fail(f"{key}.baud", f"expected a Dynamixel baud rate the SDK can open ({', '.join(map(str, DYNAMIXEL_BAUDS))}), got {baud!r}")
        if kind != "pty":
            c.fail(f"{key}.type", "expected \"pty\" (Dynamixel buses are serial lines)")
    else:
        baud = c.integer(ep.get("baud", 115_200), f"{key}.baud", *BOARD_BAUD_RANGE)
    link = ep.get("link")
    if link is not None and (not isinstance(link, str) or kind != "pty"):
        c.fail(f"{key}.link", f"expected a path string on a pty endpoint, got {link!r}")
    if kind != "udp":
        for udp_key in ("bind", "port", "peer"):
            if udp_key in ep:
                c.fail(f"{key}.{udp_key}", "only for type = \"udp\" endpoints")
    bind = ep.get("bind", "127.0.0.1")
    if not isinstance(bind, str) or not bind:
        c.fail(f"{key}.bind", f"expected an IP address string, got {bind!r}")
    port = c.integer(ep.get("port", 0), f"{key}.port", 0, 65535)
    peer = ep.get("peer")
    if peer is not None:
        try:
            if not isinstance(peer, str):
                raise ValueError
            parse_address(peer)  # what the endpoint will parse: the rules live in one place
        except ValueError:
            c.fail(f"{key}.peer", f"expected \"host:port\", got {peer!r}")
    return EndpointSpec(
        name=name,
        type=kind,
        protocol=protocol,
        baud=baud,
        paced=c.boolean(ep.get("paced", False), f"{key}.paced"),
        link=link,
        chain_policy=c.choice(ep.get("chain_policy", "continue"), f"{key}.chain_policy", CHAIN_POLICIES),
        fast_missing=c.choice(ep.get("fast_missing", "truncate"), f"{key}.fast_missing", FAST_MISSING_POLICIES),
        strict_stuffing=c.boolean(ep.get("strict_stuffing", False), f"{key}.strict_stuffing"),
        bind=bind,
        port=port,
        peer=peer,
    )


def _board(c: _Checker, key: str, dev: dict[str, Any], endpoints: dict[str, EndpointSpec]) -> BoardSpec:
    from hilbench.fakes.stm32_board.presets import OUTPUTS, make_preset, preset_names

    c.unknown(dev, key, BOARD_KEYS)
    model = dev.get("model", BOARD_MODELS[0])
    c.choice(model, f"{key}.model", BOARD_MODELS)
    endpoint = dev.get("endpoint")
    if endpoint is None and len(endpoints) == 1:
        endpoint = next(iter(endpoints))
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
    name = dev.get("name", endpoint)
    if not isinstance(name, str) or not name:
        c.fail(f"{key}.name", f"expected a string, got {name!r}")
    faults = c.table(dev.get("faults", {}), f"{key}.faults")
    c.unknown(faults, f"{key}.faults", BOARD_FAULT_KEYS)
    for fk in ("drop_rate", "corrupt_rate"):
        if fk in faults:
            c.number(faults[fk], f"{key}.faults.{fk}", 0.0, 1.0)
    for fk in ("drop_next", "corrupt_next"):
        if fk in faults:
            c.integer(faults[fk], f"{key}.faults.{fk}", 0, 2**31)
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
    return BoardSpec(
        name=name,
        endpoint=endpoint,
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
    )


def _devices(c: _Checker, key: str, dev: Any, endpoints: dict[str, EndpointSpec]) -> list[DeviceSpec]:
    dev = c.table(dev, key)
    if dev.get("model") in BOARD_MODELS:
        c.fail(f"{key}.endpoint", f"a {dev['model']} board needs an endpoint with protocol = \"vel2d\"")
    c.unknown(dev, key, DEVICE_KEYS)
    if "model" not in dev:
        c.fail(f"{key}.model", "missing (expected a model name such as 'XM430-W350')")
    try:
        model = find_model(dev["model"])
    except (KeyError, TypeError):
        c.fail(f"{key}.model", f"unknown model {dev['model']!r} (expected one of: {', '.join(model_names())})")
    endpoint = dev.get("endpoint")
    if endpoint is None and len(endpoints) == 1:
        endpoint = next(iter(endpoints))
    if endpoint not in endpoints:
        c.fail(f"{key}.endpoint", f"expected one of the endpoints ({', '.join(endpoints)}), got {endpoint!r}")
    if ("id" in dev) == ("ids" in dev):
        c.fail(f"{key}.id", "expected exactly one of id = N or ids = [N, ...]")
    ids = [dev["id"]] if "id" in dev else dev["ids"]
    if not isinstance(ids, list) or not ids:
        c.fail(f"{key}.ids", f"expected a non-empty array of IDs, got {ids!r}")
    ids = [c.integer(i, f"{key}.id", 0, 252) for i in ids]
    init = c.table(dev.get("init", {}), f"{key}.init")
    for field_key, value in init.items():
        try:
            f = model.field_named(field_key)
        except KeyError:
            c.fail(f"{key}.init.{field_key}", f"{model.name} has no such control-table item")
        if not isinstance(value, int | float) or isinstance(value, bool) or not f.in_range(value):
            rng = f"one of {f.allowed}" if f.allowed else f"{f.min}..{f.max}"
            c.fail(f"{key}.init.{field_key}", f"expected {rng}, got {value!r}")
    faults = c.table(dev.get("faults", {}), f"{key}.faults")
    c.unknown(faults, f"{key}.faults", FAULT_KEYS)
    for fk in ("drop_rate", "corrupt_rate"):
        if fk in faults:
            c.number(faults[fk], f"{key}.faults.{fk}", 0.0, 1.0)
    for fk in ("drop_next", "corrupt_next", "seed"):
        if fk in faults:
            c.integer(faults[fk], f"{key}.faults.{fk}", 0, 2**31)
    if "delay" in faults:
        c.number(faults["delay"], f"{key}.faults.delay", 0.0, 10.0)
    if "vanished" in faults:
        c.boolean(faults["vanished"], f"{key}.faults.vanished")
    if "hardware_error" in faults:
        c.integer(faults["hardware_error"], f"{key}.faults.hardware_error", 0, 0x3D)
    name = dev.get("name")
    if name is not None and (not isinstance(name, str) or len(ids) > 1):
        c.fail(f"{key}.name", "expected a string, and only with a single id")
    firmware = c.integer(dev["firmware"], f"{key}.firmware", 0, 255) if "firmware" in dev else None
    position = c.number(dev["position"], f"{key}.position", -1_048_575, 1_048_575) if "position" in dev else None
    supply = c.number(dev["supply_voltage"], f"{key}.supply_voltage", 0, 50) if "supply_voltage" in dev else None
    ambient = (c.number(dev["ambient_temperature"], f"{key}.ambient_temperature", -40, 100)
               if "ambient_temperature" in dev else None)
    fast = c.boolean(dev["fast_read"], f"{key}.fast_read") if "fast_read" in dev else None
    return [
        DeviceSpec(
            name=name or f"{endpoint}.{i}",
            model=model.name,
            id=i,
            endpoint=endpoint,
            firmware=firmware,
            init=dict(init),
            faults=dict(faults),
            position=position,
            supply_voltage=supply,
            ambient_temperature=ambient,
            fast_read=fast,
        )
        for i in ids
    ]
