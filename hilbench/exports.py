"""A package's public names, imported from the modules that define them when first used (PEP 562).

A package ``__init__`` that imported its modules to re-export their classes would load all of them for any
one: ``hilbench monitor MANIFEST`` needs ``hilbench.bench.manifest`` but not the profile loader and the
families; a monitor plug-in (``hilbench.monitor.can``) needs none of the monitor frame's modules. Such a
package declares where each name lives instead::

    __getattr__, __dir__ = lazy_exports(__name__, {"Bench": "bench", "BusKind": "bus"})

and keeps ``from ... import`` lines under ``if TYPE_CHECKING:`` for type checkers and readers.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_exports(package: str, homes: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``: each name in ``homes`` comes from the submodule
    named beside it (relative to the package), imported on first use and then kept in the package."""
    namespace = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{home}"), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *homes})

    return __getattr__, __dir__
