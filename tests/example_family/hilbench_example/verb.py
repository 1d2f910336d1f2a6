"""``hilbench blink PORT``: ping an Acme blinker board and print what it says."""

from __future__ import annotations

import argparse
import time

from hilbench.errors import DeviceError

ORDER = 95


def cmd_blink(args: argparse.Namespace) -> int:
    import serial

    from hilbench_example.protocol import PING, PONG, LineDecoder, build

    with serial.Serial(args.port, 115_200, timeout=0.1) as ser:
        ser.write(build(PING))
        dec = LineDecoder()
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            for msg in dec.feed(ser.read(256)):
                if msg.word == PONG:
                    print(f"blinker {msg.value} answered")
                    return 0
    raise DeviceError(f"{args.port}: no blinker answered within {args.timeout} s")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("blink", help="ping an Acme blinker board (example plug-in)",
                       description="Send PING to an Acme blinker board and print its id.")
    p.add_argument("port", help="serial port or an emulated bench's pty")
    p.add_argument("--timeout", type=float, default=2.0, help="seconds to wait (default 2)")
    p.set_defaults(func=cmd_blink)
