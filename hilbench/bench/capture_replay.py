"""``--verify``: replay a capture's host requests against the bench a generated profile describes.

An inferrer hands the core a :class:`Replay`: the host's requests in capture
order, each with the replies the capture shows (:class:`Exchange`,
:class:`Expected`). :meth:`Replay.run` sends the requests to a running bench
at the captured pace (``speed`` 1.0; None: as fast as the bench answers) and
compares what comes back: the same device, the same length, and the same
bytes where the state can be the same (an :class:`Expected`'s ``mask`` says
which bytes: a position that moved under the bench's motion model is compared
by length only). :class:`SerialReplay` does it on a serial endpoint (a pty),
:class:`FrameReplay` on a CAN endpoint (frames in and out through python-can's
virtual interface), where it also checks the periodic frames the capture
shows (:class:`Stream`: heartbeats, PDOs) for their period and length.
"""

from __future__ import annotations

import os
import queue
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from hilbench.transports.readiness import readable

#: Mismatches kept for the report (the first ones).
MAX_SHOWN = 10
#: How long a reply the capture shows may take beyond its wire time once the bench has left requests unanswered
#: (a profile that does not answer as the capture did must not make the replay crawl).
REPLY_TIMEOUT = 0.05
#: The same while the bench has been answering: a bench thread waking up late on a loaded machine (the first
#: request after start-up, a helper process taking both cores) is no missing reply. A reply that comes ends
#: the wait at once, so this only costs time where replies are really missing.
PATIENT_TIMEOUT = 1.0
#: How long to listen after a request the capture shows no reply to (the bench might answer it anyway).
QUIET = 0.0005


@dataclass(frozen=True)
class Expected:
    """A reply the capture shows: who sent it, its bytes, and which of them must match (``mask``: 0xFF where
    the byte is compared; None: the length only)."""

    device: Any
    raw: bytes
    mask: bytes | None = None


@dataclass(frozen=True)
class Exchange:
    """A host request at capture time ``t`` and the replies the capture shows to it, in order."""

    t: float
    request: bytes
    expected: tuple[Expected, ...]
    label: str
    #: Wire time of the request and its replies at the bus's rate (s), added to the reply timeout.
    wire: float = 0.0


class Splitter(Protocol):
    """Splits what the bench sends back into ``(device, raw packet)`` pairs (keeps partial packets)."""

    def feed(self, data: bytes) -> list[tuple[Any, bytes]]: ...


@dataclass
class VerifyReport:
    """How the bench's replies compare with the captured ones."""

    endpoint: str
    requests: int = 0
    #: Captured replies to the replayed requests (the denominator).
    replies: int = 0
    matched_content: int = 0
    matched_length: int = 0
    different: int = 0
    missing: int = 0
    #: Replies the bench gave where the capture shows none (not counted against the ratio).
    extra: int = 0
    seconds: float = 0.0
    span: float | None = None
    mismatches: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def matched(self) -> int:
        return self.matched_content + self.matched_length

    @property
    def ratio(self) -> float:
        return self.matched / self.replies if self.replies else 1.0

    def mismatch(self, text: str) -> None:
        if len(self.mismatches) < MAX_SHOWN:
            self.mismatches.append(text)

    def lines(self) -> list[str]:
        """The report as a person reads it."""
        out = [f"verify {self.endpoint}: {self.matched} of {self.replies} captured replies match "
               f"({100 * self.ratio:.1f} %) after {self.requests} replayed requests: {self.matched_content} "
               f"by content, {self.matched_length} by length where values move"]
        if self.different or self.missing or self.extra:
            out.append(f"  different {self.different}, missing {self.missing}, extra {self.extra} (the bench "
                       "answered where the capture shows no reply)")
        took = f"  took {self.seconds:.2f} s"
        if self.span is not None:
            took += f" (the capture spans {self.span:.2f} s)"
        out.append(took)
        out += [f"  {note}" for note in self.notes]
        if self.mismatches:
            out.append("  first mismatches:")
            out += [f"    {m}" for m in self.mismatches]
        return out

    def to_json(self) -> dict[str, Any]:
        return {"endpoint": self.endpoint, "requests": self.requests, "replies": self.replies,
                "matched": self.matched, "matched_content": self.matched_content,
                "matched_length": self.matched_length, "different": self.different, "missing": self.missing,
                "extra": self.extra, "ratio": round(self.ratio, 4), "seconds": round(self.seconds, 3),
                "mismatches": self.mismatches, "notes": self.notes}


class Patience:
    """How long to wait for the replies the capture shows: :data:`PATIENT_TIMEOUT` while the bench answers,
    :data:`REPLY_TIMEOUT` after an exchange where some of them did not come (until all of one exchange's come)."""

    def __init__(self) -> None:
        self.answering = True

    def timeout(self) -> float:
        return PATIENT_TIMEOUT if self.answering else REPLY_TIMEOUT

    def saw(self, wanted: int, got: int) -> None:
        if wanted:
            self.answering = got >= wanted


class Replay(Protocol):
    """What an inferrer hands ``--verify``."""

    def run(self, bench: Any, *, speed: float | None = 1.0) -> VerifyReport: ...


def compare(report: VerifyReport, ex: Exchange, got: list[tuple[Any, bytes]], name: Callable[[Any], str]) -> None:
    """Count one exchange's replies into ``report``: each expected reply against the first unused reply from
    the same device."""
    used = [False] * len(got)
    for exp in ex.expected:
        report.replies += 1
        k = next((i for i, (dev, _) in enumerate(got) if not used[i] and dev == exp.device), None)
        if k is None:
            report.missing += 1
            report.mismatch(f"{ex.label}: no reply from {name(exp.device)} (captured {len(exp.raw)} bytes: "
                            f"{exp.raw.hex(' ')})")
            continue
        used[k] = True
        raw = got[k][1]
        if len(raw) != len(exp.raw):
            report.different += 1
            report.mismatch(f"{ex.label}: {name(exp.device)} sent {len(raw)} bytes, the capture {len(exp.raw)}: "
                            f"{raw.hex(' ')} / {exp.raw.hex(' ')}")
        elif exp.mask is None:
            report.matched_length += 1
        elif all((a ^ b) & m == 0 for a, b, m in zip(raw, exp.raw, exp.mask, strict=True)):
            if 0 in exp.mask:
                report.matched_length += 1  # the rest of its bytes matched
            else:
                report.matched_content += 1
        else:
            report.different += 1
            report.mismatch(f"{ex.label}: {name(exp.device)} sent {raw.hex(' ')}, the capture {exp.raw.hex(' ')}")
    report.extra += used.count(False)


class SerialReplay:
    """A capture's exchanges replayed on a serial endpoint of a bench (its pty, opened as a host would)."""

    def __init__(self, endpoint: str, exchanges: list[Exchange], splitter: Callable[[], Splitter], *,
                 name: Callable[[Any], str] = lambda dev: f"ID {dev}", span: float | None = None,
                 notes: list[str] | None = None, t0: float | None = None) -> None:
        self.endpoint = endpoint
        #: The capture's start: the first request waits as long after it as it came in the capture.
        self.t0 = t0
        self.exchanges = exchanges
        self.splitter = splitter
        self.name = name
        self.span = span
        self.notes = list(notes or [])

    def run(self, bench: Any, *, speed: float | None = 1.0) -> VerifyReport:
        """Send every request at its captured time (divided by ``speed``; None: at once after the previous
        exchange) to ``bench``'s endpoint and compare the replies."""
        import serial

        ep = bench.endpoint(self.endpoint)
        report = VerifyReport(self.endpoint, span=self.span, notes=list(self.notes))
        port = serial.Serial(ep.path, baudrate=ep.spec.baud or 9600, timeout=0)
        split = self.splitter()
        fd = port.fileno()
        patience = Patience()
        started = time.monotonic()
        try:
            port.reset_input_buffer()
            t0 = self.t0 if self.t0 is not None else self.exchanges[0].t if self.exchanges else 0.0
            for k, ex in enumerate(self.exchanges):
                if speed is not None:
                    wait = started + (ex.t - t0) / speed - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                os.write(fd, ex.request)
                report.requests += 1
                now = time.monotonic()
                if ex.expected:
                    deadline = now + patience.timeout() + ex.wire
                else:  # listen until the next request is due, briefly
                    nxt = self.exchanges[k + 1].t if k + 1 < len(self.exchanges) else ex.t
                    due = started + (nxt - t0) / speed if speed is not None else now
                    deadline = min(max(due, now + QUIET), now + QUIET + ex.wire)
                got = _collect(fd, split, len(ex.expected), deadline)
                patience.saw(len(ex.expected), len(got))
                compare(report, ex, got, self.name)
        finally:
            port.close()
        report.seconds = time.monotonic() - started
        return report


def _collect(fd: int, split: Splitter, wanted: int, deadline: float) -> list[tuple[Any, bytes]]:
    """Replies read from ``fd`` until ``wanted`` arrived (0: until ``deadline``) or ``deadline`` passed."""
    got: list[tuple[Any, bytes]] = []
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or (wanted and len(got) >= wanted):
            return got
        if not readable([fd], left):
            return got
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            continue
        except OSError:  # the bench went away
            return got
        if data:
            got.extend(split.feed(data))


@dataclass(frozen=True)
class Stream:
    """A frame the capture shows at a steady period: its identifier, period (s), length, and payload where it
    never changed (None: compared by length)."""

    can_id: int
    period: float
    length: int
    data: bytes | None
    label: str


#: How long a CAN replay waits for the bench to be as the capture found the bus (nodes booted).
READY_TIMEOUT = 2.0
#: A stream's period on the bench may differ from the captured one by this share (or 2 ms).
PERIOD_TOLERANCE = 0.1


class FrameReplay:
    """A capture's exchanges replayed on a CAN endpoint of a bench: each request a 16-byte frame record
    (:mod:`hilbench.protocols.can_frame`), each expected reply the data of a frame from identifier ``device``;
    the periodic :class:`Stream` s are compared after the replay (each counts as one reply)."""

    def __init__(self, endpoint: str, exchanges: list[Exchange], streams: list[Stream], *,
                 span: float | None = None, notes: list[str] | None = None, settle: float = 0.0,
                 t0: float | None = None, ready: Callable[[Any], bool] | None = None) -> None:
        self.endpoint = endpoint
        #: Whether the bench is as the capture found the bus (its nodes booted when the capture starts after
        #: their boot-up): the replay's clock starts once it is true (at most :data:`READY_TIMEOUT`).
        self.ready = ready
        #: The capture's start: the first request waits as long after it as it came in the capture.
        self.t0 = t0
        self.exchanges = exchanges
        self.streams = streams
        self.span = span
        self.notes = list(notes or [])
        #: Seconds to keep listening after the last request (so the slowest stream shows its period).
        self.settle = settle

    def run(self, bench: Any, *, speed: float | None = 1.0) -> VerifyReport:
        import can

        from hilbench.protocols import can_frame as cf
        from hilbench.transports.can_messages import to_frame, to_message

        ep = bench.endpoint(self.endpoint)
        channel = ep.port.open_virtual()
        bus = can.Bus(interface="virtual", channel=channel)
        report = VerifyReport(self.endpoint, span=self.span, notes=list(self.notes))
        frames: queue.Queue = queue.Queue()
        seen: dict[int, list[tuple[float, bytes]]] = {}
        stop = threading.Event()

        def receive() -> None:
            while not stop.is_set():
                msg = bus.recv(0.05)
                if msg is None:
                    continue
                frame = to_frame(msg)
                if frame is None or frame.error:
                    continue
                now = time.monotonic()
                frames.put((frame.can_id, frame.data))
                times = seen.setdefault(frame.can_id, [])
                if len(times) < 100_000:
                    times.append((now, frame.data))

        thread = threading.Thread(target=receive, name="verify-can", daemon=True)
        thread.start()
        if self.ready is not None:
            end = time.monotonic() + READY_TIMEOUT
            while not self.ready(bench) and time.monotonic() < end:
                time.sleep(0.002)
        patience = Patience()
        started = time.monotonic()
        try:
            t0 = self.t0 if self.t0 is not None else self.exchanges[0].t if self.exchanges else 0.0
            for ex in self.exchanges:
                if speed is not None:
                    wait = started + (ex.t - t0) / speed - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                wanted = {e.device for e in ex.expected}
                while not frames.empty():  # what came before this request is no reply to it
                    frames.get_nowait()
                bus.send(to_message(cf.unpack(ex.request)))
                report.requests += 1
                got: list[tuple[Any, bytes]] = []
                deadline = time.monotonic() + patience.timeout() + ex.wire
                while len(got) < len(ex.expected):
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    try:
                        can_id, data = frames.get(timeout=left)
                    except queue.Empty:
                        break
                    if can_id in wanted:
                        got.append((can_id, data))
                patience.saw(len(ex.expected), len(got))
                compare(report, ex, got, lambda dev: f"0x{dev:03X}")
            longest = max((s.period for s in self.streams), default=0.0)
            end = time.monotonic() + max(self.settle, 3 * longest) if self.streams else time.monotonic()
            while time.monotonic() < end:
                time.sleep(min(0.05, max(0.0, end - time.monotonic())))
        finally:
            stop.set()
            thread.join(timeout=2)
            bus.shutdown()
        for st in self.streams:
            self._stream(report, st, seen.get(st.can_id, []))
        report.seconds = time.monotonic() - started
        return report

    @staticmethod
    def _stream(report: VerifyReport, st: Stream, times: list[tuple[float, bytes]]) -> None:
        report.replies += 1
        if len(times) < 3:
            report.missing += 1
            report.mismatch(f"{st.label}: {len(times)} frame(s) on the bench, the capture shows one every "
                            f"{1e3 * st.period:.1f} ms")
            return
        intervals = [b[0] - a[0] for a, b in zip(times, times[1:], strict=False)]
        period = statistics.median(intervals)
        lengths = {len(d) for _, d in times}
        if abs(period - st.period) > max(PERIOD_TOLERANCE * st.period, 0.002) or lengths != {st.length}:
            report.different += 1
            report.mismatch(f"{st.label}: every {1e3 * period:.1f} ms with {sorted(lengths)} bytes on the bench, "
                            f"every {1e3 * st.period:.1f} ms with {st.length} in the capture")
        elif st.data is not None and any(d != st.data for _, d in times):
            report.different += 1
            report.mismatch(f"{st.label}: the bench sent {times[-1][1].hex(' ')}, the capture always "
                            f"{st.data.hex(' ')}")
        elif st.data is None:
            report.matched_length += 1
        else:
            report.matched_content += 1


__all__ = ["Exchange", "Expected", "FrameReplay", "Replay", "SerialReplay", "Splitter", "Stream", "VerifyReport",
           "compare"]
