"""Emulated CANopen nodes: a generic CiA 301 node and the rover board on top of it.

- :class:`~hilbench.fakes.canopen.node.CanopenNode`: NMT, heartbeat, SDO server, EMCY, node guarding;
- :class:`~hilbench.fakes.canopen.rover.RoverNode`: the STM32 rover board's application (setpoint RPDO,
  encoder, odometry, velocity and status TPDOs) on the rover firmware's motion model.
"""

from hilbench.fakes.canopen.node import CanopenNode
from hilbench.fakes.canopen.rover import RoverNode

__all__ = ["CanopenNode", "RoverNode"]
