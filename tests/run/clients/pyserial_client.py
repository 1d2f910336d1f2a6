"""A pyserial client as robot software writes them (RPLIDAR libraries clear DTR to start the motor, pypot
flushes before every packet). Run by tests/run/test_pyserial_clients.py in a separate process, under
`hilbench run` and without it. Usage: pyserial_client.py PORT PAYLOAD_BYTES; prints JSON."""

import json
import os
import sys

import serial


def attempt(fn):
    try:
        return fn()
    except OSError as exc:
        return f"errno {exc.errno}"


port, size = sys.argv[1], int(sys.argv[2])
payload = bytes(0x41 + i % 26 for i in range(size))
out = {"shim": os.environ.get("HILBENCH_RUN")}
with serial.Serial(port, 57_600, timeout=1) as ser:
    out["dtr"] = attempt(lambda: setattr(ser, "dtr", False))
    out["rts"] = attempt(lambda: setattr(ser, "rts", False))
    out["lines"] = attempt(lambda: [ser.cts, ser.dsr, ser.ri, ser.cd])
    ser.write(payload)
    ser.reset_output_buffer()
    out["break"] = attempt(lambda: ser.send_break(0.25))
print(json.dumps(out))
