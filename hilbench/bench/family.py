"""Device families: what a kind of device is to a bench.

A family (the Dynamixel servos, the STM32 rover board, a scanner, a lab's
own board) is a :class:`DeviceFamily` registered in the ``hilbench.families``
entry-point group. It owns everything the core must not know:

- its **profile schema**: which endpoint ``protocol`` values it serves, its
  endpoint keys and baud rates, its ``[[devices]]`` keys, ``[defaults]`` keys
  and top-level tables, each checked with one-line errors
  (:meth:`~DeviceFamily.check_endpoint`, :meth:`~DeviceFamily.check_devices`,
  :meth:`~DeviceFamily.check_profile`);
- **building** its devices on an endpoint's medium (:meth:`~DeviceFamily.build`), starting
  and stopping them;
- **describing** them for the manifest and ``hilbench emulate``'s listing;
- **control commands** other processes send through the bench's control
  channel (:meth:`~DeviceFamily.control`).

The profile loader, :class:`~hilbench.bench.Bench`, ``emulate`` and the control
server call these methods and nothing family-specific. A minimal family::

    class AcmeFamily(DeviceFamily):
        name = "acme"
        protocols = ("acme",)
        device_keys = ("model", "name", "endpoint", "gain")

        def check_devices(self, c, key, raw, endpoint, profile):
            return [AcmeSpec(name=raw.get("name", endpoint.name), endpoint=endpoint.name,
                             model="acme-1", gain=c.number(raw.get("gain", 1.0), f"{key}.gain", 0, 10))]

        def build(self, bench, endpoint, devices, t):
            for spec in devices:
                endpoint.add_device(spec.name, AcmeDevice(spec.name, spec.gain), endpoint.medium)

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
    family: str = field(default="", kw_only=True)
    #: Where the profile declared it (``devices[3]``), for errors found later.
    where: str = field(default="", kw_only=True, repr=False)


class DeviceFamily:
    """Base class of device families; see the module docstring. Subclasses set the class attributes."""

    #: The family's name (its entry-point name).
    name: ClassVar[str] = ""
    #: Endpoint ``protocol`` values whose devices this family builds.
    protocols: ClassVar[tuple[str, ...]] = ()
    #: Endpoint ``type`` values (host ports) its endpoints may have.
    endpoint_types: ClassVar[tuple[str, ...]] = ("pty",)
    #: The medium kind its endpoints need (``hilbench.media``).
    medium: ClassVar[str] = "serial"
    #: The profile key its endpoints give their line rate by (``baud``, or ``bitrate`` on a CAN bus); either
    #: name is accepted and lands in ``EndpointSpec.baud``.
    rate_key: ClassVar[str] = "baud"
    #: Endpoint keys of its own (besides type, protocol, baud, paced and the host port's keys).
    endpoint_keys: ClassVar[tuple[str, ...]] = ()
    #: Keys of a ``[[devices]]`` entry (for unknown-key errors).
    device_keys: ClassVar[tuple[str, ...]] = ("model", "name", "endpoint")
    #: Model names (and aliases) it knows, so a device on another family's endpoint gets a pointed error.
    models: ClassVar[tuple[str, ...]] = ()
    #: ``[defaults]`` keys it owns: name -> (lo, hi, default).
    default_keys: ClassVar[dict[str, tuple[float, float, float]]] = {}
    #: Top-level profile tables it owns (e.g. a scene).
    profile_tables: ClassVar[tuple[str, ...]] = ()
    #: Lists of its device specs a :class:`~hilbench.bench.profile.Profile` offers (``profile.servos``).
    profile_attrs: ClassVar[tuple[str, ...]] = ()
    #: How an error message names one of its devices (``"a stm32f767-rover board needs ..."``).
    device_word: ClassVar[str] = "device"
    #: Attributes it sets on its endpoints (``endpoint.bus``); other families' endpoints read them as None.
    endpoint_attrs: ClassVar[tuple[str, ...]] = ()
    #: Methods it adds to :class:`~hilbench.bench.Bench` (``bench.board()``): name -> function(bench, ...).
    bench_methods: ClassVar[dict[str, Any]] = {}
    #: Which verb reads an endpoint's traffic tap (printed by ``hilbench emulate``).
    tap_reader: ClassVar[str] = "monitor"
    #: Control commands it answers: name -> one-line help.
    control_commands: ClassVar[dict[str, str]] = {}

    # ------------------------------------------------------------------ profile

    def knows_model(self, model: Any) -> bool:
        """Whether ``model`` names one of this family's models (decides an endpoint's default protocol)."""
        return isinstance(model, str) and model in self.models

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int | None:
        """The endpoint's ``baud`` (``value`` is None when the profile leaves it out)."""
        from hilbench.rules import LINE_BAUD

        return c.rule(115_200 if value is None else value, key, LINE_BAUD)

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        """The family's own endpoint keys (:attr:`endpoint_keys`) of ``raw``, checked; stored as options."""
        return {}

    def check_devices(self, c: Checker, key: str, raw: dict[str, Any], endpoint: EndpointSpec,
                      profile: Profile) -> list[DeviceSpec]:
        """One ``[[devices]]`` entry on ``endpoint`` -> its device specs (unknown keys are checked already)."""
        raise NotImplementedError

    def check_profile(self, c: Checker, profile: Profile) -> None:
        """Checks across the whole profile, after every device was read (unique IDs, one per endpoint...)."""

    def check_table(self, c: Checker, name: str, raw: Any) -> Any:
        """A top-level table of :attr:`profile_tables`; the result is ``profile.tables[name]``."""
        return c.table(raw, name)

    # ------------------------------------------------------------------ bench

    def paced(self, spec: EndpointSpec, requested: bool) -> bool:
        """Whether the endpoint's medium paces its traffic (a device pacing itself says False)."""
        return requested

    def build(self, bench: Bench, endpoint: Endpoint, devices: list[DeviceSpec], t: float) -> None:
        """Make the devices of ``endpoint`` and attach them to ``endpoint.medium`` (``endpoint.add_device``)."""
        raise NotImplementedError

    def start(self, endpoint: Endpoint, t: float) -> None:
        """Start devices that run on their own (after every medium started)."""

    def stop(self, endpoint: Endpoint) -> None:
        """Stop what :meth:`start` started."""

    # ------------------------------------------------------------------ description

    def describe_endpoint(self, endpoint: Endpoint) -> dict[str, Any]:
        """Extra manifest fields of an endpoint."""
        return {}

    def describe_device(self, spec: DeviceSpec, device: Any, endpoint: Endpoint | None,
                        profile: Profile) -> dict[str, Any]:
        """A device's manifest entry (``name``, ``model``, ``endpoint``, ``protocol`` at least)."""
        return {"name": spec.name, "model": spec.model, "endpoint": spec.endpoint,
                "protocol": profile.endpoints[spec.endpoint].protocol}

    def summary(self, endpoint: Endpoint) -> str:
        """What ``hilbench emulate`` prints in brackets after the endpoint's path."""
        spec = endpoint.spec
        baud = f", {spec.baud} baud" if spec.baud else ""
        return f"{spec.protocol}{baud}, {len(endpoint.devices)} devices"

    def device_at(self, endpoint: Endpoint, address: int) -> Any:
        """The device answering at ``address`` (an ID, a node id) on ``endpoint``; KeyError if none."""
        raise KeyError(f"endpoint {endpoint.name!r} has no device at {address}")

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
