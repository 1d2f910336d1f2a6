"""Servers: ways to reach a running bench's endpoints from other machines (RFC 2217, socketcand, ...).

A server is a :class:`Server` registered in the ``hilbench.servers``
entry-point group under the name ``hilbench emulate --serve NAME`` uses::

    [project.entry-points."hilbench.servers"]
    rfc2217 = "hilbench.transports.rfc2217:SERVER"

For each endpoint it :meth:`~Server.serves`, :meth:`~Server.start` returns a
running :class:`Service` (usually a second host port on the endpoint's
medium, so pacing, taps and devices need nothing new). The bench lists what
:meth:`Service.describe` returns in the endpoint's manifest entry (e.g.
``"rfc2217": "rfc2217://127.0.0.1:PORT"``) and closes the service when it
stops. :meth:`Server.labgrid_resources` says how ``hilbench labgrid
exporter-config`` publishes such an endpoint (labgrid resource classes only).
Nothing here knows a server by name.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from hilbench.transports.host_port import DEFAULT_BIND, is_loopback, url_host

if TYPE_CHECKING:
    from hilbench.bench.bench import Bench, Endpoint



class Service(Protocol):
    """A running server for one endpoint."""

    def describe(self) -> dict[str, Any]:
        """Fields for the endpoint's manifest entry (``{"rfc2217": "rfc2217://127.0.0.1:4000"}``)."""

    def close(self) -> None:
        """Stop serving and release the socket."""


class Server:
    """Base class of servers; subclasses set :attr:`name` and implement :meth:`serves` and :meth:`start`."""

    #: The name ``--serve`` takes (and the entry-point name).
    name: ClassVar[str] = ""
    #: One line for ``--help``.
    help: ClassVar[str] = ""
    #: The manifest key its services add to an endpoint entry.
    manifest_key: ClassVar[str] = ""

    def serves(self, endpoint: Endpoint) -> bool:
        """Whether this server can serve ``endpoint`` (e.g. a byte stream with modem lines)."""
        raise NotImplementedError

    def start(self, bench: Bench, endpoint: Endpoint, bind: str = DEFAULT_BIND) -> Service:
        """Start serving ``endpoint`` on ``bind`` (a free port); returns the running service."""
        raise NotImplementedError

    def labgrid_resources(self, bench: dict[str, Any], endpoint: dict[str, Any], host: str) -> dict[str, dict]:
        """labgrid resources publishing a served endpoint: resource name -> ``{"cls": ..., params}``.

        ``bench`` and ``endpoint`` are manifest entries; ``host`` is the address clients use.
        Every ``cls`` must be a class labgrid knows. The default publishes nothing.
        """
        return {}


__all__ = ["DEFAULT_BIND", "Server", "Service", "is_loopback", "url_host"]
