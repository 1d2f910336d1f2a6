"""hilbench.lazy_module: a module stands in for itself until first used, then is the module."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import sys
from hilbench.lazy_module import LazyModule
np = LazyModule("numpy", globals(), "np")
before = "numpy" in sys.modules
zeros = np.zeros(3)
import numpy
print(before, "numpy" in sys.modules, np is numpy, zeros.tolist())
"""


def test_the_module_is_imported_on_first_use_and_then_replaces_its_stand_in():
    out = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=60)
    assert out.stdout.rstrip("\n").split(None, 3) == ["False", "True", "True", "[0.0, 0.0, 0.0]"], out.stderr
