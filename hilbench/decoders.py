"""Rough input: every decoder and instrument that reads bytes from outside, for the fuzz script and benchmarks.

A :class:`DecoderTarget` says how to drive one reader of outside bytes
(a protocol decoder, the capture parser, a monitor's tracker, the profiler)
with nothing but bytes, how fast its fastest line is, and how to make clean
traffic of its kind to mutate. Targets register in the ``hilbench.decoders``
entry-point group (:data:`hilbench.registry.decoders`), so a new family's
decoder joins ``tools/fuzz.py`` and the rough-input benchmarks with one line
in its package's ``pyproject.toml``::

    [project.entry-points."hilbench.decoders"]
    acme-frames = "acme_hilbench.protocol:ROUGH_INPUT"

The rule the targets are held to (the project's): a decoder never raises on
garbage, resynchronises in linear time and counts what it dropped; on pure
noise and on mutated captures it keeps up with at least ten times its fastest
line (``tools/bench_*.py`` measure it, ``tools/fuzz.py`` hunts for exceptions).

This module imports nothing from hilbench but :mod:`hilbench.registry`.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol


class Reader(Protocol):
    """What a target makes: bytes in, counters out (one instance per input)."""

    def feed(self, data: bytes) -> None:
        """The next bytes of the input (any split)."""

    def finish(self) -> None:
        """The input ended."""

    def good(self) -> int:
        """Items decoded whole so far (packets, frames, stamps, records)."""

    def dropped(self) -> int:
        """Bytes (or items) discarded while resynchronising so far."""


@dataclass(frozen=True)
class DecoderTarget:
    """One reader of outside bytes, as the fuzz script and the benchmarks drive it.

    ``make()`` returns a fresh :class:`Reader`; ``line_rate`` is the bytes per
    second of the fastest line it reads (``line`` says which: the target is ten
    times that on noise and mutated input); ``sample(rng, size)`` makes about
    ``size`` bytes of clean traffic (the seed of mutated inputs); ``kind`` is
    ``decoder`` or ``instrument``; ``frame(noise)`` puts noise where the reader
    would meet it (a capture's after a sound header; default: as it is);
    ``refuses`` are the exception types it raises by design, in one line, for
    input it must not read (a capture of a newer format version): counted as
    refusals, not as failures.
    """

    name: str
    title: str
    make: Callable[[], Reader]
    line_rate: float
    line: str
    sample: Callable[[random.Random, int], bytes]
    kind: str = "decoder"
    frame: Callable[[bytes], bytes] | None = None
    refuses: tuple[type[Exception], ...] = ()

    def noise(self, rng: random.Random, size: int) -> bytes:
        """``size`` random bytes, framed as the reader meets them."""
        data = rng.randbytes(size)
        return self.frame(data) if self.frame is not None else data


def targets() -> list[DecoderTarget]:
    """Every registered target, in registration order (built-ins first)."""
    from hilbench import registry

    return list(registry.decoders.values())


def noise(rng: random.Random, size: int) -> bytes:
    """``size`` random bytes."""
    return rng.randbytes(size)


def mutate(rng: random.Random, data: bytes, *, rate: float = 0.01) -> bytes:
    """``data`` with about ``rate`` of its bytes damaged: flipped bits, random bytes, bytes lost or added."""
    out = bytearray(data)
    n = max(1, int(len(out) * rate))
    for _ in range(n):
        if not out:
            break
        i = rng.randrange(len(out))
        op = rng.random()
        if op < 0.5:
            out[i] ^= 1 << rng.randrange(8)
        elif op < 0.75:
            out[i] = rng.randrange(256)
        elif op < 0.9:
            del out[i : i + rng.randrange(1, 8)]
        else:
            out[i:i] = rng.randbytes(rng.randrange(1, 8))
    return bytes(out)


def run(reader: Reader, data: bytes, chunk: int | Callable[[], int] = 65536) -> Reader:
    """Feed ``data`` in pieces of ``chunk`` bytes (or of the sizes it returns), then finish."""
    pos = 0
    n = len(data)
    while pos < n:
        size = chunk() if callable(chunk) else chunk
        reader.feed(data[pos : pos + max(1, size)])
        pos += max(1, size)
    reader.finish()
    return reader


class Counting:
    """A :class:`Reader` from callables: ``feed(data)`` and ``finish()`` return item lists, ``is_good(item)``
    tells packets from problems (or counts the good units in an item: the stamps of a batch), ``dropped()``
    reads the decoder's own counter."""

    def __init__(self, feed: Callable[[bytes], Any], finish: Callable[[], Any], is_good: Callable[[Any], int],
                 dropped: Callable[[], int]) -> None:
        self._feed = feed
        self._finish = finish
        self._is_good = is_good
        self._dropped = dropped
        self.items = 0
        self.good_items = 0

    def _count(self, items: Any) -> None:
        if items:
            for item in items:
                self.items += 1
                self.good_items += int(self._is_good(item))

    def feed(self, data: bytes) -> None:
        self._count(self._feed(data))

    def finish(self) -> None:
        self._count(self._finish())

    def good(self) -> int:
        return self.good_items

    def dropped(self) -> int:
        return self._dropped()


__all__ = ["Counting", "DecoderTarget", "Reader", "mutate", "noise", "run", "targets"]
