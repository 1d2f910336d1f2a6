"""An RTPS domain whose standard unicast ports are free on 127.0.0.1 (tests run side by side on one machine)."""

from __future__ import annotations

import socket

import pytest

from hilbench.protocols import rtps


def free_domain(indices: int = 4) -> int:
    """A domain whose first ``indices`` + 2 participants' unicast ports are all free; tried in random order
    among 100-232, so concurrent test runs on one machine rarely share one (and never domain 0)."""
    import random

    domains = list(range(100, 233))
    random.shuffle(domains)
    for domain in domains:
        socks = []
        try:
            for i in range(indices + 2):
                for kind in ("metatraffic_unicast", "user_unicast"):
                    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                    socks.append(s)
                    s.bind(("127.0.0.1", rtps.ports(domain, i)[kind]))
            return domain
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    pytest.skip("no RTPS domain with free ports on 127.0.0.1")
