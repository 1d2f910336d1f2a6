"""Bus kinds: what an endpoint's ``protocol`` is to a bench, whichever families' devices sit on it.

An endpoint is one bus (an RS-485 servo line, a CAN bus, a UART, a UDP net):
its :class:`BusKind`, registered in the ``hilbench.bus_kinds`` entry-point
group under the endpoint ``protocol`` it serves, owns everything about the bus
itself:

- its **endpoint keys**: which host ports (``type``) it runs on, its line rate
  (``baud``, or ``bitrate``) and its own keys (a Dynamixel bus's
  ``protocol_version``, a CAN bus's ``bus_faults``), checked with one-line
  errors (:meth:`~BusKind.check_baud`, :meth:`~BusKind.check_endpoint`);
- the checks **across the devices** on one endpoint, whatever their families:
  at most :attr:`~BusKind.max_devices`, and no address (a servo ID, a node id) taken
  twice (:meth:`~BusKind.check_devices`);
- the **medium** kind it needs and the **shared side** its devices join
  (:meth:`~BusKind.open` makes the endpoint's ``bus``, e.g. the object that decodes a
  servo line once for every servo; :meth:`~BusKind.join` adds a device to it);
- finding a device by address (:meth:`~BusKind.device_at`), the endpoint's manifest
  fields and listing line (:meth:`~BusKind.describe_endpoint`, :meth:`~BusKind.summary`), and
  **bus-level control commands** (:meth:`~BusKind.control`, e.g. a CAN bus's error
  knobs) addressed by endpoint;
- the **labgrid driver** ``hilbench labgrid env`` puts on a served endpoint's
  console (:meth:`~BusKind.labgrid_driver`, a :class:`LabgridDriver`), if the
  family has one.

Devices come from :class:`~hilbench.bench.family.DeviceFamily` plug-ins chosen
per device **model**; a family says which bus protocols its devices join
(:attr:`~hilbench.bench.family.DeviceFamily.joins`), so one endpoint may carry
devices of several families (a lab's sensor board beside Dynamixel servos, a
second CANopen node family beside the rover board). A minimal bus kind::

    class BlinkBus(BusKind):
        protocol = "blink"               # the endpoint's protocol = "blink"
        endpoint_types = ("pty",)

    BUS_KIND = BlinkBus()
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

from hilbench.bench.checks import Checker

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench, Endpoint
    from hilbench.bench.family import DeviceSpec
    from hilbench.bench.profile import EndpointSpec


class LabgridDriver(NamedTuple):
    """A labgrid driver for an endpoint's console, as ``hilbench labgrid env`` writes it into an environment."""

    #: The module the environment imports (``imports:``); importing it registers the driver with labgrid.
    module: str
    #: The driver's class name (labgrid's key in the environment's ``drivers:``).
    cls: str
    #: Appended to the endpoint's name to name the driver (``arm`` + ``-dxl``).
    suffix: str


class BusKind:
    """Base class of bus kinds; see the module docstring. Subclasses set the class attributes."""

    #: The endpoint ``protocol`` it serves (its entry-point name); also what taps call its traffic unless
    #: :meth:`open` refines ``endpoint.medium.protocol`` (a Protocol 1.0 Dynamixel bus: ``dynamixel1``).
    protocol: ClassVar[str] = ""
    #: The medium kind its endpoints need (``hilbench.media``: serial, can, datagram).
    medium: ClassVar[str] = "serial"
    #: Endpoint ``type`` values (host ports) it runs on.
    endpoint_types: ClassVar[tuple[str, ...]] = ("pty",)
    #: The profile key its endpoints give their line rate by (``baud``, or ``bitrate`` on a CAN bus); either
    #: name is accepted and lands in ``EndpointSpec.baud``.
    rate_key: ClassVar[str] = "baud"
    #: Endpoint keys of its own (besides type, protocol, baud, paced and the host port's keys).
    endpoint_keys: ClassVar[tuple[str, ...]] = ()
    #: Devices one endpoint may carry (None: any number); :attr:`one_device_reason` says why, for errors.
    max_devices: ClassVar[int | None] = None
    one_device_reason: ClassVar[str] = ""
    #: The ``[[devices]]`` key giving a device's address on this bus (``id``, ``node_id``; "" if devices have
    #: none), and how an error names it (``ID``, ``node id``). Families fill ``DeviceSpec.address``.
    address_key: ClassVar[str] = ""
    address_word: ClassVar[str] = "address"
    #: The ``[[devices]]`` entry an endpoint that lists no device gets (an agent that needs no settings).
    default_device: ClassVar[dict[str, Any] | None] = None
    #: Which verb reads an endpoint's traffic tap (printed by ``hilbench emulate``).
    tap_reader: ClassVar[str] = "monitor"
    #: Control commands about the bus itself (not one device), addressed by endpoint: name -> one-line help.
    control_commands: ClassVar[dict[str, str]] = {}

    # ------------------------------------------------------------------ profile

    def check_baud(self, c: Checker, key: str, value: Any, port_type: str) -> int | None:
        """The endpoint's line rate (``value`` is None when the profile leaves it out)."""
        from hilbench.rules import LINE_BAUD

        return c.rule(115_200 if value is None else value, key, LINE_BAUD)

    def check_endpoint(self, c: Checker, key: str, raw: dict[str, Any], port_type: str) -> dict[str, Any]:
        """Its own endpoint keys (:attr:`endpoint_keys`) of ``raw``, checked; they become ``EndpointSpec.options``."""
        return {}

    def check_devices(self, c: Checker, endpoint: EndpointSpec, specs: list[DeviceSpec]) -> None:
        """Checks across the devices of one endpoint, of any family: :attr:`max_devices`, unique addresses."""
        if self.max_devices is not None and len(specs) > self.max_devices:
            first, extra = specs[0], specs[self.max_devices]
            reason = f": {self.one_device_reason}" if self.one_device_reason else ""
            c.fail(f"{extra.where}.endpoint", f"endpoint {endpoint.name!r} already has {_a(_word_of(first))} "
                                              f"({first.name!r}){reason}")
        taken: dict[int, DeviceSpec] = {}
        for spec in specs:
            if spec.address is None:
                continue
            other = taken.get(spec.address)
            if other is not None:
                key = f"{spec.where}.{self.address_key}" if self.address_key else spec.where
                text = f"{self.address_word} {spec.address} is taken on endpoint {endpoint.name!r} by {other.where}"
                if other.family == spec.family:
                    c.fail(key, f"{text} ({other.name!r})")
                c.fail(key, f"{text} ({other.name!r}, family {other.family}); {spec.name!r} (family {spec.family}) "
                            "needs another")
            taken[spec.address] = spec

    # ------------------------------------------------------------------ bench

    def paced(self, spec: EndpointSpec, requested: bool) -> bool:
        """Whether the endpoint's medium paces its traffic (devices pacing themselves say False)."""
        return requested

    def open(self, bench: Bench, endpoint: Endpoint) -> Any:
        """Make what the endpoint's devices share (``endpoint.bus``), before any device is built; None if they
        share only the medium."""
        return None

    def join(self, endpoint: Endpoint, device: Any, spec: DeviceSpec | None) -> None:
        """Put a device a family built on the bus (``endpoint.add_device`` calls this): by default it attaches
        to the medium itself (``device.attach(endpoint.medium)``)."""
        device.attach(endpoint.medium)

    def start(self, endpoint: Endpoint, t: float) -> None:
        """Start what :meth:`open` made (after every medium started, before the families start their devices)."""

    def stop(self, endpoint: Endpoint) -> None:
        """Stop what :meth:`start` started (after the families stopped their devices)."""

    def device_at(self, endpoint: Endpoint, address: int) -> Any:
        """The device answering at ``address`` on ``endpoint`` (by its profile address); KeyError if none."""
        for name, spec in endpoint.specs.items():
            if spec.address == address and name in endpoint.devices:
                return endpoint.devices[name]
        known = sorted(s.address for s in endpoint.specs.values() if s.address is not None)
        raise KeyError(f"endpoint {endpoint.name!r} has no device at {self.address_word} {address} "
                       f"({self.address_word}s: {known})")

    # ------------------------------------------------------------------ description

    def describe_endpoint(self, endpoint: Endpoint) -> dict[str, Any]:
        """Extra manifest fields of an endpoint."""
        return {}

    def summary(self, endpoint: Endpoint) -> str:
        """What ``hilbench emulate`` prints in brackets after the endpoint's path."""
        spec = endpoint.spec
        baud = f", {spec.baud} baud" if spec.baud else ""
        return f"{spec.protocol}{baud}, {len(endpoint.devices)} devices"

    # ------------------------------------------------------------------ control channel

    def control(self, bench: Bench, endpoint: Endpoint, cmd: str, req: dict[str, Any]) -> dict[str, Any]:
        """Answer bus command ``cmd`` (one of :attr:`control_commands`) for ``endpoint``."""
        raise NotImplementedError

    # ------------------------------------------------------------------ remote benches

    def labgrid_driver(self, endpoint: dict[str, Any]) -> LabgridDriver | None:
        """The labgrid driver for a served endpoint of this bus (``endpoint``: its manifest entry), bound to the
        endpoint's ``SerialDriver``; None: the console alone."""
        return None


def _word_of(spec: DeviceSpec) -> str:
    """How errors name a device of ``spec``'s family (its ``device_word``)."""
    from hilbench import registry

    return registry.families.get(spec.family).device_word if spec.family in registry.families else "device"


def _a(word: str) -> str:
    return f"an {word}" if word[:1] in "aeiou" else f"a {word}"


__all__ = ["BusKind", "LabgridDriver"]
