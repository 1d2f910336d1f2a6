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
:data:`families`       ``hilbench.families``      a :class:`~hilbench.bench.family.DeviceFamily`
:data:`host_ports`     ``hilbench.host_ports``    a host-port class (endpoint ``type``: pty, udp, tcp)
:data:`media`          ``hilbench.media``         a :class:`~hilbench.transports.medium.Medium` class
:data:`sources`        ``hilbench.sources``       a :class:`~hilbench.transports.sources.SourceOpener`
:data:`instruments`    ``hilbench.instruments``   an :class:`~hilbench.monitor.instrument.Instrument`
:data:`verbs`          ``hilbench.verbs``         a module with ``register(subparsers)``
:data:`fuzz_targets`   ``hilbench.fuzz_targets``  a :class:`~hilbench.fuzzing.FuzzTarget` (fuzzing,
                                                  rough-input benchmarks)
:data:`servers`        ``hilbench.servers``       a :class:`~hilbench.bench.server.Server` (``emulate --serve``)
:data:`recorders`      ``hilbench.recorders``     a recording format: ``accepts(path, protocol)``,
                                                  ``open(path, source=..., description=...)``
:data:`inferrers`      ``hilbench.inferrers``     a :class:`~hilbench.bench.capture_profile.Inferrer`: a
                                                  profile from a capture of its traffic
                                                  (``profiles from-capture``)
=====================  =========================  =============================================

Entry points load on first use of their kind. A plug-in that fails to load
is skipped with one warning naming its package (a lab's broken package must
not take the whole command down); :meth:`Kind.failures` lists them.
Objects can also be registered in code (:meth:`Kind.register`), e.g. by tests.

This module imports nothing from hilbench but :mod:`hilbench.errors`.
"""

from __future__ import annotations

import importlib.metadata
import threading
import warnings
from collections.abc import Callable, Iterator
from typing import Any

from hilbench.errors import UsageError


class PluginWarning(UserWarning):
    """A plug-in package could not be loaded (it is skipped)."""


class Kind:
    """One kind of plug-in: a name -> object table filled from an entry-point group on first use."""

    def __init__(self, name: str, group: str, *, what: str) -> None:
        self.name = name
        self.group = group
        self.what = what  # how an error message names one ("device family", "endpoint type", ...)
        self._items: dict[str, Any] = {}
        self._origin: dict[str, str] = {}
        self._failed: dict[str, str] = {}
        self._loaded = False
        self._lock = threading.RLock()

    # ------------------------------------------------------------------ loading

    def _load(self) -> None:
        if self._loaded:
            return
        with self._lock:
            if self._loaded:
                return
            eps = sorted(importlib.metadata.entry_points(group=self.group),
                         key=lambda ep: (ep.dist is None or ep.dist.name != "hilbench", ep.name))
            for ep in eps:
                dist = ep.dist.name if ep.dist is not None else "?"
                if ep.name in self._items:
                    if self._origin.get(ep.name) != dist:
                        warnings.warn(f"hilbench: {self.what} {ep.name!r} from {dist} ignored: "
                                      f"{self._origin.get(ep.name)} registers it already", PluginWarning,
                                      stacklevel=3)
                    continue
                try:
                    obj = ep.load()
                except Exception as exc:  # noqa: BLE001 (any plug-in failure is reported, not raised)
                    self._failed[ep.name] = f"{dist}: {type(exc).__name__}: {exc}"
                    warnings.warn(f"hilbench: {self.what} {ep.name!r} from {dist} could not be loaded "
                                  f"({type(exc).__name__}: {exc}); skipped", PluginWarning, stacklevel=3)
                    continue
                self._items[ep.name] = obj
                self._origin[ep.name] = dist
            self._loaded = True

    def reload(self) -> None:
        """Forget what entry points gave and read them again (after installing a package)."""
        with self._lock:
            for name in [n for n, o in self._origin.items() if o != "<code>"]:
                self._items.pop(name, None)
                self._origin.pop(name, None)
            self._failed.clear()
            self._loaded = False

    # ------------------------------------------------------------------ access

    def register(self, name: str, obj: Any = None, *, replace: bool = False) -> Any:
        """Register ``obj`` under ``name`` in code; usable as a decorator (``@kind.register("x")``)."""

        def add(o: Any) -> Any:
            self._load()
            with self._lock:
                if name in self._items and not replace:
                    raise ValueError(f"{self.what} {name!r} is registered already (by {self._origin[name]})")
                self._items[name] = o
                self._origin[name] = "<code>"
            return o

        return add if obj is None else add(obj)

    def unregister(self, name: str) -> None:
        """Remove a registration (tests)."""
        with self._lock:
            self._items.pop(name, None)
            self._origin.pop(name, None)

    def get(self, name: str) -> Any:
        """The object registered as ``name``; raises :class:`~hilbench.errors.UsageError` naming the known ones."""
        self._load()
        try:
            return self._items[name]
        except KeyError:
            known = ", ".join(sorted(self._items)) or "none"
            raise UsageError(f"unknown {self.what} {name!r} (known: {known})") from None

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._items

    def names(self) -> list[str]:
        self._load()
        return list(self._items)

    def items(self) -> list[tuple[str, Any]]:
        self._load()
        return list(self._items.items())

    def values(self) -> list[Any]:
        self._load()
        return list(self._items.values())

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def origin(self, name: str) -> str:
        """The distribution that registered ``name`` (``<code>`` for in-code registrations)."""
        self._load()
        return self._origin[name]

    def failures(self) -> dict[str, str]:
        """Entry points that could not be loaded: name -> ``"package: error"``."""
        self._load()
        return dict(self._failed)

    def find(self, predicate: Callable[[Any], bool]) -> list[Any]:
        """Registered objects for which ``predicate`` is true, in registration order."""
        return [o for o in self.values() if predicate(o)]


families = Kind("families", "hilbench.families", what="device family")
host_ports = Kind("host_ports", "hilbench.host_ports", what="endpoint type")
media = Kind("media", "hilbench.media", what="medium")
sources = Kind("sources", "hilbench.sources", what="source kind")
instruments = Kind("instruments", "hilbench.instruments", what="instrument")
verbs = Kind("verbs", "hilbench.verbs", what="verb module")
fuzz_targets = Kind("fuzz_targets", "hilbench.fuzz_targets", what="fuzz target")
servers = Kind("servers", "hilbench.servers", what="server")
recorders = Kind("recorders", "hilbench.recorders", what="recording format")
inferrers = Kind("inferrers", "hilbench.inferrers", what="profile inferrer")

KINDS: tuple[Kind, ...] = (families, host_ports, media, sources, instruments, verbs, fuzz_targets, servers,
                            recorders, inferrers)


def reload() -> None:
    """Re-read every entry-point group (after a plug-in package was installed in this process)."""
    importlib.invalidate_caches()
    for kind in KINDS:
        kind.reload()


def family_for_protocol(protocol: str) -> Any:
    """The device family serving endpoints of ``protocol``; raises UsageError naming the known ones."""
    for fam in families.values():
        if protocol in fam.protocols:
            return fam
    known = sorted(p for f in families.values() for p in f.protocols)
    raise UsageError(f"no device family speaks {protocol!r} (known: {', '.join(known)})")


def instrument_for(protocol: str) -> Any | None:
    """The instrument registered for ``protocol`` (or naming it among its aliases), else None."""
    for inst in instruments.values():
        if protocol == inst.protocol or protocol in getattr(inst, "aliases", ()):
            return inst
    return None


__all__ = ["KINDS", "Kind", "PluginWarning", "families", "family_for_protocol", "fuzz_targets", "host_ports",
           "inferrers", "instrument_for", "instruments", "media", "recorders", "reload", "servers", "sources", "verbs"]
