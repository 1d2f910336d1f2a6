"""Drive a rover board over its UART as the ROS bridge vel2d_bridge does: 28-byte Vel2d frames (three
little-endian doubles and a CRC-32/MPEG-2) over pyserial, at 20 Hz for SECONDS, then stop frames for 0.3 s.

usage: vel2d_drive.py PORT VX VY WZ SECONDS
"""

import struct
import sys
import time

import serial


def crc32_mpeg2(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for b in data:
        crc ^= b << 24
        for _ in range(8):
            crc = ((crc << 1) ^ 0x04C11DB7) & 0xFFFFFFFF if crc & 0x80000000 else (crc << 1) & 0xFFFFFFFF
    return crc


def frame(x: float, y: float, z: float) -> bytes:
    payload = struct.pack("<3d", x, y, z)
    return payload + struct.pack("<I", crc32_mpeg2(payload))


port, vx, vy, wz, seconds = sys.argv[1], *map(float, sys.argv[2:6])
ser = serial.Serial(port, 115200)
end = time.monotonic() + seconds
while time.monotonic() < end:
    ser.write(frame(vx, vy, wz))
    time.sleep(0.05)
for _ in range(6):
    ser.write(frame(0.0, 0.0, 0.0))
    time.sleep(0.05)
ser.close()
print("sent", flush=True)
