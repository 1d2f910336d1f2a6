"""rplidar-roboticia (module ``rplidar``), unmodified: info, health, N revolutions, stop, stop_motor.

usage: rplidar_roboticia.py PORT normal|express REVOLUTIONS
Prints one JSON object: info, health, per-revolution arrival times and point counts, the last revolution.
"""

import json
import sys
import time

from rplidar import RPLidar

port, scan_type, revs = sys.argv[1], sys.argv[2], int(sys.argv[3])
lidar = RPLidar(port)
info = lidar.get_info()
health = lidar.get_health()
times, counts, last = [], [], []
for i, scan in enumerate(lidar.iter_scans(scan_type=scan_type)):
    times.append(time.monotonic())
    counts.append(len(scan))
    last = scan
    if i + 1 >= revs:
        break
lidar.stop()
lidar.stop_motor()
lidar.disconnect()
print(json.dumps({"info": info, "health": list(health), "times": times, "counts": counts,
                  "scan": [[q, a, d] for q, a, d in last]}))
