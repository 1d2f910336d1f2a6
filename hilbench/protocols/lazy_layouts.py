"""Construct layouts made with construct's import when first used (start-up, issue 24).

A protocol module keeps its reference layouts in a cached ``_layouts()`` and names them in
``_LAYOUT_NAMES``; ``__getattr__ = lazy_layouts(globals(), _LAYOUT_NAMES, _layouts)`` makes them module
attributes on first access (PEP 562), kept in the module once made.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def lazy_layouts(namespace: dict[str, Any], names: tuple[str, ...],
                 make: Callable[[], dict[str, Any]]) -> Callable[[str], Any]:
    """A module ``__getattr__`` giving each of ``names`` from ``make()`` (called when first needed)."""
    module = namespace["__name__"]

    def __getattr__(name: str) -> Any:
        if name in names:
            value = namespace[name] = make()[name]
            return value
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    return __getattr__


__all__ = ["lazy_layouts"]
