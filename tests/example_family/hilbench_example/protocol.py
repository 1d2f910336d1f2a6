"""The blinker's wire format: one ASCII line per message, ``WORD [number]\\n``."""

from __future__ import annotations

from typing import NamedTuple

PING, PONG, RATE, OK, BLINK = "PING", "PONG", "RATE", "OK", "BLINK"
WORDS = (PING, PONG, RATE, OK, BLINK)
MAX_LINE = 64


class Message(NamedTuple):
    word: str
    value: int | None
    raw: bytes


def build(word: str, value: int | None = None) -> bytes:
    """One message as bytes."""
    return (word if value is None else f"{word} {value}").encode() + b"\n"


class LineDecoder:
    """Incremental decoder; never raises: unknown or overlong lines are counted in ``bad``."""

    def __init__(self) -> None:
        self._buf = b""
        self.bad = 0

    def feed(self, data: bytes) -> list[Message]:
        self._buf += data
        out = []
        *lines, self._buf = self._buf.split(b"\n")
        if len(self._buf) > MAX_LINE:  # bounded: a line that never ends is garbage
            self.bad += 1
            self._buf = b""
        for line in lines:
            parts = line.strip().split()
            word = parts[0].decode(errors="replace") if parts else ""
            try:
                value = int(parts[1]) if len(parts) > 1 else None
            except ValueError:
                value = None
                word = ""
            if word in WORDS and len(parts) <= 2:
                out.append(Message(word, value, line + b"\n"))
            else:
                self.bad += 1
        return out
