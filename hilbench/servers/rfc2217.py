"""``--serve rfc2217``: every serial endpoint of a bench as an RFC 2217 port (:mod:`hilbench.transports.rfc2217`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hilbench import __version__
from hilbench.bench.server import DEFAULT_BIND, Server

if TYPE_CHECKING:  # imported when a port starts: `emulate --help` lists this server without the protocol
    from hilbench.transports.rfc2217 import Rfc2217Port


class Rfc2217Server(Server):
    """``--serve rfc2217``: an :class:`Rfc2217Port` on every serial endpoint (a byte stream with modem lines)."""

    name = "rfc2217"
    help = "every serial endpoint as an RFC 2217 port (pyserial rfc2217://, labgrid NetworkSerialPort)"
    manifest_key = "rfc2217"

    def serves(self, endpoint: Any) -> bool:
        port = endpoint.port
        return getattr(port, "port_state", None) is not None and getattr(port, "carries", "bytes") == "bytes"

    def start(self, bench: Any, endpoint: Any, bind: str = DEFAULT_BIND) -> Rfc2217Port:
        from hilbench.transports.rfc2217 import Rfc2217Port

        port = Rfc2217Port(f"{endpoint.name}:rfc2217", endpoint.port.port_state, endpoint.medium, bind=bind,
                           baud=endpoint.spec.baud,
                           signature=f"hilbench {__version__} bench {bench.profile.name} endpoint {endpoint.name}")
        endpoint.medium.add_host(port)
        return port

    def labgrid_resources(self, bench: dict[str, Any], endpoint: dict[str, Any], host: str) -> dict[str, dict]:
        """A ``NetworkSerialPort`` (protocol rfc2217) named after the endpoint, ``speed`` its baud rate.

        labgrid's SerialDriver sets the line to ``speed`` on open, so leaving it out would move a
        2 Mbaud bus to labgrid's default 115200.
        """
        url = endpoint.get(self.manifest_key)
        if not url:
            return {}
        port = int(url.rsplit(":", 1)[1])
        return {endpoint["name"]: {"cls": "NetworkSerialPort", "host": host, "port": port,
                                   "speed": int(endpoint.get("baud") or 115_200), "protocol": "rfc2217"}}


SERVER = Rfc2217Server()

__all__ = ["SERVER", "Rfc2217Server"]
