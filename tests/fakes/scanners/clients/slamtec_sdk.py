"""Slamtec's RPLIDAR SDK through pyrplidarsdk (nanobind wrapper of the C++ SDK), unmodified.

usage: slamtec_sdk.py PORT REVOLUTIONS [WAIT_S]
connect (GET_INFO, motor-control probe, GET_HEALTH), start_scan (the SDK's typical scan mode via
GET_LIDAR_CONF), grab N revolutions (grabScanDataHq + ascendScanData), stop, disconnect.
"""

import json
import sys
import time

import pyrplidarsdk

port, revs = sys.argv[1], int(sys.argv[2])
wait = float(sys.argv[3]) if len(sys.argv) > 3 else 30.0
drv = pyrplidarsdk.RplidarDriver(port=port, baudrate=115200)
ok = drv.connect()
info = drv.get_device_info()
health = drv.get_health()
started = drv.start_scan()
times, counts, last = [], [], None
t0 = time.monotonic()
while len(times) < revs and time.monotonic() - t0 < wait:
    data = drv.get_scan_data()
    if data:
        times.append(time.monotonic())
        counts.append(len(data[0]))
        last = data
drv.stop_scan()
drv.disconnect()
print(json.dumps({"connected": ok, "started": started,
                  "info": [info.model, info.firmware_version, info.hardware_version, info.serial_number],
                  "health": [health.status, health.error_code], "times": times, "counts": counts,
                  "angles": list(last[0]) if last else [], "ranges": list(last[1]) if last else []}))
