"""Drains and output flushes as pyserial clients make them (dynamixel-sdk 3.x drains before every packet,
pypot flushes). Run by tests/run/test_delivery_ledger.py under `hilbench run`. Usage: drain_pyserial.py
PORT N. Steps, each answered by one line on stdout, each after a line on stdin:
  start   write "hello", flush()                                           -> "hello"
  idle    N x (flush(), reset_output_buffer(), termios.tcdrain): nothing pending -> "idle"
  flush   write "bye", reset_output_buffer()                                -> "flush"
"""

import sys
import termios

import serial

port, n = sys.argv[1], int(sys.argv[2])
with serial.Serial(port, 9600) as ser:
    for line in sys.stdin:
        step = line.strip()
        if step == "start":
            ser.write(b"hello")
            ser.flush()
            print("hello", flush=True)
        elif step == "idle":
            for _ in range(n):
                ser.flush()
                ser.reset_output_buffer()
                termios.tcdrain(ser.fileno())
            print("idle", flush=True)
        elif step == "flush":
            ser.write(b"bye")
            ser.reset_output_buffer()
            print("flush", flush=True)
            break
