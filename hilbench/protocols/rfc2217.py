"""Telnet with the Com Port Control Option (RFC 854, RFC 2217): a serial port over TCP.

The byte stream is data, except that 0xFF (IAC) starts a command: ``IAC IAC``
is a data byte 0xFF, ``IAC DO/DONT/WILL/WONT opt`` negotiates an option,
``IAC SB ... IAC SE`` carries a subnegotiation (inside it 0xFF is doubled
too), and ``IAC cmd`` is a one-byte command (``IAC BRK``, ``IAC NOP``, ...).
RFC 2217 subnegotiations start with the option COM-PORT-OPTION (44) and a
command: 0-12 from client to server, the same plus 100 in the answers::

    IAC SB 44 SET-BAUDRATE(1) <u32 big-endian> IAC SE        client -> server
    IAC SB 44 101            <u32 big-endian> IAC SE        server -> client

The layouts of the command values are :data:`COMMAND_VALUE` (construct,
used to build and to parse); the stream itself is :class:`TelnetDecoder`,
hand-written because telnet framing is byte stuffing with a state machine
that construct cannot express incrementally. The decoder never raises:
malformed or oversized subnegotiations are reported as
:class:`~hilbench.protocols.problem.Problem` items (``count``: the bytes
dropped) and dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from construct import Int8ub, Int32ub

from hilbench.protocols.problem import Problem

# ---------------------------------------------------------------------- telnet (RFC 854)

IAC = 0xFF
DONT = 0xFE
DO = 0xFD
WONT = 0xFC
WILL = 0xFB
SB = 0xFA
SE = 0xF0
NOP = 0xF1
BRK = 0xF3
AYT = 0xF6

#: Telnet options hilbench's server cares about.
BINARY = 0
ECHO = 1
SGA = 3
COM_PORT_OPTION = 44

#: Longest subnegotiation body kept; RFC 2217's longest is a signature text. Longer ones are dropped.
MAX_SUBNEGOTIATION = 1024


class Command(IntEnum):
    """RFC 2217 client-to-server commands (the server answers with ``value + 100``)."""

    SIGNATURE = 0
    SET_BAUDRATE = 1
    SET_DATASIZE = 2
    SET_PARITY = 3
    SET_STOPSIZE = 4
    SET_CONTROL = 5
    NOTIFY_LINESTATE = 6
    NOTIFY_MODEMSTATE = 7
    FLOWCONTROL_SUSPEND = 8
    FLOWCONTROL_RESUME = 9
    SET_LINESTATE_MASK = 10
    SET_MODEMSTATE_MASK = 11
    PURGE_DATA = 12


#: What the server adds to a command number in its answer.
SERVER_OFFSET = 100


class Control(IntEnum):
    """SET-CONTROL values (RFC 2217 section "SET-CONTROL")."""

    REQ_FLOW = 0
    FLOW_NONE = 1
    FLOW_XONXOFF = 2
    FLOW_HARDWARE = 3
    REQ_BREAK = 4
    BREAK_ON = 5
    BREAK_OFF = 6
    REQ_DTR = 7
    DTR_ON = 8
    DTR_OFF = 9
    REQ_RTS = 10
    RTS_ON = 11
    RTS_OFF = 12
    REQ_FLOW_IN = 13
    FLOW_IN_NONE = 14
    FLOW_IN_XONXOFF = 15
    FLOW_IN_HARDWARE = 16
    FLOW_DCD = 17
    FLOW_IN_DTR = 18
    FLOW_DSR = 19


class Purge(IntEnum):
    """PURGE-DATA values: the access server's receive buffer (towards the client), transmit buffer, both."""

    RECEIVE = 1
    TRANSMIT = 2
    BOTH = 3


#: Modem state bits (NOTIFY-MODEMSTATE): levels in the high nibble, changes since the last report low.
MODEM_CD = 0x80
MODEM_RI = 0x40
MODEM_DSR = 0x20
MODEM_CTS = 0x10
MODEM_DELTA = {MODEM_CD: 0x08, MODEM_RI: 0x04, MODEM_DSR: 0x02, MODEM_CTS: 0x01}
#: Line state bits the server reports: transmit shift register and holding register empty.
LINE_TRANSMITTER_EMPTY = 0x60

#: Parity codes of SET-PARITY and their pyserial letters; stop size codes and their bit counts.
PARITY = {1: "N", 2: "O", 3: "E", 4: "M", 5: "S"}
PARITY_CODE = {v: k for k, v in PARITY.items()}
STOPSIZE = {1: 1.0, 2: 2.0, 3: 1.5}
STOPSIZE_CODE = {v: k for k, v in STOPSIZE.items()}

#: The value layout of each command (absent: free bytes, e.g. a signature text); answers use the same.
COMMAND_VALUE = {
    Command.SET_BAUDRATE: Int32ub,
    Command.SET_DATASIZE: Int8ub,
    Command.SET_PARITY: Int8ub,
    Command.SET_STOPSIZE: Int8ub,
    Command.SET_CONTROL: Int8ub,
    Command.NOTIFY_LINESTATE: Int8ub,
    Command.NOTIFY_MODEMSTATE: Int8ub,
    Command.SET_LINESTATE_MASK: Int8ub,
    Command.SET_MODEMSTATE_MASK: Int8ub,
    Command.PURGE_DATA: Int8ub,
}


def modem_state(cts: bool, dsr: bool, ri: bool, cd: bool) -> int:
    """The level bits of a NOTIFY-MODEMSTATE byte."""
    return (MODEM_CTS if cts else 0) | (MODEM_DSR if dsr else 0) | (MODEM_RI if ri else 0) | (MODEM_CD if cd else 0)


def with_deltas(state: int, previous: int | None) -> int:
    """``state`` plus the change bits against ``previous`` levels (None: no earlier report)."""
    changed = state ^ (previous or 0)
    return state | sum(delta for level, delta in MODEM_DELTA.items() if changed & level)


# ---------------------------------------------------------------------- building


def escape(data: bytes) -> bytes:
    """Data bytes as they travel: every 0xFF doubled."""
    return data.replace(b"\xff", b"\xff\xff")


def negotiation(verb: int, option: int) -> bytes:
    """``IAC DO/DONT/WILL/WONT option``."""
    return bytes((IAC, verb, option))


def subnegotiation(command: int, value: bytes = b"") -> bytes:
    """``IAC SB COM-PORT-OPTION command value IAC SE`` (value escaped)."""
    return bytes((IAC, SB, COM_PORT_OPTION, command)) + escape(value) + bytes((IAC, SE))


def build_value(command: int, value: int) -> bytes:
    """A command's integer value in its layout (the baud rate as u32, the others as u8)."""
    return COMMAND_VALUE[Command(command % SERVER_OFFSET)].build(value)


def parse_value(command: int, raw: bytes) -> int | None:
    """A command's integer value, or None if ``raw`` is too short for its layout."""
    layout = COMMAND_VALUE.get(Command(command % SERVER_OFFSET))
    if layout is None or len(raw) < layout.sizeof():
        return None
    return layout.parse(raw[: layout.sizeof()])


# ---------------------------------------------------------------------- parsing


@dataclass(frozen=True)
class Data:
    """Data bytes (escapes removed)."""

    data: bytes


@dataclass(frozen=True)
class Negotiation:
    """``IAC verb option`` with verb one of DO, DONT, WILL, WONT."""

    verb: int
    option: int


@dataclass(frozen=True)
class Subnegotiation:
    """``IAC SB option body IAC SE``; for COM-PORT-OPTION, ``body`` starts with the command."""

    option: int
    body: bytes


@dataclass(frozen=True)
class TelnetCommand:
    """A one-byte telnet command (``IAC BRK``, ``IAC NOP``, ``IAC AYT``, ...)."""

    command: int


TelnetItem = Data | Negotiation | Subnegotiation | TelnetCommand | Problem

_NORMAL, _IAC, _VERB, _SB, _SB_IAC = range(5)


class TelnetDecoder:
    """Incremental telnet parser: :meth:`feed` returns the items complete so far, in stream order.

    Partial input (a lone IAC at the end of a chunk, an open subnegotiation)
    is kept for the next call. A subnegotiation longer than
    :data:`MAX_SUBNEGOTIATION` is dropped (and reported) without buffering it.
    """

    def __init__(self) -> None:
        self._state = _NORMAL
        self._verb = 0
        self._sb = bytearray()
        self._sb_overflow = 0
        self.dropped = 0

    def feed(self, chunk: bytes) -> list[TelnetItem]:
        items: list[TelnetItem] = []
        data = bytearray()
        i, n = 0, len(chunk)
        while i < n:
            state = self._state
            if state == _NORMAL:
                j = chunk.find(b"\xff", i)
                if j < 0:
                    data += chunk[i:]
                    break
                data += chunk[i:j]
                i = j + 1
                self._state = _IAC
                continue
            b = chunk[i]
            i += 1
            if state == _IAC:
                if b == IAC:
                    data.append(IAC)
                    self._state = _NORMAL
                    continue
                if data:
                    items.append(Data(bytes(data)))
                    data = bytearray()
                if b in (DO, DONT, WILL, WONT):
                    self._verb = b
                    self._state = _VERB
                elif b == SB:
                    self._sb.clear()
                    self._sb_overflow = 0
                    self._state = _SB
                elif b == SE:  # an SE outside a subnegotiation: nothing to end
                    items.append(self._problem("stray", "stray IAC SE", 2))
                    self._state = _NORMAL
                else:
                    items.append(TelnetCommand(b))
                    self._state = _NORMAL
            elif state == _VERB:
                items.append(Negotiation(self._verb, b))
                self._state = _NORMAL
            elif state == _SB:
                if b == IAC:
                    self._state = _SB_IAC
                else:
                    self._sb_add(b)
            else:  # _SB_IAC
                if b == IAC:
                    self._sb_add(IAC)
                    self._state = _SB
                elif b == SE:
                    if self._sb_overflow:
                        items.append(self._problem("overlong", "subnegotiation too long", self._sb_overflow + len(self._sb)))
                    elif not self._sb:
                        items.append(self._problem("empty", "empty subnegotiation", 4))
                    else:
                        items.append(Subnegotiation(self._sb[0], bytes(self._sb[1:])))
                    self._sb.clear()
                    self._state = _NORMAL
                else:
                    # RFC 854 leaves IAC <cmd> inside SB undefined: end the subnegotiation here
                    # (it lost its IAC SE) and treat the byte as a command after it.
                    items.append(self._problem("unterminated", "unterminated subnegotiation", len(self._sb) + 2))
                    self._sb.clear()
                    self._state = _IAC
                    i -= 1
        if data:
            items.append(Data(bytes(data)))
        return items

    def _sb_add(self, b: int) -> None:
        if self._sb_overflow or len(self._sb) >= MAX_SUBNEGOTIATION:
            self._sb_overflow += 1
        else:
            self._sb.append(b)

    def _problem(self, kind: str, detail: str, dropped: int) -> Problem:
        self.dropped += dropped
        return Problem(kind, detail=detail, count=dropped)


__all__ = [
    "AYT", "BINARY", "BRK", "COMMAND_VALUE", "COM_PORT_OPTION", "DO", "DONT", "ECHO", "IAC",
    "LINE_TRANSMITTER_EMPTY", "MAX_SUBNEGOTIATION", "MODEM_CD", "MODEM_CTS", "MODEM_DSR", "MODEM_RI", "NOP",
    "PARITY", "PARITY_CODE", "SB", "SE", "SERVER_OFFSET", "SGA", "STOPSIZE", "STOPSIZE_CODE", "WILL", "WONT",
    "Command", "Control", "Data", "Negotiation", "Purge", "Subnegotiation", "TelnetCommand",
    "TelnetDecoder", "TelnetItem", "build_value", "escape", "modem_state", "negotiation", "parse_value",
    "subnegotiation", "with_deltas",
]
