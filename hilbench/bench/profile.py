"""Bench profiles: TOML files describing endpoints (what a host opens) and devices (what answers).

A profile is read with tomllib and checked completely before anything starts;
every mistake becomes one :class:`ProfileError` line naming the file, the key
and what was expected. Example::

    schema = 1
    description = "a small arm"

    [endpoints.arm]
    type = "pty"                 # the port a host program opens (a registered host port type)
    protocol = "dynamixel"       # the bus behind it (a registered bus kind)
    baud = 1_000_000
    paced = false

    [[devices]]
    model = "XM430-W350"
    ids = [1, 2, 3]
    endpoint = "arm"

This module knows the frame only: ``schema``, ``description``,
``[endpoints.NAME]`` with ``type``, ``protocol``, ``baud`` and ``paced``, and
``[[devices]]`` with ``endpoint`` and ``model``. Everything else belongs to a
plug-in found in :mod:`hilbench.registry`: the host port of the endpoint's
``type`` checks its keys (a pty's ``link``, a UDP port's
``bind``/``port``/``peer``); the bus kind of its ``protocol`` checks the line
rate and its own endpoint keys, and across the devices on the endpoint how
many there are and that no address is taken twice; the device family of each
entry's ``model`` checks that entry's keys (so one endpoint may carry devices
of several families), and the ``[defaults]`` keys and top-level tables it
declares. An endpoint without ``protocol`` gets the one bus protocol the
families of its devices' models join; a device entry without ``model`` is of
the only family joining its endpoint's protocol.

Overrides (``hilbench emulate PROFILE --set dxl.baud=1000000``, the pytest
fixtures' ``set={...}``) change the TOML data before it is checked, so they
are checked exactly as the file is (:func:`apply_overrides`).
"""

from __future__ import annotations

import copy
import importlib.resources
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from hilbench import registry
from hilbench.bench.checks import Checker, ProfileError
from hilbench.bench.family import DeviceFamily, DeviceSpec
from hilbench.profiles import DEFAULT_PROFILE

SCHEMA = 1
#: Keys of ``[endpoints.NAME]`` the core reads itself.
CORE_ENDPOINT_KEYS = ("type", "protocol", "baud", "paced")
#: Top-level keys the core reads itself.
CORE_KEYS = ("schema", "description", "endpoints", "devices", "defaults", "world")
#: Keys of a ``[[devices]]`` entry the core reads itself, whatever the family.
CORE_DEVICE_KEYS = ("body",)

S = TypeVar("S", bound=DeviceSpec)


@dataclass
class EndpointSpec:
    """One endpoint of a profile: the core keys, the host port's options (``port_options["link"]``) and the
    bus kind's options (``options["chain_policy"]``), each as the plug-in that checked them made them."""

    name: str
    type: str
    protocol: str
    baud: int | None
    paced: bool = False
    port_options: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)


@dataclass
class Profile:
    """A checked profile: endpoints, device specs (of any family), ``[defaults]`` and family tables."""

    path: str
    name: str
    description: str
    endpoints: dict[str, EndpointSpec]
    devices: list[DeviceSpec]
    defaults: dict[str, Any] = field(default_factory=dict)
    tables: dict[str, Any] = field(default_factory=dict)
    #: The checked ``[world]`` table (:class:`~hilbench.bench.world.WorldSpec`; None: the profile has none).
    world: Any = None
    #: The overrides applied to the file (``{"dxl.baud": 1000000}``; :func:`apply_overrides`), listed in the
    #: bench's manifest (``"set"``) so a reader of the profile file can apply them too.
    overrides: dict[str, Any] = field(default_factory=dict)

    def devices_on(self, endpoint: str) -> list[DeviceSpec]:
        """The device specs of one endpoint, in profile order."""
        return [d for d in self.devices if d.endpoint == endpoint]

    def devices_of(self, family: str, kind: type[S] = DeviceSpec) -> list[S]:  # type: ignore[assignment]
        """The device specs of one family, in profile order (``kind``: the family's spec class, for typing:
        ``profile.devices_of("stm32-rover", BoardSpec)``)."""
        return [d for d in self.devices if d.family == family and isinstance(d, kind)]


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


#: What overrides take: ``["dxl.baud=1000000", ...]`` (command-line text, values read as TOML) or
#: ``{"dxl.baud": 1000000}`` (values as they are).
Overrides = Iterable[str] | Mapping[str, Any]


def load_profile(name_or_path: str | Path | Profile = DEFAULT_PROFILE, overrides: Overrides | None = None) -> Profile:
    """Read and check a profile; raises :class:`ProfileError` with one line on any mistake.

    ``overrides`` change keys before the check (:func:`apply_overrides`); a :class:`Profile` is returned as
    it is (overrides need the file's data: give its path)."""
    if isinstance(name_or_path, Profile):
        if overrides:
            raise ProfileError(f"{name_or_path.path}: overrides apply to a profile file, not a loaded Profile")
        return name_or_path
    path = resolve(name_or_path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:
        raise ProfileError(f"{path}: not a UTF-8 text file (byte {exc.start}: {exc.reason}); "
                           "TOML profiles are UTF-8") from None
    except IsADirectoryError:
        raise ProfileError(f"{path}: is a directory, not a profile file") from None
    except OSError as exc:
        raise ProfileError(f"{path}: cannot read: {exc.strerror}") from None
    if not overrides:
        return parse_profile(data, str(path))
    changed = apply_overrides(data, overrides, str(path))
    try:
        profile = parse_profile(changed.data, str(path))
    except ProfileError as exc:
        raise ProfileError(changed.explain(str(exc))) from None
    profile.overrides = changed.values
    return profile


@dataclass
class Overridden:
    """Profile data after :func:`apply_overrides`, and which full keys each override set."""

    data: dict[str, Any]
    path: str
    keys: dict[str, str] = field(default_factory=dict)  # full key -> the override as given ("dxl.baud=1000000")
    values: dict[str, Any] = field(default_factory=dict)  # key as given -> the value set (TOML text read)

    def explain(self, message: str) -> str:
        """A check's one-line message with the override that set the key it names (``(set: dxl.baud=1)``)."""
        prefix = f"{self.path}: "
        key = message[len(prefix):].split(": ", 1)[0] if message.startswith(prefix) else ""
        given = [text for full, text in self.keys.items()
                 if key and (key == full or key.startswith((f"{full}.", f"{full}[")) or full.startswith(f"{key}."))]
        return f"{message} (set: {', '.join(given)})" if given else message


def apply_overrides(data: dict[str, Any], overrides: Overrides, path: str = "<profile>") -> Overridden:
    """A copy of profile ``data`` with ``overrides`` set; ProfileError (one line) for a key that names nothing.

    A key is ``ENDPOINT.KEY[.SUBKEY...]`` (a key of ``[endpoints.ENDPOINT]``: ``dxl.baud``,
    ``can.socketcand.port``, ``nodes.domain_id``), ``devices.NAME.KEY`` (the device entry named NAME),
    or ``TABLE.KEY`` / ``KEY`` for top-level tables and keys (``defaults.return_delay_us``,
    ``scene.walls``, ``description``); the full form ``endpoints.ENDPOINT.KEY`` works too. Text values
    (command line) are read as TOML values (``1000000``, ``true``, ``"x"``, ``[1, 2]``), else taken as a
    string; tables on the way are created. Nothing is checked here: :func:`parse_profile` checks the result
    as it checks a file.
    """
    if isinstance(overrides, str):
        overrides = [overrides]  # one KEY=VALUE, not its characters
    out = Overridden(copy.deepcopy(data), path)
    items = overrides.items() if isinstance(overrides, Mapping) else (_split(text, path) for text in overrides)
    for key, value in items:
        if not isinstance(key, str):
            raise ProfileError(f"{path}: override {key!r}: expected a KEY string")
        given = f"{key}={value}" if not isinstance(overrides, Mapping) else f"{key}={value!r}"
        keys = _full_key(out.data, key, path)
        table: Any = out.data
        for i, part in enumerate(keys[:-1]):
            if isinstance(table, list):
                table = table[int(part)]
                continue
            nxt = table.setdefault(part, {})
            if not isinstance(nxt, dict | list):
                raise ProfileError(f"{path}: {_dotted(keys[:i + 1])}: is {nxt!r}, not a table: cannot set {key}")
            table = nxt
        if isinstance(value, str) and not isinstance(overrides, Mapping):
            value = _toml_value(value)
        table[keys[-1]] = value
        out.keys[_dotted(keys)] = given
        out.values[key] = value
    return out


def _split(text: Any, path: str) -> tuple[str, str]:
    key, sep, value = str(text).partition("=")
    if not sep or not key.strip():
        raise ProfileError(f"{path}: override {text!r}: expected KEY=VALUE, e.g. ENDPOINT.baud=1000000")
    return key.strip(), value.strip()


def _toml_value(text: str) -> Any:
    """``1000000`` -> 1000000, ``true`` -> True, ``"a"``/``a`` -> "a", ``[1, 2]`` -> [1, 2] (TOML's own rules)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text  # a bare word: a string (the check says if a string is wrong there)


def _dotted(keys: list[str]) -> str:
    out = ""
    for k in keys:
        out += f"[{k}]" if k.isdigit() and out.endswith(("devices", "]")) else (f".{k}" if out else k)
    return out


def _full_key(data: dict[str, Any], key: str, path: str) -> list[str]:
    """The path of ``key`` in the TOML data (see :func:`apply_overrides`)."""
    parts = key.split(".")
    if any(not p for p in parts):
        raise ProfileError(f"{path}: override {key!r}: expected KEY or TABLE.KEY (no empty parts)")
    endpoints = data.get("endpoints") if isinstance(data.get("endpoints"), dict) else {}
    tops = {*CORE_KEYS, *(name for fam in registry.families.values() for name in fam.profile_tables)}
    head = parts[0]
    if head == "devices":
        if len(parts) < 3:
            raise ProfileError(f"{path}: override {key!r}: expected devices.NAME.KEY")
        devices = data.get("devices") if isinstance(data.get("devices"), list) else []
        names = [d.get("name") if isinstance(d, dict) else None for d in devices]
        if parts[1] in names:
            return ["devices", str(names.index(parts[1])), *parts[2:]]
        if parts[1].isdigit() and int(parts[1]) < len(devices):
            return ["devices", parts[1], *parts[2:]]
        known = ", ".join(n for n in names if n) or "none named"
        raise ProfileError(f"{path}: override {key!r}: no device named {parts[1]!r} (devices: {known})")
    if head in endpoints and head in tops:
        raise ProfileError(f"{path}: override {key!r}: {head!r} is an endpoint and a table; write "
                           f"endpoints.{key} or the table's key")
    if head in endpoints:
        if len(parts) < 2:
            raise ProfileError(f"{path}: override {key!r}: expected {head}.KEY (a key of [endpoints.{head}])")
        return ["endpoints", *parts]
    if head in tops:
        if head == "endpoints" and len(parts) >= 2 and parts[1] not in endpoints:
            raise ProfileError(f"{path}: override {key!r}: no endpoint {parts[1]!r} (endpoints: "
                               f"{', '.join(endpoints)})")
        return parts
    raise ProfileError(f"{path}: override {key!r}: no endpoint or table {head!r} (endpoints: "
                       f"{', '.join(endpoints) or 'none'}; tables: {', '.join(sorted(tops - {'endpoints'}))})")


def parse_profile(data: dict[str, Any], path: str = "<profile>") -> Profile:
    """Check a profile already read into a dict."""
    c = Checker(path)
    families = registry.families.values()
    schema = data.get("schema")
    if schema != SCHEMA:
        c.fail("schema", f"expected {SCHEMA}, got {schema!r}")
    tables = {name: fam for fam in families for name in fam.profile_tables}
    c.unknown(data, "", (*CORE_KEYS, *tables))
    defaults = _defaults(c, c.table(data.get("defaults", {}), "defaults"), families)
    raw_eps = c.table(data.get("endpoints"), "endpoints")
    if not raw_eps:
        c.fail("endpoints", "expected at least one [endpoints.NAME] table")
    raw_devs = data.get("devices", [])
    if not isinstance(raw_devs, list):
        c.fail("devices", "expected an array of tables ([[devices]])")
    raw_devs = [c.table(dev, f"devices[{i}]") for i, dev in enumerate(raw_devs)]
    endpoints = {name: _endpoint(c, name, ep, raw_devs, len(raw_eps) == 1) for name, ep in raw_eps.items()}
    profile = Profile(path=path, name=Path(path).stem, description=str(data.get("description", "")),
                      endpoints=endpoints, devices=[], defaults=defaults)
    for name, fam in tables.items():
        if name in data:
            profile.tables[name] = fam.check_table(c, name, data[name])
    if "world" in data:
        from hilbench.bench.world import check_world

        profile.world = check_world(c, data["world"])
        if profile.world.scene is not None and "scene" in data:
            c.fail("scene", "the world's geometry is given in [world] already: move these keys there")
        if profile.world.scene is not None:
            profile.tables["scene"] = profile.world.scene  # (where readers of the older [scene] look)
    for i, dev in enumerate(raw_devs):
        profile.devices.extend(_devices(c, f"devices[{i}]", dev, profile))
    for name, spec in endpoints.items():
        kind = registry.bus_kinds.get(spec.protocol)
        if kind.default_device is not None and not profile.devices_on(name):
            profile.devices.extend(_devices(c, f"endpoints.{name}", {**kind.default_device, "endpoint": name},
                                            profile))
    for name, spec in endpoints.items():
        registry.bus_kinds.get(spec.protocol).check_devices(c, spec, profile.devices_on(name))
    for fam_name in dict.fromkeys(spec.family for spec in profile.devices):
        registry.families.get(fam_name).check_profile(c, profile)
    names: set[str] = set()
    for spec in profile.devices:
        if spec.name in names:
            c.fail(f"{spec.where}.name", f"device name {spec.name!r} is used twice")
        names.add(spec.name)
    return profile


def _defaults(c: Checker, raw: dict[str, Any], families: list[DeviceFamily]) -> dict[str, Any]:
    known = {key: rng for fam in families for key, rng in fam.default_keys.items()}
    c.unknown(raw, "defaults", tuple(known))
    out = {}
    for key, (lo, hi, default) in known.items():
        out[key] = c.number(raw.get(key, default), f"defaults.{key}", lo, hi)
    return out


def _device_endpoint(dev: dict[str, Any], name: str, only: bool) -> bool:
    """Whether a device entry sits on endpoint ``name`` (explicitly, or as the only endpoint)."""
    return dev.get("endpoint") == name or ("endpoint" not in dev and only)


def _endpoint(c: Checker, name: str, ep: Any, raw_devs: list[dict[str, Any]], only: bool) -> EndpointSpec:
    key = f"endpoints.{name}"
    ep = c.table(ep, key)
    kind = c.choice(ep.get("type", "pty"), f"{key}.type", registry.host_ports.names())
    port_cls = registry.host_ports.get(kind)
    protocols = registry.bus_kinds.names()
    protocol = ep.get("protocol")
    if protocol is None:
        # No protocol: the one bus protocol the families of its devices' models join (a bare servo bus stays
        # short).
        joined: set[str] | None = None
        for i, d in enumerate(raw_devs):
            if not _device_endpoint(d, name, only) or "model" not in d:
                continue
            family = registry.family_for_model(d["model"])
            if family is None:
                c.fail(f"devices[{i}].model", f"unknown model {d['model']!r} (expected one of: "
                                              f"{', '.join(_models())})")
            joins = set(family.joins_for(d["model"]))
            joined = joins if joined is None else joined & joins
        if not joined or len(joined) != 1:
            c.fail(f"{key}.protocol", f"missing (expected one of {', '.join(protocols)})")
        protocol = joined.pop()
    c.choice(protocol, f"{key}.protocol", protocols)
    bus = registry.bus_kinds.get(protocol)
    rate_key = bus.rate_key  # "baud", or what the bus's users call the line rate ("bitrate" on CAN)
    allowed = (*CORE_ENDPOINT_KEYS, *((rate_key,) if rate_key != "baud" else ()), *port_cls.profile_keys,
               *bus.endpoint_keys)
    for k in ep:
        if k not in allowed:
            owners = [n for n, cls in registry.host_ports.items() if k in cls.profile_keys]
            if owners:
                types = " or ".join(f'type = "{o}"' for o in owners)
                c.fail(f"{key}.{k}", f"only for {types} endpoints")
            c.fail(f"{key}.{k}", f"unknown key (expected one of: {', '.join(allowed)})")
    if kind not in bus.endpoint_types:
        types = " or ".join(f'"{t}"' for t in bus.endpoint_types)
        c.fail(f"{key}.type", f'expected {types} for protocol "{protocol}", got "{kind}"')
    if rate_key != "baud" and rate_key in ep and "baud" in ep:
        c.fail(f"{key}.baud", f"give the line rate once: {rate_key} or baud")
    rate_name = rate_key if rate_key in ep else "baud"
    baud = bus.check_baud(c, f"{key}.{rate_name}", ep.get(rate_name), kind)
    port_options = c.options(port_cls.check_options, {k: ep[k] for k in port_cls.profile_keys if k in ep}, key)
    options = bus.check_endpoint(c, key, ep, kind)
    return EndpointSpec(name=name, type=kind, protocol=protocol, baud=baud,
                        paced=c.boolean(ep.get("paced", False), f"{key}.paced"),
                        port_options=port_options, options=options)


def _models(protocol: str | None = None) -> list[str]:
    """Model names of every family (joining ``protocol``), for "expected one of" lists."""
    fams = registry.families_joining(protocol) if protocol is not None else registry.families.values()
    return sorted({m for fam in fams for m in fam.models})


def _devices(c: Checker, where: str, dev: dict[str, Any], profile: Profile) -> list[DeviceSpec]:
    """One ``[[devices]]`` entry, checked by the family of its model."""
    endpoints = profile.endpoints
    ep_name = dev.get("endpoint")
    if ep_name is None and len(endpoints) == 1:
        ep_name = next(iter(endpoints))
    if ep_name not in endpoints:
        c.fail(f"{where}.endpoint", f"expected one of the endpoints ({', '.join(endpoints)}), got {ep_name!r}")
    spec = endpoints[ep_name]
    if "model" in dev:
        model = dev["model"]
        family = registry.family_for_model(model)
        if family is None:
            c.fail(f"{where}.model", f"unknown model {model!r} (expected one of: {', '.join(_models(spec.protocol))})")
    else:
        joining = registry.families_joining(spec.protocol)
        if len(joining) != 1:
            c.fail(f"{where}.model", f"missing (expected a model name: {', '.join(_models(spec.protocol))})")
        family = joining[0]
        model = None
    joins = family.joins_for(model)
    if spec.protocol not in joins:
        protos = " or ".join(f'"{p}"' for p in joins)
        what = f"model {model!r}" if model is not None else f"a {family.device_word}"
        c.fail(f"{where}.endpoint", f"{what} (family {family.name}) needs an endpoint with protocol = {protos}; "
                                    f"{ep_name!r} has protocol = \"{spec.protocol}\"")
    # (``pose`` is a core key too where the family has none: any device may sit on a body at a mount pose)
    core = CORE_DEVICE_KEYS if "pose" in family.device_keys else (*CORE_DEVICE_KEYS, "pose")
    c.unknown(dev, where, (*family.device_keys, *core))
    body = mount = None
    if "body" in dev:
        from hilbench.bench.world import check_body

        body = check_body(c, dev["body"], f"{where}.body", profile.world)
    if "pose" in core and "pose" in dev:
        from hilbench.bench.world import check_pose

        mount = check_pose(c, dev["pose"], f"{where}.pose")
    specs = family.check_devices(c, where, {k: v for k, v in dev.items() if k not in core}, spec, profile)
    for s in specs:
        s.family = family.name
        s.where = where
        s.body = body
        s.mount = mount
    return specs


__all__ = ["DEFAULT_PROFILE", "SCHEMA", "Checker", "DeviceSpec", "EndpointSpec", "Overridden", "Overrides", "Profile",
           "ProfileError", "apply_overrides", "bundled_profiles", "load_profile", "parse_profile", "resolve"]
