"""Which instrument watches a source: by the protocol it names, or told from its first bytes.

A bench's tap and a hilbench capture name their protocol; a raw dump, a
serial port or a pipe does not. Then every registered instrument scores the
first bytes (:meth:`~hilbench.monitor.instrument.Instrument.sniff`) and the
best one wins; with a single monitoring instrument registered there is
nothing to choose. A source whose protocol another verb reads (a board's
trace output is ``hilbench trace``'s) is refused in one line that says so.
"""

from __future__ import annotations

from hilbench import registry
from hilbench.errors import UsageError
from hilbench.monitor.instrument import Instrument
from hilbench.transports.sources import Source, peek


def _for_verb(verb: str) -> list[Instrument]:
    return [i for i in registry.instruments.values() if i.verb == verb]


def _refuse(name: str, inst: Instrument, verb: str) -> UsageError:
    mine = "/".join(i.protocol for i in _for_verb(verb)) or "nothing"
    return UsageError(f"{name} carries {inst.protocol}, not {mine} ({inst.title}: use `hilbench {inst.verb}`)")


def choose(protocol: str | None, *, verb: str | None = "monitor", name: str = "the source") -> Instrument | None:
    """The instrument for ``protocol``; without one, the only instrument of ``verb`` (else None: detect).

    Raises :class:`~hilbench.errors.UsageError` for a protocol no instrument knows, or one that
    another verb reads.
    """
    if protocol:
        inst = registry.instrument_for(protocol)
        if inst is None:
            known = ", ".join(i.protocol for i in registry.instruments.values())
            raise UsageError(f"{name}: no instrument decodes {protocol!r} (known: {known})")
        if verb is not None and inst.verb != verb:
            raise _refuse(name, inst, verb)
        return inst
    if verb is None:
        return None
    candidates = _for_verb(verb)
    return candidates[0] if len(candidates) == 1 else None


def detect(source: Source, *, verb: str = "monitor", timeout: float | None = None,
           rivals: list[str] | None = None) -> tuple[Instrument | None, Source]:
    """Tell the instrument of ``source`` from its first bytes; returns it (None if the source ended
    empty) and a source that yields those bytes again first. Waits for traffic up to ``timeout`` s
    (None: as long as it takes; closing the source ends the wait). ``rivals``, if given, receives the
    protocols of the verb's other instruments that found the bytes plausible too (best first)."""
    inst = choose(source.protocol, verb=verb, name=source.name)
    if inst is not None:
        return inst, source
    data, peeked = peek(source, timeout=timeout)
    if not data:
        return None, peeked
    scored = sorted(((i.sniff(data), n, i) for n, i in enumerate(registry.instruments.values())),
                    key=lambda x: (-x[0], x[1]))
    score, _, best = scored[0]
    if score <= 0:
        known = ", ".join(i.protocol for i in _for_verb(verb))
        raise UsageError(f"{source.name}: no known traffic recognised in its first {len(data)} bytes "
                         f"(if it carries one of {known}, say which: --protocol P)")
    if best.verb != verb:
        raise _refuse(source.name, best, verb)
    if rivals is not None:
        rivals.extend(i.protocol for s, _, i in scored[1:] if s > 0 and i.verb == verb)
    peeked._protocol = best.protocol
    return best, peeked


__all__ = ["choose", "detect"]
