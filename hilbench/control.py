"""The control channel: press a board's button, reset it or turn its fault knobs from another process.

``hilbench emulate`` serves it on 127.0.0.1 (a free port, listed in the
manifest as ``"control": "127.0.0.1:PORT"``). The protocol is one JSON object
per line each way::

    -> {"cmd": "button", "device": "rover"}
    <- {"ok": true, "status": {...}}

Commands: ``devices`` (the boards), ``taps`` (each endpoint's traffic tap and how
many clients it serves), ``status``, ``button``, ``reset``,
``fault`` (with ``"knobs": {"drop_rate": 0.01, "stall": 0.5, ...}``), ``log``
(recent log lines) and ``wait_report`` (until the board has printed more
reports than ``"after"``, default: the count when asked; ``"timeout"`` seconds). ``device`` may be left out when
the bench has one board. Errors come back as ``{"ok": false, "error": "..."}``.
:class:`ControlClient` is the Python side; ``hilbench board`` the command line.
"""

from __future__ import annotations

import json
import socket
import socketserver
import threading
import time
from pathlib import Path
from typing import Any

MAX_LINE = 65536


class ControlError(Exception):
    """The bench refused or failed a command (one line)."""


class ControlServer:
    """Serves the control channel of a running bench in a background thread."""

    def __init__(self, bench, host: str = "127.0.0.1", port: int = 0) -> None:
        self.bench = bench
        server = self

        class Handler(socketserver.StreamRequestHandler):
            def handle(self) -> None:
                while raw := self.rfile.readline(MAX_LINE + 1):  # bounded: a line never grows past this
                    if len(raw) > MAX_LINE:
                        self.wfile.write(b'{"ok": false, "error": "request too long"}\n')
                        return  # the rest of that line is not worth reading
                    reply = server.handle(raw)
                    self.wfile.write((json.dumps(reply) + "\n").encode())
                    self.wfile.flush()

        class Server(socketserver.ThreadingTCPServer):
            daemon_threads = True
            allow_reuse_address = True

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
        try:
            req = json.loads(raw)
            if not isinstance(req, dict):
                raise ControlError("expected a JSON object")
            return {"ok": True, **self._dispatch(req)}
        except ControlError as exc:
            return {"ok": False, "error": str(exc)}
        except (ValueError, KeyError, TypeError) as exc:
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}"}

    def _board(self, req: dict[str, Any]):
        from hilbench.fakes.stm32_board import Board

        boards = {n: d for n, d in self.bench.devices.items() if isinstance(d, Board)}
        name = req.get("device")
        if name is None:
            if len(boards) != 1:
                raise ControlError(f"name a device: the bench has boards {sorted(boards)}")
            return next(iter(boards.values()))
        if name not in boards:
            raise ControlError(f"no board named {name!r} (boards: {', '.join(sorted(boards)) or 'none'})")
        return boards[name]

    def _dispatch(self, req: dict[str, Any]) -> dict[str, Any]:
        cmd = req.get("cmd")
        if cmd == "devices":
            from hilbench.fakes.stm32_board import Board

            return {"boards": sorted(n for n, d in self.bench.devices.items() if isinstance(d, Board))}
        if cmd == "taps":
            return {"taps": {ep.name: {"url": ep.tap.url, "clients": ep.tap.clients}
                             for ep in self.bench.endpoints.values() if ep.tap is not None}}
        board = self._board(req)
        if cmd == "status":
            return {"status": board.status()}
        if cmd == "button":
            board.press_button()
            board.settle()  # the reply shows the press's effect (sampling on/off)
            return {"status": board.status()}
        if cmd == "reset":
            board.reset()
            board.settle()
            return {"status": board.status()}
        if cmd == "fault":
            knobs = req.get("knobs", {})
            if not isinstance(knobs, dict):
                raise ControlError("knobs: expected an object")
            return {"faults": board.set_faults(**knobs)}
        if cmd == "log":
            return {"log": board.status()["log"]}
        if cmd == "wait_report":
            timeout = float(req.get("timeout", 10.0))
            deadline = time.monotonic() + timeout
            start = req.get("after")
            start = len(board.reports) if start is None else int(start)
            while len(board.reports) <= start:
                if time.monotonic() > deadline:
                    raise ControlError(f"no report within {timeout} s")
                time.sleep(0.01)
            rep = board.reports[-1]
            return {"report": rep._asdict(), "status": board.status()}
        raise ControlError(f"unknown command {cmd!r} (expected devices, status, button, reset, fault, log, "
                           "wait_report)")


class ControlClient:
    """Talks to a bench's control channel (``host:port``, or the manifest that lists it)."""

    def __init__(self, address: str | tuple[str, int], timeout: float = 10.0) -> None:
        if isinstance(address, str):
            host, _, port = address.rpartition(":")
            if not host or not port.isdigit():
                raise ControlError(f"expected HOST:PORT, got {address!r}")
            address = (host, int(port))
        self.address = address
        self.timeout = timeout

    @classmethod
    def from_manifest(cls, path: str | Path, timeout: float = 10.0) -> ControlClient:
        data = json.loads(Path(path).read_text())
        if "control" not in data:
            raise ControlError(f"{path}: the bench serves no control channel (run it with hilbench emulate)")
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
                        raise ControlError(f"the bench at {where} closed the control connection")
                    buf += chunk
        except OSError as exc:
            raise ControlError(f"no bench control channel at {where}: {exc.strerror or exc}") from None
        reply = json.loads(buf)
        if not reply.get("ok"):
            raise ControlError(reply.get("error", "command failed"))
        return reply

    def status(self, device: str | None = None) -> dict[str, Any]:
        return self.call("status", device=device)["status"]

    def taps(self) -> dict[str, dict[str, Any]]:
        """Each endpoint's traffic tap: ``{"rover": {"url": "tcp://...", "clients": 1}}``."""
        return self.call("taps")["taps"]

    def button(self, device: str | None = None) -> dict[str, Any]:
        return self.call("button", device=device)["status"]

    def reset(self, device: str | None = None) -> dict[str, Any]:
        return self.call("reset", device=device)["status"]

    def fault(self, device: str | None = None, **knobs: float) -> dict[str, Any]:
        return self.call("fault", device=device, knobs=knobs)["faults"]

    def log(self, device: str | None = None) -> list[str]:
        return self.call("log", device=device)["log"]

    def wait_report(self, device: str | None = None, timeout: float = 10.0, after: int | None = None) -> dict:
        return self.call("wait_report", device=device, timeout=timeout, after=after)
