"""Writing a file so that a reader, a full disk or a kill never sees half of it.

:func:`atomic_write` writes to a temporary file in the target's directory,
flushes it to disk (``fsync``) and renames it over the target in one step
(``os.replace``): until then the old file stays whole, and if anything fails
(``ENOSPC``, ``EFBIG``, an exception, Ctrl-C) the temporary file is removed
and the old file is untouched. A replaced file keeps its permission bits (and,
where allowed, its owner and group). A symlink is written through: its target
is replaced and the link stays. A path that is no regular file (``/dev/null``,
a FIFO, a terminal) cannot be replaced and is written in place.

:func:`write_atomically` is the one-call form for data already in memory.
Long recordings stream into a file of their own instead
(:mod:`hilbench.transports.recording_file`).
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from hilbench.errors import HilbenchError

#: Longest part of the target's name kept in the temporary name (file names are at most 255 bytes).
_NAME_KEPT = 180


class WriteError(HilbenchError):
    """An output could not be written (disk full, file too large, no permission); one line, exit status 1.

    The message says what was kept: the old file (if there was one) is unchanged.
    """


def replaced_path(path: str | os.PathLike[str]) -> Path | None:
    """The regular file that writing ``path`` replaces (symlinks resolved; it need not exist yet), or None
    if ``path`` is something written in place (a device, FIFO or socket). A directory raises
    :class:`IsADirectoryError`."""
    real = Path(os.path.realpath(path))
    try:
        mode = os.stat(real).st_mode
    except FileNotFoundError:
        return real
    if stat.S_ISDIR(mode):
        raise IsADirectoryError(f"{path}: is a directory")
    return real if stat.S_ISREG(mode) else None


def temp_name(target: Path) -> Path:
    """A fresh hidden name next to ``target`` (``.NAME.1a2b3c4d.tmp``)."""
    import secrets  # (here: secrets imports hashlib, and a command that writes nothing need not)

    return target.with_name(f".{target.name[:_NAME_KEPT]}.{secrets.token_hex(4)}.tmp")


def create_temp(target: Path) -> tuple[int, Path]:
    """Create (exclusively) and open a temporary file next to ``target``; ``(descriptor, path)``.

    Made with mode 0o666 less the umask, as ``open()`` makes a new file.
    """
    for _ in range(100):
        tmp = temp_name(target)
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"{target.parent}: no free temporary name")  # pragma: no cover (2^32 names)


def keep_attributes(old: Path, new: Path) -> None:
    """Give ``new`` the permission bits (and, where allowed, owner and group) of ``old``, if it exists."""
    try:
        st = os.stat(old)
    except FileNotFoundError:
        return
    os.chmod(new, stat.S_IMODE(st.st_mode))
    with contextlib.suppress(OSError):  # only root may give a file away; a group of one's own is fine
        nst = os.stat(new)
        if (nst.st_uid, nst.st_gid) != (st.st_uid, st.st_gid):
            os.chown(new, st.st_uid, st.st_gid)
            os.chmod(new, stat.S_IMODE(st.st_mode))  # chown clears set-id bits


def sync_directory(directory: Path) -> None:
    """Flush a directory's entries to disk (after a rename), where the system allows it."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def describe_failure(path: str | os.PathLike[str], exc: OSError, *, existed: bool) -> str:
    """``PATH: cannot write: No space left on device (the old PATH is unchanged)``."""
    reason = exc.strerror or str(exc)
    kept = f" (the old {path} is unchanged)" if existed else f" (nothing was written to {path})"
    return f"{path}: cannot write: {reason}{kept}"


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "wb", *, encoding: str | None = None,
                 newline: str | None = None) -> Iterator[IO[Any]]:
    """A file object whose content replaces ``path`` in one step when the block ends without an exception.

    ``mode`` is ``"wb"`` or ``"w"`` (text, ``encoding`` default UTF-8). On an exception the old file is
    untouched and the temporary file removed; an :class:`OSError` of writing becomes a one-line
    :class:`WriteError` naming ``path``.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', not {mode!r}")
    if mode == "w" and encoding is None:
        encoding = "utf-8"
    target = replaced_path(path)
    if target is None:  # a device or FIFO: nothing to replace, written as it is
        try:
            with open(path, mode, encoding=encoding, newline=newline) as f:
                yield f
        except OSError as exc:
            raise WriteError(f"{path}: cannot write: {exc.strerror or exc}") from None
        return
    existed = target.exists()
    try:
        fd, tmp = create_temp(target)
    except OSError as exc:
        raise WriteError(f"{path}: cannot create a file in {target.parent}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, mode, encoding=encoding, newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        keep_attributes(target, tmp)
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise WriteError(describe_failure(path, exc, existed=existed)) from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    sync_directory(target.parent)


def write_atomically(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Replace ``path`` with ``data`` (str as UTF-8) in one step (see :func:`atomic_write`)."""
    if isinstance(data, str):
        data = data.encode()
    with atomic_write(path, "wb") as f:
        f.write(data)


__all__ = ["WriteError", "atomic_write", "create_temp", "describe_failure", "keep_attributes", "replaced_path",
           "sync_directory", "temp_name", "write_atomically"]
