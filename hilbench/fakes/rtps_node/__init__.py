"""Emulated FreeRTPS boards: minimal RTPS participants on 127.0.0.1 unicast.

- :mod:`~hilbench.fakes.rtps_participant` (the kit the micro-ROS agent's bridge shares): SPDP, SEDP, user
  writers and readers (:class:`RtpsParticipant`).
- :mod:`node`: a board's topics: publishers at a rate, subscribers, echoes (:class:`FreeRtpsNode`).
"""

from hilbench.fakes.rtps_node.node import FreeRtpsNode, TopicSpec, mac_prefix
from hilbench.fakes.rtps_participant import RtpsParticipant

__all__ = ["FreeRtpsNode", "RtpsParticipant", "TopicSpec", "mac_prefix"]
