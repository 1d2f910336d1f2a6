"""The plug-in registry: which device families, host ports, media, sources, instruments and verbs exist.

hilbench's core (profile loading, :class:`~hilbench.bench.Bench`, ``emulate``,
the manifest, the monitor and dashboard frames, source opening, the command's
verb table) knows no device family by name. Everything family-specific
registers itself here, the way python-can finds its interfaces
(``can.interfaces.BACKENDS`` plus the ``can.interface`` entry-point group):
through Python entry points, built-ins exactly as an outside package would::

    # pyproject.toml of a lab's own package
    [project.entry-points."hilbench.families"]
    acme-board = "acme_hilbench.family:FAMILY"

=====================  =========================  =============================================
kind                   entry-point group          the object an entry point names
=====================  =========================  =============================================
:data:`families`       ``hilbench.families``      a :class:`~hilbench.bench.family.DeviceFamily` (chosen per
                                                  device model)
:data:`bus_kinds`      ``hilbench.bus_kinds``     a :class:`~hilbench.bench.bus.BusKind` (chosen per endpoint
                                                  ``protocol``)
:data:`host_ports`     ``hilbench.host_ports``    a host-port class (endpoint ``type``: pty, udp, tcp)
:data:`media`          ``hilbench.media``         a :class:`~hilbench.transports.medium.Medium` class
:data:`sources`        ``hilbench.sources``       a :class:`~hilbench.transports.sources.SourceOpener`
:data:`instruments`    ``hilbench.instruments``   an :class:`~hilbench.monitor.instrument.Instrument`
:data:`clients`        ``hilbench.clients``       a :class:`~hilbench.clients.base.ClientDriver` (a device's host
                                                  side, for the verb of its role: ``hilbench lidar``)
:data:`verbs`          ``hilbench.verbs``         a module with ``register(subparsers)``, named once per
                                                  verb it adds; ``VERB.NAME``: an extension of VERB, a
                                                  module with ``extend(subparsers)``
:data:`fuzz_targets`   ``hilbench.fuzz_targets``  a :class:`~hilbench.fuzzing.FuzzTarget` (fuzzing,
                                                  rough-input benchmarks)
:data:`servers`        ``hilbench.servers``       a :class:`~hilbench.bench.server.Server` (``emulate --serve``)
:data:`recorders`      ``hilbench.recorders``     a recording format: ``accepts(path, protocol)``,
                                                  ``open(path, source=..., description=...)``
:data:`inferrers`      ``hilbench.inferrers``     a :class:`~hilbench.bench.capture_profile.Inferrer`: a
                                                  profile from a capture of its traffic
                                                  (``profiles from-capture``)
=====================  =========================  =============================================

Entry points load one by one, when asked for: ``kind.get(name)`` imports
the module of that entry point alone, ``kind.names()`` and ``name in kind``
read the names without importing anything, and ``values()``, ``items()``,
``find()`` load the whole group. So ``hilbench monitor`` on a Dynamixel
capture imports no CAN or laser scanner code, and plug-in modules stay light
(what they name imports its heavy parts when it runs). A plug-in that fails
to load is skipped with one warning naming its package (a lab's broken
package must not take the whole command down); :meth:`Kind.failures` lists
them.
Objects can also be registered in code (:meth:`Kind.register`), e.g. by tests.

A registration that clashes with one already made is refused: two families
claiming one family name or model (or one ``[defaults]`` key, or one
top-level profile table with different checks), two bus kinds for one
protocol, two instruments for one protocol or alias, two verb modules adding
one verb, two inferrers for one protocol. An entry point that clashes is skipped with a :class:`PluginWarning`
naming both packages (the first registered wins: hilbench's own, then by
name); :meth:`Kind.register` raises :class:`ValueError`. Client drivers claim
their protocol and aliases, and the options they add to their role's verb.

The entry points are read from a small cache while no package was installed, removed or reinstalled
since (:mod:`hilbench.entry_points`: :mod:`importlib.metadata` alone costs a command 20 - 40 ms).

This module imports nothing from hilbench but :mod:`hilbench.errors` and :mod:`hilbench.entry_points`.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from hilbench import entry_points
from hilbench.entry_points import Entry
from hilbench.errors import UsageError


class PluginWarning(UserWarning):
    """A plug-in package could not be loaded, or clashes with one registered before (it is skipped)."""


#: What a registration claims besides its name: ``(what, value)``, e.g. ``("model", "MX-64")``, or
#: ``(what, value, token)`` for a claim others may share when they bring the same token (a profile table
#: two families check with one function).
Claim = tuple[str, str] | tuple[str, str, str]


_ENTRY_POINTS: list[Entry] | None = None


def _group(group: str) -> list[Entry]:
    """The entry points of ``group`` (every installed package's read once for all kinds)."""
    global _ENTRY_POINTS
    if _ENTRY_POINTS is None:
        _ENTRY_POINTS = entry_points.read()
    return [ep for ep in _ENTRY_POINTS if ep.group == group]


def _dist(ep: Entry) -> str:
    return ep.dist


class Kind:
    """One kind of plug-in: a name -> object table filled from an entry-point group, one entry point at a time.

    Entry points are kept by name and loaded when asked for: :meth:`get` loads the one it names,
    :meth:`names` and ``in`` read the names alone, :meth:`items`, :meth:`values`, :meth:`find` and
    :meth:`failures` load them all (a verb that needs one family's plug-in imports that one).

    ``claims(obj)`` lists what a registration takes besides its name (:data:`Claim`); a registration whose
    name or claims another one holds is refused. A clash between two entry points is found once both are
    loaded; the first in order (hilbench's own, then by name) keeps the claim either way.
    """

    def __init__(self, name: str, group: str, *, what: str,
                 claims: Callable[[Any], Iterable[Claim]] | None = None) -> None:
        self.name = name
        self.group = group
        self.what = what  # how an error message names one ("device family", "endpoint type", ...)
        self._claims_of = claims
        self._items: dict[str, Any] = {}
        self._origin: dict[str, str] = {}
        self._failed: dict[str, str] = {}
        self._held: dict[tuple[str, str], tuple[str, str | None]] = {}  # (what, value) -> (name, token)
        self._eps: dict[str, Entry] | None = None  # name -> the entry point that has it, in load order
        self._rank: dict[str, int] = {}  # name -> its place in that order (code registrations come last)
        self._tried: set[str] = set()  # entry points loaded (or failed to)
        self._loaded = False  # every entry point tried
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ claims

    def _claims(self, obj: Any) -> list[tuple[str, str, str | None]]:
        if self._claims_of is None:
            return []
        return [(c[0], c[1], c[2] if len(c) > 2 else None) for c in self._claims_of(obj)]

    def _clashes(self, name: str, obj: Any) -> Iterator[tuple[str, str, str]]:
        """``(owner, what, value)`` for each claim of ``obj`` another registration holds."""
        for what, value, token in self._claims(obj):
            held = self._held.get((what, value))
            if held is not None and held[0] != name and (token is None or held[1] != token):
                yield held[0], what, value

    def _why(self, owner: str, what: str, value: str) -> str:
        return f"its {what} {value!r} is taken by {self.what} {owner!r} (from {self._origin.get(owner, '?')})"

    def _add(self, name: str, obj: Any, origin: str) -> None:
        self._items[name] = obj
        self._origin[name] = origin
        for what, value, token in self._claims(obj):
            self._held.setdefault((what, value), (name, token))

    def _drop(self, name: str) -> None:
        self._items.pop(name, None)
        self._origin.pop(name, None)
        self._held = {k: v for k, v in self._held.items() if v[0] != name}

    # ------------------------------------------------------------------ loading

    def _entry_points(self) -> dict[str, Entry]:
        """The group's entry points by name, read once (names only: nothing is imported)."""
        if self._eps is None:
            with self._lock:
                if self._eps is None:
                    eps = sorted(_group(self.group), key=lambda ep: (_dist(ep) != "hilbench", ep.name))
                    chosen: dict[str, Entry] = {}
                    for ep in eps:
                        first = chosen.get(ep.name)
                        if first is None:
                            chosen[ep.name] = ep
                        elif _dist(first) != _dist(ep):  # another package wants the name: skipped unloaded
                            why = f"{_dist(first)} registers it already"
                            self._failed[f"{ep.name} ({_dist(ep)})"] = f"{_dist(ep)}: {why}"
                            warnings.warn(f"hilbench: {self.what} {ep.name!r} from {_dist(ep)} skipped: {why}",
                                          PluginWarning, stacklevel=4)
                    self._rank = {name: n for n, name in enumerate(chosen)}
                    self._eps = chosen
        return self._eps

    def _load_one(self, name: str) -> None:
        """Load the entry point ``name`` (once); a failure or a clash is a warning and a :meth:`failures` entry."""
        eps = self._entry_points()
        if name in self._tried or name not in eps or name in self._items:
            return
        with self._lock:
            if name in self._tried:
                return
            self._tried.add(name)
            ep = eps[name]
            dist = _dist(ep)
            try:
                obj = ep.load()
            except Exception as exc:  # noqa: BLE001 (any plug-in failure is reported, not raised)
                self._failed[name] = f"{dist}: {type(exc).__name__}: {exc}"
                warnings.warn(f"hilbench: {self.what} {name!r} from {dist} could not be loaded "
                              f"({type(exc).__name__}: {exc}); skipped", PluginWarning, stacklevel=4)
                return
            # Whichever of two clashing entry points loads first, the one earlier in order keeps the claim.
            rank = self._rank[name]
            for owner, what, value in list(self._clashes(name, obj)):
                if owner in self._items and self._rank.get(owner, len(self._rank)) > rank:
                    why = f"its {what} {value!r} is taken by {self.what} {name!r} (from {dist})"
                    self._skip(owner, self._origin[owner], why)
                    self._drop(owner)
            clash = next(self._clashes(name, obj), None)
            if clash is not None:
                self._skip(name, dist, self._why(*clash))
                return
            self._add(name, obj, dist)

    def _skip(self, name: str, dist: str, why: str) -> None:
        self._failed[name] = f"{dist}: clashes: {why}"
        warnings.warn(f"hilbench: {self.what} {name!r} from {dist} skipped: {why}", PluginWarning, stacklevel=5)

    def _load(self) -> None:
        """Load every entry point of the group."""
        if self._loaded:
            return
        with self._lock:
            if self._loaded:
                return
            for name in self._entry_points():
                self._load_one(name)
            self._loaded = True

    def reload(self) -> None:
        """Forget what entry points gave and read them again (after installing a package)."""
        with self._lock:
            for name in [n for n, o in self._origin.items() if o != "<code>"]:
                self._drop(name)
            self._failed.clear()
            self._tried.clear()
            self._eps = None
            self._loaded = False

    # ------------------------------------------------------------------ access

    def register(self, name: str, obj: Any = None, *, replace: bool = False) -> Any:
        """Register ``obj`` under ``name`` in code; usable as a decorator (``@kind.register("x")``).

        Raises :class:`ValueError` when ``name`` is taken (unless ``replace``) or ``obj`` claims what another
        registration holds (a model, a protocol, ...)."""

        def add(o: Any) -> Any:
            self._load()  # every claim known before this one is checked
            with self._lock:
                if name in self._items and not replace:
                    raise ValueError(f"{self.what} {name!r} is registered already (by {self._origin[name]})")
                clash = next(self._clashes(name, o), None)
                if clash is not None:
                    raise ValueError(f"{self.what} {name!r} clashes: {self._why(*clash)}")
                self._drop(name)
                self._add(name, o, "<code>")
            return o

        return add if obj is None else add(obj)

    def unregister(self, name: str) -> None:
        """Remove a registration (tests)."""
        with self._lock:
            self._drop(name)

    def get(self, name: str) -> Any:
        """The object registered as ``name`` (its entry point alone is loaded); raises
        :class:`~hilbench.errors.UsageError` naming the known ones."""
        self._load_one(name)
        try:
            return self._items[name]
        except KeyError:
            pass
        if name in self._failed:
            raise UsageError(f"{self.what} {name!r} could not be loaded ({self._failed[name]})") from None
        known = ", ".join(sorted(self.names())) or "none"
        raise UsageError(f"unknown {self.what} {name!r} (known: {known})") from None

    def __contains__(self, name: object) -> bool:
        """Whether ``name`` is registered (read from the entry points' names: nothing is loaded)."""
        return name in self._items or (name in self._entry_points() and name not in self._failed)

    def names(self) -> list[str]:
        """The registered names, from the entry points' names (nothing is loaded; one that fails to load
        later is skipped then)."""
        eps = self._entry_points()
        with self._lock:
            return [*(n for n in eps if n not in self._failed), *(n for n in self._items if n not in eps)]

    def _ordered(self) -> list[str]:
        """The registered names in order: the entry points' (hilbench's own, then by name), then code's."""
        eps = self._entry_points()
        return [*(n for n in eps if n in self._items), *(n for n in self._items if n not in eps)]

    def items(self) -> list[tuple[str, Any]]:
        """``(name, object)`` of every registration, in order (every entry point is loaded)."""
        self._load()
        with self._lock:
            return [(n, self._items[n]) for n in self._ordered()]

    def values(self) -> list[Any]:
        """Every registered object, in order (every entry point is loaded)."""
        return [obj for _, obj in self.items()]

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def origin(self, name: str) -> str:
        """The distribution that registered ``name`` (``<code>`` for in-code registrations)."""
        if name in self._origin:
            return self._origin[name]
        eps = self._entry_points()
        if name in eps:
            return _dist(eps[name])
        raise KeyError(name)

    def failures(self) -> dict[str, str]:
        """Entry points that could not be loaded: name -> ``"package: error"``."""
        self._load()
        return dict(self._failed)

    def find(self, predicate: Callable[[Any], bool]) -> list[Any]:
        """Registered objects for which ``predicate`` is true, in registration order."""
        return [o for o in self.values() if predicate(o)]


def _family_claims(family: Any) -> Iterator[Claim]:
    yield ("name", family.name)
    for model in family.models:
        yield ("model", model)
    for key in family.default_keys:
        yield ("[defaults] key", key)
    check = type(family).check_table
    for table in family.profile_tables:  # shared only with the same check
        yield ("profile table", table, f"{check.__module__}.{check.__qualname__}")


def _instrument_claims(inst: Any) -> Iterator[Claim]:
    for protocol in (inst.protocol, *getattr(inst, "aliases", ())):
        yield ("protocol", protocol)


def _client_claims(client: Any) -> Iterator[Claim]:
    """A client driver's protocol and aliases, and the options it adds to its role's verb (they share one
    parser with the other clients of that role)."""
    import argparse

    yield from _instrument_claims(client)
    parser = argparse.ArgumentParser(add_help=False)
    client.add_arguments(parser)
    for action in parser._actions:
        for option in action.option_strings:
            yield (f"{client.role} option", option)


def _verb_claims(module: Any) -> Iterator[Claim]:
    # A module is registered once per verb it adds (and once per extension): it shares its verbs with itself.
    for verb in getattr(module, "VERBS", {}):
        yield ("verb", verb, getattr(module, "__name__", repr(module)))


#: Device families (:class:`~hilbench.bench.family.DeviceFamily`), by name; chosen per device model.
families = Kind("families", "hilbench.families", what="device family", claims=_family_claims)
#: Bus kinds (:class:`~hilbench.bench.bus.BusKind`), by endpoint ``protocol``.
bus_kinds = Kind("bus_kinds", "hilbench.bus_kinds", what="bus kind",
                 claims=lambda kind: [("protocol", kind.protocol)])
#: Host-port classes, by endpoint ``type``.
host_ports = Kind("host_ports", "hilbench.host_ports", what="endpoint type")
#: Medium classes, by kind.
media = Kind("media", "hilbench.media", what="medium")
#: Source openers (:class:`~hilbench.transports.sources.SourceOpener`).
sources = Kind("sources", "hilbench.sources", what="source kind")
#: Instruments (:class:`~hilbench.monitor.instrument.Instrument`), by protocol.
instruments = Kind("instruments", "hilbench.instruments", what="instrument", claims=_instrument_claims)
#: Client drivers (:class:`~hilbench.clients.base.ClientDriver`): a device's host side, by protocol.
clients = Kind("clients", "hilbench.clients", what="client driver", claims=_client_claims)
#: Verb modules of the ``hilbench`` command.
verbs = Kind("verbs", "hilbench.verbs", what="verb module", claims=_verb_claims)
#: Fuzz targets (:class:`~hilbench.fuzzing.FuzzTarget`): readers and servers the fuzzer and rough-input tools drive.
fuzz_targets = Kind("fuzz_targets", "hilbench.fuzz_targets", what="fuzz target")
#: Servers a bench can run (``emulate --serve``).
servers = Kind("servers", "hilbench.servers", what="server")
#: Recording formats.
recorders = Kind("recorders", "hilbench.recorders", what="recording format")
#: Profile inferrers (:class:`~hilbench.bench.capture_profile.Inferrer`), by the protocols they read.
inferrers = Kind("inferrers", "hilbench.inferrers", what="profile inferrer",
                 claims=lambda inf: [("protocol", p) for p in inf.protocols])

KINDS: tuple[Kind, ...] = (families, bus_kinds, host_ports, media, sources, instruments, verbs, fuzz_targets,
                            servers, recorders, inferrers, clients)


def reload() -> None:
    """Re-read every entry-point group (after a plug-in package was installed in this process)."""
    global _ENTRY_POINTS
    import importlib

    importlib.invalidate_caches()
    _ENTRY_POINTS = None
    for kind in KINDS:
        kind.reload()


def family_for_model(model: Any) -> Any | None:
    """The device family that knows ``model`` (a ``[[devices]]`` entry's ``model``), else None."""
    for fam in families.values():
        if fam.knows_model(model):
            return fam
    return None


def families_joining(protocol: str) -> list[Any]:
    """The device families whose devices may sit on an endpoint of bus ``protocol``."""
    return [fam for fam in families.values() if protocol in fam.joins]


def instrument_for(protocol: str) -> Any | None:
    """The instrument registered for ``protocol`` (or naming it among its aliases), else None."""
    for inst in instruments.values():
        if protocol == inst.protocol or protocol in getattr(inst, "aliases", ()):
            return inst
    return None


__all__ = ["KINDS", "Claim", "Kind", "PluginWarning", "bus_kinds", "clients", "families", "families_joining",
           "family_for_model", "fuzz_targets", "host_ports", "inferrers", "instrument_for", "instruments", "media",
           "recorders", "reload", "servers", "sources", "verbs"]
