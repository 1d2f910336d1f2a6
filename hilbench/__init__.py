"""hilbench: hardware-in-the-loop benches for robots over serial, CAN and UDP."""

__version__ = "0.1.0"
