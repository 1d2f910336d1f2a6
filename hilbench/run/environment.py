"""From bench manifests to the environment a client runs in under ``hilbench run``."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from hilbench.errors import BenchError, UsageError
from hilbench.run.build import ShimBuildError, shim_library

#: What ``HILBENCH_RUN_SHIM`` / ``--shim`` accept.
SHIMS = ("auto", "c", "python")


@dataclass
class BenchPorts:
    """A running bench's port-state server as its manifest lists it: the socket and the ptys by endpoint."""

    manifest: str
    socket: str | None  # None: the bench has no ptys (no port-state server)
    ports: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The manifest's ``clock`` entry of a virtual-time bench (its clock page), else None.
    clock: dict[str, Any] | None = None

    @property
    def rdevs(self) -> list[int]:
        return [int(p["rdev"]) for p in self.ports.values()]


def manifest_paths(given: Iterable[str] | None, environ: Mapping[str, str] | None = None) -> list[str]:
    """``--manifest`` values, else ``$HILBENCH_MANIFEST`` (several joined with ``:``); raises UsageError."""
    paths = [p for p in (given or []) if p]
    if not paths:
        env = (os.environ if environ is None else environ).get("HILBENCH_MANIFEST", "")
        paths = [p for p in env.split(os.pathsep) if p]
    if not paths:
        raise UsageError("no bench given: --manifest FILE (what `hilbench emulate --manifest FILE` writes) "
                         "or HILBENCH_MANIFEST=FILE")
    return paths


def read_bench(manifest: str | os.PathLike[str] | Mapping[str, Any], *, check: bool = True) -> BenchPorts:
    """The port-state server of the bench a manifest (a file, or its parsed content) describes.

    A file is read with :func:`~hilbench.bench.manifest.read_manifest`. With ``check``, the bench must
    answer on its socket. Raises :class:`BenchError` (not running, no port-state server) or :class:`UsageError`
    (not a manifest), one line each.
    """
    if isinstance(manifest, Mapping):
        data, name = manifest, str(manifest.get("manifest_path") or "the manifest")
        if not isinstance(data.get("endpoints"), list):
            raise UsageError(f"{name}: not a bench manifest (no endpoints)")
    else:
        from hilbench.bench.manifest import read_manifest

        name = str(manifest)
        data = read_manifest(manifest)
    lines = data.get("port_state")
    clock = data.get("clock")
    clock = dict(clock) if isinstance(clock, Mapping) and clock.get("virtual") else None
    if isinstance(lines, Mapping) and isinstance(lines.get("socket"), str):
        bench = BenchPorts(name, lines["socket"], dict(lines.get("ports") or {}), clock)
    else:  # a bench without ptys (sockets only): nothing to serve but its clock, if it has one
        bench = BenchPorts(name, None, {}, clock)
    pid = data.get("pid")
    if check and bench.socket is not None and not ping(bench.socket):
        raise BenchError(f"{name}: the bench (pid {pid}) does not answer on {bench.socket}; is it still running?")
    if check and bench.socket is None and isinstance(pid, int) and not _alive(pid):
        raise BenchError(f"{name}: the bench (pid {pid}) is not running")
    if check and clock is not None and not os.path.exists(str(clock.get("page"))):
        raise BenchError(f"{name}: the bench's clock page {clock.get('page')} is gone; is it still running?")
    return bench


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def ping(path: str, timeout: float = 2.0) -> bool:
    """Whether a port-state server answers on ``path``."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(timeout)
            s.connect(path)
            s.sendall(b"0 ping\n")
            return s.recv(64).startswith(b"ok")
    except OSError:
        return False


def ports_value(benches: Iterable[BenchPorts]) -> str:
    """``HILBENCH_RUN_PORTS``: ``RDEV=SOCKET`` for every served pty, joined with ``;``."""
    return ";".join(f"{rdev}={b.socket}" for b in benches if b.socket for rdev in b.rdevs)


def python_site_dir() -> str:
    """The directory whose ``sitecustomize`` loads the pyserial fallback."""
    return str(resources.files("hilbench.run").joinpath("site"))


def run_environment(benches: Iterable[BenchPorts], shim: str = "auto",
                    environ: Mapping[str, str] | None = None) -> tuple[dict[str, str], list[str]]:
    """The environment for a client of ``benches`` and notes for the user (a fallback taken).

    ``shim``: ``c`` (the preload library, built on first use; raises
    :class:`ShimBuildError` without a compiler), ``python`` (the pyserial
    fallback alone), ``auto`` (c, else python with a note).
    """
    if shim not in SHIMS:
        raise UsageError(f"unknown shim {shim!r}; expected one of {', '.join(SHIMS)}")
    benches = list(benches)
    env = dict(os.environ if environ is None else environ)
    env["HILBENCH_RUN_PORTS"] = ports_value(benches)
    clocks = [b for b in benches if b.clock is not None]
    if len(clocks) > 1:
        raise UsageError(f"{clocks[0].manifest} and {clocks[1].manifest} both run in virtual time: a client "
                         "can follow one bench's clock only")
    if clocks and shim == "python":
        raise UsageError("virtual time needs the preload shim: --shim python cannot put a client on the bench's "
                         "clock")
    notes: list[str] = []
    library = None
    if shim in ("auto", "c"):
        try:
            library = shim_library()
        except ShimBuildError as exc:
            if clocks:
                raise BenchError(f"virtual time needs the preload shim: {exc}") from None
            if shim == "c":
                raise
            notes.append(f"{exc}; pyserial clients get the Python fallback, compiled programs see a plain pty")
    if clocks:
        from hilbench.run.vclock_page import ENV

        env[ENV] = str(clocks[0].clock["page"])  # type: ignore[index]
        # Python clients iterate sets of strings in the same order in every run (PLAN26 §6.5)
        env.setdefault("PYTHONHASHSEED", "0")
    else:
        env.pop("HILBENCH_CLOCK", None)  # (a client of a wall-clock bench never follows a stale page)
    if library is not None:
        env["LD_PRELOAD"] = ":".join(p for p in (str(library), env.get("LD_PRELOAD", "")) if p)
        env["HILBENCH_RUN"] = "c"
    else:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (python_site_dir(), env.get("PYTHONPATH", "")) if p)
        env["HILBENCH_RUN"] = "python"
    return env, notes


__all__ = ["SHIMS", "BenchPorts", "manifest_paths", "ping", "ports_value", "python_site_dir", "read_bench",
           "run_environment"]
