"""A bench profile from a capture of a real bus: the generic part of ``hilbench profiles from-capture``.

The core knows no device family. It reads a source (anything the monitor
opens: a hilbench capture, a raw dump, a pcap file, a python-can log), hands
its chunks in bus order to the :class:`Inferrer` registered for the traffic's
protocol (``hilbench.inferrers`` entry points, :mod:`hilbench.registry`), and
turns the :class:`ProfileDraft` the inferrer returns into a commented TOML
profile (:func:`render`) whose header says what was seen, what was guessed,
what contradicted itself and what could not be read, and what the host did.

An inferrer owns everything protocol-specific: decoding, pairing requests
with replies, telling models apart, which profile keys its family takes, and
the :class:`~hilbench.bench.capture_replay.Replay` that ``--verify`` runs
against the bench the profile describes.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from hilbench import registry
from hilbench.errors import HilbenchError, UsageError

if TYPE_CHECKING:
    from hilbench.bench.capture_replay import Replay
    from hilbench.bench.profile import Profile
    from hilbench.transports.chunk import Chunk
    from hilbench.transports.sources import Source

#: Lines kept per header section (a capture with thousands of findings still gives a readable header).
MAX_LINES = 40


@dataclass
class SourceFacts:
    """What the capture itself says: its name, protocol, line rate, kind of times, size and damage."""

    name: str
    protocol: str
    baud: int | None = None
    #: Where ``baud`` comes from: ``"--baud"``, ``"the capture"`` or ``""`` (not known).
    baud_from: str = ""
    #: ``measured``, ``synthetic`` (a raw dump at byte time) or ``none``.
    timestamps: str = "none"
    chunks: int = 0
    bytes: int = 0
    #: Bytes lost before they reached the recorder (loss records in the capture).
    lost: int = 0
    t_first: float | None = None
    t_last: float | None = None
    #: The capture file's own damage (cut short, corrupted records, times out of order).
    findings: list[str] = field(default_factory=list)

    @property
    def span(self) -> float | None:
        """Seconds from the first to the last chunk (None without times)."""
        if self.timestamps == "none" or self.t_first is None or self.t_last is None:
            return None
        return self.t_last - self.t_first


@dataclass
class Entry:
    """One key of a table, with an optional comment after its value."""

    key: str
    value: Any
    note: str = ""


@dataclass
class Table:
    """A TOML table of the profile: ordered keys, comment lines above it, and whether it is written as a
    comment only (a device that never answered, kept for the user to enable)."""

    entries: list[Entry] = field(default_factory=list)
    comment: list[str] = field(default_factory=list)
    disabled: bool = False

    def set(self, key: str, value: Any, note: str = "") -> Table:
        """Set ``key`` (replacing an earlier value, keeping its place)."""
        for e in self.entries:
            if e.key == key:
                e.value, e.note = value, note
                return self
        self.entries.append(Entry(key, value, note))
        return self

    def get(self, key: str, default: Any = None) -> Any:
        return next((e.value for e in self.entries if e.key == key), default)

    def as_dict(self) -> dict[str, Any]:
        return {e.key: _plain(e.value) for e in self.entries}


def _plain(value: Any) -> Any:
    if isinstance(value, Commented):
        return _plain(value.value)
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


@dataclass
class ProfileDraft:
    """What an inferrer made of a capture: the profile's tables and the header's sections.

    ``seen``: facts the capture shows; ``guessed``: conclusions with their
    reasons; ``contradictions``: values the capture contradicts itself on
    (reported, not applied); ``unread``: what could not be read (damage,
    truncation); ``pattern``: the host's traffic (what its software did).
    """

    description: str
    endpoints: dict[str, Table] = field(default_factory=dict)
    devices: list[Table] = field(default_factory=list)
    defaults: Table = field(default_factory=Table)
    seen: list[str] = field(default_factory=list)
    guessed: list[str] = field(default_factory=list)
    contradictions: list[str] = field(default_factory=list)
    unread: list[str] = field(default_factory=list)
    pattern: list[str] = field(default_factory=list)
    #: The host's requests and the captured replies, for ``--verify`` (None: the inferrer cannot replay).
    replay: Replay | None = None
    #: Per device (its address), the names of the items the host read: what the profile's values rest on.
    read: dict[Any, list[str]] = field(default_factory=dict)

    def data(self) -> dict[str, Any]:
        """The profile as the TOML parser would return it (disabled devices left out)."""
        out: dict[str, Any] = {"schema": 1, "description": self.description}
        if self.defaults.entries:
            out["defaults"] = self.defaults.as_dict()
        out["endpoints"] = {name: t.as_dict() for name, t in self.endpoints.items()}
        out["devices"] = [t.as_dict() for t in self.devices if not t.disabled]
        return out


@dataclass(frozen=True)
class InferOptions:
    """What the command line asks of every inferrer."""

    #: Devices asked for but never answering become absent devices (else comments).
    keep_silent: bool = False


class InferenceSession(Protocol):
    """One capture's worth of inference: chunks in, a draft out."""

    def feed(self, chunk: Chunk) -> None:
        """Bytes one party put on the bus (``chunk.lost`` > 0: bytes lost before the recorder)."""

    def finish(self) -> ProfileDraft:
        """The source ended: the draft of everything seen."""


class Inferrer:
    """Base class of the ``hilbench.inferrers`` plug-ins: a profile from traffic of its protocols."""

    #: Instrument protocols whose traffic it reads (a source's ``protocol``).
    protocols: ClassVar[tuple[str, ...]] = ()
    #: A few words for listings.
    title: ClassVar[str] = ""

    def session(self, facts: SourceFacts, options: InferOptions) -> InferenceSession:
        """A new session for a capture (``facts`` grow while it is read; final at :meth:`InferenceSession.finish`)."""
        raise NotImplementedError


def inferrer_for(protocol: str) -> Inferrer:
    """The inferrer registered for ``protocol``; UsageError naming the protocols some inferrer reads."""
    for inf in registry.inferrers.values():
        if protocol in inf.protocols:
            return inf
    known = sorted({p for inf in registry.inferrers.values() for p in inf.protocols})
    raise UsageError(f"no profile inferrer reads {protocol} traffic (known: {', '.join(known) or 'none'})")


def inferrer_known(protocol: str) -> bool:
    """Whether some registered inferrer reads ``protocol``."""
    return any(protocol in inf.protocols for inf in registry.inferrers.values())


def protocol_source(source: Source, protocol: str | None) -> str:
    """Where :func:`traffic_of` will take ``source``'s protocol from (call it before): ``"--protocol"``, ``"the
    capture"`` or ``"its first bytes"`` (for :func:`infer`'s ``protocol_from``)."""
    return "--protocol" if protocol else "the capture" if source.protocol else "its first bytes"


def traffic_of(source: Source, protocol: str | None = None, *,
               rivals: list[str] | None = None) -> tuple[str, Source]:
    """The protocol of ``source``'s traffic (``protocol`` if given, checked against what the capture says; else
    the capture's, else told from its first bytes as the monitor does) and the source to read (the bytes read to
    tell it come again). Raises :class:`~hilbench.errors.UsageError` in one line. ``rivals`` receives the other
    protocols the first bytes could be (when they were told from them)."""
    from hilbench.monitor.detect import choose, detect

    if protocol:
        inst = choose(protocol, name=source.name)
        if source.protocol and choose(source.protocol, name=source.name) is not inst:
            raise UsageError(f"{source.name} carries {source.protocol}, not {protocol}")
        return inst.protocol, source
    inst, source = detect(source, timeout=None, rivals=rivals)
    if inst is None:
        raise UsageError(f"{source.name}: the capture is empty")
    return inst.protocol, source


def infer(source: Source, protocol: str, *, baud: int | None = None, options: InferOptions | None = None,
          baud_from: str = "", protocol_from: str = "", rivals: list[str] | None = None,
          ) -> tuple[ProfileDraft, SourceFacts]:
    """Read ``source`` (its traffic is ``protocol``) to its end and return the inferred draft and the facts.

    ``protocol_from``: where ``protocol`` comes from (``"--protocol"``, ``"the capture"``); ``"its first bytes"``
    (:func:`traffic_of` told it) makes it a guess the header names, with the ``rivals`` those bytes fit too."""
    facts = SourceFacts(name=source.name, protocol=protocol, baud=baud or source.baud,
                        baud_from=baud_from or ("the capture" if source.baud else ""),
                        timestamps=source.timestamps)
    session = inferrer_for(protocol).session(facts, options or InferOptions())
    broken = None
    try:
        for chunk in source:
            facts.chunks += 1
            if chunk.lost:
                facts.lost += chunk.lost
            else:
                facts.bytes += len(chunk.data)
            if facts.t_first is None:
                facts.t_first = chunk.t
            facts.t_last = chunk.t
            session.feed(chunk)
    except (HilbenchError, OSError) as exc:  # a reader that gives up mid-file: keep what came before
        if not facts.chunks:
            raise
        broken = f"the capture could not be read past record {facts.chunks}: {exc}"
    facts.findings = list(source.quality().get("findings", []))
    if not facts.chunks:  # (a log of headers only, or every line damaged): no profile to make
        why = f" ({'; '.join(facts.findings)})" if facts.findings else ""
        raise UsageError(f"{source.name}: the capture holds no traffic{why}")
    if broken:
        facts.findings.append(broken)
    draft = session.finish()
    if protocol_from == "its first bytes":
        others = [r for r in rivals or [] if r != protocol and inferrer_known(r)]
        draft.guessed.insert(0, f"protocol {protocol}: told from the capture's first bytes (it names none)"
                             + (f"; they fit {' and '.join(others)} too, its host's addresses decided" if others
                                else "") + f"; give --protocol {others[0] if others else 'P'} if that is wrong")
    if facts.lost:
        draft.unread.append(f"{facts.lost} bytes were lost before the recorder (loss records in the capture)")
    draft.unread.extend(f"capture: {line}" for line in facts.findings)
    return draft, facts


# --------------------------------------------------------------------------------------------- TOML

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else toml_value(key)


def toml_value(value: Any) -> str:
    """A value as TOML text: strings, booleans, integers (hex where asked by :class:`Hex`), floats, arrays and
    inline tables."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Hex):
        return f"0x{int(value):0{value.width}X}"
    if isinstance(value, int):
        return f"{value:_}" if abs(value) >= 100_000 else str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"TOML profiles take finite numbers, not {value}")
        text = repr(round(value, 6))
        return text if any(c in text for c in ".e") else f"{text}.0"
    if isinstance(value, str):
        out = value.replace("\\", "\\\\").replace('"', '\\"')
        out = "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in out)
        return f'"{out}"'
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{toml_key(k)} = {toml_value(v)}" for k, v in value.items()) + " }" \
            if value else "{}"
    if isinstance(value, Commented):
        return toml_value(value.value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML for {type(value).__name__}")


class Commented:
    """An array item with a comment after it (the array is then written one item a line)."""

    def __init__(self, value: Any, note: str) -> None:
        self.value = value
        self.note = note


#: An array whose one-line text is longer than this is written one item a line.
WRAP = 100


class Hex(int):
    """An integer written in hex (a model number, a COB-ID), ``width`` digits at least."""

    width: int

    def __new__(cls, value: int, width: int = 1) -> Hex:
        obj = super().__new__(cls, value)
        obj.width = width
        return obj


def _comment(lines: Iterable[str], prefix: str = "# ") -> list[str]:
    return [f"{prefix}{line}".rstrip() for line in lines]


def _table_lines(header: str, table: Table) -> list[str]:
    lines = _comment(table.comment)
    body = [header]
    width = max((len(toml_key(e.key)) for e in table.entries), default=0)
    for e in table.entries:
        one = toml_value(e.value)
        items = e.value if isinstance(e.value, list | tuple) else None
        if items and (len(one) > WRAP or any(isinstance(v, Commented) for v in items)):
            body.append(f"{toml_key(e.key):<{width}} = [" + (f"   # {e.note}" if e.note else ""))
            for v in items:
                line = f"  {toml_value(v)},"
                if isinstance(v, Commented) and v.note:
                    line += f"   # {v.note}"
                body.append(line)
            body.append("]")
            continue
        text = f"{toml_key(e.key):<{width}} = {one}"
        if e.note:
            text = f"{text}   # {e.note}"
        body.append(text)
    if table.disabled:
        body = [f"# {line}" for line in body]
    return lines + body


def _section(title: str, lines: list[str]) -> list[str]:
    if not lines:
        return []
    shown = lines[:MAX_LINES]
    if len(lines) > MAX_LINES:
        shown.append(f"... and {len(lines) - MAX_LINES} more")
    return ["#", f"# {title}:", *_comment(shown, "#   ")]


def describe_source(facts: SourceFacts) -> str:
    """One line on the capture: its size, its times and its line rate."""
    times = {"measured": "measured times", "synthetic": "times from its byte count",
             "none": "no times"}.get(facts.timestamps, facts.timestamps)
    parts = [f"{facts.bytes} bytes in {facts.chunks} records", times]
    if facts.span is not None:
        parts.append(f"{facts.span:.3f} s")
    if facts.baud:
        parts.append(f"{facts.baud} baud ({facts.baud_from or 'given'})")
    return ", ".join(parts)


def render(draft: ProfileDraft, facts: SourceFacts, *, command: str = "") -> str:
    """The draft as a commented TOML profile."""
    from hilbench import __version__

    head = [f"A bench of the bus recorded in {facts.name}, generated by hilbench {__version__}"]
    if command:
        head.append(f"with `{command}`.")
    head.append(f"The capture: {describe_source(facts)}.")
    head.append("Edit freely: comments say where each value comes from; values the capture did not show are the")
    head.append("models' defaults.")
    lines = _comment(head)
    lines += _section("Seen", draft.seen)
    lines += _section("Guessed", draft.guessed)
    lines += _section("Contradictions in the capture (reported, not applied)", draft.contradictions)
    lines += _section("Could not be read", draft.unread)
    lines += _section("The host's traffic", draft.pattern)
    lines += ["", "schema = 1", f"description = {toml_value(draft.description)}"]
    if draft.defaults.entries:
        lines += ["", *_table_lines("[defaults]", draft.defaults)]
    for name, table in draft.endpoints.items():
        lines += ["", *_table_lines(f"[endpoints.{toml_key(name)}]", table)]
    for table in draft.devices:
        lines += ["", *_table_lines("[[devices]]", table)]
    return "\n".join(lines) + "\n"


def check_profile_text(text: str, name: str = "<generated profile>") -> Profile:
    """Load generated TOML as ``hilbench emulate`` would (raises the profile's own one-line errors)."""
    from hilbench.bench.profile import parse_profile

    return parse_profile(tomllib.loads(text), name)


def id_ranges(ids: Iterable[int]) -> str:
    """``1-6, 19, 20`` for [1, 2, 3, 4, 5, 6, 19, 20] (runs of three or more as ranges)."""
    ids = sorted(set(ids))
    parts: list[str] = []
    i = 0
    while i < len(ids):
        j = i
        while j + 1 < len(ids) and ids[j + 1] == ids[j] + 1:
            j += 1
        if j - i >= 2:
            parts.append(f"{ids[i]}-{ids[j]}")
        else:
            parts.extend(str(x) for x in ids[i : j + 1])
        i = j + 1
    return ", ".join(parts)


__all__ = ["Commented", "Entry", "Hex", "InferOptions", "InferenceSession", "Inferrer", "ProfileDraft", "SourceFacts", "Table",
           "check_profile_text", "describe_source", "id_ranges", "infer", "inferrer_for", "inferrer_known", "protocol_source", "render",
           "toml_value", "traffic_of"]
