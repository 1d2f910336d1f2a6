"""hokuyolx 0.9.0, unmodified, over TCP: constructor (%ST, time sync, PP, BM), GD, MD for N scans.

usage: hokuyolx_client.py HOST PORT SCANS
"""

import json
import sys
import time

from hokuyolx import HokuyoLX

host, port, scans = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
laser = HokuyoLX(addr=(host, port))
ts, scan = laser.get_dist()
angles = laser.get_angles()
times, stamps, pendings = [], [], []
last = None
for dist, stamp, pending in laser.iter_dist(scans=scans):
    times.append(time.monotonic())
    stamps.append(int(stamp))
    pendings.append(int(pending))
    last = dist
state = laser.laser_state()
version = laser.version()
laser.close()
print(json.dumps({"params": {"amin": laser.amin, "amax": laser.amax, "aforw": laser.aforw, "ares": laser.ares,
                             "dmin": laser.dmin, "dmax": laser.dmax, "scan_freq": laser.scan_freq, "model": laser.model},
                  "single_ts": int(ts), "angles": angles.tolist(), "single": scan.tolist(), "times": times,
                  "stamps": stamps, "pendings": pendings, "last": last.tolist(), "state": list(state),
                  "version": {k: str(v) for k, v in version.items()}}))
