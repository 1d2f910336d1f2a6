"""Device families: what a kind of device is to a bench, on whichever bus it sits.

A family (the Dynamixel servos, the STM32 rover board, a scanner, a lab's
own board) is a :class:`DeviceFamily` registered in the ``hilbench.families``
entry-point group. It is chosen per device **model** (a ``[[devices]]``
entry's ``model``), so one endpoint may carry devices of several families;
the endpoint itself (its keys, medium, shared bus object, addresses) belongs
to the :class:`~hilbench.bench.bus.BusKind` of its ``protocol``. A family
owns everything about its devices the core must not know:

- its **profile schema**: its models, which bus protocols they join
  (:attr:`~DeviceFamily.joins`), its ``[[devices]]`` keys (each device entry
  is checked by its own family), ``[defaults]`` keys and top-level tables,
  each checked with one-line errors (:meth:`~DeviceFamily.check_devices`,
  :meth:`~DeviceFamily.check_profile`);
- **building** its devices on an endpoint (:meth:`~DeviceFamily.build`: each
  goes onto the bus with ``endpoint.add_device``), starting and stopping them;
- **describing** them for the manifest;
- **control commands** other processes send through the bench's control
  channel (:meth:`~DeviceFamily.control`);
- **typed access** to its devices on a running bench: a :class:`FamilyAccess`
  subclass (:attr:`~DeviceFamily.access`) that ``bench.family(NAME)`` returns,
  with lookups named after the family's devices (``bench.family("stm32-rover").board()``).

The profile loader, :class:`~hilbench.bench.Bench`, ``emulate`` and the control
server call these methods and nothing family-specific. A minimal family::

    class AcmeFamily(DeviceFamily):
        name = "acme"
        models = ("acme-1",)
        joins = ("acme",)                    # the bus protocols its devices sit on
        device_keys = ("model", "name", "endpoint", "gain")

        def check_devices(self, c, key, raw, endpoint, profile):
            return [AcmeSpec(name=raw.get("name", endpoint.name), endpoint=endpoint.name,
                             model="acme-1", gain=c.number(raw.get("gain", 1.0), f"{key}.gain", 0, 10))]

        def build(self, bench, endpoint, devices, t):
            for spec in devices:
                endpoint.add_device(spec.name, AcmeDevice(spec.name, spec.gain))

    class AcmeDevices(FamilyAccess):
        def amplifier(self, name: str | None = None) -> AcmeDevice:
            return self.device(name)

    AcmeFamily.access = AcmeDevices
    FAMILY = AcmeFamily()
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from hilbench.bench.checks import Checker

if TYPE_CHECKING:
    from typing import Self

    from hilbench.bench.bench import Bench, Endpoint
    from hilbench.bench.profile import EndpointSpec, Profile


@dataclass
class DeviceSpec:
    """One device of a profile as its family checked it (families subclass this with their fields)."""

    name: str
    endpoint: str
    model: str = ""
    #: The family that checked it (set by the profile loader).
    family: str = field(default="", kw_only=True)
    #: Its address on the endpoint's bus (a servo ID, a CANopen node id), filled by its family; None if the
    #: bus addresses none. The bus kind refuses an address taken twice on one endpoint, across families.
    address: int | None = field(default=None, kw_only=True)
    #: Where the profile declared it (``devices[3]``), for errors found later.
    where: str = field(default="", kw_only=True, repr=False)
    #: The world body it sits on (``body = "rover"``, a core key checked by the profile loader); None: fixed in
    #: the world (or not in it at all).
    body: str | None = field(default=None, kw_only=True)
    #: Its mount pose on ``body`` (or its pose in the world) as (x m, y m, theta rad), from the core ``pose`` key
    #: of a family whose devices have no ``pose`` of their own (the scanners keep theirs); None: not given.
    mount: tuple[float, float, float] | None = field(default=None, kw_only=True)


class DeviceFamily:
    """Base class of device families; see the module docstring. Subclasses set the class attributes."""

    #: The family's name (its entry-point name).
    name: ClassVar[str] = ""
    #: Model names (and aliases) it knows: a ``[[devices]]`` entry naming one is this family's.
    models: ClassVar[tuple[str, ...]] = ()
    #: Bus protocols (``hilbench.bus_kinds``) its devices may sit on (:meth:`joins_for` may narrow by model).
    joins: ClassVar[tuple[str, ...]] = ()
    #: Keys of a ``[[devices]]`` entry (for unknown-key errors).
    device_keys: ClassVar[tuple[str, ...]] = ("model", "name", "endpoint")
    #: ``[defaults]`` keys it owns: name -> (lo, hi, default).
    default_keys: ClassVar[dict[str, tuple[float, float, float]]] = {}
    #: Top-level profile tables it owns (e.g. a scene).
    profile_tables: ClassVar[tuple[str, ...]] = ()
    #: How messages name one of its devices (``"no board named 'x'"``).
    device_word: ClassVar[str] = "device"
    #: Control commands it answers for its devices: name -> one-line help.
    control_commands: ClassVar[dict[str, str]] = {}
    #: Files it writes about its devices for other tools (``"dbc"``, ``"eds"``): name -> one-line help; see
    #: :meth:`artefact`.
    artefacts: ClassVar[dict[str, str]] = {}
    #: What ``bench.family(name)`` returns for it: a :class:`FamilyAccess` (sub)class with its typed lookups.
    access: ClassVar[type[FamilyAccess]]

    # ------------------------------------------------------------------ profile

    def knows_model(self, model: Any) -> bool:
        """Whether ``model`` names one of this family's models (the profile loader picks the family by it)."""
        return isinstance(model, str) and model in self.models

    def joins_for(self, model: Any) -> tuple[str, ...]:
        """The bus protocols a device of ``model`` may sit on (by default :attr:`joins`)."""
        return self.joins

    def check_devices(self, c: Checker, key: str, raw: dict[str, Any], endpoint: EndpointSpec,
                      profile: Profile) -> list[DeviceSpec]:
        """One ``[[devices]]`` entry on ``endpoint`` -> its device specs (unknown keys are checked already)."""
        raise NotImplementedError

    def check_profile(self, c: Checker, profile: Profile) -> None:
        """Checks of its own across the whole profile, after every device was read (the bus kinds checked
        addresses and device counts per endpoint already)."""

    def check_table(self, c: Checker, name: str, raw: Any) -> Any:
        """A top-level table of :attr:`profile_tables`; the result is ``profile.tables[name]``."""
        return c.table(raw, name)

    # ------------------------------------------------------------------ bench

    def build(self, bench: Bench, endpoint: Endpoint, devices: list[DeviceSpec], t: float) -> None:
        """Make its devices of ``endpoint`` (``devices``: their specs, in profile order) and put each on the bus
        with ``endpoint.add_device(name, device)``."""
        raise NotImplementedError

    def start(self, endpoint: Endpoint, devices: dict[str, Any], t: float) -> None:
        """Start its devices on ``endpoint`` (name -> device) that run on their own, after every medium started."""

    def stop(self, endpoint: Endpoint, devices: dict[str, Any]) -> None:
        """Stop what :meth:`start` started."""

    # ------------------------------------------------------------------ description

    def describe_device(self, spec: DeviceSpec, device: Any, endpoint: Endpoint | None,
                        profile: Profile) -> dict[str, Any]:
        """A device's manifest entry (``name``, ``model``, ``endpoint``, ``protocol`` at least; the bench adds
        ``family``)."""
        return {"name": spec.name, "model": spec.model, "endpoint": spec.endpoint,
                "protocol": profile.endpoints[spec.endpoint].protocol}

    def overflow(self, device: Any, endpoint: Endpoint) -> dict[str, Any]:
        """What a device's own bounded queues turned away, for the control channel's ``status`` and
        ``overflow`` (:mod:`hilbench.bench.overflow`): ``{"limits": {...}, COUNTER: N, ...}``; ``{}`` (the
        default) for a device that bounds nothing a client fills."""
        return {}

    def artefact(self, kind: str, profile: Profile | str, device: str | None = None) -> str | None:
        """The text of artefact ``kind`` (one of :attr:`artefacts`) describing ``profile``'s devices of this
        family, or the one named ``device``; None if the profile has none (or the family makes no ``kind``).

        ``profile`` may be a profile's name or file, which the family reads itself (one that cannot be read:
        None): so an instrument, which knows no profiles, finds a bench's CAN database by the profile's name
        (``hilbench monitor --dbc mecarover-can``) through :data:`hilbench.registry.families`.
        """
        return None

    # ------------------------------------------------------------------ control channel

    def control(self, bench: Bench, device: Any, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        """Answer control command ``cmd`` (one of :attr:`control_commands`) for ``device``."""
        raise NotImplementedError


class FamilyAccess:
    """One family's devices on a running bench: what ``bench.family(name)`` returns.

    :meth:`devices` and :meth:`device` find them by profile name; a family subclasses this with lookups
    named after its devices and typed by what they return (``board()``, ``node(2)``, ``servo(3)``) and names
    the subclass in :attr:`DeviceFamily.access`. ``Subclass.of(bench)`` is ``bench.family(...)`` typed as the
    subclass (it sets :attr:`family_name`).
    """

    #: The family :meth:`of` looks up (a subclass written for one family sets it).
    family_name: ClassVar[str] = ""

    def __init__(self, bench: Bench, family: DeviceFamily) -> None:
        self.bench = bench
        self.family = family

    @classmethod
    def of(cls, bench: Bench) -> Self:
        """``bench.family(cls.family_name)``, checked to be this class."""
        access = bench.family(cls.family_name)
        if not isinstance(access, cls):
            raise TypeError(f"family {cls.family_name!r} gives {type(access).__name__}, not {cls.__name__}")
        return access

    def specs(self) -> dict[str, DeviceSpec]:
        """Its devices' profile entries, by name, in profile order."""
        return {s.name: s for s in self.bench.profile.devices_of(self.family.name)}

    def devices(self) -> dict[str, Any]:
        """Its devices on the bench, by profile name, in profile order."""
        return {name: self.bench.devices[name] for name in self.specs() if name in self.bench.devices}

    def device(self, name: str | None = None) -> Any:
        """Its device ``name``, or its only one; KeyError naming them (as its :attr:`~DeviceFamily.device_word`)."""
        devices = self.devices()
        word = self.family.device_word
        if name is None:
            if len(devices) != 1:
                raise KeyError(f"bench has {word}s {list(devices)} of family {self.family.name}; name one")
            return next(iter(devices.values()))
        if name not in devices:
            raise KeyError(f"no {word} named {name!r} of family {self.family.name} ({word}s: {list(devices)})")
        return devices[name]

    def endpoints(self) -> list[Endpoint]:
        """The endpoints carrying its devices, in profile order."""
        names = dict.fromkeys(s.endpoint for s in self.specs().values())
        return [self.bench.endpoints[n] for n in names if n in self.bench.endpoints]

    def endpoint(self, name: str | None = None) -> Endpoint:
        """The endpoint ``name`` carrying its devices, or the only one; KeyError naming them."""
        eps = {ep.name: ep for ep in self.endpoints()}
        if name is None:
            if len(eps) != 1:
                raise KeyError(f"the {self.family.name} devices sit on endpoints {list(eps)}; name one")
            return next(iter(eps.values()))
        if name not in eps:
            raise KeyError(f"endpoint {name!r} has no {self.family.name} devices (endpoints: {list(eps)})")
        return eps[name]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.family.name!r}: {list(self.specs())})"


DeviceFamily.access = FamilyAccess


__all__ = ["DeviceFamily", "DeviceSpec", "FamilyAccess"]
