"""Bench manifests: the JSON file ``hilbench emulate --manifest`` writes so other programs find the bench.

Data safety comes first, because ``--manifest`` names a path the user typed:

- :func:`write_manifest` never replaces a file hilbench did not write. A
  manifest is recognised by its content: the marker key :data:`MARKER`, the
  writer's ``pid`` (with the process's start time, so a recycled pid is not
  taken for the bench) and a ``token`` unique to the writing bench. It refuses
  a live bench's manifest, takes over a stale one (its bench was killed and
  left it behind) and replaces its own. New files are created without ever
  clobbering (a hard link of a finished temporary file), so readers never see
  half a manifest and a file that appears meanwhile is not overwritten.
- :func:`remove_manifest` removes only the manifest this bench wrote, and only
  while it is still that one (same file, same token).
- :func:`read_manifest` is the one reader every client uses (the ``manifest``
  source of ``monitor``/``trace``/``record``, :meth:`ControlClient.from_manifest
  <hilbench.bench.control.ControlClient.from_manifest>`, the ``can``, ``lidar``,
  ``labgrid`` and ``run`` verbs, the pytest plug-in, the benchmarks): a file
  that is not a manifest gives one line (exit status 2), a manifest whose bench
  is gone too, ``bench not running (stale manifest, pid N gone)`` (exit status 1).
- :func:`endpoint_of` is the one ``FILE.json#NAME`` rule: the endpoint named
  ``NAME``, else the only one of the kind a verb wants; :func:`devices_on` the
  devices on an endpoint.

The manifest source lives here rather than in :mod:`hilbench.transports.sources`:
the manifest is the bench layer's format, and transports must not import the
bench layer. It is registered like any source plug-in (``hilbench.sources``
entry point ``manifest``) and hands back a transports
:class:`~hilbench.transports.sources.TcpSource`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from hilbench.errors import BenchError, UsageError
from hilbench.transports.sources.base import SourceError, SourceOpener

#: The key that marks a file as a hilbench manifest; its value is the manifest format version.
MARKER = "hilbench_manifest"
FORMAT = 1
#: Larger files are not manifests (a manifest lists endpoints and devices: a few kB).
MAX_SIZE = 4 << 20


class ManifestError(UsageError, ValueError):
    """The file is not a hilbench manifest, or hilbench may not replace it (one line, exit status 2)."""


class BenchNotRunning(BenchError):
    """The manifest's bench is gone (killed without removing it): one line, exit status 1."""


class ManifestBusy(BenchError):
    """The path holds the manifest of a bench that is still running (one line, exit status 1)."""


# --------------------------------------------------------------------------- processes


def process_start(pid: int) -> int | None:
    """When process ``pid`` started (clock ticks since boot, from /proc), or None where that is unknown."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_bytes()
    except OSError:
        return None
    # The command name (field 2) may hold spaces and parentheses: fields follow its last ')'.
    fields = raw[raw.rfind(b")") + 2:].split()
    try:
        return int(fields[19])  # field 22 of proc(5), counted from field 3
    except (IndexError, ValueError):
        return None


def pid_alive(pid: int, started: int | None = None) -> bool:
    """Whether process ``pid`` runs (and, given its recorded start time, is still the same process)."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's process: it exists
    except OSError:
        return False
    if started is not None:
        now = process_start(pid)
        if now is not None and now != started:
            return False  # the number was recycled for another process
    return True


# --------------------------------------------------------------------------- reading


class _NoManifest(ManifestError):
    """No file at the path (a reader reports it as :class:`BenchNotRunning`)."""


def _load(path: Path) -> Any:
    """The JSON a path holds; ManifestError in one line for anything else."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise _NoManifest(f"{path}: no such manifest (is the bench running? start it with hilbench emulate "
                            "--manifest)") from None
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ManifestError(f"{path}: not a bench manifest (not a regular file)")
    if st.st_size > MAX_SIZE:
        raise ManifestError(f"{path}: not a bench manifest ({st.st_size} bytes)")
    try:
        with open(path, "rb") as fh:
            return json.loads(fh.read(MAX_SIZE + 1))
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read: {exc.strerror}") from None
    except (ValueError, RecursionError):  # not JSON, not UTF-8 (UnicodeDecodeError is a ValueError)
        raise ManifestError(f"{path}: not a bench manifest (not JSON)") from None


def is_manifest(data: Any) -> bool:
    """Whether parsed JSON is a hilbench manifest: the marker, or (written before it) pid, endpoints, devices."""
    if not isinstance(data, dict):
        return False
    if MARKER in data:
        return True
    return (isinstance(data.get("pid"), int) and isinstance(data.get("endpoints"), list)
            and isinstance(data.get("devices"), list))


def stale_pid(data: dict[str, Any]) -> int | None:
    """The pid of a manifest whose bench is gone, else None (running, or no pid recorded)."""
    pid = data.get("pid")
    if not isinstance(pid, int) or isinstance(pid, bool):
        return None
    started = data.get("pid_start")
    return None if pid_alive(pid, started if isinstance(started, int) else None) else pid


def read_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A running bench's manifest; raises :class:`ManifestError` (not a manifest) or
    :class:`BenchNotRunning` (no manifest there, or ``bench not running (stale manifest, pid N gone)``), each
    one line."""
    path = Path(path)
    try:
        data = _load(path)
    except _NoManifest as exc:  # a bench removes its manifest when it stops: it is not running
        raise BenchNotRunning(str(exc)) from None
    if not isinstance(data, dict) or not isinstance(data.get("endpoints"), list):
        raise ManifestError(f"{path}: not a bench manifest (no endpoints)")
    pid = stale_pid(data)
    if pid is not None:
        raise BenchNotRunning(f"{path}: bench not running (stale manifest, pid {pid} gone)")
    return data


def endpoint_of(data: Mapping[str, Any], fragment: str | None, where: str,
                predicate: Callable[[dict[str, Any]], bool] | None = None,
                what: str = "endpoints") -> dict[str, Any]:
    """The endpoint a verb works on: the one named ``fragment`` (``FILE.json#NAME``), else the only one
    ``predicate`` accepts (every endpoint without one).

    ``where`` starts the messages (the manifest's path, ``bench:PROFILE``); ``what`` names the endpoints
    ``predicate`` accepts, in the plural (``"scanner endpoints"``). Raises :class:`~hilbench.errors.UsageError`
    in one line (exit status 2: the bench has no such endpoint) when no endpoint has that name, the named
    one is not among ``what``, none is, or several are and no name says which.
    """
    endpoints = [e for e in data.get("endpoints") or [] if isinstance(e, dict) and isinstance(e.get("name"), str)]
    names = ", ".join(e["name"] for e in endpoints) or "none"
    if fragment:
        found = next((e for e in endpoints if e["name"] == fragment), None)
        if found is None:
            raise UsageError(f"{where}: no endpoint named {fragment!r} (endpoints: {names})")
        if predicate is not None and not predicate(found):
            raise UsageError(f"{where}: endpoint {fragment!r} is not among the {what}")
        return found
    fitting = [e for e in endpoints if predicate is None or predicate(e)]
    if not fitting:
        raise UsageError(f"{where}: no {what} (endpoints: {names})")
    if len(fitting) > 1:
        raise UsageError(f"{where}: several {what} ({', '.join(e['name'] for e in fitting)}); add #NAME")
    return fitting[0]


def devices_on(data: Mapping[str, Any], endpoint: str | Mapping[str, Any]) -> list[dict[str, Any]]:
    """The devices a manifest lists on ``endpoint`` (its name, or its entry), in manifest order."""
    name = endpoint if isinstance(endpoint, str) else endpoint.get("name")
    return [d for d in data.get("devices") or [] if isinstance(d, dict) and d.get("endpoint") == name]


# --------------------------------------------------------------------------- writing


@dataclass
class ManifestClaim:
    """What :func:`write_manifest` wrote: remove it with :func:`remove_manifest` (only while it is ours)."""

    path: Path
    token: str
    inode: tuple[int, int] | None = None
    #: The pid of a stale manifest this write replaced (its bench had been killed), else None.
    took_over: int | None = None


def new_token() -> str:
    """A token naming one bench's manifests (the writer recognises its own by it)."""
    import secrets  # (here: the manifest source plug-in is loaded by every monitor, secrets imports hashlib)

    return secrets.token_hex(8)


def check_path(path: str | os.PathLike[str], token: str | None = None) -> int | None:
    """Whether a manifest may be written at ``path``; raises if not, returns the pid of a stale manifest there.

    Free: nothing there; this bench's own manifest (``token``); a manifest whose bench is gone.
    Refused: any other file (:class:`ManifestError`), a running bench's manifest (:class:`ManifestBusy`).
    """
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        if not path.parent.is_dir():
            raise ManifestError(f"{path}: cannot write the manifest: no directory {path.parent}") from None
        return None
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISREG(st.st_mode):
        raise ManifestError(f"{path}: exists and is not a hilbench manifest (not a regular file); refusing to "
                            "replace it (choose another --manifest path)")
    try:
        data = _load(path)
    except ManifestError:
        data = None
    if not is_manifest(data):
        raise ManifestError(f"{path}: exists and is not a hilbench manifest; refusing to replace it (choose "
                            "another --manifest path)")
    if token is not None and data.get("token") == token:
        return None
    pid = stale_pid(data)
    if pid is None:
        owner = data.get("pid")
        raise ManifestBusy(f"{path}: the manifest of a running bench (pid {owner}); stop that bench or choose "
                           "another --manifest path")
    return pid


def write_manifest(path: str | os.PathLike[str], data: dict[str, Any], *, token: str | None = None) -> ManifestClaim:
    """Write a manifest atomically (readers never see half a file), never replacing another's file.

    ``token`` names the writing bench (:func:`new_token`; a new one if None): its own manifest is
    replaced, a stale one taken over, anything else refused (see :func:`check_path`).
    """
    import tempfile  # (here: every monitor loads this module's source plug-in, not the writer)

    path = Path(path)
    token = token or new_token()
    doc = {MARKER: FORMAT, **data, "token": token}
    if isinstance(doc.get("pid"), int):
        doc.setdefault("pid_start", process_start(doc["pid"]))
    text = json.dumps(doc, indent=2) + "\n"
    stale = check_path(path, token)
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())  # a crash after the rename leaves the whole manifest, not an empty file
        os.chmod(tmp, 0o644)
        if os.path.lexists(path):
            # Ours or stale (checked just now): replace it in one step.
            os.replace(tmp, path)
        else:
            _create(tmp, path)
    except FileExistsError:
        raise ManifestError(f"{path}: a file appeared there while the manifest was written; refusing to replace "
                            "it") from None
    except OSError as exc:
        raise ManifestError(f"{path}: cannot write the manifest: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
    st = os.stat(path)
    return ManifestClaim(path, token, (st.st_dev, st.st_ino), stale)


def _create(tmp: Path, path: Path) -> None:
    """Put the finished ``tmp`` at ``path`` without ever replacing a file that is there."""
    try:
        os.link(tmp, path)  # atomic and no-clobber: FileExistsError if someone was faster
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
            raise
        # A file system without hard links: claim the name exclusively, then fill it in one step.
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
        os.replace(tmp, path)


def remove_manifest(claim: ManifestClaim | None) -> bool:
    """Remove the manifest ``claim`` wrote if it is still that file with that token; True if removed."""
    if claim is None:
        return False
    try:
        st = os.lstat(claim.path)
    except OSError:
        return False
    if claim.inode is not None and (st.st_dev, st.st_ino) != claim.inode:
        return False  # replaced since (a stale take-over by another bench, or the user's own file)
    try:
        data = _load(claim.path)
    except ManifestError:
        return False
    if not isinstance(data, dict) or data.get("token") != claim.token:
        return False
    with contextlib.suppress(FileNotFoundError):
        claim.path.unlink()
    return True


# --------------------------------------------------------------------------- the manifest source


def _tapped(path: str | os.PathLike[str], endpoint: str | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(manifest, endpoint entry)``: the endpoint named (default: the first with a tap) of a running bench."""
    try:
        data = read_manifest(path)
    except ManifestError as exc:
        raise SourceError(str(exc)) from None
    eps = [e for e in data["endpoints"] if isinstance(e, dict)]
    if endpoint is not None:
        eps = [e for e in eps if e.get("name") == endpoint]
        if not eps:
            raise SourceError(f"{path}: no endpoint named {endpoint!r}")
    for ep in eps:
        if isinstance(ep.get("tap"), str):
            return data, ep
    raise SourceError(f"{path}: the bench offers no tap (started with --no-tap?)")


def manifest_tap(path: str | os.PathLike[str], endpoint: str | None = None) -> tuple[str, str]:
    """``(tap URL, name)`` of an endpoint (default: the first with a tap) of a running bench."""
    _data, ep = _tapped(path, endpoint)
    return ep["tap"], f"{path}#{ep.get('name')}"


def open_manifest(spec: str, target: str, fragment: str, **_: object):
    """Source opener: the traffic tap of a running bench, found through its manifest; the source's
    ``bench_control`` is the bench's control channel and the endpoint (whose overflow ``monitor`` asks:
    :func:`hilbench.bench.control.control_overflow`)."""
    from hilbench.transports.sources.stream import TcpSource

    data, ep = _tapped(target, fragment or None)
    url = urlparse(ep["tap"])
    source = TcpSource(url.hostname or "127.0.0.1", url.port or 0, name=f"{target}#{ep.get('name')}")
    if isinstance(data.get("control"), str):
        source.bench_control = (data["control"], str(ep.get("name")))
    return source


def sniff_manifest(head: bytes) -> bool:
    """Whether a file's first bytes are a manifest's (``emulate --manifest`` takes any file name)."""
    return head.lstrip().startswith(b"{") and f'"{MARKER}"'.encode() in head


#: The ``manifest`` source plug-in (``hilbench.sources`` entry point).
SOURCE = SourceOpener("manifest", open_manifest, suffixes=(".json",), usage="/tmp/bench.json[#endpoint]",
                      what="the traffic tap of a running hilbench emulate, found through its manifest",
                      sniff=sniff_manifest)

__all__ = ["FORMAT", "MARKER", "SOURCE", "BenchNotRunning", "ManifestBusy", "ManifestClaim", "ManifestError",
           "check_path", "devices_on", "endpoint_of", "is_manifest", "manifest_tap", "new_token", "open_manifest", "pid_alive", "process_start",
           "read_manifest", "remove_manifest", "sniff_manifest", "stale_pid", "write_manifest"]
