"""Test-only stand-in for ``hilbench run``'s pyserial fallback (until it lands on main).

A pty has no modem lines: pyserial's DTR/RTS ioctls fail with ENOTTY there.
Imported at interpreter start (this directory is put on PYTHONPATH by the
tests), it lets those ioctls fail quietly and hands the new levels to the
bench's control channel (``HILBENCH_CONTROL`` = host:port,
``HILBENCH_LINES_DEVICE`` = the device), which sets the endpoint's
LineState exactly as the shim will. The client library stays unmodified.
"""

import errno
import json
import os
import socket


def _forward(dtr=None, rts=None):
    address = os.environ.get("HILBENCH_CONTROL")
    device = os.environ.get("HILBENCH_LINES_DEVICE")
    if not address or not device or dtr is None:
        return
    host, _, port = address.rpartition(":")
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        sock.sendall((json.dumps({"cmd": "dtr", "device": device, "dtr": bool(dtr)}) + "\n").encode())
        sock.makefile().readline()


def _patch():
    try:
        import serial.serialposix as sp
    except Exception:  # noqa: BLE001
        return
    orig_dtr = sp.Serial._update_dtr_state
    orig_rts = sp.Serial._update_rts_state

    def update_dtr(self):
        try:
            orig_dtr(self)
        except OSError as exc:
            if exc.errno != errno.ENOTTY:
                raise
        _forward(dtr=self._dtr_state)

    def update_rts(self):
        try:
            orig_rts(self)
        except OSError as exc:
            if exc.errno != errno.ENOTTY:
                raise

    sp.Serial._update_dtr_state = update_dtr
    sp.Serial._update_rts_state = update_rts


_patch()
