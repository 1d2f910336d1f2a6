"""dynamixel-sdk 3.x, which `make install` puts beside the venv's packages (``.venv/dynamixel-sdk-3``).

Our dependency is dynamixel-sdk 4.x, whose ``clearPort()`` flushes input; 3.x (what ROS packages and most
robots run) calls ``ser.flush()``, a tcdrain, before every packet. Tests load it under its own module
name, beside 4.x, or run it in a subprocess with ``PYTHONPATH=SDK3_DIR``.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

SDK3_DIR = Path(sys.prefix) / "dynamixel-sdk-3"
MISSING = f"dynamixel-sdk 3.x is not installed in {SDK3_DIR} (`make install` puts it there)"
_NAME = "dynamixel_sdk_3"


def available() -> bool:
    """Whether the 3.x SDK is there."""
    return (SDK3_DIR / "dynamixel_sdk" / "__init__.py").exists()


def load() -> ModuleType:
    """The 3.x SDK as the module ``dynamixel_sdk_3`` (its imports are relative, so it loads beside 4.x)."""
    if _NAME in sys.modules:
        return sys.modules[_NAME]
    package = SDK3_DIR / "dynamixel_sdk"
    spec = importlib.util.spec_from_file_location(_NAME, package / "__init__.py",
                                                  submodule_search_locations=[str(package)])
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[_NAME] = module
    spec.loader.exec_module(module)
    return module
