"""The Hokuyo SCIP 2.0 host side: :class:`~hilbench.clients.scip2.ScipDriver` and its ``hilbench lidar`` client.

Registered as ``hilbench.clients`` entry point ``scip2`` (:data:`CLIENT`, alias
``scip``); a ``HOST:PORT`` source with no ``--protocol`` is taken to be a SCIP
unit on Ethernet (a UST-10LX).
"""

from __future__ import annotations

import contextlib

from hilbench.clients.scanners import ScannerClient, ScannerDriver


class ScipDriver(ScannerDriver):
    """PP (the unit's steps), BM, MD over the whole field; QT stops."""

    protocol = "scip2"

    def start(self) -> None:
        from hilbench.protocols import scip

        tr = self.tracker
        replies = tr.replies
        self.send(b"PP\n")
        self.wait_for(lambda: tr.replies > replies, 2.0)
        p = tr.params
        self.send(b"BM\n")
        self.send(scip.request("MD", {"start": p["AMIN"], "end": p["AMAX"], "cluster": 0, "skip": 0, "scans": 0}))

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            self.send(b"QT\n")


class ScipClient(ScannerClient):
    """Hokuyo SCIP 2.0 host: PP, BM, MD over the whole field."""

    protocol = "scip2"
    aliases = ("scip",)
    title = "Hokuyo SCIP 2.0 host"
    driver = ScipDriver
    default_on = ("tcp",)  # HOST:PORT and nothing else said: a SCIP unit on Ethernet


#: The client driver this module registers (entry point ``hilbench.clients``).
CLIENT = ScipClient()

__all__ = ["CLIENT", "ScipClient", "ScipDriver"]
