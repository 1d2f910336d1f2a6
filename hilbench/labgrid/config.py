"""labgrid configuration for a served bench: an exporter configuration and an environment file.

Both are made from a bench's manifest (``hilbench emulate PROFILE --serve
rfc2217 --manifest FILE``) and use only resource classes labgrid knows:

- every endpoint a server serves: what that server's
  :meth:`~hilbench.bench.server.Server.labgrid_resources` says (RFC 2217:
  a ``NetworkSerialPort``, protocol ``rfc2217``, ``speed`` the endpoint's
  baud rate, named after the endpoint);
- each endpoint's traffic tap (``NAME-tap``) and the bench's control channel
  (``control``): TCP byte streams, published as ``NetworkSerialPort`` with
  protocol ``raw``, the closest labgrid class to a plain TCP service
  (``NetworkService`` means an SSH login and requires a user name).

The exporter configuration groups them under the bench's name, so
``labgrid-exporter`` announces ``EXPORTER/BENCH/NetworkSerialPort/NAME`` and a
place matches them with ``add-match 'EXPORTER/BENCH/*'``. The environment
file is the same resources as one target with drivers (labgrid's
``SerialDriver`` per port, hilbench's :mod:`hilbench.labgrid.drivers` on
the control channel and on each endpoint the driver its bus kind names,
:meth:`~hilbench.bench.bus.BusKind.labgrid_driver`), for use without a
coordinator.

This module does not need labgrid; it writes YAML with PyYAML when that is
installed (labgrid depends on it) and JSON, which YAML readers accept, otherwise.
"""

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any

from hilbench import registry
from hilbench.errors import UsageError
from hilbench.transports.host_port import url_host

#: Resource names besides the endpoints'.
CONTROL_RESOURCE = "control"
TAP_SUFFIX = "-tap"
#: The module an environment imports to register hilbench's generic labgrid drivers (bus kinds name theirs).
DRIVERS_MODULE = "hilbench.labgrid.drivers"


def load_manifest(path: str | Path) -> dict[str, Any]:
    """A running bench's manifest (:func:`~hilbench.bench.manifest.read_manifest`: one-line errors, exit status
    2 for a file that is not one, 1 for a bench that is not running), with the name labgrid's groups take."""
    from hilbench.bench.manifest import ManifestError, read_manifest

    data = read_manifest(path)
    if not isinstance(data.get("name"), str):
        raise ManifestError(f"{path}: not a bench manifest (no name)")
    return data


def _hostport(address: str) -> tuple[str, int]:
    """``tcp://H:P``, ``H:P`` -> (H, P)."""
    address = address.split("://", 1)[-1].rstrip("/")
    host, _, port = address.rpartition(":")
    return host.strip("[]"), int(port)


def published_host(bind_host: str, host: str | None) -> str:
    """The host labgrid clients are told: ``host`` if given, else where the bench listens.

    A wildcard bind has no single address: the machine's name stands for it.
    """
    if host:
        return host
    if url_host(bind_host) != bind_host:
        return socket.getfqdn()
    return bind_host


def bench_resources(manifest: dict[str, Any], host: str | None = None) -> dict[str, dict[str, Any]]:
    """Resource name -> ``{"cls": ..., params}`` for everything the bench serves; UsageError if nothing."""
    resources: dict[str, dict[str, Any]] = {}

    def add(name: str, entry: dict[str, Any]) -> None:
        if name in resources:
            raise UsageError(f"bench {manifest['name']!r}: two labgrid resources would be named {name!r}")
        resources[name] = entry

    for ep in manifest["endpoints"]:
        for _, server in registry.servers.items():
            key = server.manifest_key
            if not ep.get(key):
                continue
            ep_host, _ = _hostport(ep[key])
            where = published_host(ep.get(f"{key}_bind") or ep_host, host)
            for name, entry in server.labgrid_resources(manifest, ep, where).items():
                add(name, entry)
    if not resources:
        raise UsageError(f"bench {manifest['name']!r} serves no endpoint over the network "
                         "(start it with hilbench emulate --serve rfc2217)")
    for ep in manifest["endpoints"]:
        if ep.get("tap"):
            tap_host, tap_port = _hostport(ep["tap"])
            add(ep["name"] + TAP_SUFFIX, _raw(published_host(tap_host, host), tap_port, ep.get("baud")))
    if manifest.get("control"):
        ctl_host, ctl_port = _hostport(manifest["control"])
        add(CONTROL_RESOURCE, _raw(published_host(ctl_host, host), ctl_port, None))
    return resources


def _raw(host: str, port: int, baud: int | None) -> dict[str, Any]:
    return {"cls": "NetworkSerialPort", "host": host, "port": port, "speed": int(baud or 115_200),
            "protocol": "raw"}


def exporter_config(manifest: dict[str, Any], host: str | None = None) -> dict[str, Any]:
    """labgrid-exporter's configuration: one group named after the bench."""
    return {manifest["name"]: bench_resources(manifest, host)}


def environment(manifest: dict[str, Any], host: str | None = None, target: str = "main") -> dict[str, Any]:
    """A labgrid environment: one target with the bench's resources, a SerialDriver on each, and
    hilbench's drivers (on each endpoint the one its bus kind names, e.g. a DynamixelDriver; a
    BenchControlDriver on the control channel) bound by name."""
    resources = bench_resources(manifest, host)
    endpoints = {ep["name"]: ep for ep in manifest["endpoints"]}
    res_list, drivers, imports = [], [], [DRIVERS_MODULE]
    for name, entry in resources.items():
        params = {k: v for k, v in entry.items() if k != "cls"}
        res_list.append({entry["cls"]: {"name": name, **params}})
        if entry["cls"] != "NetworkSerialPort" or name.endswith(TAP_SUFFIX):
            continue  # a tap is read with `hilbench monitor`, not through a console
        console = f"{name}-console"
        drivers.append({"SerialDriver": {"name": console, "bindings": {"port": name}}})
        if name == CONTROL_RESOURCE:
            drivers.append({"BenchControlDriver": {"name": "bench-control", "bindings": {"console": console}}})
        elif name in endpoints and (driver := _bus_driver(endpoints[name])) is not None:
            drivers.append({driver.cls: {"name": f"{name}{driver.suffix}", "bindings": {"console": console}}})
            if driver.module not in imports:
                imports.append(driver.module)
    return {"targets": {target: {"resources": res_list, "drivers": drivers}}, "imports": imports}


def _bus_driver(endpoint: dict[str, Any]):
    """The labgrid driver the endpoint's bus kind puts on its console (None: none, or no such bus kind here)."""
    protocol = endpoint.get("protocol")
    if not isinstance(protocol, str) or protocol not in registry.bus_kinds:
        return None
    return registry.bus_kinds.get(protocol).labgrid_driver(endpoint)


def dump(data: dict[str, Any], comment: str = "") -> str:
    """YAML text (JSON if PyYAML is missing, which YAML readers take as well), with a leading comment.

    Comments start with ``##``: labgrid renders an exporter configuration with jinja2, where a line
    starting with a single ``#`` is a template statement.
    """
    head = "".join(f"## {line}\n" for line in comment.splitlines())
    try:
        import yaml
    except ImportError:
        return head + json.dumps(data, indent=2) + "\n"
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=False)


__all__ = ["CONTROL_RESOURCE", "DRIVERS_MODULE", "TAP_SUFFIX", "bench_resources", "dump", "environment",
           "exporter_config", "load_manifest", "published_host"]
