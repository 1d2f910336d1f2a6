"""Building ``hilbench run``'s preload shim with the system's C compiler, once per user and source.

One library from two sources: ``shim.c`` (modem lines, breaks, flushes on the
bench's ptys) and ``vclock.c`` (virtual time; dormant unless ``HILBENCH_CLOCK``
names a bench's clock page). It is cached under ``$XDG_CACHE_HOME/hilbench``
(``~/.cache/hilbench``), named after a hash of the sources, the machine and the
compiler, so an upgrade of
hilbench or a new compiler builds afresh and concurrent first uses cannot see
half a file (each builds beside it and renames).
"""

from __future__ import annotations

import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
from importlib import resources
from pathlib import Path

from hilbench.errors import HilbenchError

SHIM_SOURCE = "shim.c"
#: Every C source of the library, in link order.
SOURCES = (SHIM_SOURCE, "vclock.c")


class ShimBuildError(HilbenchError):
    """No C compiler, or the shim did not compile (the Python fallback then applies)."""


def shim_source(name: str = SHIM_SOURCE) -> bytes:
    """A C source shipped in the package (``shim.c`` by default)."""
    return resources.files("hilbench.run").joinpath(name).read_bytes()


def shim_sources() -> dict[str, bytes]:
    """Every source of the library by file name."""
    return {name: shim_source(name) for name in SOURCES}


def find_compiler() -> list[str] | None:
    """``$CC`` (which may carry arguments, e.g. ``ccache gcc``), else cc, gcc or clang on PATH."""
    cc = os.environ.get("CC")
    if cc:
        words = shlex.split(cc)
        if words and shutil.which(words[0]):
            return words
        return None
    for name in ("cc", "gcc", "clang"):
        found = shutil.which(name)
        if found:
            return [found]
    return None


def cache_dir() -> Path:
    """Where built shims live: ``$XDG_CACHE_HOME/hilbench``, else ``~/.cache/hilbench``.

    LD_PRELOAD splits on spaces and colons, so a cache path with either (or an
    unwritable one) falls back to a private directory under the system temp dir.
    """
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = Path(base) / "hilbench"
    if not any(c in str(path) for c in " :") and path.is_absolute():
        try:
            path.mkdir(parents=True, exist_ok=True)
            if os.access(path, os.W_OK):
                return path
        except OSError:
            pass
    return _private_temp_dir()


def _private_temp_dir() -> Path:
    """``/tmp/hilbench-UID``, accepted only if it is ours and nobody else can write it (it holds a
    library other programs will load)."""
    path = Path(tempfile.gettempdir()) / f"hilbench-{os.getuid()}"
    try:
        path.mkdir(mode=0o700, exist_ok=True)
        st = path.lstat()
        if st.st_uid == os.getuid() and not st.st_mode & 0o022 and path.is_dir() and not path.is_symlink():
            return path
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix="hilbench-"))


def shim_library() -> Path:
    """The built shim (building it on first use); raises :class:`ShimBuildError`."""
    compiler = find_compiler()
    if compiler is None:
        cc = os.environ.get("CC")
        raise ShimBuildError(f"no C compiler (CC={cc!r} not found)" if cc
                             else "no C compiler (cc, gcc or clang) on PATH")
    sources = shim_sources()
    parts = [part for name, text in sources.items() for part in (name.encode(), text)]
    key = hashlib.sha256(b"\0".join([*parts, platform.machine().encode(), " ".join(compiler).encode()]))
    target = cache_dir() / f"run-shim-{key.hexdigest()[:16]}.so"
    if target.exists():
        return target
    with tempfile.TemporaryDirectory(prefix="hilbench-shim-") as tmp:
        paths = []
        for name, text in sources.items():
            paths.append(str(Path(tmp) / name))
            Path(paths[-1]).write_bytes(text)
        out = target.with_name(f".{target.name}.{os.getpid()}.tmp")
        cmd = [*compiler, "-shared", "-fPIC", "-O2", "-o", str(out), *paths, "-ldl", "-pthread"]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise ShimBuildError(f"{compiler[0]} failed to run: {exc}") from None
        if proc.returncode != 0:
            out.unlink(missing_ok=True)
            first = (proc.stderr.strip().splitlines() or ["no message"])[0]
            raise ShimBuildError(f"{compiler[0]} could not build the shim: {first}")
        out.replace(target)
    return target


__all__ = ["SOURCES", "ShimBuildError", "cache_dir", "find_compiler", "shim_library", "shim_source", "shim_sources"]
