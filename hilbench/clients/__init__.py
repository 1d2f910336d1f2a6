"""Host-side programs: what a robot's own software does to a device, for the CLI, the demo and tests.

- :mod:`~hilbench.clients.dynamixel`: scan, ping, read and write Dynamixel devices through the official SDK;
- :mod:`~hilbench.clients.dynamixel_demo`: the demo's control loop (the official SDK, as the Wolfgang robot
  drives its bus) with staged faults, watched by the bus monitor;
- :mod:`~hilbench.clients.teleop`: keyboard teleoperation of a rover board (Vel2d frames).

Clients use protocols, transports and third-party SDKs, never the fakes: they work on real hardware alike.
"""
