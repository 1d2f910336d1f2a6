"""The socketcand text protocol (linux-can/socketcand ``doc/protocol.md``): messages, frames, commands.

Every message in both directions is ``< word word ... >`` with no newline or
length prefix; several may share a TCP segment and one may be split across
segments (:class:`MessageSplitter`). The server greets with ``< hi >``; the
client opens a bus (``< open can0 >``), is then in BCM mode, and switches to
RAW mode (``< rawmode >``) to receive every frame::

    < frame 123 1700000000.123456 DEADBEEF >     RAW: data uppercase, no spaces
    < frame 123 1700000000.123456 DE AD BE EF  > BCM: one byte per word
    < error 004 1700000000.523456 >              an error frame (its class bits)
    < send 123 3 de ad 1 >                       client: ID (8 digits = extended), DLC, bytes

Formatting follows the daemon's ``sprintf`` calls (``state_raw.c``,
``state_bcm.c``) and parsing its ``sscanf`` rules: a malformed ``send`` is
dropped, not answered. This is a text protocol of space-separated words,
which ``construct`` does not describe better than ``str.split``.
"""

from __future__ import annotations

from typing import NamedTuple

from hilbench.errors import RequestRefused
from hilbench.protocols.can_frame import CAN_EFF_MASK, CAN_SFF_MASK, CanFrame

DEFAULT_PORT = 29536
#: Discovery beacons go to this UDP port.
BEACON_PORT = 42000
#: A bus name is at most this long (the daemon's ``MAX_BUSNAME``, minus the terminator).
MAX_BUS_NAME = 16
#: Longest message kept while waiting for its ``>`` (the daemon's command buffer is 4096 bytes).
MAX_MESSAGE = 4096

#: Longest BCM timer the kernel takes (``BCM_TIMER_SEC_MAX``: 400 days); a longer one is refused.
BCM_TIMER_SEC_MAX = 400 * 24 * 60 * 60
#: Largest ``statistics`` interval in ms (the daemon reads it with ``%u``).
MAX_STATISTICS_MS = 0xFFFF_FFFF

HI = "< hi >"
OK = "< ok >"
ECHO = "< echo >"
ERROR_UNKNOWN = "< error unknown command >"
ERROR_OPEN = "< error could not open bus >"


def error_out_of_range(what: str) -> str:
    """The reply to a number out of range, e.g. ``< error interval out of range >`` (``what`` starts with a
    letter beyond ``f``: python-can reads ``< error HEX ...`` as an error frame)."""
    return f"< error {what} out of range >"


class MessageSplitter:
    """Bytes of a stream in, whole ``< ... >`` messages out; bounded, never raises.

    Bytes before a ``<`` and a message longer than :data:`MAX_MESSAGE` without
    its ``>`` are dropped and counted in :attr:`dropped` (the daemon also
    discards data without a ``<``).
    """

    def __init__(self, max_message: int = MAX_MESSAGE) -> None:
        self.max_message = max_message
        self._buf = bytearray()
        self.dropped = 0  #: bytes dropped (outside or beyond a message)

    def feed(self, data: bytes) -> list[str]:
        buf = self._buf
        buf += data
        out: list[str] = []
        while buf:
            start = buf.find(b"<")
            if start < 0:
                self.dropped += len(buf)
                buf.clear()
                break
            if start:
                self.dropped += start
                del buf[:start]
            end = buf.find(b">")
            if end < 0:
                if len(buf) > self.max_message:
                    self.dropped += len(buf)
                    buf.clear()
                break
            out.append(buf[: end + 1].decode("ascii", "replace"))
            del buf[: end + 1]
        return out


def words(message: str) -> list[str]:
    """The words between ``<`` and ``>``."""
    return message.strip()[1:-1].split()


def _stamp(t_wall: float) -> str:
    sec = int(t_wall)
    usec = int(round((t_wall - sec) * 1e6))
    if usec >= 1_000_000:
        sec, usec = sec + 1, usec - 1_000_000
    return f"{sec}.{usec:06d}"


def frame_message(frame: CanFrame, t_wall: float, *, bcm: bool = False) -> str:
    """The server's report of a received frame (RAW mode, or BCM mode's spaced bytes).

    ``t_wall`` is Unix time (what the daemon takes from SO_TIMESTAMP): clients
    write it into log files. Remote frames are not reported (the daemon leaves
    them out too); the caller checks :attr:`CanFrame.remote`.
    """
    stamp = _stamp(t_wall)
    if frame.error:
        return f"< error {frame.can_id:03X} {stamp} >"
    ident = f"{frame.can_id & CAN_EFF_MASK:08X}" if frame.extended else f"{frame.can_id & CAN_SFF_MASK:03X}"
    if bcm:
        return f"< frame {ident} {stamp} {''.join(f'{b:02X} ' for b in frame.data)} >"
    return f"< frame {ident} {stamp} {frame.data.hex().upper()} >"


def send_message(frame: CanFrame) -> str:
    """A client's ``send`` command for ``frame`` (what python-can writes)."""
    ident = f"{frame.can_id:08X}" if frame.extended else f"{frame.can_id:03X}"
    return f"< send {ident} {frame.length:X} {' '.join(f'{b:x}' for b in frame.data)} >"


def stat_message(rbytes: int, rpackets: int, tbytes: int, tpackets: int) -> str:
    """A CONTROL-mode statistics report."""
    return f"< stat {rbytes} {rpackets} {tbytes} {tpackets} >"


class Command(NamedTuple):
    """A parsed client message: ``name`` (``open``, ``send``, ``add``, ...) and its checked arguments.

    ``frame`` is set for ``send``/``add``/``update``/``filter``; ``interval`` (seconds)
    for ``add``/``filter``/``subscribe``; ``can_id``/``extended`` for
    ``delete``/``unsubscribe``/``subscribe``; ``value`` is the bus name of ``open``
    or the interval of ``statistics`` (ms). ``name`` is ``"invalid"`` for a
    malformed command of a known name, ``"range"`` for one with a number out of range
    (``value`` says which: ``interval``, ``identifier``, ``statistics interval``), ``"unknown"`` for
    anything else.
    """

    name: str
    frame: CanFrame | None = None
    interval: float = 0.0
    can_id: int = 0
    extended: bool = False
    value: str = ""
    mask: bytes = b""


MODE_COMMANDS = ("rawmode", "bcmmode", "controlmode", "isotpmode")


class _OutOfRange(RequestRefused, ValueError):
    """A number the protocol bounds is beyond its bounds (``args[0]`` names it); the server answers it
    with its ``< error >`` (see :func:`parse_command`)."""


def _hex(word: str) -> int:
    return int(word, 16)


def _can_id(word: str) -> int:
    """An identifier word: eight digits mean an extended frame (the daemon's rule); raises _OutOfRange if too
    large for its kind (the daemon would pass it on truncated; a wider ID is a client error)."""
    can_id = _hex(word)
    if not 0 <= can_id <= (CAN_EFF_MASK if len(word) == 8 else CAN_SFF_MASK):
        raise _OutOfRange("identifier")
    return can_id


def _frame_from(args: list[str]) -> CanFrame | None:
    """``ID DLC B0 B1 ...`` as the daemon's ``sscanf("%x %hhu %hhx...")`` reads it; None if malformed
    (raises _OutOfRange for an identifier beyond its kind's range)."""
    if len(args) < 2:
        return None
    try:
        can_id = _hex(args[0])
        dlc = int(args[1], 10)
        data = bytes(_hex(b) & 0xFF for b in args[2:])
    except ValueError:
        return None
    if not 0 <= dlc <= 8 or len(data) != dlc:
        return None
    can_id = _can_id(args[0])
    return CanFrame(can_id, data, len(args[0]) == 8, False, False, dlc)


def _interval(sec: str, usec: str) -> float:
    """A BCM interval: what the kernel takes (``bcm_is_invalid_tv``: seconds up to 400 days, microseconds
    below a million); raises _OutOfRange beyond, ValueError if not numbers."""
    s, u = int(sec, 10), int(usec, 10)
    if not (0 <= s <= BCM_TIMER_SEC_MAX and 0 <= u < 1_000_000):
        raise _OutOfRange("interval")
    return s + u / 1e6


def parse_command(message: str) -> Command:
    """Read one client message; never raises (see :class:`Command` for the result)."""
    w = words(message)
    if not w:
        return Command("unknown")
    name, args = w[0], w[1:]
    try:
        if name == "open":
            if len(args) != 1 or len(args[0]) > MAX_BUS_NAME:
                return Command("invalid", value=" ".join(args))
            return Command("open", value=args[0])
        if name in MODE_COMMANDS or name == "echo":
            return Command(name) if not args else Command("unknown")
        if name in ("send", "update"):
            frame = _frame_from(args)
            return Command(name, frame=frame) if frame else Command("invalid")
        if name in ("add", "filter"):
            if len(args) < 4:
                return Command("invalid")
            frame = _frame_from(args[2:])
            if frame is None:
                return Command("invalid")
            mask = frame.data if name == "filter" else b""
            return Command(name, frame=frame, interval=_interval(args[0], args[1]), can_id=frame.can_id,
                           extended=frame.extended, mask=mask)
        if name in ("subscribe", "muxfilter"):
            if len(args) < 3:
                return Command("invalid")
            interval = _interval(args[0], args[1])
            return Command("subscribe", interval=interval, can_id=_can_id(args[2]), extended=len(args[2]) == 8)
        if name in ("delete", "unsubscribe"):
            if len(args) != 1:
                return Command("invalid")
            return Command(name, can_id=_can_id(args[0]), extended=len(args[0]) == 8)
        if name == "statistics":
            if len(args) != 1:
                return Command("invalid")
            ms = int(args[0], 10)
            if not 0 <= ms <= MAX_STATISTICS_MS:
                raise _OutOfRange("statistics interval")
            return Command("statistics", value=str(ms))
        if len(args) >= 1 and args[0] in ("B", "C"):
            return Command("configure", value=name)  # "< can0 B bitrate ... >": bus settings in NO_BUS mode
    except _OutOfRange as exc:
        return Command("range", value=exc.args[0])
    except ValueError:  # not a number (or one of more than 4300 digits)
        return Command("invalid")
    return Command("unknown")


class ServerMessage(NamedTuple):
    """A server message as a client reads it: ``frame`` for ``frame``/``error`` reports, else ``kind``."""

    kind: str  # "frame", "error-frame", "hi", "ok", "echo", "error", "stat", "unknown"
    frame: CanFrame | None = None
    t_wall: float = 0.0
    text: str = ""


def parse_server_message(message: str) -> ServerMessage:
    """Read one server message (either frame format); never raises."""
    w = words(message)
    if not w:
        return ServerMessage("unknown", text=message)
    kind = w[0]
    if kind == "frame" and len(w) >= 3:
        try:
            can_id = _hex(w[1])
            t = float(w[2])
            data = bytes.fromhex("".join(w[3:]))
        except ValueError:
            return ServerMessage("unknown", text=message)
        if len(data) > 8:
            return ServerMessage("unknown", text=message)
        extended = len(w[1]) != 3
        return ServerMessage("frame", CanFrame(can_id, data, extended, False, False, len(data)), t)
    if kind == "error" and len(w) >= 3:
        try:
            cls, t = _hex(w[1]), float(w[2])
        except ValueError:
            return ServerMessage("error", text=" ".join(w[1:]))
        return ServerMessage("error-frame", CanFrame(cls, bytes(8), False, False, True, 8), t)
    if kind in ("hi", "ok", "echo", "error", "stat"):
        return ServerMessage(kind, text=" ".join(w[1:]))
    return ServerMessage("unknown", text=message)


def beacon(name: str, host: str, port: int, buses: list[str], description: str = "") -> bytes:
    """The discovery beacon datagram (``src/beacon.c``): which buses this server offers where."""
    from xml.sax.saxutils import quoteattr

    bus_xml = "".join(f"<Bus name={quoteattr(b)}/>" for b in buses)
    return (f"<CANBeacon name={quoteattr(name)} type=\"SocketCAN\" description={quoteattr(description)}>"
            f"<URL>can://{host}:{port}</URL>{bus_xml}</CANBeacon>").encode()


__all__ = ["BCM_TIMER_SEC_MAX", "BEACON_PORT", "DEFAULT_PORT", "ECHO", "ERROR_OPEN", "ERROR_UNKNOWN", "HI", "MAX_BUS_NAME", "OK",
           "MAX_STATISTICS_MS", "Command", "MessageSplitter", "ServerMessage", "beacon", "error_out_of_range", "frame_message", "parse_command",
           "parse_server_message", "send_message", "stat_message", "words"]
