"""A thread that computes without ever waiting, beside a main thread that sleeps 3 x 1 virtual s: the
clock can only move by a lockstep stall (then at the wall clock's rate). Prints the spinner's thread id
and the virtual and wall seconds the sleeps took."""

import json
import os
import threading
import time


def spin():
    x = 0
    while True:
        x += 1


t = threading.Thread(target=spin, daemon=True)
t.start()
v0, w0 = time.monotonic(), os.times().elapsed
for _ in range(3):
    time.sleep(1)
print(json.dumps({"spinner": t.native_id, "main": threading.get_native_id(), "virtual": time.monotonic() - v0,
                  "wall": os.times().elapsed - w0}))
