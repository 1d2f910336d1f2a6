"""Single keys from a real terminal, without waiting for Enter.

:class:`KeyReader` puts the terminal in cbreak mode (no line buffering, no
echo; Ctrl-C still interrupts) for the life of the dashboard and restores it
afterwards, also on errors. Arrow and page keys arrive as escape sequences
and are returned as names (``"left"``, ``"pgdn"``, ...). When stdin is not a
terminal there are no keys: the dashboard is then steered by its options.
"""

from __future__ import annotations

import os
import sys
import termios
import tty

from hilbench.transports.readiness import readable

_SEQUENCES = {
    "\x1b[A": "up",
    "\x1b[B": "down",
    "\x1b[C": "right",
    "\x1b[D": "left",
    "\x1bOA": "up",
    "\x1bOB": "down",
    "\x1bOC": "right",
    "\x1bOD": "left",
    "\x1b[5~": "pgup",
    "\x1b[6~": "pgdn",
    "\x1b[H": "home",
    "\x1b[F": "end",
    "\x1b[1~": "home",
    "\x1b[4~": "end",
    "\x1b[Z": "backtab",
}
_NAMES = {"\t": "tab", "\r": "enter", "\n": "enter", " ": "space", "\x7f": "backspace", "\x1b": "escape"}


def split_keys(text: str) -> list[str]:
    """Split what the terminal sent into keys (escape sequences become names)."""
    keys = []
    i = 0
    while i < len(text):
        if text[i] == "\x1b":
            for seq, name in _SEQUENCES.items():
                if text.startswith(seq, i):
                    keys.append(name)
                    i += len(seq)
                    break
            else:
                keys.append("escape")
                i += 1
            continue
        ch = text[i]
        keys.append(_NAMES.get(ch, ch))
        i += 1
    return keys


class KeyReader:
    """Non-blocking keys from ``stream`` (default stdin) while in a ``with`` block; inert if not a tty."""

    def __init__(self, stream=None) -> None:
        self.stream = stream or sys.stdin
        try:
            self.fd = self.stream.fileno()
            self.active = os.isatty(self.fd)
        except (AttributeError, ValueError, OSError):
            self.fd, self.active = -1, False
        self._saved = None

    def __enter__(self) -> KeyReader:
        if self.active:
            try:
                self._saved = termios.tcgetattr(self.fd)
                tty.setcbreak(self.fd)
            except termios.error:
                self.active = False
        return self

    def __exit__(self, *exc) -> None:
        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
            self._saved = None

    def read(self, timeout: float) -> list[str]:
        """Keys typed within ``timeout`` seconds (waits at most that long; [] if none)."""
        if not self.active:
            return []
        if not readable([self.fd], timeout):
            return []
        try:
            data = os.read(self.fd, 1024)
        except OSError:
            return []
        if not data:  # end of input (the terminal went away)
            self.active = False
            return ["eof"]
        return split_keys(data.decode("utf-8", errors="replace"))
