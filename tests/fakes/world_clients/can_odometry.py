"""python-can (unmodified) over socketcand: the rover board's odometry as its TPDO2 carries it.

usage: can_odometry.py HOST PORT CHANNEL NODE_ID SECONDS
Prints one JSON line per TPDO2 frame (COB-ID 0x280 + node): {"t": monotonic time it arrived, "x", "y" (m),
"theta" (rad)}, decoded by hand from the board's DBC layout (x, y: int24 little-endian in mm at bytes 0 and 3;
theta: int16 in 0.0001 rad at byte 6).
"""

import json
import sys
import time

import can

host, port, channel, node, seconds = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5])
bus = can.Bus(interface="socketcand", host=host, port=port, channel=channel)
end = time.monotonic() + seconds
try:
    while time.monotonic() < end:
        msg = bus.recv(0.2)
        if msg is None or msg.arbitration_id != 0x280 + node or len(msg.data) != 8:
            continue
        d = bytes(msg.data)
        x = int.from_bytes(d[0:3], "little", signed=True) / 1000.0
        y = int.from_bytes(d[3:6], "little", signed=True) / 1000.0
        theta = int.from_bytes(d[6:8], "little", signed=True) / 10000.0
        print(json.dumps({"t": time.monotonic(), "x": x, "y": y, "theta": theta}), flush=True)
finally:
    bus.shutdown()
