"""Drive the rover board over CAN as a host's own code would, with python-can (unmodified) over socketcand: NMT
start, then RPDO1 velocity setpoints every 50 ms (the board's DBC layout, built by hand here), then stop
setpoints for 0.3 s.

usage: can_drive.py HOST PORT CHANNEL NODE_ID VX VY OMEGA SECONDS
RPDO1 (COB-ID 0x200 + node): vx, vy (int16, mm/s), omega (int16, mrad/s), alive counter (+1 per frame),
CRC-8/SAE-J1850 (poly 0x1D, init 0xFF, xorout 0xFF) of bytes 0..6.
"""

import struct
import sys
import time

import can


def crc8_j1850(data: bytes) -> int:
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


host, port, channel, node = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
vx, vy, omega, seconds = map(float, sys.argv[5:9])
bus = can.Bus(interface="socketcand", host=host, port=port, channel=channel)
counter = 0


def setpoint(x: float, y: float, w: float) -> None:
    global counter
    counter = (counter + 1) % 256
    body = struct.pack("<hhhB", round(x * 1000), round(y * 1000), round(w * 1000), counter)
    bus.send(can.Message(arbitration_id=0x200 + node, data=body + bytes([crc8_j1850(body)]), is_extended_id=False))


try:
    bus.send(can.Message(arbitration_id=0x000, data=[0x01, node], is_extended_id=False))  # NMT start
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        setpoint(vx, vy, omega)
        time.sleep(0.05)
    for _ in range(6):
        setpoint(0.0, 0.0, 0.0)
        time.sleep(0.05)
finally:
    bus.shutdown()
print("sent", counter, flush=True)
