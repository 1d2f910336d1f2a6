"""A SICK LMS 200 host over pyserial (as sicktoolbox talks to the unit; no published Python LMS 200 client
exists to install): switch the link to 38400 baud, then poll one scan after another.

usage: lms_scans.py PORT SECONDS
Prints one JSON line per scan: {"t": monotonic time it arrived, "values": the range values (mm)}.
"""

import json
import sys
import time

import serial

from hilbench.protocols import sick_lms200 as lms

port, seconds = sys.argv[1], float(sys.argv[2])
ser = serial.Serial(port, 9600, timeout=0.05)
dec = lms.Decoder()


def ask(data: bytes, want, timeout: float = 3.0):
    ser.write(data)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for item in dec.feed(ser.read(4096)):
            if want(item):
                return item
    raise SystemExit(f"no answer to {data.hex()}")


ask(lms.mode_request(lms.Mode.BAUD_38400), lambda i: isinstance(i, lms.Frame))
ser.baudrate = 38400
end = time.monotonic() + seconds
while time.monotonic() < end:
    frame = ask(lms.request(lms.Cmd.SCAN, b"\x01"), lambda i: isinstance(i, lms.Frame) and i.cmd == 0xB0)
    print(json.dumps({"t": time.monotonic(), "values": list(frame.fields()["values"])}), flush=True)
