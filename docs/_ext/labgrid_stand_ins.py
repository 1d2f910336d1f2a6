"""Stand-ins for labgrid, attrs and pexpect, so the reference documents ``hilbench.labgrid.drivers``.

labgrid lives in a venv of its own (it replaces pyserial's ``serial`` package: see the Makefile), so the
documentation's venv does not have it. autodoc's mocks do not do here: the drivers are classes under two
decorators (``@target_factory.reg_driver``, ``@attr.s``) on a mocked base class, and autodoc gives up on
them (one decorator unwrapped) or never finishes (type hints of a class whose base is a mock). These
modules define what ``hilbench/labgrid/drivers.py`` uses, as plain Python: decorators that return what
they decorate, base classes that are classes. :func:`install` puts them in ``sys.modules`` only for
packages that cannot be imported; nothing but the documentation build loads this file.
"""

from __future__ import annotations

import importlib.util
import sys
import types
from collections.abc import Callable
from typing import Any


def _module(name: str, **attrs: Any) -> types.ModuleType:
    module = types.ModuleType(name)
    for key, value in attrs.items():
        if isinstance(value, type):
            value.__module__ = name
        setattr(module, key, value)
    return module


def _identity_decorator(*args: Any, **kwargs: Any) -> Any:
    """``@deco`` and ``@deco(...)`` both return the decorated object unchanged."""
    if len(args) == 1 and not kwargs and callable(args[0]):
        return args[0]
    return lambda obj: obj


class Driver:
    """labgrid's driver base class (stand-in)."""

    check_active = staticmethod(_identity_decorator)


class Strategy(Driver):
    """labgrid's strategy base class (stand-in)."""


class StrategyError(Exception):
    """labgrid's strategy error (stand-in)."""


class ConsoleProtocol:
    """labgrid's console protocol (stand-in)."""


class TIMEOUT(Exception):  # noqa: N801 (pexpect's name)
    """pexpect's timeout (stand-in)."""


class _Factory:
    reg_driver = staticmethod(_identity_decorator)
    reg_resource = staticmethod(_identity_decorator)


def _attrib(default: Any = None, **kwargs: Any) -> Any:
    return default() if isinstance(default, _AttrFactory) else default


class _AttrFactory:
    def __init__(self, factory: Callable[[], Any]) -> None:
        self.factory = factory

    def __call__(self) -> Any:
        return self.factory()


def install() -> list[str]:
    """Put the stand-ins in ``sys.modules`` for the packages that are not installed; returns their names."""
    stand_ins = {
        "attr": [_module("attr", s=_identity_decorator, ib=_attrib, Factory=_AttrFactory,
                         validators=types.SimpleNamespace(instance_of=lambda *types_: None))],
        "pexpect": [_module("pexpect", TIMEOUT=TIMEOUT)],
        "labgrid": [_module("labgrid"), _module("labgrid.driver", Driver=Driver),
                    _module("labgrid.factory", target_factory=_Factory()),
                    _module("labgrid.protocol", ConsoleProtocol=ConsoleProtocol),
                    _module("labgrid.step", step=_identity_decorator),
                    _module("labgrid.strategy", Strategy=Strategy, StrategyError=StrategyError)],
    }
    installed = []
    for package, modules in stand_ins.items():
        if importlib.util.find_spec(package) is None:
            for module in modules:
                sys.modules.setdefault(module.__name__, module)
            installed.append(package)
    return installed
