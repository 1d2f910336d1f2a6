"""Per-flow statistics the UDP monitor keeps: sample rates and inter-arrival times, sequence gaps.

Both are O(1) per datagram with bounded memory: a rate keeps the last
:data:`RECENT` arrival times (the recent rate) and running sums (mean and
population standard deviation of the inter-arrival time, Welford), a sequence
tracker keeps counters and a bounded set of recently seen numbers.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

#: Arrival times kept per flow for its recent rate.
RECENT = 64
#: Sequence numbers remembered per reliable stream (to tell retransmissions).
SEEN = 512


class Rate:
    """Arrivals of one flow: count, recent rate, inter-arrival mean / sigma / min / max."""

    __slots__ = ("count", "first", "last", "times", "_n", "_mean", "_m2", "min", "max", "bytes")

    def __init__(self) -> None:
        self.count = 0
        self.first: float | None = None
        self.last: float | None = None
        self.times: deque[float] = deque(maxlen=RECENT)
        self._n = 0
        self._mean = 0.0
        self._m2 = 0.0
        self.min = math.inf
        self.max = 0.0
        self.bytes = 0

    def add(self, t: float, nbytes: int = 0) -> None:
        self.count += 1
        self.bytes += nbytes
        last = self.last
        if last is not None:
            d = t - last
            self._n += 1
            delta = d - self._mean
            self._mean += delta / self._n
            self._m2 += delta * (d - self._mean)
            if d < self.min:
                self.min = d
            if d > self.max:
                self.max = d
        else:
            self.first = t
        self.last = t
        self.times.append(t)

    def rate(self) -> float | None:
        """Arrivals per second over the recent ones (None with fewer than two)."""
        times = self.times
        if len(times) < 2 or times[-1] <= times[0]:
            return None
        return (len(times) - 1) / (times[-1] - times[0])

    def summary(self, timed: bool = True) -> dict[str, Any]:
        out: dict[str, Any] = {"count": self.count}
        if timed and self._n:
            out.update(rate_hz=_round(self.rate()), interval_ms={
                "mean": _round(self._mean * 1e3), "sigma": _round(math.sqrt(self._m2 / self._n) * 1e3),
                "min": _round(self.min * 1e3), "max": _round(self.max * 1e3)})
        return out


def _round(v: float | None, nd: int = 3) -> float | None:
    return None if v is None else round(v, nd)


class SeqStats:
    """Sequence numbers of one stream (u16 serial arithmetic for XRCE, plain integers for RTPS)."""

    __slots__ = ("last", "received", "lost", "duplicates", "late", "retransmissions", "seen", "modulus")

    def __init__(self, modulus: int | None = 65536) -> None:
        self.last: int | None = None
        self.received = 0
        self.lost = 0
        self.duplicates = 0
        self.late = 0
        self.retransmissions = 0
        self.seen: set[int] = set()
        self.modulus = modulus

    def best_effort(self, seq: int) -> None:
        """A best-effort receiver's view (§3.2): gaps are lost, d = 0 duplicate, d >= 32768 late."""
        self.received += 1
        last = self.last
        if last is None:
            self.last = seq
            return
        if self.modulus:
            d = (seq - last) % self.modulus
            if d == 0:
                self.duplicates += 1
            elif d < self.modulus // 2:
                self.lost += d - 1
                self.last = seq
            else:
                self.late += 1
        else:
            d = seq - last
            if d == 0:
                self.duplicates += 1
            elif d > 0:
                self.lost += d - 1
                self.last = seq
            else:
                self.late += 1

    def reliable(self, seq: int) -> bool:
        """A reliable stream: True for a new number, False for a retransmission (a number seen again)."""
        self.received += 1
        if seq in self.seen:
            self.retransmissions += 1
            return False
        seen = self.seen
        seen.add(seq)
        if len(seen) > SEEN:
            seen.pop()
        self.last = seq
        return True

    def summary(self) -> dict[str, Any]:
        return {"received": self.received, "lost": self.lost, "duplicates": self.duplicates, "late": self.late,
                "retransmissions": self.retransmissions, "last": self.last}


__all__ = ["RECENT", "Rate", "SeqStats"]
