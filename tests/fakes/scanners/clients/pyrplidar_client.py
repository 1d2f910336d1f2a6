"""pyrplidar 0.1.2, unmodified: info, health, sample rate, scan modes, then a standard or express scan.

usage: pyrplidar_client.py PORT standard|express REVOLUTIONS
"""

import json
import sys
import time

from pyrplidar import PyRPlidar

port, mode, revs = sys.argv[1], sys.argv[2], int(sys.argv[3])
lidar = PyRPlidar()
lidar.connect(port=port, baudrate=115200, timeout=3)
info = lidar.get_info()
health = lidar.get_health()
rate = lidar.get_samplerate()
modes = lidar.get_scan_modes()
typical = lidar.get_scan_mode_typical()
lidar.set_motor_pwm(660)
gen = lidar.start_scan() if mode == "standard" else lidar.start_scan_express(typical)
times, counts, last, cur = [], [], [], None
for m in gen():
    if m.start_flag:
        if cur is not None:
            times.append(time.monotonic())
            counts.append(len(cur))
            last = cur
            if len(times) >= revs:
                break
        cur = []
    if cur is not None and m.distance > 0:
        cur.append([m.quality, m.angle, m.distance])
lidar.stop()
lidar.set_motor_pwm(0)
lidar.disconnect()
print(json.dumps({"info": [info.model, info.firmware_major, info.firmware_minor, info.hardware, info.serialnumber],
                  "health": [health.status, health.error_code], "rate": [rate.t_standard, rate.t_express],
                  "modes": [[m.name, m.max_distance, m.us_per_sample, m.ans_type] for m in modes],
                  "typical": typical, "times": times, "counts": counts, "scan": last}))
