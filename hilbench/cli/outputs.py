"""What every verb that writes files does before and while writing them, so nothing a user had is lost.

- :func:`check_outputs` runs before anything is opened or created: an output
  that is one of the verb's inputs (the same file, also through a symlink or
  a hard link; a file not there yet by its resolved path), two outputs naming
  one file, an output in a directory that does not exist, a directory as an
  output, and a recording onto an existing non-empty file (unless ``--force``)
  are refused in one line (exit status 2), and nothing is created.
- :func:`write_output` and :func:`output_file` replace a file in one step
  (:mod:`hilbench.transports.atomic_file`): a full disk or a kill leaves the
  old file whole.
- :func:`start_recording` streams a recording into its ``.partial`` file,
  flushed at least every half second, renamed into place when it ends
  (:mod:`hilbench.transports.recording_file`).
"""

from __future__ import annotations

import os
import stat
import sys
from collections.abc import Callable, Iterable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import IO, Any
from urllib.parse import urlparse

from hilbench.cli.common import CliError
from hilbench.transports.atomic_file import atomic_write, write_atomically
from hilbench.transports.recording_file import Recording, RecordingFile

#: An output: how the command line names it (``--json-out``, ``FILE``) and its path (None: not given).
Output = tuple[str, str | None]


@dataclass(frozen=True)
class _File:
    """What a path names, to tell whether two names are one file."""

    name: str
    ident: tuple[int, int] | None  # (st_dev, st_ino) of what is there, following links
    real: str | None  # the resolved path (also for a file that does not exist yet)

    def same(self, other: _File) -> bool:
        if self.ident is not None and self.ident == other.ident:
            return True
        return self.real is not None and self.real == other.real


def _stdio(name: str, fd: int) -> _File:
    """stdin or stdout: a file it is redirected to (``< X``, ``>> X``); a pipe or terminal is no file."""
    try:
        st = os.fstat(fd)
    except OSError:
        return _File(name, None, None)
    return _File(name, (st.st_dev, st.st_ino) if stat.S_ISREG(st.st_mode) else None, None)


def _named(path: str, *, stdio_fd: int) -> _File:
    if path == "-":
        return _stdio(path, stdio_fd)
    try:
        st = os.stat(path)
        ident: tuple[int, int] | None = (st.st_dev, st.st_ino)
    except (OSError, ValueError):
        ident = None
    return _File(path, ident, os.path.realpath(path))


def source_files(spec: str | None) -> list[str]:
    """The files a source string (as ``monitor``, ``record``, ``trace`` take it) may read: the path of a
    file, port or manifest (without its ``#endpoint``), ``-`` (stdin), a ``serial://`` URL's path, the profile
    file of ``bench:PROFILE``."""
    if not spec:
        return []
    if spec == "-":
        return ["-"]
    if spec.startswith("bench:"):
        body = spec[len("bench:"):].partition("#")[0]
        return [body] if body and os.path.isfile(body) else []
    url = urlparse(spec)
    if len(url.scheme) > 1:  # (one letter would be a Windows drive)
        return [url.path] if url.path and os.path.exists(url.path) and not os.path.isdir(url.path) else []
    path = spec.partition("#")[0]
    return [path, spec] if path != spec else [spec]


def check_outputs(outputs: Iterable[Output], *, inputs: Iterable[str | None] = (),
                  recordings: Sequence[str] = (), force: bool = False) -> None:
    """Refuse, in one line and before anything is created, outputs that would destroy what the user has.

    ``outputs``: ``(label, path)`` pairs (None paths are skipped; ``-`` is stdout). ``inputs``: the files the
    verb reads (paths; ``-`` is stdin). ``recordings``: the labels of outputs that are recordings, which do
    not replace an existing non-empty file (or a killed recording's ``.partial`` file) unless ``force``.
    """
    given = [(label, path) for label, path in outputs if path is not None]
    ins = [_named(p, stdio_fd=0) for p in dict.fromkeys(p for p in inputs if p)]
    seen: list[tuple[str, _File]] = []
    for label, path in given:
        out = _named(path, stdio_fd=1)
        shown = "standard output" if path == "-" else path
        for inp in ins:
            if out.same(inp):
                what = "standard input" if inp.name == "-" else inp.name
                same = "" if what == shown else f" ({what})"
                raise CliError(f"{label} {shown} is the input{same}: writing it would destroy what is read; "
                               "choose another file")
        for other_label, other in seen:
            if out.same(other):
                raise CliError(f"{other_label} and {label} name the same file {path}; choose two")
        seen.append((label, out))
        if path == "-":
            continue
        if label in recordings:
            recording = RecordingFile(path, force=force)
            if recording.partial is not None:  # where it streams to until it ends: no input either
                running = _named(str(recording.partial), stdio_fd=-1)
                for inp in ins:
                    if running.same(inp):
                        raise CliError(f"{label} {path} records into {recording.partial}, the input: writing it "
                                       "would destroy what is read; choose another file")
            recording.check()
            continue
        if os.path.isdir(path):
            raise CliError(f"{label} {path}: is a directory")
        parent = os.path.dirname(os.path.realpath(path))
        if not os.path.isdir(parent):
            raise CliError(f"{label} {path}: no directory {parent}")


def write_output(path: str | None, data: str | bytes) -> None:
    """``data`` to stdout (``None`` or ``-``) or into ``path``, replacing it in one step."""
    if path in (None, "-"):
        if isinstance(data, bytes):
            sys.stdout.buffer.write(data)
        else:
            sys.stdout.write(data)
        sys.stdout.flush()
        return
    write_atomically(path, data)


def output_file(path: str, mode: str = "w") -> AbstractContextManager[IO[Any]]:
    """A file object whose content replaces ``path`` in one step when the block ends without an error."""
    return atomic_write(path, mode)


#: What a ``--png`` picture may be written as, by the file's suffix (none: PNG).
PICTURE_FORMATS = ("png", "svg", "pdf")


def picture_format(label: str, path: str, what: str) -> str:
    """The matplotlib format of picture ``path`` by its suffix (none: ``png``); another suffix is refused in
    one line (exit status 2), before anything is drawn."""
    suffix = os.path.splitext(path)[1].lstrip(".").lower()
    if suffix and suffix not in PICTURE_FORMATS:
        raise CliError(f"{label} {path}: {what} is drawn as .png (or .svg, .pdf)")
    return suffix or "png"


def start_recording(path: str, open_writer: Callable[[str], Any], *, force: bool = False) -> Recording:
    """A recording into ``path`` (see :mod:`hilbench.transports.recording_file`); ``open_writer(p)`` makes the
    format's writer on the path it is given."""
    return Recording(path, open_writer, force=force)


__all__ = ["PICTURE_FORMATS", "Output", "check_outputs", "output_file", "picture_format", "source_files",
           "start_recording", "write_output"]
