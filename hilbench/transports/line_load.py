"""Bus load, and the lines that have none to speak of: those not paced at their rate.

Load is the bits a line carried per second over what it carries at its baud rate. A bench with
``paced = false`` (or a capture of one) delivers bytes as fast as they are made, so the figure can pass
100 %, which no real line can: such a line is shown as "unpaced" instead of a load (JSON: the load is
null and ``unpaced`` is true).
"""

from __future__ import annotations

#: A load above this means the bytes came faster than the wire carries them (the margin over 1 allows for
#: where a measuring window starts and ends).
UNPACED_ABOVE = 1.1


def is_unpaced(*loads: float | None) -> bool:
    """Whether any of ``loads`` is more than the line could carry."""
    return any(load is not None and load > UNPACED_ABOVE for load in loads)


__all__ = ["UNPACED_ABOVE", "is_unpaced"]
