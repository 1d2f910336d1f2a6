"""rplidar-roboticia (module ``rplidar``), unmodified: the range straight ahead of every revolution.

usage: rplidar_ahead.py PORT SECONDS
Prints one JSON line per revolution: {"t": monotonic time the revolution arrived, "ahead": median range (m) of
the points within 3 degrees of straight ahead (null: none)}, until SECONDS passed. On a busy machine this
process may fall behind the scanner and lose bytes, as a real host does: it then starts the scan again, as
the library's users do (RPLidarException -> stop, clean_input, iter_scans again).
"""

import json
import statistics
import sys
import time

from rplidar import RPLidar, RPLidarException

port, seconds = sys.argv[1], float(sys.argv[2])
lidar = RPLidar(port)
end = time.monotonic() + seconds
try:
    while time.monotonic() < end:
        try:
            for scan in lidar.iter_scans(scan_type="normal", max_buf_meas=False):
                ahead = [d / 1000.0 for _q, a, d in scan if (a <= 3.0 or a >= 357.0) and d > 0]
                print(json.dumps({"t": time.monotonic(), "ahead": statistics.median(ahead) if ahead else None}),
                      flush=True)
                if time.monotonic() > end:
                    break
        except RPLidarException as exc:
            print(f"restarting the scan: {exc}", file=sys.stderr, flush=True)
            lidar.stop()
            time.sleep(0.05)
            lidar.clean_input()
finally:
    lidar.stop()
    lidar.disconnect()
