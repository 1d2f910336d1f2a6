"""``hilbench dxl``: Dynamixel tools for any port, real or emulated, through the official SDK.

The Dynamixel family's own verb module (entry point ``dxl``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from hilbench.cli.common import int_arg
from hilbench.rules import Rule


def sdk_baud() -> Rule:
    """``--baud``: a rate the official SDK opens (what a real or emulated port can be driven at)."""
    # (the model tables import construct: once dxl is registered, not for every verb's --help)
    from hilbench.protocols.dynamixel_models import SDK_BAUDS

    return Rule(int, choices=SDK_BAUDS, what="a baud rate the Dynamixel SDK can open")


#: LENGTH of a read or write by address, in bytes.
DATA_LENGTH = Rule(int, 1, 1024)


def dxl_id(text: str) -> int:
    """A device ID, 0-252 (253-255 are reserved or broadcast)."""
    value = int_arg(text)
    if not 0 <= value <= 252:
        raise argparse.ArgumentTypeError(f"expected a device ID 0..252, got {value}")
    return value


class ScanCounter:
    """``dxl scan``'s progress as one line on a terminal's stderr, rewritten in place (nothing elsewhere)."""

    def __init__(self, stream=None, every: float = 0.1) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.active = self.stream.isatty()
        self.every = every
        self._last = -1.0

    def __call__(self, baud: int, dev_id: int | None, found: int) -> None:
        if not self.active:
            return
        now = time.monotonic()
        if now - self._last < self.every and dev_id not in (0, None):
            return
        self._last = now
        where = "broadcast ping" if dev_id is None else f"ID {dev_id}/252"
        self.stream.write(f"\rscanning at {baud} baud: {where}, {found} found\x1b[K")
        self.stream.flush()

    def close(self) -> None:
        if self.active and self._last >= 0:
            self.stream.write("\r\x1b[K")
            self.stream.flush()


def found_line(found: list, bauds: tuple[int, ...]) -> str:
    """What a scan found, in one line: ``3 devices: 2 at 57600 baud, 1 at 1000000 baud``."""
    if not found:
        return f"no device answered at {', '.join(map(str, bauds))} baud"
    per = {b: sum(1 for f in found if f.baud == b) for b in bauds}
    where = ", ".join(f"{n} at {b} baud" for b, n in per.items() if n)
    return f"{len(found)} device{'s' if len(found) != 1 else ''}: {where}"


def cmd_dxl_scan(args: argparse.Namespace) -> int:
    from hilbench.clients import dynamixel as dxl_client

    bauds = tuple(args.baud) if args.baud else dxl_client.SCAN_BAUDS
    counter = ScanCounter()
    try:
        found = dxl_client.scan(args.port, bauds, protocol=float(args.protocol), progress=counter)
    finally:
        counter.close()
    if args.json:
        print(json.dumps([{"id": f.id, "model": f.model_number, "model_name": f.model_name,
                           "firmware": f.firmware, "baud": f.baud} for f in found]))
    if not found:  # no device answered: status 1 (as a ping that gets no answer), whatever the output's form
        from hilbench.errors import DeviceError

        raise DeviceError(found_line(found, bauds))
    if args.json:
        return 0
    from rich.table import Table

    from hilbench.console import Console

    table = Table(title=f"Dynamixel devices on {args.port}")
    for col in ("ID", "model", "number", "firmware", "baud"):
        table.add_column(col, justify="right")
    for f in found:
        table.add_row(str(f.id), f.model_name, str(f.model_number), str(f.firmware), str(f.baud))
    Console().print(table)
    print(found_line(found, bauds))
    return 0


def cmd_dxl_ping(args: argparse.Namespace) -> int:
    from hilbench.clients import dynamixel as dxl_client

    f = dxl_client.ping(args.port, args.id, args.baud, protocol=float(args.protocol))
    if args.json:
        print(json.dumps({"id": f.id, "model": f.model_number, "model_name": f.model_name, "firmware": f.firmware}))
    else:
        print(f"ID {f.id}: {f.model_name} (model {f.model_number}), firmware {f.firmware}")
    return 0


def cmd_dxl_read(args: argparse.Namespace) -> int:
    from hilbench.clients import dynamixel as dxl_client

    address, raw, f = dxl_client.read(args.port, args.id, args.item, args.baud, args.length,
                                      protocol=float(args.protocol))
    if args.json:
        value = f.decode(raw[: f.size]) if f and len(raw) >= f.size else int.from_bytes(raw, "little")
        print(json.dumps({"id": args.id, "address": address, "item": f.key if f else None, "value": value,
                          "unit": f.unit if f else "", "raw": raw.hex()}))
    else:
        name = f.name if f else f"address {address}"
        print(f"ID {args.id} {name}: {dxl_client.format_value(raw, f)}")
    return 0


def cmd_dxl_write(args: argparse.Namespace) -> int:
    from hilbench.clients import dynamixel as dxl_client

    address, f = dxl_client.write(args.port, args.id, args.item, args.value, args.baud, args.length,
                                  protocol=float(args.protocol))
    print(f"ID {args.id} {f.name if f else f'address {address}'} <- {args.value}")
    return 0


ORDER = 30
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "dxl": "Dynamixel tools for any port, real or emulated (official SDK)",
}


def register(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("dxl", help=VERBS["dxl"],
                       description="Talk to Dynamixel devices on a serial port through the official dynamixel-sdk.")
    dsub = d.add_subparsers(dest="dxl_verb", required=True, metavar="TOOL")
    sdk_rate = sdk_baud()

    def port_args(q: argparse.ArgumentParser, baud: bool = True) -> None:
        q.add_argument("port", help="serial port, e.g. /dev/ttyUSB0, an emulated pty or a remote rfc2217://HOST:PORT")
        if baud:
            q.add_argument("--baud", type=sdk_rate, default=57_600, help="baud rate (default: 57600)")
        q.add_argument("--protocol", choices=("1", "2"), default="2",
                       help="protocol version: 2, or 1 for AX/MX servos with 1.0 firmware (default: 2)")

    s = dsub.add_parser("scan", help="find IDs and models across baud rates",
                        description="Broadcast-ping at each baud rate (Protocol 1.0: ping IDs 0-252 one by one, "
                                    "about 9 s per rate; a terminal shows the progress) and list every device "
                                    "that answers.")
    port_args(s, baud=False)
    s.add_argument("--baud", type=sdk_rate, action="append", help="baud rate to try (repeatable; default: all)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=cmd_dxl_scan)

    pg = dsub.add_parser("ping", help="ping one ID", description="Ping one ID and print its model and firmware.")
    port_args(pg)
    pg.add_argument("id", type=dxl_id, help="device ID (0-252)")
    pg.add_argument("--json", action="store_true", help="print JSON")
    pg.set_defaults(func=cmd_dxl_ping)

    r = dsub.add_parser("read", help="read a control-table item",
                        description="Read an item by name (present_position) or address (132 [LENGTH]).")
    port_args(r)
    r.add_argument("id", type=dxl_id, help="device ID")
    r.add_argument("item", help="item name (e.g. present_position) or address")
    r.add_argument("length", type=DATA_LENGTH, nargs="?", help="bytes to read (default: the item's size)")
    r.add_argument("--json", action="store_true", help="print JSON")
    r.set_defaults(func=cmd_dxl_read)

    w = dsub.add_parser("write", help="write a control-table item",
                        description="Write an item by name (goal_position) or address.")
    port_args(w)
    w.add_argument("id", type=dxl_id, help="device ID")
    w.add_argument("item", help="item name (e.g. goal_position) or address")
    w.add_argument("value", type=int_arg, help="value to write (decimal or 0x hex; negative for signed items)")
    w.add_argument("--length", type=DATA_LENGTH, help="bytes to write (default: the item's size)")
    w.set_defaults(func=cmd_dxl_write)
