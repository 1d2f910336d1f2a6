"""A module imported when first used, for modules that use a heavy package in a few of their paths.

numpy costs a command 50 - 150 ms to import. A bench's world holds arrays of walls and bodies, but a
bench of servos has neither and must not pay for numpy to start. A module whose functions use numpy
throughout writes, instead of ``import numpy as np``::

    if TYPE_CHECKING:
        import numpy as np
    else:
        np = LazyModule("numpy", globals(), "np")

The first ``np.something`` imports numpy and puts the module itself in the global ``np``, so later uses
cost nothing more than a plain global.
"""

from __future__ import annotations

import importlib
from typing import Any


class LazyModule:
    """Stands for module ``name`` in ``namespace[alias]`` until its first attribute is asked for."""

    def __init__(self, name: str, namespace: dict[str, Any], alias: str) -> None:
        self._name = name
        self._namespace = namespace
        self._alias = alias

    def __getattr__(self, attr: str) -> Any:
        module = importlib.import_module(self._name)
        self._namespace[self._alias] = module
        return getattr(module, attr)

    def __repr__(self) -> str:
        return f"<module {self._name!r}, imported when first used>"


__all__ = ["LazyModule"]
