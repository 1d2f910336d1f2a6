"""An emulated Micro XRCE-DDS agent (the host side of micro-ROS) for a datagram net.

- :mod:`agent`: :class:`XrceAgent`, sessions, streams, entities and routing.
- :mod:`entities`: DDS entities from CREATE by reference, XML or binary.
- :mod:`bridge`: the agent's samples on RTPS, so ROS 2 nodes and micro-ROS clients see each other.
"""

from hilbench.fakes.xrce_agent.agent import Session, XrceAgent

__all__ = ["Session", "XrceAgent"]
