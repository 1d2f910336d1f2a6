"""hilbench: hardware-in-the-loop benches for robots over serial, CAN and UDP."""

from hilbench import _compat as _compat  # serves the deprecated module paths

__version__ = "0.1.0"
