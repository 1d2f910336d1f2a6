"""Byte sources for instruments: where traffic comes from, as timestamped chunks.

Every source yields :class:`~hilbench.transports.chunk.Chunk` s
``(t, source, data)``: the bytes one party put on the medium, complete at
time ``t`` (seconds, ``time.monotonic()`` for live data, the recording's own
clock for captures). The monitor, the recorder and the trace profiler consume
sources the same way.

Source strings are opened by plug-ins (:class:`SourceOpener`, registered in
the ``hilbench.sources`` entry-point group, as python-can's ``MESSAGE_READERS``
map file suffixes to readers): :func:`open_source` picks one by URL scheme
(``tcp://``), by file suffix (``.json``) or by the kind of file (``-``, a
character device, a FIFO, any other file). :func:`source_kinds` lists them
for help texts. Built in:

=====================================  ==================================================
source string                          what it opens
=====================================  ==================================================
``capture.hbcap``, ``trace.bin``       a capture file: hilbench format, or a raw dump
``-``, a FIFO                          the same, arriving live on stdin or a named pipe
``/dev/ttyUSB0``, a pty                a serial port, receive-only (sniffing a bus)
``serial:///dev/ttyUSB0?baud=N``       the same with its baud rate in the URL
``udp://127.0.0.1:PORT[?peer=H:P]``    datagrams arriving on a UDP port
``tcp://127.0.0.1:PORT``               a bench's tap server (capture format over TCP)
``manifest.json[#endpoint]``           the tap server of a running ``hilbench emulate``
=====================================  ==================================================

In-process benches are tapped with :class:`MediumSource`, and
:class:`PushSource` turns any callback (a pty proxy, a test) into a source.
``Source.chunks(idle)`` yields ``None`` after ``idle`` seconds without data
(live sources only); ``close()`` ends the iteration from another thread.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from urllib.parse import urlparse

from hilbench import registry
from hilbench.transports.chunk import Chunk
from hilbench.transports.sources.base import (
    SNIFF_SIZE,
    MediumSource,
    PeekedSource,
    PushSource,
    Source,
    SourceError,
    SourceOpener,
    SourceUnavailable,
    peek,
)
from hilbench.transports.sources.file import FileSource
from hilbench.transports.sources.serial import SerialSource
from hilbench.transports.sources.stream import StreamSource, TcpSource
from hilbench.transports.sources.udp import UdpSource


def source_kinds() -> list[SourceOpener]:
    """Every registered kind of source, in registration order."""
    return list(registry.sources.values())


def _by_kind(kind: str) -> SourceOpener:
    for opener in source_kinds():
        if kind in opener.kinds:
            return opener
    raise SourceError(f"no source plug-in opens a {kind}")


def open_source(spec: str, *, baud: int | None = None, speed: float | None = None,
                default_baud: int = 57_600) -> Source:
    """Open a source string (see the module docstring); raises :class:`SourceError` with one line.

    ``baud`` is the line rate of a serial port (``default_baud`` if not given)
    and the byte time of a raw file; ``speed`` replays a file in its recorded
    time (1.0) instead of as fast as possible.
    """
    options = {"baud": baud, "speed": speed, "default_baud": default_baud}
    if spec == "-":
        return _by_kind("stdin").open(spec, spec, "", **options)
    url = urlparse(spec)
    if len(url.scheme) > 1:  # one letter would be a Windows drive
        for opener in source_kinds():
            if url.scheme in opener.schemes:
                return opener.open(spec, spec, url.fragment, **options)
        schemes = sorted(f"{s}://" for o in source_kinds() for s in o.schemes)
        raise SourceError(f"{spec}: unknown source scheme {url.scheme!r} (use a path, -, {', '.join(schemes)})")
    path_text, _, fragment = spec.partition("#")
    path = Path(path_text)
    if not path.exists():
        if path.suffix.lower() == ".json":  # a manifest: its bench writes it, and removes it when it stops
            raise SourceUnavailable(f"{spec}: no such manifest (is the bench running? start it with hilbench "
                                    "emulate --manifest)")
        raise SourceUnavailable(f"{spec}: no such file, port or source")
    mode = os.stat(path).st_mode
    if stat.S_ISDIR(mode):
        raise SourceError(f"{spec}: is a directory, not a capture, port or source")
    kind = "char" if stat.S_ISCHR(mode) else "fifo" if stat.S_ISFIFO(mode) else "file"
    if kind == "file":
        for opener in source_kinds():
            if path.suffix.lower() in opener.suffixes:
                return opener.open(spec, path_text, fragment, **options)
        sniffers = [opener for opener in source_kinds() if opener.sniff is not None]
        if sniffers:  # a file named freely (a manifest written to bench.manifest, say)
            try:
                with open(path, "rb") as f:
                    head = f.read(SNIFF_SIZE)
            except OSError as exc:
                raise SourceUnavailable(f"{spec}: {exc.strerror}") from None
            for opener in sniffers:
                if opener.sniff(head):  # type: ignore[misc]
                    return opener.open(spec, path_text, fragment, **options)
    return _by_kind(kind).open(spec, path_text, fragment, **options)


__all__ = [
    "Chunk",
    "FileSource",
    "MediumSource",
    "PeekedSource",
    "PushSource",
    "SerialSource",
    "Source",
    "SourceError",
    "SourceUnavailable",
    "SourceOpener",
    "StreamSource",
    "TcpSource",
    "UdpSource",
    "open_source",
    "peek",
    "source_kinds",
]
