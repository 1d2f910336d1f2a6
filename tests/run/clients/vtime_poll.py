"""A client that polls the clock (as the official Dynamixel SDK's rxPacket does with time.time()) until
one virtual second has passed, with nothing to wait for: it counts as waiting, and time moves in quanta."""

import json
import os
import time

v0, w0 = time.monotonic_ns(), os.times().elapsed
end = v0 + 10**9
reads = 0
while time.monotonic_ns() < end:
    reads += 1
print(json.dumps({"virtual": time.monotonic_ns() - v0, "reads": reads, "wall": os.times().elapsed - w0}))
