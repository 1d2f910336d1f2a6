"""Small pieces every dashboard view set draws with: one-line texts, fixed-width table rows, padding.

Views render exactly the height they are given and never wrap a line (a
line longer than the width ends in an ellipsis), so a screen fits the
terminal however much the tracker has to show.
"""

from __future__ import annotations

from rich.console import Group
from rich.text import Text

#: One table cell: (content, width, "<" left or ">" right aligned).
Cell = tuple[str | Text, int, str]


def line(text: str | Text, style: str = "", width: int = 80) -> Text:
    """One screen line: ``text`` (styled with ``style`` if a str) cut to ``width`` columns with an ellipsis."""
    t = text if isinstance(text, Text) else Text(text, style=style)
    t.no_wrap = True
    t.overflow = "ellipsis"
    t.truncate(width, overflow="ellipsis")
    return t


def pad(lines: list[Text], height: int) -> Group:
    """Exactly ``height`` lines: the first of ``lines``, then blank ones."""
    lines = lines[:height]
    return Group(*lines, *[Text("")] * (height - len(lines)))


def row(cells: list[Cell], width: int, style: str = "") -> Text:
    """One table line of fixed-width cells, one space apart (each cut to its width with an ellipsis)."""
    out = Text(style=style)
    for k, (content, w, align) in enumerate(cells):
        t = content.copy() if isinstance(content, Text) else Text(str(content))
        t.truncate(w, overflow="ellipsis")
        gap = " " * (w - t.cell_len)
        if k:
            out.append(" ")
        if align == ">":
            out.append(gap)
        out.append(t)
        if align != ">":
            out.append(gap)
    return line(out, width=width)


def ms(x: float | None, digits: int = 2) -> str:
    """Seconds as milliseconds with ``digits`` decimals (``-`` for None)."""
    return "-" if x is None else f"{x * 1000:.{digits}f}"


__all__ = ["Cell", "line", "ms", "pad", "row"]
