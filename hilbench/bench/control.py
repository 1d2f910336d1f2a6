"""The control channel: commands to a running bench's devices from another process.

``hilbench emulate`` serves it on 127.0.0.1 (a free port, listed in the
manifest as ``"control": "127.0.0.1:PORT"``). The protocol is one JSON object
per line each way::

    -> {"cmd": "button", "device": "rover"}
    <- {"ok": true, "status": {...}}

The bench answers ``devices`` (each device that takes commands, with them),
``taps`` (each endpoint's traffic tap: its clients, limits and what it dropped),
``media`` (each endpoint's line or bus: kind, paced, what its thread is scheduled
under and its counters, e.g. how late a paced serial line handed transmissions
over against its wire model; ``host``: the host port's own, e.g. a socketcand
server's clients and what it refused or dropped),
``servers`` (each endpoint's network servers, e.g. RFC 2217, with their
client and counters) and ``manifest`` (the bench's manifest, for programs that reach the bench only
through this channel, e.g. over labgrid);
every other command belongs to a device family
(:attr:`~hilbench.bench.family.DeviceFamily.control_commands`), e.g. the rover
board's ``status``, ``button``, ``reset``, ``fault``, ``log`` and
``wait_report``. ``device`` may be left out when one device answers the
command. Errors come back as ``{"ok": false, "error": "...", "exit": N}``,
malformed requests included (``exit``: 2 for a request the bench cannot do as
asked, such as an unknown device or a knob out of range, 1 when the bench or
device failed, as :mod:`hilbench.errors`' rule says; the client raises a
:class:`ControlError` with that exit status): a line is at most :data:`MAX_LINE` bytes and JSON nested at
most :data:`MAX_DEPTH` levels, at most :data:`MAX_CLIENTS` connections are
served at once and one idle for :data:`IDLE_TIMEOUT` s is closed, and nothing a
client sends (or a client leaving early) puts a traceback on the bench's
stderr.
:class:`ControlClient` is the Python side; ``hilbench board`` a command line.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import re
import socket
import socketserver
import threading
from itertools import accumulate
from pathlib import Path
from typing import Any

from hilbench.errors import BenchError, HilbenchError
from hilbench.transports.medium import medium_timing

#: Longest request line the bench reads (bytes); longer ones are answered with an error and dropped.
MAX_LINE = 65536
#: Longest reply a client reads (a status with the board's log is a few kB).
MAX_REPLY = 16 << 20
#: Deepest nesting of arrays and objects a request may have.
MAX_DEPTH = 32
#: Connections served at once; more are answered with an error and closed.
MAX_CLIENTS = 32
#: A connection that sends nothing for this long is closed (seconds).
IDLE_TIMEOUT = 300.0

#: What every bench answers, whatever its devices.
BENCH_COMMANDS = ("devices", "manifest", "media", "servers", "taps")

_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"')
_NESTING = bytes.maketrans(b"[{]}", b"\x01\x01\x02\x02")


def nesting(raw: bytes) -> int:
    """How deeply the arrays and objects of a JSON text nest (strings do not count); linear time."""
    opened = _JSON_STRING.sub(b"", raw).translate(_NESTING)
    steps = (1 if c == 1 else -1 for c in opened if c in (1, 2))
    return max(accumulate(steps, initial=0))


class ControlError(BenchError):
    """The bench refused or failed a command (one line)."""


class ControlUnreachable(ControlError):
    """No bench answered at the control address (refused, closed, not JSON): exit status 1."""


class ControlRequestError(ControlError):
    """A request the bench cannot do as asked (unknown command or device, a bad argument): exit status 2."""

    exit_code = 2


class ControlServer:
    """Serves the control channel of a running bench in a background thread.

    :data:`BENCH_COMMANDS` are the bench's own commands; every other command
    goes to the family of the device it names (or of the only device whose
    family answers it): :attr:`DeviceFamily.control_commands`.
    """

    def __init__(self, bench, host: str = "127.0.0.1", port: int = 0) -> None:
        self.bench = bench
        server = self

        clients = threading.BoundedSemaphore(MAX_CLIENTS)

        class Handler(socketserver.StreamRequestHandler):
            timeout = IDLE_TIMEOUT

            def handle(self) -> None:
                # A client that leaves early, stalls or resets is no error of the bench's: OSError covers
                # them all (BrokenPipeError, ConnectionResetError, TimeoutError).
                with contextlib.suppress(OSError):
                    if not clients.acquire(blocking=False):
                        self.wfile.write(b'{"ok": false, "error": "too many control clients"}\n')
                        return
                    try:
                        self._serve()
                    finally:
                        clients.release()

            def _serve(self) -> None:
                while raw := self.rfile.readline(MAX_LINE + 1):  # bounded: a line never grows past this
                    if len(raw) > MAX_LINE:
                        self.wfile.write(b'{"ok": false, "error": "request too long (at most %d bytes)"}\n'
                                         % MAX_LINE)
                        return  # the rest of that line is not worth reading
                    reply = server.handle(raw)
                    self.wfile.write((json.dumps(reply, default=str) + "\n").encode())
                    self.wfile.flush()

        class Server(socketserver.ThreadingTCPServer):
            daemon_threads = True
            allow_reuse_address = True

            def handle_error(self, request, client_address) -> None:
                pass  # Handler.handle lets nothing escape; this is the last guard against a traceback

        self._server = Server((host, port), Handler)
        self._thread = threading.Thread(target=self._server.serve_forever, name="hilbench-control", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self._server.server_address[:2]

    @property
    def address_text(self) -> str:
        host, port = self.address
        return f"{host}:{port}"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()

    # ------------------------------------------------------------------ commands

    def handle(self, raw: bytes) -> dict[str, Any]:
        """The reply to one request line; never raises (a malformed request gets an error reply)."""
        try:
            if nesting(raw) > MAX_DEPTH:
                raise ControlRequestError(f"request nested too deeply (at most {MAX_DEPTH} levels)")
            try:
                req = json.loads(raw)
            except (ValueError, RecursionError):  # UnicodeDecodeError is a ValueError
                raise ControlRequestError("request is not JSON (one object per line)") from None
            if not isinstance(req, dict):
                raise ControlRequestError("expected a JSON object")
            return {"ok": True, **self._dispatch(req)}
        except HilbenchError as exc:  # ControlError and the rules' one-line errors (their exit status too)
            return {"ok": False, "error": str(exc), "exit": exc.exit_code}
        except Exception as exc:  # noqa: BLE001 (a command that broke must not break the channel)
            return {"ok": False, "error": f"command failed: {type(exc).__name__}: {exc}"}

    def _commands(self) -> dict[str, list[str]]:
        """Device name -> the control commands its family answers."""
        out = {}
        for ep in self.bench.endpoints.values():
            for name in ep.devices:
                if ep.family.control_commands:
                    out[name] = list(ep.family.control_commands)
        return out

    def _device(self, cmd: str, req: dict[str, Any]):
        commands = self._commands()
        able = sorted(n for n, cmds in commands.items() if cmd in cmds)
        name = req.get("device")
        if name is not None and not isinstance(name, str):
            raise ControlRequestError(f"device: expected a device name, got {name!r:.40}")
        if name is None:
            if len(able) != 1:
                if not able:
                    known = sorted({c for cmds in commands.values() for c in cmds} | set(BENCH_COMMANDS))
                    raise ControlRequestError(f"unknown command {cmd!r} (expected {', '.join(known)})")
                raise ControlRequestError(f"name a device: the bench has {', '.join(able)} answering {cmd!r}")
            name = able[0]
        if name not in able:
            family = self.bench.family_of(name) if name in self.bench.devices else None
            if family is not None and family.control_commands:
                raise ControlRequestError(f"{name} ({family.name}) has no command {cmd!r} "
                                          f"(expected {', '.join(family.control_commands)})")
            word = self._word(cmd)
            raise ControlRequestError(f"no {word} named {name!r} ({word}s: {', '.join(able) or 'none'})")
        return name, self.bench.devices[name], self.bench.family_of(name)

    def _word(self, cmd: str) -> str:
        """How the devices answering ``cmd`` are called (a family's device word, e.g. "board")."""
        words = {ep.family.device_word for ep in self.bench.endpoints.values() if cmd in ep.family.control_commands}
        return words.pop() if len(words) == 1 else "device"

    def _dispatch(self, req: dict[str, Any]) -> dict[str, Any]:
        cmd = req.get("cmd")
        if not isinstance(cmd, str):
            raise ControlRequestError("expected {\"cmd\": NAME, ...}")
        if cmd == "devices":
            return {"devices": self._commands()}
        if cmd == "servers":
            return {"servers": {ep.name: {name: service.status() if hasattr(service, "status") else service.describe()
                                          for name, service in ep.services.items()}
                                for ep in self.bench.endpoints.values() if ep.services}}
        if cmd == "manifest":
            return {"manifest": self.bench.manifest()}
        if cmd == "media":
            return {"media": {ep.name: {**medium_status(ep.medium),
                                        **({"host": ep.port.status()} if hasattr(ep.port, "status") else {})}
                              for ep in self.bench.endpoints.values() if ep.medium is not None}}
        if cmd == "taps":
            return {"taps": {ep.name: {"url": ep.tap.url, **ep.tap.status()}
                             for ep in self.bench.endpoints.values() if ep.tap is not None}}
        _name, device, family = self._device(cmd, req)
        return family.control(self.bench, device, cmd, req)


def medium_status(medium: Any) -> dict[str, Any]:
    """A line's or bus's kind, pacing, scheduling and counters (its ``stats`` dataclass), for ``media``.

    The counters are read while the medium's thread runs: each field is one consistent value, the whole
    is not an atomic snapshot (a dict the thread grows meanwhile is copied again)."""
    stats: dict[str, Any] = {}
    counters = getattr(medium, "stats", None)  # (a plug-in's medium may keep none)
    for f in dataclasses.fields(counters) if dataclasses.is_dataclass(counters) else ():
        value = getattr(counters, f.name)
        for _ in range(5):
            try:
                stats[f.name] = dict(value) if isinstance(value, dict) else value
                break
            except RuntimeError:  # the line thread added a key while we copied
                continue
    return {"kind": getattr(medium, "kind", None), "paced": getattr(medium, "paced", False),
            "scheduling": None, **medium_timing(medium), "stats": stats}


class ControlClient:
    """Talks to a bench's control channel (``host:port``, or the manifest that lists it).

    :meth:`call` sends any command; families add clients with named methods
    (:class:`hilbench.families.stm32_rover.BoardClient`: ``button()``, ``status()``, ...).
    """

    def __init__(self, address: str | tuple[str, int], timeout: float = 10.0) -> None:
        if isinstance(address, str):
            host, _, port = address.rpartition(":")
            if not host or not port.isdigit():
                raise ControlRequestError(f"expected HOST:PORT, got {address!r}")
            address = (host, int(port))
        self.address = address
        self.timeout = timeout

    @classmethod
    def from_manifest(cls, path: str | Path, timeout: float = 10.0) -> ControlClient:
        """The client of the bench whose manifest is ``path`` (:func:`~hilbench.bench.manifest.read_manifest`:
        a bench that is gone raises :class:`~hilbench.bench.manifest.BenchNotRunning`)."""
        from hilbench.bench.manifest import ManifestError, read_manifest

        try:
            data = read_manifest(path)
        except ManifestError as exc:
            raise ControlRequestError(str(exc)) from None
        if not isinstance(data.get("control"), str):
            raise ControlRequestError(f"{path}: the bench serves no control channel (run it with hilbench emulate)")
        return cls(data["control"], timeout)

    def call(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one command; returns the reply or raises :class:`ControlError`."""
        req = {"cmd": cmd, **{k: v for k, v in args.items() if v is not None}}
        timeout = self.timeout + float(args.get("timeout") or 0)
        where = f"{self.address[0]}:{self.address[1]}"
        try:
            with socket.create_connection(self.address, timeout=timeout) as sock:
                sock.sendall((json.dumps(req) + "\n").encode())
                buf = b""
                while not buf.endswith(b"\n"):
                    chunk = sock.recv(65536)
                    if not chunk:
                        raise ControlUnreachable(f"the bench at {where} closed the control connection")
                    buf += chunk
                    if len(buf) > MAX_REPLY:
                        raise ControlUnreachable(f"the bench at {where} sent a reply longer than {MAX_REPLY} bytes")
        except OSError as exc:
            raise ControlUnreachable(f"no bench control channel at {where}: {exc.strerror or exc}") from None
        try:
            reply = json.loads(buf)
        except (ValueError, RecursionError):
            raise ControlUnreachable(f"the bench at {where} sent something that is not JSON") from None
        if not isinstance(reply, dict):
            raise ControlUnreachable(f"the bench at {where} sent a reply that is not a JSON object")
        if not reply.get("ok"):
            error = ControlError(str(reply.get("error", "command failed")))
            if reply.get("exit") in (1, 2):  # the bench's judgement (benches before it sent none: 1)
                error.exit_code = reply["exit"]
            raise error
        return reply

    def devices(self) -> dict[str, list[str]]:
        """Each device that takes commands, with the commands: ``{"rover": ["status", "button", ...]}``."""
        return self.call("devices")["devices"]

    def manifest(self) -> dict[str, Any]:
        """The bench's manifest, as ``hilbench emulate --manifest`` writes it."""
        return self.call("manifest")["manifest"]

    def media(self) -> dict[str, dict[str, Any]]:
        """Each endpoint's line or bus: ``{"dxl": {"kind": "serial", "paced": true, "scheduling": ...,
        "stats": {"transmissions": ..., "late_count": ..., "late_total": ..., ...}}}``."""
        return self.call("media")["media"]

    def servers(self) -> dict[str, dict[str, Any]]:
        """Each served endpoint's servers: ``{"arm": {"rfc2217": {"url": ..., "client": ..., ...}}}``."""
        return self.call("servers")["servers"]

    def taps(self) -> dict[str, dict[str, Any]]:
        """Each endpoint's traffic tap: ``{"rover": {"url": "tcp://...", "clients": 1}}``."""
        return self.call("taps")["taps"]


__all__ = ["BENCH_COMMANDS", "MAX_LINE", "MAX_REPLY", "ControlClient", "ControlError", "ControlRequestError",
           "ControlServer", "ControlUnreachable"]
