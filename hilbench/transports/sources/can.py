"""CAN sources: live buses through python-can (socketcand, SLCAN, SocketCAN, virtual) and python-can log files.

Every CAN source yields chunks of 16-byte SocketCAN frame records
(:mod:`hilbench.protocols.can_frame`) and says ``protocol = "can"``, so the
monitor, the recorder and captures treat them like any other source.

==============================================  ======================================================
source string                                   what it opens
==============================================  ======================================================
``socketcand://HOST:PORT/CHANNEL[?bitrate=N]``  a socketcand server (a bench's, or the linux-can daemon)
``slcan:///dev/ttyACM0[?bitrate=N]``            a LAWICEL adapter (or a bench's SLCAN pty); also
                                                ``slcan://socket://HOST:PORT``
``socketcan://vcan0``                           a kernel CAN interface (where the kernel has AF_CAN)
``virtual://CHANNEL``                           a python-can virtual channel in this process
``run.asc``, ``run.blf``, ``run.trc``,          python-can's log readers (a ``.log`` that is not candump
``run.csv``, ``run.log``                        text is read as any other file); the text formats also
(candump ``-L``)                                gzipped (``run.log.gz``, as ``hilbench record`` writes them)
==============================================  ======================================================

A candump log is read line by line (:class:`CandumpLogSource`): a damaged
line is skipped and counted, a last line cut by a killed recorder reported,
and reading goes on, where python-can's readers (the other formats) stop at
the first bad record.

Live buses stamp frames with Unix time (what socketcand and python-can give);
``bitrate`` only tells the monitor the bus load's reference.
"""

from __future__ import annotations

import logging
import re
import struct
import threading
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlparse

from hilbench.protocols import can_frame as cf
from hilbench.transports.can_log import log_suffix
from hilbench.transports.chunk import Chunk, sound_quality
from hilbench.transports.sources.base import (
    PushSource,
    ReplaySource,
    Source,
    SourceError,
    SourceOpener,
    SourceUnavailable,
)

#: python-can log formats read by suffix (``.csv``: python-can's own CSV log).
LOG_SUFFIXES = (".asc", ".blf", ".trc", ".log", ".csv", ".gz")
#: The formats read gzipped (``run.log.gz``): python-can's text formats.
GZIP_SUFFIXES = (".asc", ".trc", ".log", ".csv")
_CANDUMP = re.compile(r"^\(\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]{1,8}#")


def _query_int(query: dict[str, list[str]], key: str, spec: str) -> int | None:
    if key not in query:
        return None
    try:
        return int(query[key][0], 0)
    except ValueError:
        raise SourceError(f"{spec}: {key} must be an integer, got {query[key][0]!r}") from None


def open_bus(spec: str) -> tuple[Any, str, int | None]:
    """A python-can bus for a CAN source string, its channel name and the bitrate the string gives.

    Raises :class:`SourceError` in one line (unknown scheme, no server, no AF_CAN, ...).
    """
    import can

    url = urlparse(spec)
    query = parse_qs(url.query)
    bitrate = _query_int(query, "bitrate", spec)
    scheme = url.scheme
    try:
        if scheme == "socketcand":
            channel = url.path.strip("/") or "can0"
            if not url.hostname or not url.port:
                raise SourceError(f"{spec}: expected socketcand://HOST:PORT/CHANNEL")
            import socket

            # python-can retries a refused connection for 10 s and then waits for the greeting forever: say at
            # once when nothing listens, or when what listens does not greet as socketcand does (< hi >).
            try:
                with socket.create_connection((url.hostname, url.port), timeout=2) as probe:
                    greeting = probe.recv(64)
            except TimeoutError:
                raise SourceUnavailable(f"{spec}: no socketcand greeting within 2 s (a socketcand server says "
                                        "< hi > at once)") from None
            except OSError as exc:
                raise SourceUnavailable(f"{spec}: no socketcand server there ({exc.strerror or exc})") from None
            if not greeting.startswith(b"< hi >"):
                said = greeting.decode("ascii", "replace").strip() or "nothing (closed)"
                raise SourceUnavailable(f"{spec}: the server said {said[:60]!r}, not socketcand's < hi >")
            bus = can.Bus(interface="socketcand", host=url.hostname, port=url.port, channel=channel)
            return bus, channel, bitrate
        if scheme == "slcan":
            target = spec[len("slcan://"):].split("?", 1)[0]
            if not target:
                raise SourceError(f"{spec}: expected slcan:///dev/PORT or slcan://socket://HOST:PORT")
            kwargs: dict[str, Any] = {"sleep_after_open": 0}
            if bitrate:
                kwargs["bitrate"] = bitrate
            tty = _query_int(query, "tty_baudrate", spec)
            if tty:
                kwargs["tty_baudrate"] = tty
            bus = can.Bus(interface="slcan", channel=target, **kwargs)
            return bus, target, bitrate
        if scheme == "socketcan":
            channel = url.netloc or url.path.strip("/")
            from hilbench.transports.socketcan import af_can_status

            ok, why = af_can_status()
            if not ok:
                raise SourceError(f"{spec}: {why}")
            return can.Bus(interface="socketcan", channel=channel), channel, bitrate
        if scheme == "virtual":
            channel = url.netloc or url.path.strip("/")
            return can.Bus(interface="virtual", channel=channel), channel, bitrate
    except SourceError:
        raise
    except (can.CanError, OSError, ValueError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise SourceError(f"{spec}: {text}") from None
    raise SourceError(f"{spec}: not a CAN bus URL (socketcand://, slcan://, socketcan://, virtual://)")


class CanBusSource(PushSource):
    """A live CAN bus through python-can: a thread receives frames and queues them (bounded)."""

    protocol = "can"
    live = True

    def __init__(self, spec: str, *, baud: int | None = None) -> None:
        bus, channel, bitrate = open_bus(spec)
        super().__init__(spec, baud=baud or bitrate)
        self.bus = bus
        self.channel = channel
        self.wall_offset = 0.0  # frames carry Unix time already
        self.errors: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"can-source-{channel}", daemon=True)
        self._thread.start()

    def clock(self) -> float | None:
        return time.time()

    def _run(self) -> None:
        from hilbench.transports.can_messages import to_frame

        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.2)
            except Exception as exc:  # the bus went away: end the source, say why
                if not self._stop.is_set():
                    self.errors.append(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
                break
            if msg is None:
                continue
            frame = to_frame(msg)
            if frame is None:
                continue
            t = msg.timestamp or time.time()
            self.push(t, self.channel if msg.is_rx else f"{self.channel} tx", cf.pack(frame))
        self.end()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        try:
            self.bus.shutdown()
        except Exception:  # shutting down a broken bus must not hide why it broke
            pass
        super().close()


def _open_text(path: str) -> Any:
    """A log's bytes, unpacked if its name ends in ``.gz``."""
    if path.lower().endswith(".gz"):
        import gzip

        return gzip.open(path, "rb")
    return open(path, "rb")


class CanLogSource(ReplaySource):
    """A python-can log file (ASC, BLF, TRC, CSV, candump ``.log``; text formats also gzipped), replayed
    fast or at recorded speed."""

    protocol = "can"
    timestamps = "measured"

    def __init__(self, path: str, *, baud: int | None = None, speed: float | None = None) -> None:
        import can

        if not Path(path).exists():
            raise SourceUnavailable(f"{path}: no such file")
        self.check_speed(speed)
        self.name = path
        self.baud = baud
        self.wall_offset = 0.0
        if Path(path).stat().st_size == 0:
            raise SourceError(f"{path}: the capture is empty")
        #: Lines python-can's reader skipped with a warning (its own words for the first).
        self.skipped = 0
        self.first_skipped = ""
        try:
            self.reader = can.LogReader(path)
        except Exception as exc:
            raise SourceError(f"{path}: python-can cannot read it: {exc}") from None
        self._start_replay(speed)

    def _skip(self, record: logging.LogRecord) -> bool:
        """A logging filter on the reader's logger: a line it skips is counted here, not printed on stderr."""
        if record.levelno < logging.WARNING:
            return True
        self.skipped += 1
        if not self.first_skipped:
            self.first_skipped = record.getMessage()[:120]
        return False

    def quality(self) -> dict[str, Any]:
        """What the file shows of damage: lines the reader skipped, a text log whose last line has no end, a
        BLF file shorter than its header says."""
        findings = []
        if self.skipped:
            findings.append(f"{self.skipped} record(s) python-can's reader could not parse, skipped (the first: "
                            f"{self.first_skipped})")
        path = Path(self.name)
        try:
            size = path.stat().st_size
            if log_suffix(self.name) == ".blf":
                said = getattr(self.reader, "file_size", 0)
                if said > size:
                    findings.append(f"truncated: the file is {size} bytes, its header says {said}: what the "
                                    "recorder wrote after the cut is lost")
            elif not self.name.lower().endswith(".gz") and size:
                with open(path, "rb") as fh:
                    fh.seek(size - 1)
                    if fh.read(1) != b"\n":
                        findings.append("truncated: the last line has no end (the recording was cut off)")
        except OSError:
            pass
        return {**sound_quality(), "corruptions": self.skipped, "truncated_bytes": int(any(
            f.startswith("truncated") for f in findings)), "findings": findings}

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        from hilbench.transports.can_messages import to_frame

        stop = self._stop
        log = logging.getLogger(type(self.reader).__module__)  # (python-can's readers log what they skip)
        log.addFilter(self._skip)
        try:
            for msg in self.reader:
                if stop.is_set():
                    return
                frame = to_frame(msg)
                if frame is None:
                    continue
                t = float(msg.timestamp)
                if self.speed is not None and (yield from self._pace(t, idle)):
                    return
                channel = msg.channel if msg.channel is not None else "can"
                yield Chunk(t, f"{channel}" if msg.is_rx else f"{channel} tx", cf.pack(frame))
        except (ValueError, OSError, EOFError, IndexError, KeyError, struct.error, zlib.error) as exc:
            # a corrupt or truncated log
            raise SourceError(f"{self.name}: {type(exc).__name__}: {exc}") from None
        finally:
            log.removeFilter(self._skip)

    def close(self) -> None:
        super().close()
        stop = getattr(self.reader, "stop", None)
        if stop is not None:
            try:
                stop()
            except Exception:
                pass


#: One candump ``-L`` line (python-can's ``.log``): ``(time) channel id#data [R|T]``; data is hex bytes, ``R`` with
#: an optional length (a remote frame), or ``#F`` and hex bytes (CAN FD, flags F).
_CANDUMP_LINE = re.compile(
    rb"^\((\d{1,12}(?:\.\d{1,9})?)\)[ \t]+(\S{1,64})[ \t]+([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#"
    rb"(R[0-9A-Fa-f]?|#[0-9A-Fa-f](?:[0-9A-Fa-f]{2}){0,64}|(?:[0-9A-Fa-f]{2}){0,8})(?:[ \t]+([RTrt]))?[ \t]*\r?$")
#: Longest candump line read (a longer one is damage, skipped without reading it all into memory).
MAX_CANDUMP_LINE = 512


class CandumpLogSource(CanLogSource):
    """A candump ``-L`` text log (python-can's ``.log``), read line by line: a line that is no frame (damage, a
    line cut by a recording that was killed) is skipped and counted, and reading goes on (python-can's own
    reader stops at the first one)."""

    def __init__(self, path: str, *, baud: int | None = None, speed: float | None = None) -> None:
        if not Path(path).exists():
            raise SourceUnavailable(f"{path}: no such file")
        self.check_speed(speed)
        self.name = path
        self.baud = baud
        self.wall_offset = 0.0
        self.reader = None
        self.bad_lines = 0
        self.first_bad: int | None = None
        self.cut_last = False
        self.fd_frames = 0
        self._start_replay(speed)

    def quality(self) -> dict[str, Any]:
        findings = []
        if self.bad_lines:
            findings.append(f"{self.bad_lines} line(s) that are no candump frame skipped (the first: line "
                            f"{self.first_bad})")
        if self.cut_last:
            findings.append("truncated: the last line has no end (the recording was cut off): skipped")
        if self.fd_frames:
            findings.append(f"{self.fd_frames} CAN FD frame(s) longer than 8 bytes skipped (a classic bus)")
        return {**sound_quality(), "corruptions": self.bad_lines, "truncated_bytes": int(self.cut_last),
                "findings": findings}

    def _frame(self, m: re.Match) -> tuple[float, str, cf.CanFrame] | None:
        t = float(m.group(1))
        ident, data, flag = m.group(3), m.group(4), m.group(5)
        can_id = int(ident, 16)
        extended = len(ident) == 8
        direction = "" if flag is None or flag in (b"R", b"r") else " tx"
        channel = m.group(2).decode("ascii", "replace")
        if data[:1] == b"R":
            return t, channel + direction, cf.CanFrame(can_id & cf.CAN_EFF_MASK, b"", extended, True, False,
                                                    min(int(data[1:] or b"0", 16), 8))
        if data[:1] == b"#":
            data = data[2:]
            if len(data) > 16:
                self.fd_frames += 1
                return None
        raw = bytes.fromhex(data.decode("ascii"))
        if extended and can_id & cf.CAN_ERR_FLAG:
            return t, channel + direction, cf.CanFrame(can_id & cf.CAN_ERR_MASK, raw[:8].ljust(8, b"\0"), False, False,
                                                    True, 8)
        return t, channel + direction, cf.CanFrame(can_id & cf.CAN_EFF_MASK, raw, extended, False, False, len(raw))

    def _bad(self, number: int) -> None:
        self.bad_lines += 1
        if self.first_bad is None:
            self.first_bad = number

    def chunks(self, idle: float | None = None) -> Iterator[Chunk | None]:
        stop = self._stop
        try:
            with _open_text(self.name) as fh:
                number = 0
                while not stop.is_set():
                    line = fh.readline(MAX_CANDUMP_LINE + 1)
                    if not line:
                        return
                    number += 1
                    if not line.endswith(b"\n"):
                        if len(line) > MAX_CANDUMP_LINE:  # no candump line is this long: skip the rest of it
                            while line and not line.endswith(b"\n"):
                                line = fh.readline(MAX_CANDUMP_LINE + 1)
                            self._bad(number)
                            continue
                        if line.strip():
                            self.cut_last = True  # the last line, without its end: a recorder killed mid-write
                        return
                    text = line.rstrip(b"\r\n")
                    if not text.strip():
                        continue
                    m = _CANDUMP_LINE.match(text)
                    if m is None:
                        self._bad(number)
                        continue
                    got = self._frame(m)
                    if got is None:
                        continue
                    t, source, frame = got
                    if self.speed is not None and (yield from self._pace(t, idle)):
                        return
                    yield Chunk(t, source, cf.pack(frame))
        except (OSError, EOFError) as exc:  # (EOFError: a gzipped log cut short)
            raise SourceError(f"{self.name}: {exc}") from None

    def close(self) -> None:
        ReplaySource.close(self)


def _is_candump(path: str) -> bool:
    try:
        with _open_text(path) as fh:
            for line in fh:
                if line.strip():
                    return bool(_CANDUMP.match(line.decode("ascii", "replace").strip()))
    except (OSError, EOFError):
        return False
    return False


def open_can_bus(spec: str, target: str, fragment: str, *, baud: int | None = None, **_: object) -> Source:
    return CanBusSource(spec, baud=baud)


def open_can_log(spec: str, target: str, fragment: str, *, baud: int | None = None, speed: float | None = None,
                 **options: object) -> Source:
    suffix = log_suffix(target)
    if target.lower().endswith(".gz") and suffix not in GZIP_SUFFIXES:
        raise SourceError(f"{target}: a gzipped file that is no python-can text log (read: "
                          f"{', '.join(s + '.gz' for s in GZIP_SUFFIXES)})")
    if suffix == ".log" and not _is_candump(target):
        if target.lower().endswith(".gz"):
            raise SourceError(f"{target}: no candump -L log (its first line is no frame)")
        from hilbench.transports.sources.file import open_file

        return open_file(spec, target, fragment, baud=baud, speed=speed)
    if suffix == ".log":
        return CandumpLogSource(target, baud=baud, speed=speed)
    return CanLogSource(target, baud=baud, speed=speed)


CAN_BUS = SourceOpener("can-bus", open_can_bus, schemes=("socketcand", "slcan", "socketcan", "virtual"),
                       usage="socketcand://127.0.0.1:PORT/can0, slcan:///dev/ttyACM0, socketcan://vcan0",
                       what="a live CAN bus through python-can (add ?bitrate=N for the bus load)")
CAN_LOG = SourceOpener("can-log", open_can_log, suffixes=LOG_SUFFIXES,
                       usage="run.asc, run.blf, run.trc, run.csv, run.log (text formats also .gz)",
                       what="a python-can log file (Vector ASC/BLF, PEAK TRC, python-can CSV, candump -L)")

__all__ = ["CAN_BUS", "CAN_LOG", "CanBusSource", "CanLogSource", "CandumpLogSource", "open_bus"]
