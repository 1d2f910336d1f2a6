"""An RFC 2217 server for a bench's serial endpoint: the fake's own remote serial port.

``hilbench emulate PROFILE --serve rfc2217`` starts one :class:`Rfc2217Port`
per serial endpoint. It is a second host port on the endpoint's medium (a
second door onto the same line): bytes from the TCP client reach the devices
exactly as a pty client's bytes do (pacing, taps and devices see nothing
new), and the devices' bytes reach the client. pyserial's
``serial_for_url("rfc2217://127.0.0.1:PORT")``, labgrid's SerialDriver and
other RFC 2217 clients connect unmodified.

A pty has no modem lines to forward, so the server does not wrap a
``serial.Serial`` (pyserial's ``PortManager`` would fail with ENOTTY): it
keeps the line itself, in the endpoint's
:class:`~hilbench.transports.port_state.PortState`:

- SET-BAUDRATE / -DATASIZE / -PARITY / -STOPSIZE become
  :class:`~hilbench.transports.port_state.SerialSettings` (devices hear
  ``on_port_event``; the baud is the sender's rate on the line, so servos at
  another rate do not hear the client, as on a real bus);
- SET-CONTROL DTR/RTS/BREAK become ``host_sets`` / ``host_break``; flow
  control settings are kept and reported; every SET-CONTROL is answered
  with the value asked for, which plain pyserial waits for;
- CTS/DSR/RI/CD come from the device (``device_sets``) and are reported
  with NOTIFY-MODEMSTATE when they change, after negotiation, and on a poll;
- PURGE-DATA drops what is held for the client; FLOWCONTROL-SUSPEND holds
  the devices' bytes until RESUME (bounded, the excess dropped and counted).

One client at a time, as a real port: a second one gets a line of text
saying who holds the port and is disconnected (ser2net does the same). When
the client leaves, DTR and RTS drop, as closing a real port does (HUPCL).
Everything runs in the medium's thread; the socket binds 127.0.0.1 unless
told otherwise.

Bounds (a client must not take the line, or the bench's memory, from the
others): what waits for the client (the devices' bytes, replies) is at most
:data:`MAX_HELD` bytes: beyond, data is dropped (``dropped``) and so are
replies (``replies_dropped``; an ``IAC AYT`` while the last answer still
waits is answered by that one: 32 MiB of them from a client that reads
nothing cost 276 MB before); the client's input is read only while fewer
than :data:`MAX_INBOX` commands wait and while what it sent before is no more
than :data:`MAX_BACKLOG` seconds of wire time from delivered on a paced line
(TCP holds the client back meanwhile, as a UART's full FIFO holds a writer);
a baud rate outside :data:`MIN_BAUD`..:data:`MAX_BAUD` is not applied (the
answer is the rate kept, as a real port's server answers an impossible one).
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from hilbench import __version__
from hilbench.protocols import rfc2217 as p
from hilbench.transports.host_port import DEFAULT_BIND, HostPort, url_host
from hilbench.transports.listener import NO_DESCRIPTORS, Listener
from hilbench.transports.medium_loop import WakePipe
from hilbench.transports.port_state import PortState, SerialSettings

log = logging.getLogger(__name__)

#: Bytes held for a client that suspended the flow or reads too slowly; beyond this, data is dropped.
MAX_HELD = 1 << 20
#: The client's kernel send buffer (bytes; the kernel holds up to megabytes for a client that reads nothing).
SEND_BUFFER = 256 << 10
#: Commands and data items of the client waiting for the line; the client is not read beyond this.
MAX_INBOX = 1024
#: Seconds of wire time the client's bytes may still need on a paced line before it is read again.
MAX_BACKLOG = 0.1
#: Bytes read from the client at a time: parsing a chunk of telnet commands holds the line's thread (~25 ms
#: for 16 KiB of IAC AYT on a 2-core VM), and a chunk of data becomes one transmission.
RECV_SIZE = 16384
#: Baud rates a client may set (the lowest termios rate; far beyond any UART).
MIN_BAUD = 50
MAX_BAUD = 20_000_000
_OURS = (p.BINARY, p.ECHO, p.SGA, p.COM_PORT_OPTION)  # options we do (WILL) when asked
_THEIRS = (p.BINARY, p.SGA, p.COM_PORT_OPTION)  # options we let the client do (DO)


class Rfc2217Port(HostPort):
    """A one-client RFC 2217 (telnet) server acting as a host port of a serial medium.

    ``port_state`` of the endpoint's host port is where modem lines, BREAK and settings go
    (:attr:`endpoint_state`); the port itself has no :attr:`port_state` of its own, so
    the medium keeps its listener on the endpoint's port. ``medium`` (needed
    for :meth:`~hilbench.transports.medium.Medium.call_at`) is where it runs.
    """

    kind = "rfc2217"
    port_state = None

    def __init__(self, name: str, endpoint_state: PortState, medium: Any, *, bind: str = DEFAULT_BIND, port: int = 0,
                 baud: int | None = None, signature: str = "") -> None:
        self.name = name
        self.endpoint_state = endpoint_state  #: the endpoint's modem lines, BREAK and settings
        self.medium = medium
        self.signature = signature or f"hilbench {__version__}"
        self.listener = Listener(bind, port, 4, max_clients=1, refusal=self._refusal, send_buffer=SEND_BUFFER)
        self.bind = bind
        self._ready = WakePipe()  # readable while parsed input waits for the next read()
        self._lock = threading.RLock()  # socket output: the medium's thread and line watchers
        self.client: socket.socket | None = None
        self.peer: tuple[str, int] | None = None
        self.since = 0.0
        self.settings = SerialSettings(baud)
        self.default_baud = baud
        # statistics
        self.connections = 0
        self.refused = 0
        self.bytes_in = 0
        self.bytes_out = 0
        self.dropped = 0
        self.replies_dropped = 0
        self.problems = 0
        self._reset_session()
        endpoint_state.add_watcher(self._device_lines_changed)

    # ------------------------------------------------------------------ description

    @property
    def address(self) -> tuple[str, int]:
        return self.listener.getsockname()[:2]

    @property
    def url(self) -> str:
        """What clients open: ``rfc2217://127.0.0.1:PORT``."""
        return f"rfc2217://{url_host(self.bind)}:{self.address[1]}"

    @property
    def client_path(self) -> str:
        return self.url

    def describe(self) -> dict[str, Any]:
        """The endpoint's manifest fields: ``{"rfc2217": URL, "rfc2217_limits": {...}}`` (plus ``rfc2217_bind``
        beyond loopback)."""
        out: dict[str, Any] = {"rfc2217": self.url}
        if url_host(self.bind) != self.bind:
            out["rfc2217_bind"] = self.bind
        out["rfc2217_limits"] = self.limits()
        return out

    def limits(self) -> dict[str, Any]:
        """Its bounds (see the module docstring), for the manifest (``rfc2217_limits``)."""
        return {"max_clients": self.listener.max_clients, "max_held": MAX_HELD, "max_inbox": MAX_INBOX,
                "max_backlog_s": MAX_BACKLOG, "baud": [MIN_BAUD, MAX_BAUD], "send_buffer": SEND_BUFFER}

    def status(self) -> dict[str, Any]:
        """Counters and the current client, for status reports."""
        return {"url": self.url, "client": f"{self.peer[0]}:{self.peer[1]}" if self.peer else None,
                "connections": self.connections, "refused": self.refused, "bytes_in": self.bytes_in,
                "bytes_out": self.bytes_out, "dropped": self.dropped, "replies_dropped": self.replies_dropped,
                "problems": self.problems, "out_of_descriptors": self.listener.exhausted,
                "held_bytes": len(self._out) + len(self._held), "max_held": MAX_HELD,
                "baud": self.settings.baud, "flow": self.flow}

    def __repr__(self) -> str:
        return f"Rfc2217Port({self.name!r}, {self.url})"

    # ------------------------------------------------------------------ host port I/O (medium thread)

    def fileno(self) -> int:
        return self.listener.fileno()

    def filenos(self) -> list[int]:
        fds = [*self.listener.filenos(), self._ready.fd]
        if self.client is not None and not self._eof and self._may_receive():
            fds.append(self.client.fileno())
        return fds

    def _may_receive(self) -> bool:
        """Whether to read the client now (see the module docstring's bounds)."""
        if len(self._inbox) >= MAX_INBOX:
            return False  # (the ready pipe keeps the line reading the inbox meanwhile)
        backlog = getattr(self.medium, "backlog", None)
        return backlog is None or backlog(self.name) <= MAX_BACKLOG

    def client_baud(self) -> int | None:
        """The baud rate the client set (SET-BAUDRATE); the endpoint's rate before it set one."""
        return self.settings.baud

    def read(self) -> bytes:
        """The client's next data bytes, after running the commands that came before them."""
        self._ready.drain(64)
        if not self._inbox:  # a new client only once the last one's input (and hang-up) is done
            self._accept()
        if self.client is not None and not self._eof and self._may_receive():
            self._receive()
        self._flush()
        out = b""
        while self._inbox:
            item = self._inbox.popleft()
            if isinstance(item, bytes):
                out = item
                break
            item()
        if self._inbox:
            self._ready.wake()
        return out

    def write(self, data: bytes) -> int:
        """The devices' bytes to the client (held while it suspended the flow; dropped without a client)."""
        if self.client is None:
            self.dropped += len(data)
            return 0
        if self.suspended:
            return self._hold(data)
        return self._send(p.escape(data), droppable=len(data))

    def close(self) -> None:
        self.endpoint_state.remove_watcher(self._device_lines_changed)
        self._hang_up(notify=False)
        with contextlib.suppress(OSError):
            self.listener.close()
        self._ready.close()

    # ------------------------------------------------------------------ connections

    def _reset_session(self) -> None:
        self.decoder = p.TelnetDecoder()
        self._inbox: deque[bytes | Callable[[], None]] = deque()
        self._out = bytearray()
        self._held = bytearray()
        self._flush_scheduled = False
        self.suspended = False
        self.flow = "none"
        self.flow_in = "none"
        self.modem_mask = 0xFF
        self.line_mask = 0
        self._reported: int | None = None
        self._client_ok = False
        self._us: set[int] = set()
        self._them: set[int] = set()
        self._asked_us: set[int] = set()
        self._asked_them: set[int] = set()
        self._cr = False
        self._eof = False

    def _accept(self) -> None:
        for sock, addr in self.listener.accept(0 if self.client is None else 1):
            with self._lock:
                self._reset_session()
                self.client, self.peer, self.since = sock, addr[:2], time.time()  # wall-clock: connected at
            self.connections += 1
            self.settings = SerialSettings(self.default_baud)
            # Opening a real port asserts DTR and RTS (the client then sets them as it likes).
            self.endpoint_state.host_sets(dtr=True, rts=True)
            hello = b"".join(p.negotiation(p.WILL, o) for o in _OURS) + p.negotiation(p.DO, p.BINARY)
            self._asked_us.update(_OURS)
            self._asked_them.add(p.BINARY)
            self._send(hello)

    def _refusal(self, reason: str) -> bytes:
        """What a refused client reads: a busy port says who holds it, then hangs up (what ser2net does)."""
        self.refused += 1
        if reason == NO_DESCRIPTORS:
            log.warning("%s: refused a client (%s)", self.name, reason)
            return f"hilbench: {self.name} ({self.url}): {reason}\r\n".encode()
        held = time.strftime("%H:%M:%S", time.localtime(self.since))
        who = f"{self.peer[0]}:{self.peer[1]}" if self.peer else "another client"
        log.warning("%s: refused a client (%s holds the port)", self.name, who)
        return (f"hilbench: port busy: {self.name} ({self.url}) is in use by {who} since {held}; "
                "one client at a time\r\n").encode()

    def _receive(self) -> None:
        try:
            chunk = self.client.recv(RECV_SIZE)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            chunk = b""
        if not chunk:  # the client left: hang up after the input it sent before
            self._eof = True
            self._inbox.append(lambda: self._hang_up(notify=True))
            return
        for item in self.decoder.feed(chunk):
            if isinstance(item, p.Data):
                self._take_data(item.data)
            elif isinstance(item, p.Negotiation):
                self._negotiate(item.verb, item.option)
            elif isinstance(item, p.Subnegotiation):
                if item.option == p.COM_PORT_OPTION and item.body:
                    self._inbox.append(lambda body=item.body: self._command(body[0], body[1:]))
                else:
                    self.problems += 1
            elif isinstance(item, p.TelnetCommand):
                if item.command == p.BRK:  # a plain telnet client's break key
                    self._inbox.append(lambda: self.endpoint_state.host_break(True, duration=0.25))
                elif item.command == p.AYT:
                    if self._out:  # the last answer is not even sent: this one joins it (counted)
                        self.replies_dropped += 1
                    else:
                        self._send(b"[hilbench: yes]\r\n")
            else:  # Problem
                self.problems += 1

    def _take_data(self, data: bytes) -> None:
        if p.BINARY not in self._them:
            data = self._strip_cr_nul(data)  # NVT: CR is sent as CR NUL outside binary mode
        if not data:
            return
        self.bytes_in += len(data)
        if self._inbox and isinstance(self._inbox[-1], bytes):
            self._inbox[-1] += data
        else:
            self._inbox.append(data)

    def _strip_cr_nul(self, data: bytes) -> bytes:
        out = bytearray()
        for b in data:
            if self._cr and b == 0:
                self._cr = False
                continue
            self._cr = b == 0x0D
            out.append(b)
        return bytes(out)

    def _detach_socket(self) -> None:
        with self._lock:
            if self.client is not None:
                with contextlib.suppress(OSError):
                    self.client.close()
            self.client = None

    def _hang_up(self, notify: bool) -> None:
        """The client left: close its socket; DTR and RTS drop and any BREAK ends, as closing a port does."""
        self._detach_socket()
        self.peer = None
        with self._lock:
            self._out.clear()
            self._held.clear()
        if notify:
            if self.endpoint_state.break_active:
                self.endpoint_state.host_break(False)
            self.endpoint_state.host_sets(dtr=False, rts=False)

    # ------------------------------------------------------------------ output

    def _send(self, raw: bytes, droppable: int = 0) -> int:
        """Send escaped bytes in order; what the socket does not take now waits (data beyond MAX_HELD is dropped)."""
        with self._lock:
            sock = self.client
            if sock is None:
                self.dropped += droppable
                return 0
            if self._out:
                if len(self._out) > MAX_HELD:
                    if droppable:
                        self.dropped += droppable
                    else:
                        self.replies_dropped += 1
                    return 0
                self._out += raw
                self._schedule_flush()
                self.bytes_out += droppable
                return droppable
            try:
                sent = sock.send(raw)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError:
                return 0  # the next read() finds the connection closed
            if sent < len(raw):
                self._out += raw[sent:]
                self._schedule_flush()
            self.bytes_out += droppable
            return droppable

    def _flush(self) -> None:
        with self._lock:
            self._flush_scheduled = False
            if not self._out or self.client is None:
                return
            try:
                sent = self.client.send(self._out)
            except (BlockingIOError, InterruptedError):
                sent = 0
            except OSError:
                self._out.clear()
                return
            del self._out[:sent]  # (a bytearray shrinks its buffer once it is less than half full)
            if self._out:
                self._schedule_flush()

    def _schedule_flush(self) -> None:
        if not self._flush_scheduled:
            self._flush_scheduled = True
            self.medium.call_at(self.medium.clock.now() + 0.002, self._flush)  # (the medium's heap: its time)

    def _hold(self, data: bytes) -> int:
        if len(self._held) + len(data) > MAX_HELD:
            self.dropped += len(data)
            return 0
        self._held += data
        return len(data)

    def _reply(self, command: int, value: bytes) -> None:
        self._send(p.subnegotiation(command + p.SERVER_OFFSET, value))

    # ------------------------------------------------------------------ telnet options

    def _negotiate(self, verb: int, option: int) -> None:
        """RFC 854 option negotiation without loops: answer a request once, never answer an answer."""
        if verb in (p.DO, p.DONT):
            mine, asked, able, yes, no = self._us, self._asked_us, option in _OURS, p.WILL, p.WONT
        else:
            mine, asked, able, yes, no = self._them, self._asked_them, option in _THEIRS, p.DO, p.DONT
        want = verb in (p.DO, p.WILL)
        if want and able:
            if option not in mine:
                mine.add(option)
                if option not in asked:
                    self._send(p.negotiation(yes, option))
        elif want:
            self._send(p.negotiation(no, option))
        elif option in mine:
            mine.discard(option)
            if option not in asked:
                self._send(p.negotiation(no, option))
        asked.discard(option)
        if option == p.COM_PORT_OPTION and option in mine and not self._client_ok:
            self._client_ok = True
            self._notify_modem(force=True)  # the client learns CTS/DSR/RI/CD at once (pyserial needs one)

    # ------------------------------------------------------------------ RFC 2217 commands

    def _command(self, command: int, raw: bytes) -> None:
        """One COM-PORT-OPTION command from the client, in stream order with its data."""
        try:
            cmd = p.Command(command)
        except ValueError:
            self.problems += 1
            return
        if cmd == p.Command.SIGNATURE:
            if not raw:  # a request for ours (a client's own signature needs no answer)
                self._reply(cmd, self.signature.encode())
            return
        if cmd in (p.Command.FLOWCONTROL_SUSPEND, p.Command.FLOWCONTROL_RESUME):
            self.suspended = cmd == p.Command.FLOWCONTROL_SUSPEND
            if not self.suspended and self._held:
                held, self._held = bytes(self._held), bytearray()
                self._send(p.escape(held), droppable=len(held))
            return
        if cmd == p.Command.NOTIFY_MODEMSTATE:  # a poll (pyserial's poll_modem sends no value)
            self._notify_modem(force=True)
            return
        if cmd == p.Command.NOTIFY_LINESTATE:
            self._reply(cmd, p.build_value(cmd, p.LINE_TRANSMITTER_EMPTY))
            return
        value = p.parse_value(cmd, raw)
        if value is None:
            self.problems += 1
            return
        s = self.settings
        if cmd == p.Command.SET_BAUDRATE:
            if value and not MIN_BAUD <= value <= MAX_BAUD:
                self.problems += 1  # not applied: the answer is the rate kept
            elif value:
                self._apply(SerialSettings(value, s.bytesize, s.parity, s.stopbits))
            self._reply(cmd, p.build_value(cmd, self.settings.baud or 0))
        elif cmd == p.Command.SET_DATASIZE:
            if 5 <= value <= 8:
                self._apply(SerialSettings(s.baud, value, s.parity, s.stopbits))
            self._reply(cmd, p.build_value(cmd, self.settings.bytesize))
        elif cmd == p.Command.SET_PARITY:
            if value in p.PARITY:
                self._apply(SerialSettings(s.baud, s.bytesize, p.PARITY[value], s.stopbits))
            self._reply(cmd, p.build_value(cmd, p.PARITY_CODE[self.settings.parity]))
        elif cmd == p.Command.SET_STOPSIZE:
            if value in p.STOPSIZE:
                self._apply(SerialSettings(s.baud, s.bytesize, s.parity, p.STOPSIZE[value]))
            self._reply(cmd, p.build_value(cmd, p.STOPSIZE_CODE[self.settings.stopbits]))
        elif cmd == p.Command.SET_CONTROL:
            answer = self._control(value)
            if answer is not None:
                self._reply(cmd, p.build_value(cmd, answer))
        elif cmd == p.Command.SET_LINESTATE_MASK:
            self.line_mask = value
            self._reply(cmd, p.build_value(cmd, value))
        elif cmd == p.Command.SET_MODEMSTATE_MASK:
            self.modem_mask = value
            self._reply(cmd, p.build_value(cmd, value))
        elif cmd == p.Command.PURGE_DATA:
            if value not in (p.Purge.RECEIVE, p.Purge.TRANSMIT, p.Purge.BOTH):
                self.problems += 1
                return
            if value in (p.Purge.RECEIVE, p.Purge.BOTH):
                self._held.clear()  # bytes for the client it has not been sent yet
            # The transmit side holds nothing: the client's bytes went on the line when they arrived.
            self._reply(cmd, p.build_value(cmd, value))

    def _apply(self, settings: SerialSettings) -> None:
        self.settings = settings
        self.endpoint_state.host_settings(settings)

    def _control(self, value: int) -> int | None:
        """SET-CONTROL: change or report a line; returns the value to answer with."""
        c, state = p.Control, self.endpoint_state
        flows = {c.FLOW_NONE: "none", c.FLOW_XONXOFF: "xonxoff", c.FLOW_HARDWARE: "hardware",
                 c.FLOW_DCD: "dcd", c.FLOW_DSR: "dsr"}
        flows_in = {c.FLOW_IN_NONE: "none", c.FLOW_IN_XONXOFF: "xonxoff", c.FLOW_IN_HARDWARE: "hardware",
                    c.FLOW_IN_DTR: "dtr"}
        if value in flows:
            self.flow = flows[value]
        elif value in flows_in:
            self.flow_in = flows_in[value]
        elif value == c.REQ_FLOW:
            return {v: k for k, v in flows.items()}[self.flow]
        elif value == c.REQ_FLOW_IN:
            return {v: k for k, v in flows_in.items()}[self.flow_in]
        elif value in (c.BREAK_ON, c.BREAK_OFF):
            state.host_break(value == c.BREAK_ON)
        elif value == c.REQ_BREAK:
            return c.BREAK_ON if state.break_active else c.BREAK_OFF
        elif value in (c.DTR_ON, c.DTR_OFF):
            state.host_sets(dtr=value == c.DTR_ON)
        elif value == c.REQ_DTR:
            return c.DTR_ON if state.dtr else c.DTR_OFF
        elif value in (c.RTS_ON, c.RTS_OFF):
            state.host_sets(rts=value == c.RTS_ON)
        elif value == c.REQ_RTS:
            return c.RTS_ON if state.rts else c.RTS_OFF
        else:
            self.problems += 1
            return None
        return value

    # ------------------------------------------------------------------ modem state

    def _device_lines_changed(self, lines: dict[str, bool]) -> None:
        """The device moved CTS/DSR/RI/CD (any thread): report it from the medium's thread."""
        if self.client is not None:
            self.medium.call_at(None, self._notify_modem)

    def _notify_modem(self, force: bool = False) -> None:
        if self.client is None or not (self._client_ok or force):
            return
        state = p.modem_state(**self.endpoint_state.device_lines())
        if not force and state == self._reported:
            return
        value = p.with_deltas(state, self._reported) & self.modem_mask
        self._reported = state
        self._reply(p.Command.NOTIFY_MODEMSTATE, bytes((value,)))


__all__ = ["MAX_BACKLOG", "MAX_BAUD", "MAX_HELD", "MAX_INBOX", "MIN_BAUD", "RECV_SIZE", "Rfc2217Port"]
