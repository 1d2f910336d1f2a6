"""The control channel as a fuzz target (:mod:`hilbench.fuzzing`, kind ``server``): a client's session of request
lines on a running bench.

A session is the bytes one client sends over one connection, cut into request lines by
:func:`~hilbench.bench.control.next_request` and answered by :meth:`~hilbench.bench.control.ControlServer.reply`
as the channel's loop does, so every command meets whatever the mutations made of the requests. The client
counts as gone (a command that waits, ``wait_report``, returns at once), as one that sends its session and
leaves. ``good`` counts the requests answered ``"ok": true``, ``dropped`` the others.

Each family that takes control commands brings a :class:`ControlTarget` in its own files (registered in
``hilbench.fuzz_targets`` as ``server-control-<family>``): the endpoints and devices of a small bench and the
requests a client sends them. Each drives a bench of its own; ``server-control`` (:data:`CONTROL`) drives
them all at once, on one bench holding every registered control target's endpoints and devices, with the
requests of all (a device name now and then swapped for another's) and the bench's own commands.

:func:`running_bench` is the kit for any target that needs a running bench: started on first use (every port a
free one, on 127.0.0.1), stopped at exit.
"""

from __future__ import annotations

import atexit
import json
import random
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from hilbench.fuzzing import FuzzTarget, TracebackWatch, targets

#: A bench's command costs about this long to answer: the line the figures are measured against.
LINE = "a client sending 1 000 requests/s of 60 bytes"
LINE_RATE = 1000 * 60
#: Share of a session's requests that are the bench's own commands (:data:`~hilbench.bench.control.BENCH_COMMANDS`).
BENCH_SHARE = 0.3
#: Share of requests naming a device whose name is swapped for another device's (or nobody's).
SWAP_SHARE = 0.1

_lock = threading.Lock()
_benches: dict[str, Any] = {}


def running_bench(key: str, profile: dict[str, Any]) -> Any:
    """The :class:`~hilbench.bench.Bench` of ``profile`` (a parsed TOML table; ``schema`` may be left out) kept
    under ``key``: started on first use with its control channel served, stopped at exit; every port a free
    one, on 127.0.0.1."""
    with _lock:
        if key not in _benches:
            from hilbench.bench import Bench
            from hilbench.bench.profile import parse_profile

            bench = Bench(parse_profile({"schema": 1, **profile}, f"{key}.toml")).start()
            bench.serve_control()
            atexit.register(bench.stop)
            _benches[key] = bench
        return _benches[key]


def merge_profiles(parts: Sequence[dict[str, Any]], description: str) -> dict[str, Any]:
    """One profile holding every part's endpoints, devices and other tables. Endpoints of one name are
    refused; a table two parts give must be the same, or both tables whose lists are joined (a scene's
    walls)."""
    out: dict[str, Any] = {"schema": 1, "description": description, "endpoints": {}, "devices": []}
    for part in parts:
        for key, value in part.items():
            if key in ("schema", "description"):
                continue
            if key == "endpoints":
                clash = set(out["endpoints"]) & set(value)
                if clash:
                    raise ValueError(f"two control targets name endpoint {sorted(clash)[0]!r}")
                out["endpoints"].update(value)
            elif key == "devices":
                out["devices"] += list(value)
            elif key not in out or out[key] == value:
                out[key] = value
            elif isinstance(value, dict) and isinstance(out[key], dict):
                out[key] = _join(out[key], value, key)
            else:
                raise ValueError(f"two control targets give different {key!r} tables")
    return out


def _join(a: dict[str, Any], b: dict[str, Any], key: str) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        if isinstance(v, list) and isinstance(out.get(k), list):
            out[k] = out[k] + [x for x in v if x not in out[k]]
        elif k not in out or out[k] == v:
            out[k] = v
        else:
            raise ValueError(f"two control targets give different {key}.{k}")
    return out


def control_session(rng: random.Random, size: int, requests: Sequence[Callable[[random.Random], dict[str, Any]]],
                    devices: Sequence[str] = ()) -> bytes:
    """What a client of the channel sends over one connection: request lines, one JSON object each, made by
    ``requests`` (a family's) and the bench's own commands; now and then a request naming a device names
    another of ``devices`` (or one that is not there)."""
    from hilbench.bench.control import BENCH_COMMANDS

    out = bytearray()
    while len(out) < size:
        if not requests or rng.random() < BENCH_SHARE:
            req: dict[str, Any] = {"cmd": rng.choice(BENCH_COMMANDS)}
        else:
            req = rng.choice(requests)(rng)
            if "device" in req and rng.random() < SWAP_SHARE:
                req["device"] = rng.choice([*devices, "nobody"])
        out += json.dumps(req).encode() + b"\n"
    return bytes(out)


class ControlSession:
    """One client's session: lines cut as the channel's loop cuts them, each answered by a running bench."""

    def __init__(self, bench: Any) -> None:
        from hilbench.bench import control

        self.control = control
        self.server = bench.control
        self.buf = bytearray()
        self.gone = threading.Event()
        self.gone.set()  # the client sent its session and left: waits end at once
        self.ok = 0
        self.bad = 0
        self.watch = TracebackWatch.shared()
        self.watch.clear()

    def _answer(self, line: bytes) -> None:
        with self.control.serving(self.gone):
            reply = json.loads(self.server.reply(line))  # what the client reads must be one JSON object
        if reply.get("ok") is True:
            self.ok += 1
        else:
            assert isinstance(reply.get("error"), str) and "\n" not in reply["error"], reply
            self.bad += 1

    def feed(self, data: bytes) -> None:
        self.buf += data
        while True:
            try:
                line = self.control.next_request(self.buf)
            except self.control.RequestTooLong:
                self.bad += 1
                continue
            if line is None:
                break
            self._answer(line)

    def finish(self) -> None:
        if self.buf.strip():  # a last line without its newline is still a request
            self._answer(bytes(self.buf))
        self.watch.check()

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.bad


def _device_names(profile: dict[str, Any]) -> list[str]:
    return [d["name"] for d in profile.get("devices", ()) if isinstance(d.get("name"), str)]


@dataclass(frozen=True)
class ControlTarget(FuzzTarget):
    """A family's control target: :attr:`profile` is its bench (a TOML table: endpoints, devices, other tables
    such as a scene), :attr:`request` makes one request for its devices. Make one with :func:`control_target`."""

    profile: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    request: Callable[[random.Random], dict[str, Any]] | None = None


def control_target(family: str, profile: dict[str, Any],
                   request: Callable[[random.Random], dict[str, Any]]) -> ControlTarget:
    """``server-control-<family>``: the control channel of a bench of ``profile``, sent ``request`` s and the
    bench's own commands."""
    name = f"server-control-{family}"
    devices = _device_names(profile)
    return ControlTarget(
        name, f"control channel: a client's session of request lines on a running {family} bench",
        lambda: ControlSession(running_bench(name, profile)), LINE_RATE, LINE,
        lambda rng, size: control_session(rng, size, [request], devices), kind="server", max_input=1024,
        profile=profile, request=request)


def _parts() -> list[ControlTarget]:
    return [t for t in targets() if isinstance(t, ControlTarget)]


def _all_profile() -> dict[str, Any]:
    return merge_profiles([t.profile for t in _parts()], "every registered control target's devices on one bench")


def _all_session(rng: random.Random, size: int) -> bytes:
    parts = _parts()
    return control_session(rng, size, [t.request for t in parts if t.request is not None],
                           [n for t in parts for n in _device_names(t.profile)])


#: ``server-control``: every registered :class:`ControlTarget`'s devices on one bench, sent all their requests.
CONTROL = FuzzTarget("server-control", "control channel: a client's session of request lines on a running bench "
                     "with every family that takes commands", lambda: ControlSession(running_bench(
                         "server-control", _all_profile())), LINE_RATE, LINE, _all_session, kind="server",
                     max_input=1024)

__all__ = ["CONTROL", "ControlSession", "ControlTarget", "control_session", "control_target", "merge_profiles",
           "running_bench"]
