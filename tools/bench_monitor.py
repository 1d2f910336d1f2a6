#!/usr/bin/env python3
"""Bus monitor benchmarks; prints one JSON object per figure (see DESIGN.md §10).

1. Decode + track throughput on the real Wolfgang capture, as a ratio to the
   4.5 Mbaud line rate (450,000 bytes/s). Target: >= 20x.
   - ``monitor_track_64k``: the capture in 64 KiB chunks without times (what
     ``hilbench monitor trace.bin`` does);
   - ``monitor_track_timed_4k``: 4 KiB chunks stamped with byte time, so the
     time work (latencies, rates, reply timeout) runs too;
   - ``monitor_pipeline_file``: the whole pipeline, file reading and the
     monitor thread included (``Monitor(open_source(path))``);
   - ``dxl_decoder_4k``: the decoder alone, measured in the same run, for
     comparison.
   Each figure is the median of several runs (``ratio``) with the best run
   (``best_ratio``) and the median over this process's CPU time
   (``cpu_ratio``, ``time.process_time``), the figures taking turns run by
   run: the machine is shared and noisy, and its speed changes by 2x from one
   minute to the next.
2. Lag between a byte entering a tap and the monitor state reflecting it, with
   the SDK driving the Wolfgang bench (unpaced) in this process:
   - ``monitor_lag_bench_line``: tapped on the bench's serial line (in-process);
   - ``monitor_lag_tcp_tap``: through the bench's TCP tap server;
   - ``monitor_lag_serial_tap``: through ``SerialTap`` (``hilbench tap``)
     between the SDK and the bench's pty;
   - ``dashboard_lag_screen``: until a rendered dashboard frame shows the new
     value (the screen refreshes at most every 100 ms).
   The reference is the dashboard's refresh period (100 ms).

Usage: tools/bench_monitor.py [--capture PATH] [--repeats N] [--samples N] [--only throughput|lag]
"""

from __future__ import annotations

import argparse
import io
import json
import statistics
import threading
import time
from pathlib import Path

import dynamixel_sdk as sdk
from rich.console import Console

from hilbench.bench import Bench
from hilbench.dashboard import Dashboard
from hilbench.monitor import Monitor
from hilbench.monitor.dynamixel.tracker import BusTracker
from hilbench.protocols.dynamixel import Decoder
from hilbench.transports.serial_tap import SerialTap
from hilbench.transports.sources import MediumSource, open_source

REPO = Path(__file__).resolve().parents[1]
LINE_RATE_4M5 = 450_000  # bytes/s at 4.5 Mbaud, 8N1
REFRESH = 0.1  # the dashboard's refresh period


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 4), "unit": unit, "reference": round(reference, 4),
                      "ratio": round(ratio, 3), **extra}), flush=True)


# --------------------------------------------------------------------------- throughput


def _track(data: bytes, chunk: int, timed: bool) -> tuple[float, float]:
    tr = BusTracker(baud=2_000_000, timestamps=timed)
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(0, len(data), chunk):
        tr.feed((i + chunk) * 5e-6, "bus", data[i : i + chunk])
    tr.finish()
    return time.perf_counter() - t0, time.process_time() - c0


def _decode(data: bytes, chunk: int) -> tuple[float, float]:
    dec = Decoder()
    t0, c0 = time.perf_counter(), time.process_time()
    for i in range(0, len(data), chunk):
        dec.feed(data[i : i + chunk], 0.0)
    dec.flush()
    return time.perf_counter() - t0, time.process_time() - c0


def _pipeline(path: Path) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()  # process time covers the monitor thread too
    mon = Monitor(open_source(str(path))).start()
    mon.wait()
    mon.stop()
    return time.perf_counter() - t0, time.process_time() - c0


def bench_throughput(capture: Path, repeats: int) -> None:
    data = capture.read_bytes()
    runs = {
        "monitor_track_64k": lambda: _track(data, 65536, False),
        "monitor_track_timed_4k": lambda: _track(data, 4096, True),
        "monitor_pipeline_file": lambda: _pipeline(capture),
        "dxl_decoder_4k": lambda: _decode(data, 4096),
    }
    # round robin, so every figure samples the same phases of a noisy machine
    all_times: dict[str, list[tuple[float, float]]] = {name: [] for name in runs}
    for _ in range(repeats):
        for name, run in runs.items():
            all_times[name].append(run())
    for name, times in all_times.items():
        wall = [w for w, _ in times]
        rate = len(data) / statistics.median(wall)
        emit(name, rate, "bytes/s", LINE_RATE_4M5, rate / LINE_RATE_4M5, target_ratio=20 if name != "dxl_decoder_4k" else 30,
             best_ratio=round(len(data) / min(wall) / LINE_RATE_4M5, 3),
             cpu_ratio=round(len(data) / statistics.median(c for _, c in times) / LINE_RATE_4M5, 3), runs=repeats)


# --------------------------------------------------------------------------- lag


class LagProbe:
    """Wraps a tracker's feed: for chunks carrying the marker, how long from tap stamp to state updated."""

    def __init__(self, tracker: BusTracker, marker_of) -> None:
        self.lags: list[float] = []
        self.marker_of = marker_of
        feed = tracker.feed

        def probed(t, source, data):
            feed(t, source, data)
            if self.marker_of(data) is not None:
                self.lags.append(time.monotonic() - t)

        tracker.feed = probed


def _goal_marker(data: bytes) -> int | None:
    # the Sync Write of Goal Position (116/4) to ID 1 that the driver sends
    return 1 if data[7:12] == b"\x83\x74\x00\x04\x00" else None


def _drive(path: str, samples: int, on_sent=None) -> None:
    port = sdk.PortHandler(path)
    assert port.openPort() and port.setBaudRate(2_000_000)
    ph = sdk.PacketHandler(2.0)
    writer = sdk.GroupSyncWrite(port, ph, 116, 4)
    reader = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in range(1, 21):
        reader.addParam(i)
    for k in range(samples):
        value = 1000 + k
        writer.clearParam()
        writer.addParam(1, list(value.to_bytes(4, "little")))
        writer.txPacket()
        if on_sent is not None:
            on_sent(value)
        reader.txRxPacket()
        time.sleep(0.002)  # a robot-like cycle, and room for the monitor thread
    port.closePort()


def _lag_figure(name: str, lags: list[float], **extra) -> None:
    lags = sorted(lags)
    med = statistics.median(lags)
    p99 = lags[min(len(lags) - 1, int(0.99 * len(lags)))]
    emit(name, med * 1e3, "ms", REFRESH * 1e3, med / REFRESH, p99_ms=round(p99 * 1e3, 3),
         max_ms=round(lags[-1] * 1e3, 3), samples=len(lags), **extra)


def _screen_lag(path: str, mon: Monitor, samples: int) -> None:
    """Write a new Goal Position, hold it, and time until a rendered frame shows it."""
    dash = Dashboard(mon.tracker, lock=mon.lock, view="details", device=1)
    render = dash.render
    pending: dict[str, float] = {}
    shown: list[float] = []
    seen = threading.Event()

    def watching(width=80, height=24):
        group = render(width, height)
        console = Console(width=width, height=height, file=io.StringIO(), color_system=None)
        with console.capture() as cap:
            console.print(group)
        text = cap.get()
        for marker, t in list(pending.items()):
            if marker in text:
                shown.append(time.monotonic() - t)
                del pending[marker]
                seen.set()
        return group

    dash.render = watching
    stop = threading.Event()
    screen = threading.Thread(target=lambda: dash.run(console=Console(file=io.StringIO(), width=80, height=24),
                                                      stop=stop.is_set, screen_mode=False), daemon=True)
    screen.start()
    port = sdk.PortHandler(path)
    assert port.openPort() and port.setBaudRate(2_000_000)
    ph = sdk.PacketHandler(2.0)
    for k in range(samples):
        value = 3000 + k
        seen.clear()
        pending[f"({value})"] = time.monotonic()
        ph.write4ByteTxRx(port, 1, 116, value)
        seen.wait(1.0)
        time.sleep(0.013 * (k % 7))  # spread the writes over the frame period
    port.closePort()
    stop.set()
    screen.join()
    _lag_figure("dashboard_lag_screen", shown, path="SDK write -> bench line -> tracker -> rendered frame (10 fps)")


def _settle(mon: Monitor, total) -> None:
    """Wait until the monitor has taken in every byte sent so far (``total()``)."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        with mon.lock:
            if mon.tracker.bytes >= total():
                return
        time.sleep(0.005)
    raise SystemExit("the monitor did not catch up within 10 s")


def bench_lag(samples: int) -> None:
    with Bench("wolfgang", paced=False, tap=True) as bench:
        ep = bench.endpoint()
        # 1. in-process tap on the serial line
        mon = Monitor(MediumSource(ep.medium))
        probe = LagProbe(mon.tracker, _goal_marker)
        mon.start()
        _drive(ep.path, samples)
        _settle(mon, lambda: ep.medium.stats.bytes)
        _lag_figure("monitor_lag_bench_line", probe.lags, path="bench line -> MediumSource -> tracker")
        # 1b. until the dashboard (10 frames/s, device details of ID 1) shows a new Goal Position
        _screen_lag(ep.path, mon, max(10, samples // 15))
        mon.stop()
        # 2. the bench's TCP tap, as `hilbench monitor manifest.json` in another process reads it
        base = ep.medium.stats.bytes
        mon = Monitor(open_source(ep.tap.url))
        probe = LagProbe(mon.tracker, _goal_marker)
        mon.start()
        _drive(ep.path, samples)
        _settle(mon, lambda: ep.medium.stats.bytes - base)
        mon.stop()
        _lag_figure("monitor_lag_tcp_tap", probe.lags, path="bench line -> TapServer -> TCP -> tracker")
        # 3. hilbench tap between the SDK and the bench's pty
        tap = SerialTap(ep.path).start()
        mon = Monitor(tap.source, protocol="dynamixel")  # a tap has no protocol to say: the bus is known
        probe = LagProbe(mon.tracker, lambda d: 1 if d[7:12] == b"\x83\x74\x00\x04\x00" else None)
        mon.start()
        _drive(tap.app_path, samples)
        _settle(mon, lambda: tap.bytes_to_device + tap.bytes_to_app)
        tap.close()
        mon.stop()
        _lag_figure("monitor_lag_serial_tap", probe.lags, path="SerialTap read -> PushSource -> tracker")


def bench_rough(capture: Path) -> None:
    """The tracker and the capture parser on noise and on damaged input: the Wolfgang capture with 1 % of
    its bytes damaged, raw (tracker) and as a .hbcap with byte times (capture parser) (tools/rough.py)."""
    from rough import measure

    from hilbench.monitor.dynamixel.targets import TRACKER
    from hilbench.transports.capture_file import CaptureReader, CaptureWriter
    from hilbench.transports.capture_targets import CAPTURE

    raw = capture.read_bytes()
    measure(TRACKER, seed=raw, seed_name="the Wolfgang capture", prefix="monitor_rough_")
    buf = io.BytesIO()
    with CaptureWriter(buf, baud=2_000_000, protocol="dynamixel", timestamps="synthetic") as w, \
            CaptureReader(capture, raw_baud=2_000_000) as r:
        for chunk in r:
            w.chunk(chunk)
        hbcap = buf.getvalue()
    measure(CAPTURE, seed=hbcap, seed_name="the Wolfgang capture as .hbcap", prefix="monitor_rough_")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=REPO / "tests/data/dynamixel/wolfgang_trace.bin")
    ap.add_argument("--repeats", type=int, default=11, help="runs per throughput figure")
    ap.add_argument("--samples", type=int, default=300, help="marked packets per lag figure")
    ap.add_argument("--only", choices=("throughput", "rough", "lag"))
    args = ap.parse_args()
    if args.only in (None, "throughput"):
        bench_throughput(args.capture, args.repeats)
    if args.only in (None, "rough"):
        bench_rough(args.capture)
    if args.only in (None, "lag"):
        bench_lag(args.samples)


if __name__ == "__main__":
    main()
