"""Deprecated names: modules and objects that moved when device families became plug-ins.

Old imports keep working with a :class:`DeprecationWarning` that names the new
place. Every alias lives in the two tables below and nowhere else: a module
that moved is served by a finder on ``sys.meta_path``; a name that left a
package that still exists is served by that package's ``__getattr__``
(``__getattr__ = _compat.module_getattr(__name__)``).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
import warnings
from collections.abc import Callable
from typing import Any

#: Old module -> new module.
MOVED_MODULES: dict[str, str] = {
    "hilbench.profile": "hilbench.bench.profile",
    "hilbench.control": "hilbench.bench.control",
    "hilbench.dxl_client": "hilbench.clients.dynamixel",
    "hilbench.teleop": "hilbench.clients.teleop",
    "hilbench.demo": "hilbench.clients.dynamixel_demo",
    "hilbench.monitor.tracker": "hilbench.monitor.dynamixel.tracker",
    "hilbench.monitor.devices": "hilbench.monitor.dynamixel.devices",
    "hilbench.monitor.summary": "hilbench.monitor.dynamixel.summary",
    "hilbench.dashboard.views": "hilbench.dashboard.dynamixel_views",
}

#: (old module, name) -> "new.module:name" for names whose meaning moved with a family.
MOVED_NAMES: dict[tuple[str, str], str] = {
    ("hilbench.profile", "DeviceSpec"): "hilbench.families.dynamixel:ServoSpec",
    ("hilbench.profile", "BoardSpec"): "hilbench.families.stm32_rover:BoardSpec",
    ("hilbench.bench", "DeviceSpec"): "hilbench.families.dynamixel:ServoSpec",
    ("hilbench.bench", "BoardSpec"): "hilbench.families.stm32_rover:BoardSpec",
    ("hilbench.bench", "board_config"): "hilbench.families.stm32_rover:board_config",
    ("hilbench.control", "ControlClient"): "hilbench.families.stm32_rover:BoardClient",
    ("hilbench.monitor", "BusTracker"): "hilbench.monitor.dynamixel.tracker:BusTracker",
    ("hilbench.monitor", "DeviceState"): "hilbench.monitor.dynamixel.devices:DeviceState",
    ("hilbench.monitor", "summary"): "hilbench.monitor.dynamixel.summary:summary",
    ("hilbench.dashboard", "VIEWS"): "hilbench.dashboard.dynamixel_views:VIEWS",
    ("hilbench.dashboard", "TITLES"): "hilbench.dashboard.dynamixel_views:TITLES",
}


def _resolve(target: str) -> Any:
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def _warn(old: str, new: str) -> None:
    warnings.warn(f"{old} is deprecated: use {new}", DeprecationWarning, stacklevel=3)


def module_getattr(module: str) -> Callable[[str], Any]:
    """A module ``__getattr__`` serving the moved names of ``module`` (with a warning)."""

    def __getattr__(name: str) -> Any:
        target = MOVED_NAMES.get((module, name))
        if target is None:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        _warn(f"{module}.{name}", target.replace(":", "."))
        return _resolve(target)

    return __getattr__


class _AliasLoader(importlib.abc.Loader):
    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        old = spec.name
        new = MOVED_MODULES[old]
        _warn(old, new)
        target = importlib.import_module(new)
        alias = types.ModuleType(old, f"Deprecated alias of {new}.")
        moved = module_getattr(old)

        def __getattr__(name: str) -> Any:
            if (old, name) in MOVED_NAMES:
                return moved(name)
            return getattr(target, name)

        alias.__getattr__ = __getattr__  # type: ignore[attr-defined]
        alias.__all__ = list(getattr(target, "__all__", []))  # type: ignore[attr-defined]
        return alias

    def exec_module(self, module: types.ModuleType) -> None:
        pass


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: Any, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname in MOVED_MODULES:
            return importlib.machinery.ModuleSpec(fullname, _AliasLoader())
        return None


def install() -> None:
    """Put the alias finder first on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _AliasFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _AliasFinder())


install()
