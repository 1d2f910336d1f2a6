"""Recording to a file without losing what was recorded, or what the file held before.

A recording of real hardware cannot be made again, so:

- it streams into ``NAME.partial.SUFFIX`` next to the file asked for (the
  ``.partial`` goes before the format's suffix, so ``rec.hbcap`` records into
  ``rec.partial.hbcap`` and ``run.log.gz`` into ``run.partial.log.gz``, and every
  tool still tells the format from the name), flushed at least every
  :data:`FLUSH_EVERY` seconds: a recorder killed with ``kill -9`` (or a machine
  that loses power after the page cache was written) leaves everything up to
  the last flush there, readable as a capture cut short;
- an ended recording (its source ended, Ctrl-C, SIGTERM, a time limit) is
  flushed to disk and renamed to the name asked for in one step
  (``os.replace``): until then an old file of that name stays whole;
- an existing non-empty file, or the ``.partial`` file a killed recording left,
  is not replaced unless ``force``; one recorder at a time writes a file (a
  lock on the ``.partial`` file);
- a write that fails (disk full, file too large) stops the recording; what was
  written stays in the ``.partial`` file (removed if it holds nothing) and the
  old file is unchanged.

A device, FIFO or ``-`` (stdout) is written in place, flushed as often.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hilbench.errors import UsageError
from hilbench.transports.atomic_file import WriteError, keep_attributes, replaced_path, sync_directory

#: Seconds between flushes of a running recording (a kill loses at most this, plus one read's wait).
FLUSH_EVERY = 0.5
#: The infix of a running recording's file name.
PARTIAL = ".partial"
#: Compression suffixes: the format's suffix is the one before them (``.log.gz``).
COMPRESSED = (".gz", ".bz2", ".xz", ".zst")


class RecordingRefused(UsageError):
    """A recording that would replace a file (or another recording's data) without ``force``: exit status 2."""


def partial_path(path: str | os.PathLike[str]) -> Path:
    """Where a recording of ``path`` streams while it runs: ``.partial`` before the format's suffix."""
    p = Path(path)
    stem, ext = os.path.splitext(p.name)
    if ext.lower() in COMPRESSED:
        inner_stem, inner_ext = os.path.splitext(stem)
        if inner_ext:
            stem, ext = inner_stem, inner_ext + ext
    return p.with_name(f"{stem}{PARTIAL}{ext}")


def _size(path: Path) -> int | None:
    """Size of a regular file (following links), None if nothing is there; a non-file counts as non-empty."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return None
    return st.st_size if stat.S_ISREG(st.st_mode) else 1


class RecordingFile:
    """The file a recording of ``path`` writes (see the module docstring): :meth:`check`, :meth:`claim`,
    then a writer on :attr:`write_path`, then :meth:`finish` (or :meth:`abandon`)."""

    def __init__(self, path: str | os.PathLike[str], *, force: bool = False) -> None:
        self.path = str(path)
        self.force = force
        try:
            self.target = None if self.path == "-" else replaced_path(path)
        except IsADirectoryError:
            raise RecordingRefused(f"{path}: is a directory") from None
        self.partial = partial_path(self.target) if self.target is not None else None
        self.existed = False
        self._fd: int | None = None

    @property
    def write_path(self) -> str:
        """The path the format's writer opens."""
        return str(self.partial) if self.partial is not None else self.path

    def check(self) -> None:
        """Refuse (one line) what :meth:`claim` would refuse, without creating anything."""
        if self.target is None:
            return
        if not self.target.parent.is_dir():
            raise RecordingRefused(f"{self.path}: no directory {self.target.parent}")
        size = _size(self.target)
        if size and not self.force:
            raise RecordingRefused(f"{self.path}: exists ({size} bytes); a recording does not replace a file "
                                   "(choose another name, or add --force)")
        size = _size(self.partial)
        if size and not self.force:
            raise RecordingRefused(f"{self.path}: {self.partial} holds {size} bytes of an earlier recording that "
                                   "did not end (killed?); move it away first (or add --force to replace it)")

    def claim(self) -> None:
        """Create (or take) the ``.partial`` file and lock it; refused as :meth:`check` says, or if another
        recording is writing it."""
        self.check()
        if self.partial is None:
            return
        flags = os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW
        created = True
        try:
            fd = os.open(self.partial, flags | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            created = False
            try:
                fd = os.open(self.partial, flags)
            except OSError as exc:
                raise RecordingRefused(f"{self.path}: cannot use {self.partial}: {exc.strerror or exc}") from None
        except OSError as exc:
            raise WriteError(f"{self.path}: cannot create {self.partial}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise RecordingRefused(f"{self.path}: another recording is writing {self.partial}") from None
            raise
        if not created and os.fstat(fd).st_size and not self.force:  # filled since check(): not ours to empty
            os.close(fd)
            raise RecordingRefused(f"{self.path}: {self.partial} holds an earlier recording; move it away first")
        os.ftruncate(fd, 0)
        self._fd = fd
        self.existed = self.target is not None and self.target.exists()

    def sync(self) -> None:
        """Flush what the writer handed to the system to the disk."""
        if self._fd is not None:
            os.fsync(self._fd)

    def finish(self) -> None:
        """Put the recording at its name in one step (the writer closed already)."""
        if self._fd is None or self.partial is None or self.target is None:
            return
        try:
            self.sync()
            if _size(self.target) and not self.force:  # absent or empty when the recording started
                raise WriteError(f"{self.path}: a file of that name appeared during the recording; the "
                                 f"recording is in {self.partial}")
            keep_attributes(self.target, self.partial)
            os.replace(self.partial, self.target)
        except OSError as exc:
            raise WriteError(f"{self.path}: cannot finish the recording: {exc.strerror or exc}; it is in "
                             f"{self.partial}") from None
        finally:
            self._release()
        sync_directory(self.target.parent)

    def holds_data(self) -> bool:
        """Whether the ``.partial`` file has anything on disk (what a failed recording wrote before it failed)."""
        if self._fd is None:
            return False
        try:
            return os.fstat(self._fd).st_size > 0
        except OSError:
            return False

    def abandon(self, *, keep: bool) -> None:
        """Give up: keep the ``.partial`` file (it holds data) or remove it (it holds nothing)."""
        if self._fd is None or self.partial is None:
            return
        if not keep:
            with contextlib.suppress(OSError):
                self.partial.unlink()
        self._release()

    def _release(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None


class Recording:
    """A format's writer (hilbench capture, pcap, CAN log) recording into a :class:`RecordingFile`.

    ``open_writer(path)`` makes the writer on the path it is given (the ``.partial`` file; its suffix is the
    final name's). The writer needs ``chunk(chunk)``, ``flush()``, ``close()`` and counts ``bytes`` and
    ``records``. :meth:`close` ends the recording: renamed into place if every write succeeded.
    """

    def __init__(self, path: str | os.PathLike[str], open_writer: Callable[[str], Any], *,
                 force: bool = False) -> None:
        self.file = RecordingFile(path, force=force)
        self.path = self.file.path
        self.file.claim()
        try:
            self.writer = open_writer(self.file.write_path)
        except OSError as exc:
            self.file.abandon(keep=False)
            raise WriteError(f"{self.path}: cannot write: {exc.strerror or exc}") from None
        except BaseException:
            self.file.abandon(keep=False)
            raise
        self.failed: BaseException | None = None
        self._flushed = time.monotonic()
        self._closed = False

    @property
    def bytes(self) -> int:
        return getattr(self.writer, "bytes", 0)

    @property
    def records(self) -> int:
        return getattr(self.writer, "records", 0)

    def chunk(self, chunk: Any) -> None:
        """Record one chunk (and flush when :data:`FLUSH_EVERY` has passed)."""
        try:
            self.writer.chunk(chunk)
        except BrokenPipeError:
            raise  # the reader of stdout went away: the command line ends quietly
        except OSError as exc:
            self._fail(exc)
        except Exception as exc:  # refused by the format (pcap: not a datagram): nothing more is recorded
            self.failed = exc
            self._salvage()
            written = self.file.write_path
            if written != self.path and len(exc.args) == 1 and isinstance(exc.args[0], str):
                exc.args = (exc.args[0].replace(written, self.path),)  # the .partial file goes away: name the file
            raise
        if time.monotonic() - self._flushed >= FLUSH_EVERY:
            self.flush()

    def tick(self) -> None:
        """Flush if :data:`FLUSH_EVERY` has passed since the last flush (call while the source is quiet)."""
        if time.monotonic() - self._flushed >= FLUSH_EVERY:
            self.flush()

    def flush(self) -> None:
        """Hand everything written so far to the system (a kill no longer loses it)."""
        self._flushed = time.monotonic()
        if self._closed or self.failed is not None:
            return
        try:
            self.writer.flush()
        except BrokenPipeError:
            raise
        except OSError as exc:
            self._fail(exc)

    def _salvage(self) -> None:
        """After a failure, hand what the writer still buffers to the file, as far as it goes."""
        with contextlib.suppress(Exception):
            self.writer.flush()

    def _fail(self, exc: OSError) -> None:
        """A write failed: stop, keep what was written, and say where (raises :class:`WriteError`)."""
        self.failed = exc
        self._salvage()
        reason = exc.strerror or str(exc)
        f = self.file
        if f.partial is None:
            raise WriteError(f"{self.path}: cannot write: {reason}") from None
        kept = f"what was written before is in {f.partial}" if f.holds_data() else "nothing was recorded"
        old = f"; the old {self.path} is unchanged" if f.existed else ""
        raise WriteError(f"{self.path}: recording stopped: {reason}; {kept}{old}") from None

    def close(self) -> None:
        """End the recording: renamed into place, or (after a failed write) left in the ``.partial`` file."""
        if self._closed:
            return
        self._closed = True
        if self.failed is not None:
            keep = self.file.holds_data()  # judged before the writer's close adds to it (a pcap's header)
            with contextlib.suppress(Exception):
                self.writer.close()
            self.file.abandon(keep=keep)
            return
        try:
            self.writer.close()
        except BrokenPipeError:
            self.file.abandon(keep=self.file.holds_data())
            raise
        except OSError as exc:
            self.failed = exc
            try:
                self._fail(exc)
            finally:
                self.file.abandon(keep=self.file.holds_data())
        except Exception as exc:
            self.failed = exc
            self.file.abandon(keep=self.file.holds_data())
            raise
        self.file.finish()

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["COMPRESSED", "FLUSH_EVERY", "PARTIAL", "Recording", "RecordingFile", "RecordingRefused", "partial_path"]
