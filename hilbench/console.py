"""The rich console hilbench prints with.

rich reacts to a closed pipe (``hilbench monitor x --summary | head -1``) by
raising ``SystemExit(1)`` from inside any print. A reader that goes away is no
error, so :class:`Console` raises :class:`BrokenPipeError` instead, which the
``hilbench`` command turns into a quiet exit with status 0, as for a plain
``print``.
"""

from __future__ import annotations

from rich.console import Console as _RichConsole


class Console(_RichConsole):
    """``rich.console.Console`` whose closed pipe raises :class:`BrokenPipeError` (rich's documented hook)."""

    def on_broken_pipe(self) -> None:
        self.quiet = True  # nothing more is written through this console
        raise BrokenPipeError("the reader closed the pipe")


__all__ = ["Console"]
