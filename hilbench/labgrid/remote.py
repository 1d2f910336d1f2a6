"""A bench taken from a labgrid target instead of started here (a place acquired through a coordinator,
or an environment file from ``hilbench labgrid env``).

:func:`bench_from_target` reads the target's ``NetworkSerialPort`` resources
(through labgrid's proxy manager, so SSH proxying applies), asks the bench's
control channel for its manifest, and returns a :class:`RemoteBench` with the
parts of :class:`~hilbench.bench.Bench` a test uses from outside:
``endpoint(name).path``, ``manifest()``, ``control``. Each endpoint's
``path`` is a local pseudo-terminal bridged to its RFC 2217 port (opened on
first use), so a test that hands ``bench.endpoint().path`` to an unmodified
client (the official SDK's PortHandler) runs unchanged against a remote
bench; the baud rate a client sets on that pty is passed on with
SET-BAUDRATE. ``endpoint(name).url`` is the RFC 2217 URL itself.
The devices' Python objects stay on the bench machine:
:meth:`RemoteBench.device` says so instead of pretending.
"""

from __future__ import annotations

import contextlib
import threading
from types import SimpleNamespace
from typing import Any

import serial

from hilbench.bench.control import ControlClient
from hilbench.errors import BenchError
from hilbench.labgrid.config import CONTROL_RESOURCE, TAP_SUFFIX
from hilbench.transports.pty import PtyPort
from hilbench.transports.readiness import readable
from hilbench.transports.serial_url import open_url


class PtyBridge:
    """A local pty whose bytes go to and come from an RFC 2217 URL; the pty client's baud rate follows."""

    def __init__(self, url: str, baud: int | None) -> None:
        self.url = url
        self.pty = PtyPort("bridge")
        self.serial = open_url(url, baudrate=baud or 115_200, timeout=0.05)
        self._stop = threading.Event()
        self.errors: list[str] = []
        self._threads = [threading.Thread(target=self._up, name="pty-bridge-up", daemon=True),
                         threading.Thread(target=self._down, name="pty-bridge-down", daemon=True)]
        for t in self._threads:
            t.start()

    @property
    def path(self) -> str:
        return self.pty.path

    def _up(self) -> None:
        """pty -> remote: follow the client's baud rate before forwarding what it wrote."""
        try:
            while not self._stop.is_set():
                ready = readable([self.pty.master_fd], 0.05)
                baud = self.pty.client_baud()
                if baud and baud != self.serial.baudrate:
                    self.serial.baudrate = baud
                if ready and (data := self.pty.read()):
                    self.serial.write(data)
        except (OSError, serial.SerialException, ValueError) as exc:
            if not self._stop.is_set():
                self.errors.append(f"to {self.url}: {exc}")

    def _down(self) -> None:
        """remote -> pty."""
        try:
            while not self._stop.is_set():
                data = self.serial.read(max(1, self.serial.in_waiting))
                if data:
                    self.pty.write(data)
        except (OSError, serial.SerialException) as exc:
            if not self._stop.is_set():
                self.errors.append(f"from {self.url}: {exc}")

    def close(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=2)
        with contextlib.suppress(Exception):
            self.serial.close()
        self.pty.close()


class RemoteEndpoint:
    """An endpoint of a remote bench: ``url`` (RFC 2217), ``path`` (a local pty bridged to it), ``tap``."""

    def __init__(self, entry: dict[str, Any], url: str | None, tap: str | None) -> None:
        self.entry = entry
        self.name: str = entry["name"]
        self.url = url
        self.tap_url = tap
        self.spec = SimpleNamespace(name=self.name, baud=entry.get("baud"), protocol=entry.get("protocol"),
                                    type=entry.get("type"))
        self._bridge: PtyBridge | None = None

    @property
    def path(self) -> str:
        """A local pty any serial client can open; bridged to the remote endpoint on first use."""
        if self.url is None:
            raise BenchError(f"endpoint {self.name!r} of the remote bench is not served over RFC 2217")
        if self._bridge is None:
            self._bridge = PtyBridge(self.url, self.spec.baud)
        return self._bridge.path

    def close(self) -> None:
        if self._bridge is not None:
            self._bridge.close()
            self._bridge = None

    def __repr__(self) -> str:
        return f"RemoteEndpoint({self.name!r}, {self.url})"


class RemoteBench:
    """A running bench on another machine (or process), reached through labgrid resources."""

    remote = True

    def __init__(self, manifest: dict[str, Any], endpoints: dict[str, RemoteEndpoint],
                 control: ControlClient | None, where: str) -> None:
        self._manifest = manifest
        self.endpoints = endpoints
        self.control = control
        self.where = where
        self.profile = SimpleNamespace(name=manifest["name"], path=manifest.get("profile"))

    def endpoint(self, name: str | None = None) -> RemoteEndpoint:
        """An endpoint by name (or the only one)."""
        if name is None:
            if len(self.endpoints) != 1:
                raise KeyError(f"bench has endpoints {list(self.endpoints)}; name one")
            return next(iter(self.endpoints.values()))
        return self.endpoints[name]

    def manifest(self) -> dict[str, Any]:
        """The bench's manifest, with each endpoint's ``rfc2217`` and ``tap`` as this machine reaches them."""
        out = dict(self._manifest)
        out["endpoints"] = [dict(e, rfc2217=self.endpoints[e["name"]].url, tap=self.endpoints[e["name"]].tap_url)
                            for e in self._manifest["endpoints"]]
        return out

    def device(self, name_or_address: str | int, endpoint: str | None = None) -> Any:
        raise BenchError(f"bench {self.profile.name!r} runs remotely ({self.where}): its devices are not objects "
                         "in this process; use bench.control or the wire")

    def family(self, name: str) -> Any:
        """As :meth:`device`: a family's devices live on the bench's machine."""
        return self.device(name)

    def stop(self) -> None:
        for ep in self.endpoints.values():
            ep.close()

    close = stop


def bench_from_target(target: Any) -> RemoteBench:
    """The bench whose resources ``target`` holds (``NetworkSerialPort`` named after endpoints, ``control``)."""
    from labgrid.resource import NetworkSerialPort
    from labgrid.util.proxy import proxymanager

    ports = {r.name: r for r in target.resources if isinstance(r, NetworkSerialPort)}
    if CONTROL_RESOURCE not in ports:
        raise BenchError(f"labgrid target {target.name!r} has no {CONTROL_RESOURCE!r} NetworkSerialPort "
                         "(expected a bench published with hilbench labgrid exporter-config / env)")

    def address(name: str) -> tuple[str, int]:
        res = ports[name]
        target.await_resources([res], timeout=10.0)
        host, port = proxymanager.get_host_and_port(res)
        return host, int(port)

    host, port = address(CONTROL_RESOURCE)
    control = ControlClient((host, port))
    manifest = control.manifest()
    endpoints = {}
    for entry in manifest["endpoints"]:
        name = entry["name"]
        url = tap = None
        if name in ports and ports[name].protocol == "rfc2217":
            h, p = address(name)
            url = f"rfc2217://{h}:{p}"
        if name + TAP_SUFFIX in ports:
            h, p = address(name + TAP_SUFFIX)
            tap = f"tcp://{h}:{p}"
        endpoints[name] = RemoteEndpoint(entry, url, tap)
    return RemoteBench(manifest, endpoints, control, f"labgrid target {target.name!r}")


__all__ = ["PtyBridge", "RemoteBench", "RemoteEndpoint", "bench_from_target"]
