"""Host-side programs: what a robot's own software does to a device, for the CLI, the demo and tests.

- :mod:`~hilbench.clients.dynamixel`: scan, ping, read and write Dynamixel devices through the official SDK;
- :mod:`~hilbench.clients.dynamixel_demo`: the demo's control loop (each servo bus's own SDK, as the Wolfgang
  robot drives its bus) with staged faults, watched by the bus monitor;
- :mod:`~hilbench.clients.servo_connections`: a servo bus through its vendor's SDK (dynamixel-sdk's Protocol 2.0
  and 1.0 handlers, Feetech's scservo_sdk) behind one small interface;
- :mod:`~hilbench.clients.teleop`: keyboard teleoperation of a rover board (Vel2d frames).

Clients use protocols, transports and third-party SDKs, never the fakes: they work on real hardware alike.
"""
