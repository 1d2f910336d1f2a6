"""A python-can client run as a separate process by the CAN tests (unmodified python-can, any interface).

    python tests/can_client.py INTERFACE RECEIVE_ID COUNT SEND_ID [key=value ...]

Opens ``can.Bus(interface=INTERFACE, **kwargs)``, prints ``ready``, receives
until COUNT frames of RECEIVE_ID arrived (10 s at most), sends COUNT frames
``SEND_ID#<i>`` back, and prints one JSON line: what it received (other IDs
too) and what python-can's ``get_version`` says for SLCAN.
"""

from __future__ import annotations

import json
import sys
import time

import can


def main() -> None:
    interface, rx_id, count, tx_id = sys.argv[1], int(sys.argv[2], 0), int(sys.argv[3]), int(sys.argv[4], 0)
    kwargs: dict = {}
    for item in sys.argv[5:]:
        key, _, value = item.partition("=")
        kwargs[key] = int(value) if value.isdigit() else value
    bus = can.Bus(interface=interface, **kwargs)
    extra = {}
    if interface == "slcan":
        extra["version"] = bus.get_version(2.0)
    print("ready", flush=True)
    got = []
    deadline = time.monotonic() + 10
    while sum(1 for g in got if g["id"] == rx_id) < count and time.monotonic() < deadline:
        msg = bus.recv(0.5)
        if msg is None:
            continue
        got.append({"id": msg.arbitration_id, "ext": msg.is_extended_id, "data": bytes(msg.data).hex(),
                    "t": msg.timestamp, "error": msg.is_error_frame})
    for i in range(count):
        bus.send(can.Message(arbitration_id=tx_id, data=[i, 0xAA], is_extended_id=tx_id > 0x7FF))
    time.sleep(0.2)  # let the last writes leave before the connection closes
    bus.shutdown()
    print(json.dumps({"received": got, **extra}), flush=True)


if __name__ == "__main__":
    main()
