"""Emulated CANopen nodes: the generic CiA 301 node (the kit the CANopen families build on).

- :class:`~hilbench.fakes.canopen.node.CanopenNode`: NMT, heartbeat, SDO server, EMCY, node guarding;
- :mod:`~hilbench.fakes.canopen.rover` (the CANopen board family's): the STM32 rover board's application
  (setpoint RPDO, encoder, odometry, velocity and status TPDOs) on the rover firmware's motion model.
"""

from hilbench.fakes.canopen.node import CanopenNode

__all__ = ["CanopenNode"]
