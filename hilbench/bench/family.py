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
  channel (:meth:`~DeviceFamily.control`).

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

    FAMILY = AcmeFamily()
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from hilbench.bench.checks import Checker

if TYPE_CHECKING:
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
    #: Lists of its device specs a :class:`~hilbench.bench.profile.Profile` offers (``profile.servos``).
    profile_attrs: ClassVar[tuple[str, ...]] = ()
    #: How an error message names one of its devices (``"a stm32f767-rover board needs ..."``).
    device_word: ClassVar[str] = "device"
    #: Attributes it sets on its endpoints (``endpoint.board``); other families' endpoints read them as None.
    endpoint_attrs: ClassVar[tuple[str, ...]] = ()
    #: Methods it adds to :class:`~hilbench.bench.Bench` (``bench.board()``): name -> function(bench, ...).
    bench_methods: ClassVar[dict[str, Any]] = {}
    #: Control commands it answers for its devices: name -> one-line help.
    control_commands: ClassVar[dict[str, str]] = {}

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

    # ------------------------------------------------------------------ control channel

    def control(self, bench: Bench, device: Any, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        """Answer control command ``cmd`` (one of :attr:`control_commands`) for ``device``."""
        raise NotImplementedError


def bench_device(bench: Bench, kind: type, word: str, name: str | None = None) -> Any:
    """A bench's device of class ``kind`` named ``name``, or its only one (for :attr:`DeviceFamily.bench_methods`
    such as ``bench.board()``); KeyError naming them (as ``word``, e.g. ``"boards"``) when it cannot tell."""
    devices = {n: d for n, d in bench.devices.items() if isinstance(d, kind)}
    if name is None:
        if len(devices) != 1:
            raise KeyError(f"bench has {word} {list(devices)}; name one")
        return next(iter(devices.values()))
    return devices[name]


__all__ = ["DeviceFamily", "DeviceSpec", "bench_device"]
