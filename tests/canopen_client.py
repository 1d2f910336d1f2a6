"""The canopen package as a separate process on a bench's socketcand server (run by the CAN tests).

    python tests/canopen_client.py HOST PORT CHANNEL EDS

Imports the board's EDS, waits for heartbeats and measures their period,
reads the identity over SDO, sets 0x1017 to 100 ms and measures again,
starts the node, drives it with RPDO setpoints (0.2 m/s for 0.6 s) and
reads the odometry TPDO; prints one JSON line.
"""

from __future__ import annotations

import json
import sys
import time

import canopen

from hilbench.protocols import board_can as bc


def period(node, n: int) -> float:
    stamps = []
    for _ in range(n):
        node.nmt.wait_for_heartbeat(3)
        stamps.append(time.monotonic())
    return (stamps[-1] - stamps[0]) / (n - 1)


def main() -> None:
    host, port, channel, eds = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    canopen.Network.NOTIFIER_SHUTDOWN_TIMEOUT = 0.0
    net = canopen.Network()
    net.connect(interface="socketcand", host=host, port=port, channel=channel)
    node = net.add_node(2, eds)
    out = {"first_state": node.nmt.wait_for_heartbeat(3)}
    out["period_before"] = period(node, 3)
    out["vendor_id"] = node.sdo[0x1018][1].raw
    out["device_name"] = node.sdo[0x1008].raw
    node.sdo[0x1017].raw = 100
    node.nmt.wait_for_heartbeat(1)
    out["period_after"] = period(node, 6)
    node.nmt.state = "OPERATIONAL"
    node.tpdo.read()
    poses = []
    node.tpdo[2].add_callback(lambda m: poses.append([v.phys for v in m]))
    start = time.monotonic()
    counter = 0
    while time.monotonic() - start < 0.6:
        net.send_message(0x202, bc.build_setpoint(0.2, 0.0, 0.0, counter))
        counter += 1
        time.sleep(0.05)
    time.sleep(0.4)
    out["odometry_x"], out["odometry_y"], out["odometry_theta"] = poses[-1]
    net.disconnect()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
