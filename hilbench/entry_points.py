"""The installed packages' ``hilbench.*`` entry points, read from a small cache while nothing was installed.

:mod:`importlib.metadata` costs every command 20 - 40 ms before the first entry point is read (it imports
the ``email`` package, then parses each distribution's metadata). The table of the ``hilbench.*`` groups
is kept in ``$XDG_CACHE_HOME/hilbench/entry-points-*.json`` (``~/.cache/hilbench`` without it), under a
fingerprint of everything :mod:`importlib.metadata` reads it from: each ``sys.path`` entry, the directory's
own change time, and the size, change time and inode of each ``*.dist-info`` / ``*.egg-info``'s
``entry_points.txt`` and metadata file and of each ``*.pth`` file in it. ``pip install``, ``pip
uninstall``, an upgrade and an editable reinstall (``pip install -e .``, which writes the package's
``.dist-info`` anew from ``pyproject.toml``) each change one of them, so the next command reads the
metadata again: a cached table is never served once what it was read from has changed.

Anything unusual reads the metadata as before, silently: no cache file, an unreadable or damaged one, a
cache directory that cannot be written (the table is then read each time), or a finder on
``sys.meta_path`` other than the path finder that can list distributions (its packages would be
invisible to the fingerprint). There is a file per ``sys.path`` list, the last few kept (``python -m``
puts the working directory first, so each directory it runs in has its own).

This module imports nothing from hilbench (the registry is built on it).
"""

from __future__ import annotations

import json
import os
import sys
import zlib
from collections.abc import Iterator
from typing import Any, NamedTuple

#: Entry-point groups the table holds: every one whose name starts so.
PREFIX = "hilbench."
#: The cache file's format (a file of another format is a miss).
FORMAT = 1
#: Cache files kept (one per ``sys.path`` list: the most recently written ones).
KEEP = 8


class Entry(NamedTuple):
    """One entry point: what :class:`importlib.metadata.EntryPoint` says of it, and how to load it."""

    group: str
    name: str
    value: str  # "module:attr" (an attribute path), or "module"
    dist: str  # the name of the distribution that declares it

    def load(self) -> Any:
        """Import the entry point's module and return the object it names (as ``EntryPoint.load``)."""
        import importlib

        target = self.value.split("[", 1)[0]  # (extras, if any, name what to install, not what to load)
        module, _, attrs = target.partition(":")
        obj = importlib.import_module(module.strip())
        for attr in filter(None, attrs.strip().split(".")):
            obj = getattr(obj, attr)
        return obj


def cache_dir() -> str:
    """Where the cache lives: ``$XDG_CACHE_HOME/hilbench``, or ``~/.cache/hilbench`` (XDG: a relative
    ``XDG_CACHE_HOME`` is ignored)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "hilbench")


def read() -> list[Entry]:
    """Every ``hilbench.*`` entry point of the installed packages: from the cache when its fingerprint is the
    current one, else from :mod:`importlib.metadata` (then cached)."""
    try:
        key = _path_key()
        fingerprint = _fingerprint()  # (before the metadata is read: a change meanwhile makes the next run miss)
    except Exception:  # noqa: BLE001 (an odd sys.path or file system: read the metadata, as without a cache)
        fingerprint = None
    if fingerprint is not None:
        path = os.path.join(cache_dir(), f"entry-points-{zlib.crc32(key.encode(errors='surrogatepass')):08x}.json")
        table = _cached(path, key, fingerprint)
        if table is not None:
            return table
    table = from_metadata()
    if fingerprint is not None:
        _store(path, key, fingerprint, table)
    return table


def from_metadata() -> list[Entry]:
    """Every ``hilbench.*`` entry point, as :mod:`importlib.metadata` lists them (one per distribution name,
    the first on ``sys.path``)."""
    import importlib.metadata

    every = importlib.metadata.entry_points()
    names: dict[int, str] = {}  # (``dist.name`` parses the metadata file: once per distribution)
    table = []
    for ep in (ep for group in sorted(every.groups) if group.startswith(PREFIX) for ep in every.select(group=group)):
        dist = ep.dist
        if dist is None:
            name = "?"
        elif id(dist) in names:
            name = names[id(dist)]
        else:
            name = names[id(dist)] = dist.name
        table.append(Entry(ep.group, ep.name, ep.value, name))
    return table


# ---------------------------------------------------------------------------------------------- fingerprint


def _path_key() -> str:
    """What a table is read for: hilbench's and Python's versions and the ``sys.path`` list."""
    from hilbench import __version__

    return "\n".join([__version__, sys.version, sys.executable, *(_entries())])


def _entries() -> Iterator[str]:
    """``sys.path``'s entries as the path finder reads them (absolute; ``""``: the working directory)."""
    for entry in sys.path:
        if isinstance(entry, str):  # (the path finder skips others)
            yield os.path.abspath(entry or ".")


def _lists_distributions(finder: Any) -> bool:
    return getattr(finder, "find_distributions", None) is not None


def _fingerprint() -> str | None:
    """What the entry points are read from, stamped (see the module's docstring; kept whole, not hashed: a
    few kB); None when it cannot cover them (a finder other than the path finder lists distributions)."""
    import importlib.machinery

    if any(_lists_distributions(f) and f is not importlib.machinery.PathFinder for f in sys.meta_path):
        return None
    return "\n".join(part for entry in _entries() for part in _stat_entry(entry))


def _stamp(st: os.stat_result) -> str:
    return f"{st.st_mtime_ns} {st.st_ctime_ns} {st.st_size} {st.st_ino}"


def _stat(path: str) -> str:
    try:
        return _stamp(os.stat(path))
    except OSError:
        return "-"


def _stat_entry(root: str) -> Iterator[str]:
    """The lines of one ``sys.path`` entry's fingerprint."""
    yield root
    try:
        st = os.stat(root)
    except OSError:
        yield "missing"
        return
    yield _stamp(st)
    if not os.path.isdir(root):
        return  # a zip file: its stamp covers its contents
    try:
        with os.scandir(root) as it:
            names = sorted(e.name for e in it)
    except OSError:
        yield "unlisted"
        return
    for name in names:
        low = name.lower()
        if low.endswith((".dist-info", ".egg-info")):
            where = os.path.join(root, name)
            yield name
            yield _stat(where)
            # the metadata files a directory holds (an .egg-info may also be a file: its own stamp above)
            yield _stat(os.path.join(where, "entry_points.txt"))
            yield _stat(os.path.join(where, "METADATA" if low.endswith(".dist-info") else "PKG-INFO"))
        elif low.endswith(".pth"):
            yield name
            yield _stat(os.path.join(root, name))


# ---------------------------------------------------------------------------------------------- the file


def _cached(path: str, key: str, fingerprint: str) -> list[Entry] | None:
    """The table stored in ``path`` for ``key`` under ``fingerprint``; None when there is none or the file is
    damaged."""
    try:
        with open(path, encoding="utf-8") as fh:
            doc = json.load(fh)
        if doc.get("format") != FORMAT or doc.get("key") != key or doc.get("fingerprint") != fingerprint:
            return None
        table = [Entry(*row) for row in doc["entries"]]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None
    if not all(isinstance(field, str) for e in table for field in (e.group, e.name, e.value, e.dist)):
        return None
    return table


def _store(path: str, key: str, fingerprint: str, table: list[Entry]) -> None:
    """Write ``table`` to ``path`` and forget all but the last :data:`KEEP` files; nothing happens if the cache
    cannot be written."""
    text = json.dumps({"format": FORMAT, "key": key, "fingerprint": fingerprint, "entries": [list(e) for e in table]},
                      separators=(",", ":"))
    folder = os.path.dirname(path)
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        os.makedirs(folder, exist_ok=True)
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)  # (a reader sees the old file or the new one, never half of one)
        with os.scandir(folder) as it:
            files = [e for e in it if e.name.startswith("entry-points-") and e.name.endswith(".json")]
        files.sort(key=lambda e: e.stat().st_mtime_ns, reverse=True)
        for old in files[KEEP:]:
            os.unlink(old.path)
    except OSError:
        try:
            os.unlink(tmp)
        except OSError:
            pass


__all__ = ["Entry", "cache_dir", "from_metadata", "read"]
