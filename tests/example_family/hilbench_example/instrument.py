"""The blinker's instrument: a tracker counting messages, its summary, and how it recognises the line."""

from __future__ import annotations

import argparse
from typing import Any

from hilbench.monitor.instrument import Instrument
from hilbench_example.protocol import BLINK, PING, PONG, LineDecoder


class BlinkTracker:
    protocol = "blink"

    def __init__(self, *, baud: int | None, timestamps: bool, pong_limit: int = 0) -> None:
        self.baud = baud
        self.timestamps = timestamps
        self.t0: float | None = None
        self.t_last: float | None = None
        self.counts: dict[str, int] = {}
        self.decoders: dict[str, LineDecoder] = {}
        self.pong_limit = pong_limit

    def feed(self, t: float, source: str, data: bytes) -> None:
        if self.t0 is None:
            self.t0 = t
        self.t_last = t
        dec = self.decoders.setdefault(source, LineDecoder())
        for msg in dec.feed(data):
            self.counts[msg.word] = self.counts.get(msg.word, 0) + 1

    def gap(self, t: float, source: str, nbytes: int) -> None:
        pass

    def flush(self, t: float | None = None) -> None:
        pass

    def tick(self, t: float) -> None:
        pass

    def finish(self) -> None:
        pass


class BlinkInstrument(Instrument):
    protocol = "blink"
    title = "Acme blinker line"

    def sniff(self, data: bytes) -> float:
        lines = data.split(b"\n")
        good = sum(1 for line in lines if line.split(b" ")[0] in (b"PING", b"PONG", b"BLINK", b"RATE", b"OK"))
        return good / (len(lines) + 1)

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--blink-pong-limit", type=int, default=0, help="blinker: PONGs to expect (0: any)")

    def tracker_options(self, args: argparse.Namespace) -> dict[str, Any]:
        return {"pong_limit": args.blink_pong_limit}

    def make_tracker(self, *, baud: int | None, timestamps: bool, **options: Any) -> BlinkTracker:
        return BlinkTracker(baud=baud, timestamps=timestamps, **options)

    def summary(self, tracker: BlinkTracker, *, source: str, timestamps: str | None, errors: int = 50) -> dict:
        bad = sum(d.bad for d in tracker.decoders.values())
        return {"source": source, "protocol": self.protocol, "blinks": tracker.counts.get(BLINK, 0),
                "pings": tracker.counts.get(PING, 0), "pongs": tracker.counts.get(PONG, 0), "bad_lines": bad}

    def print_summary(self, report: dict[str, Any], console: Any) -> None:
        console.print(f"{report['source']}: {report['blinks']} blinks, {report['pings']} pings, "
                      f"{report['pongs']} pongs, {report['bad_lines']} bad lines", highlight=False)


INSTRUMENT = BlinkInstrument()
