"""``hilbench can``: the CAN side of a bench and small CAN tools; CAN families add their own sub-commands.

Subcommands::

    hilbench can dump SOURCE [--dbc F] [--eds F:N]     frames as candump -L lines (decoded with --dbc/--eds)
    hilbench can send BUS ID#DATA ...               send frames (cansend syntax; ID#R for remote)
    hilbench can nmt BUS start|stop|preop|reset|reset-comm [--node N]
    hilbench can sdo BUS --node N read INDEX[:SUB] [--type T]
    hilbench can sdo BUS --node N write INDEX[:SUB] VALUE --type T
    hilbench can bus --manifest FILE [KEY=VALUE ...]   a running bench's CAN bus (control channel)

BUS is a bench manifest (``hilbench emulate --manifest``; its socketcand
server is used) or a CAN bus URL (``socketcand://127.0.0.1:PORT/can0``,
``slcan:///dev/pts/N``, ``socketcan://vcan0``).

A device family adds sub-commands of its own through an extension of the verb
(entry point ``can.NAME`` of ``hilbench.verbs``, see :mod:`hilbench.cli`): the
CANopen board's ``dbc``, ``eds``, ``drive`` and control commands are
:mod:`hilbench.cli.canopen_board`'s.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import time
from collections.abc import Iterator
from typing import Any

from hilbench.cli.common import CliError, add_set_option, open_cli_source, terminate_on_sigterm
from hilbench.errors import DeviceError, require
from hilbench.rules import POSITIVE_COUNT, SECONDS, SPEED, Rule

TYPES = {"u8": (1, False), "u16": (2, False), "u32": (4, False), "i8": (1, True), "i16": (2, True),
         "i32": (4, True)}
#: ``--node`` of sdo (and of the families' commands): a CANopen node id.
NODE_ID = Rule(int, 1, 127, what="a CANopen node id")
#: ``--node`` of nmt: a node id, or 0 for every node.
NMT_NODE = Rule(int, 0, 127, what="a CANopen node id, or 0 for all nodes")
#: ``send --gap`` (s).
GAP = Rule(float, 0, 60)
#: ``sdo --timeout`` (s).
SDO_TIMEOUT = Rule(float, 0, 3600, above=True)
#: What a BUS argument takes (the help of every sub-command that opens a bus).
BUS_HELP = "a bench manifest (its socketcand server) or a CAN bus URL (socketcand://, slcan://, socketcan://)"
NMT = {"start": 0x01, "stop": 0x02, "preop": 0x80, "pre-operational": 0x80, "reset": 0x81, "reset-node": 0x81,
       "reset-comm": 0x82, "reset-communication": 0x82}


# --------------------------------------------------------------------------- helpers

def manifest_socketcand(path: str) -> str:
    """The socketcand URL of a bench manifest's CAN endpoint (``file.json#endpoint`` picks one)."""
    from hilbench.bench.manifest import endpoint_of, read_manifest

    file, _, endpoint = path.partition("#")
    # not a manifest: exit status 2; a bench that is not running (no manifest, a stale one): 1
    data = read_manifest(file)
    ep = endpoint_of(data, endpoint, file, lambda e: isinstance(e.get("socketcand"), dict),
                     "CAN endpoints with a socketcand server")
    s = ep["socketcand"]
    return f"socketcand://{s['host']}:{s['port']}/{s['channel']}"


def open_bus(spec: str):
    """A python-can bus for BUS (a manifest or a CAN bus URL); CliError in one line."""
    from hilbench.transports.sources.can import open_bus as open_bus_url

    if spec.split("#", 1)[0].endswith(".json"):
        spec = manifest_socketcand(spec)
    bus, _channel, _bitrate = open_bus_url(spec)  # SourceError: one line, 2 or 1 (not there, refused)
    return bus


def parse_frame(text: str):
    """``123#DEADBEEF``, ``12345678#01``, ``123#R``, ``123#R4`` (cansend syntax) as a frame."""
    from hilbench.protocols.can_frame import data_frame, remote_frame

    ident, sep, body = text.partition("#")
    try:
        if not sep or not ident or len(ident) not in (3, 8):
            raise ValueError
        can_id = int(ident, 16)
        extended = len(ident) == 8
        if body.upper().startswith("R"):
            return remote_frame(can_id, int(body[1:] or "0"), extended=extended)
        return data_frame(can_id, bytes.fromhex(body.replace(".", "")), extended=extended)
    except ValueError:
        raise CliError(f"{text!r}: expected ID#DATA as cansend takes it (3 or 8 hex ID digits, up to 8 bytes), "
                       "or ID#R[LEN]") from None


def _index(text: str) -> tuple[int, int]:
    index, _, sub = text.partition(":")
    try:
        i = int(index, 16) if not index.lower().startswith("0x") else int(index, 0)
        s = int(sub or "0", 0)
        if not (0 <= i <= 0xFFFF and 0 <= s <= 0xFF):
            raise ValueError
    except ValueError:
        raise CliError(f"{text!r}: expected INDEX[:SUB] (index 0..FFFF in hex, sub 0..255), e.g. 1018:1 or "
                       "0x1017") from None
    return i, s


# --------------------------------------------------------------------------- bus tools

def cmd_dump(args: argparse.Namespace) -> int:
    from hilbench.monitor.can.decoders import load_dbc, load_eds
    from hilbench.protocols import can_frame as cf

    terminate_on_sigterm()
    decoders = [load_dbc(d) for d in args.dbc] + [load_eds(e) for e in args.eds]
    deadline = time.monotonic() + args.seconds if args.seconds else None
    count = 0
    with open_cli_source(args.source, baud=None, speed=args.speed, overrides=args.overrides) as source:
        if source.protocol not in (None, "can"):
            raise CliError(f"{source.name} carries {source.protocol}, not CAN")
        if source.protocol is None and not source.live:  # a raw file: CAN frames only if its bytes are some
            source = _raw_can(source)
        offset = getattr(source, "wall_offset", None)
        if offset is None:
            offset = time.time() - time.monotonic() if source.live else 0.0
        try:
            for chunk in source.chunks(0.1):
                if chunk is not None and not chunk.lost:
                    frames, _ = cf.split(chunk.data)
                    for frame in frames:
                        line = _candump(frame, chunk.t + offset, args.channel)
                        for dec in decoders:
                            try:
                                values = dec.decode(frame)
                            except Exception as exc:
                                line += f" :: {dec.name(frame) or '?'}(error: {exc})"
                                break
                            if values is not None:
                                line += f" :: {dec.name(frame)}(" + ", ".join(f"{k}: {v}" for k, v in values.items()) + ")"
                                break
                        print(line, flush=True)
                        count += 1
                        if args.count and count >= args.count:
                            return 0
                if deadline is not None and time.monotonic() >= deadline:
                    break
        except KeyboardInterrupt:
            pass
    return 0


def _raw_can(source):
    """``source`` (a file that names no protocol) if its first bytes are raw SocketCAN frames, as ``monitor``
    tells them; else one line, exit 2 (random bytes decoded as frames would print nonsense)."""
    from hilbench.errors import UsageError
    from hilbench.monitor.detect import detect

    try:
        inst, source = detect(source)
    except UsageError:
        inst = None
    else:
        if inst is None or inst.protocol == "can":  # (an empty file: nothing to dump)
            return source
    what = f"it carries {inst.protocol}" if inst is not None else "no CAN frames recognised in its first bytes"
    raise CliError(f"{source.name}: {what} (can dump reads candump and python-can logs, hilbench captures of a "
                   "CAN bus and raw SocketCAN frames)")


def _candump(frame, t: float, channel: str) -> str:
    if frame.error:
        body = f"{frame.can_id | 0x20000000:08X}#{frame.data.hex().upper()}"
    elif frame.remote:
        body = f"{frame.id_text}#R{frame.length if frame.length else ''}"
    else:
        body = f"{frame.id_text}#{frame.data.hex().upper()}"
    return f"({t:.6f}) {channel} {body}"


def cmd_send(args: argparse.Namespace) -> int:
    import can

    from hilbench.transports.can_messages import to_message

    frames = [parse_frame(f) for f in args.frames]
    bus = open_bus(args.bus)
    try:
        for frame in frames:
            bus.send(to_message(frame))
            if args.gap:
                time.sleep(args.gap)
    except can.CanError as exc:
        raise DeviceError(f"{args.bus}: {exc}") from None
    finally:
        time.sleep(0.05)  # let the last write leave before the connection closes
        bus.shutdown()
    return 0


def cmd_nmt(args: argparse.Namespace) -> int:
    from hilbench.protocols.can_frame import data_frame
    from hilbench.protocols.canopen import nmt_command
    from hilbench.transports.can_messages import to_message

    bus = open_bus(args.bus)
    try:
        bus.send(to_message(data_frame(0x000, nmt_command(NMT[args.command], args.node))))
        time.sleep(0.05)
    finally:
        bus.shutdown()
    return 0


def cmd_sdo(args: argparse.Namespace) -> int:
    canopen = require("canopen", "can", "hilbench can sdo")
    index, sub = _index(args.object)
    bus = open_bus(args.bus)
    # The notifier's thread looks at the bus every 50 ms and is waited for at the end: not waited for, it
    # could still be inside the bus's recv when the bus closes, and python-can prints that thread's failure.
    net = canopen.Network(bus)
    net.NOTIFIER_CYCLE = 0.05
    net.NOTIFIER_SHUTDOWN_TIMEOUT = 2.0
    with _quiet_logger("canopen"):  # it logs its own abort ("Transfer aborted by client ...") before ours
        return _sdo(canopen, net, args, index, sub)


@contextlib.contextmanager
def _quiet_logger(name: str) -> Iterator[None]:
    """A library's log records go nowhere while the block runs (the command says what happened, once)."""
    log = logging.getLogger(name)
    saved = log.propagate
    quiet = logging.NullHandler()
    log.addHandler(quiet)
    log.propagate = False
    try:
        yield
    finally:
        log.removeHandler(quiet)
        log.propagate = saved


def _sdo(canopen, net, args: argparse.Namespace, index: int, sub: int) -> int:
    try:
        net.connect()
        node = canopen.RemoteNode(args.node, canopen.ObjectDictionary())
        node.sdo.RESPONSE_TIMEOUT = args.timeout
        net.add_node(node)
        try:
            if args.action == "read":
                raw = node.sdo.upload(index, sub)
                print(_show(raw, args.type))
            else:
                node.sdo.download(index, sub, _encode(args.value, args.type), force_segment=args.segmented)
        except canopen.SdoAbortedError as exc:
            raise DeviceError(f"node {args.node} 0x{index:04X}:{sub:02X}: SDO aborted: {exc}") from None
        except canopen.SdoCommunicationError as exc:
            if "No SDO response" in str(exc):
                raise DeviceError(f"node {args.node} 0x{index:04X}:{sub:02X}: no SDO response within "
                                  f"{args.timeout:g} s (is node {args.node} on the bus?)") from None
            raise DeviceError(f"node {args.node} 0x{index:04X}:{sub:02X}: {exc}") from None
    finally:
        net.disconnect()
    return 0


def _encode(value: str | None, kind: str) -> bytes:
    if value is None:
        raise CliError("write needs a VALUE")
    try:
        if kind in TYPES:
            size, signed = TYPES[kind]
            return int(value, 0).to_bytes(size, "little", signed=signed)
        if kind == "f32":
            import struct

            return struct.pack("<f", float(value))
        if kind == "str":
            return value.encode("latin-1")
        return bytes.fromhex(value)
    except (ValueError, OverflowError) as exc:
        raise CliError(f"{value!r} is not a {kind}: {exc}") from None


def _show(raw: bytes, kind: str) -> str:
    if kind in TYPES:
        size, signed = TYPES[kind]
        return str(int.from_bytes(raw[:size], "little", signed=signed))
    if kind == "f32":
        import struct

        return repr(struct.unpack("<f", raw[:4])[0])
    if kind == "str":
        return raw.decode("latin-1")
    if kind == "auto":
        if len(raw) <= 4:
            return f"{int.from_bytes(raw, 'little')} (0x{raw[::-1].hex().upper()})"
        if all(32 <= b < 127 for b in raw):
            return raw.decode("ascii")
    return raw.hex(" ").upper()


# --------------------------------------------------------------------------- control channel

def knobs(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` words as a control command's knobs (booleans, integers, numbers, else strings)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise CliError(f"{item!r}: expected KEY=VALUE")
        low = value.lower()
        if low in ("true", "on", "yes"):
            out[key] = True
        elif low in ("false", "off", "no"):
            out[key] = False
        else:
            try:
                out[key] = int(value, 0)
            except ValueError:
                try:
                    out[key] = float(value)
                except ValueError:
                    out[key] = value
    return out


# --------------------------------------------------------------------------- parser

ORDER = 45
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "can": "CAN: the board's DBC/EDS, dump/send/nmt/sdo/drive, a CAN bench's control channel",
}

HELP = """\
The CAN side of a bench and small CAN tools:

  hilbench can dump SOURCE [--dbc F] [--eds F:N]      frames as candump -L lines, decoded
  hilbench can send BUS ID#DATA ...                send frames (cansend syntax, ID#R for remote)
  hilbench can nmt BUS start|stop|preop|reset|reset-comm [--node N]
  hilbench can sdo BUS read|write INDEX[:SUB] [VALUE] --node N [--type T]
  hilbench can bus --manifest FILE [KEY=VALUE ...]    control channel: the bus's figures and faults

BUS is a bench manifest (hilbench emulate --manifest; its socketcand server)
or a CAN bus URL: socketcand://127.0.0.1:PORT/can0, slcan:///dev/pts/N,
socketcan://vcan0."""


def cmd_bus(args: argparse.Namespace) -> int:
    """The CAN bus's own control command (every CAN bench has it, whatever its nodes' families)."""
    from hilbench.bench.control import ControlClient

    client = ControlClient.from_manifest(args.manifest)
    out = {"bus": client.call("bus", device=args.device, knobs=knobs(args.knobs))["bus"]}
    print(json.dumps(out, indent=None if args.compact else 2))
    return 0


def add_control_options(parser: argparse.ArgumentParser) -> None:
    """``--manifest``, ``--device`` and ``--compact``: what every control-channel sub-command takes."""
    parser.add_argument("--manifest", required=True, help="manifest of `hilbench emulate --manifest`")
    parser.add_argument("--device", help="node name (when the bench has several)")
    parser.add_argument("--compact", action="store_true", help="JSON on one line")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("can", help=VERBS["can"],
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    cs = p.add_subparsers(dest="can_cmd", required=True, metavar="COMMAND")

    u = cs.add_parser("dump", help="print frames as candump -L lines, decoded with --dbc/--eds",
                      description="Print every frame of SOURCE (anything `hilbench monitor` opens: a CAN bus URL, "
                                  "a manifest, bench:PROFILE, a capture or python-can log) as candump -L lines, "
                                  "which `cantools decode` and can-utils read; --dbc/--eds append the decoded "
                                  "signals after ' :: '.")
    u.add_argument("source")
    u.add_argument("--dbc", action="append", default=[], metavar="FILE", help="DBC file or profile name")
    u.add_argument("--eds", action="append", default=[], metavar="FILE:NODE", help="EDS and its node")
    u.add_argument("--channel", default="can0", help="channel name in the lines (default can0)")
    u.add_argument("--seconds", type=SECONDS, help="stop after this many seconds (0: no limit)")
    u.add_argument("-n", "--count", type=POSITIVE_COUNT, help="stop after this many frames")
    u.add_argument("--speed", type=SPEED, help="replay a file at this multiple of its recorded speed")
    add_set_option(u, "bench:PROFILE: ")
    u.set_defaults(func=cmd_dump)

    bus_help = BUS_HELP
    s = cs.add_parser("send", help="send frames (cansend syntax: 123#DEADBEEF, 12345678#01, 123#R)")
    s.add_argument("bus", metavar="BUS", help=bus_help)
    s.add_argument("frames", nargs="+", metavar="ID#DATA")
    s.add_argument("--gap", type=GAP, default=0.0, help="seconds between frames (default 0)")
    s.set_defaults(func=cmd_send)

    n = cs.add_parser("nmt", help="send an NMT command")
    n.add_argument("bus", metavar="BUS", help=bus_help)
    n.add_argument("command", choices=sorted(NMT))
    n.add_argument("--node", type=NMT_NODE, default=0, help="node id (default 0: all nodes)")
    n.set_defaults(func=cmd_nmt)

    o = cs.add_parser("sdo", help="read or write an object over SDO (needs the canopen package)")
    o.add_argument("bus", metavar="BUS", help=bus_help)
    o.add_argument("action", choices=("read", "write"))
    o.add_argument("object", metavar="INDEX[:SUB]", help="e.g. 1018:1, 0x1017, 2002:1")
    o.add_argument("value", nargs="?", help="the value to write")
    o.add_argument("--node", type=NODE_ID, required=True, help="node id")
    o.add_argument("--type", default="auto", choices=("auto", "hex", "str", "f32", *TYPES),
                   help="how to show (read) or encode (write) the value (default: auto / hex)")
    o.add_argument("--segmented", action="store_true", help="write with a segmented transfer even when short")
    o.add_argument("--timeout", type=SDO_TIMEOUT, default=1.0, help="SDO response timeout in seconds (default 1)")
    o.set_defaults(func=cmd_sdo)


    b = cs.add_parser("bus", help="control channel: the bus's figures; bus fault knobs KEY=VALUE (error_rate, "
                                  "error_next, auto_recover, bus_off=SENDER)")
    add_control_options(b)
    b.add_argument("knobs", nargs="*", metavar="KEY=VALUE")
    b.set_defaults(func=cmd_bus)
