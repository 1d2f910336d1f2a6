"""The CAN bridges' text parsers as fuzz targets (:mod:`hilbench.fuzzing`): what the SLCAN adapter reads from its
host, what the socketcand server reads from its clients and what a socketcand client reads from the server.
Registered in ``pyproject.toml`` (``hilbench.fuzz_targets``); ``tools/fuzz.py`` and the rough-input benchmarks
drive them like every other fuzz target."""

from __future__ import annotations

import random

from hilbench.fuzzing import FuzzTarget
from hilbench.protocols import slcan
from hilbench.protocols import socketcand as scd
from hilbench.protocols.can_frame import CanFrame

#: A USB SLCAN adapter's serial link at its fastest (CANUSB's FTDI at 3 Mbaud), 8N1.
SLCAN_LINE = 3_000_000 / 10
#: A saturated 1 Mbit/s bus in socketcand's RAW text: about 8 000 eight-byte frames/s, ~48 characters each.
SOCKETCAND_LINE = 8_000 * 48
#: The SLCAN commands the adapter (:mod:`hilbench.transports.slcan_port`) answers.
SLCAN_OPS = frozenset("OLCSsFVvNZMmtTrR")


def _frame(rng: random.Random) -> CanFrame:
    extended = rng.random() < 0.3
    can_id = rng.randrange(0x2000_0000 if extended else 0x800)
    remote = rng.random() < 0.05
    dlc = rng.randrange(9)
    return CanFrame(can_id, b"" if remote else rng.randbytes(dlc), extended, remote, False, dlc)


class _LineReader:
    """Stream bytes -> lines (or messages) -> parsed commands: ``good`` counts the commands understood,
    ``dropped`` the splitter's bytes plus every line not understood (with its terminator)."""

    def __init__(self, splitter, understood, terminator: int) -> None:
        self.splitter = splitter
        self.understood = understood
        self.terminator = terminator
        self.ok = 0
        self.bad = 0

    def feed(self, data: bytes) -> None:
        for line in self.splitter.feed(data):
            if self.understood(line):
                self.ok += 1
            else:
                self.bad += len(line) + self.terminator

    def finish(self) -> None:
        pass  # a line without its end is not a command yet (both readers keep it for the next bytes)

    def good(self) -> int:
        return self.ok

    def dropped(self) -> int:
        return self.splitter.dropped + self.bad


# --------------------------------------------------------------------------- SLCAN


def slcan_traffic(rng: random.Random, size: int) -> bytes:
    """A host driving an adapter: set-up (bitrate, version, timestamps, filter, open), then frames to send,
    now and then a status poll; python-can's ``slcan`` and ``slcand`` send these."""
    out = bytearray(b"C\rS6\rV\rN\rZ1\rM00000000\rmFFFFFFFF\rO\r")
    while len(out) < size:
        if rng.random() < 0.05:
            out += rng.choice((b"F\r", b"v\r", b"C\rO\r", b"s031C\r"))
        else:
            out += slcan.encode_command(_frame(rng))
    return bytes(out)


def _slcan_understood(line: str) -> bool:
    command = slcan.parse_command(line)
    return command.valid and command.op in SLCAN_OPS


SLCAN_HOST = FuzzTarget(
    "slcan", "SLCAN host commands (the adapter's line splitter and command parser)",
    lambda: _LineReader(slcan.LineSplitter(), _slcan_understood, 1), SLCAN_LINE, "3 Mbaud USB-serial link",
    slcan_traffic)


# --------------------------------------------------------------------------- socketcand


def socketcand_client_traffic(rng: random.Random, size: int) -> bytes:
    """A client of the daemon: open a bus, RAW mode, then frames to send, BCM jobs, now and then an echo."""
    out = bytearray(b"< open can0 >< rawmode >")
    while len(out) < size:
        frame = _frame(rng)
        if frame.remote:
            frame = CanFrame(frame.can_id, b"", frame.extended, False, False, 0)
        kind = rng.random()
        if kind < 0.8:
            out += scd.send_message(frame).encode()
        elif kind < 0.9:
            ident = f"{frame.can_id:08X}" if frame.extended else f"{frame.can_id:03X}"
            data = " ".join(f"{b:02X}" for b in frame.data)
            out += f"< add 0 {rng.randrange(1, 1000) * 1000} {ident} {frame.length} {data} >".encode()
        else:
            out += rng.choice((b"< echo >", b"< statistics 1000 >", b"< bcmmode >< rawmode >"))
    return bytes(out)


def _client_understood(message: str) -> bool:
    return scd.parse_command(message).name not in ("invalid", "unknown")


def socketcand_server_traffic(rng: random.Random, size: int) -> bytes:
    """What the daemon sends a RAW-mode client: its greeting and answers, then frames, error frames, echoes."""
    out = bytearray(b"< hi >< ok >< ok >")
    t = 1_700_000_000.0
    while len(out) < size:
        t += rng.uniform(0, 0.01)
        kind = rng.random()
        if kind < 0.9:
            out += scd.frame_message(_frame(rng), t).encode()
        elif kind < 0.95:
            out += f"< error 004 {t:.6f} >".encode()
        else:
            out += rng.choice((b"< echo >", b"< stat 123 4 567 8 >"))
    return bytes(out)


def _server_understood(message: str) -> bool:
    return scd.parse_server_message(message).kind != "unknown"


SOCKETCAND_CLIENT = FuzzTarget(
    "socketcand-client", "socketcand client messages (the server's message splitter and command parser)",
    lambda: _LineReader(scd.MessageSplitter(), _client_understood, 0), SOCKETCAND_LINE,
    "a saturated 1 Mbit/s bus in socketcand text", socketcand_client_traffic)

SOCKETCAND_SERVER = FuzzTarget(
    "socketcand-server", "socketcand server messages (a client's message splitter and parser)",
    lambda: _LineReader(scd.MessageSplitter(), _server_understood, 0), SOCKETCAND_LINE,
    "a saturated 1 Mbit/s bus in socketcand text", socketcand_server_traffic)
