#!/usr/bin/env python3
"""Dynamixel benchmarks; prints one JSON object per figure (see DESIGN.md §10).

1. Decoder throughput on the real Wolfgang capture, as a ratio to the
   4.5 Mbaud line rate (450,000 bytes/s). Target: >= 30x.
2. A 20-servo control cycle (Sync Read of Present Position + Sync Write of
   Goal Position) driven by the official SDK in this process against
   ``hilbench emulate wolfgang`` in another:
   - the emulator's CPU per cycle (target <= 150 us), from the unpaced run;
   - unpaced: cycles/s (target >= 2000/s on a 2-core machine); the reference
     is the cycle rate the 2 Mbaud wire allows; ``sdk_cpu_us`` is this
     process's CPU per cycle (the SDK busy-polls, so it is the cycle time
     less the time it was descheduled);
   - paced at 2 Mbaud and at 4.5 Mbaud (the profile's bus at 4_500_000; the SDK
     opens it as users do, see docs/families/dynamixel.md): measured cycle time against the
     wire-time model of the cycle (target: within 10%, i.e. ratio 0.9..1.1).
   With ``--load N`` (default 1) every cycle figure is measured twice, on the
   machine as it is and with N CPU-bound neighbour processes running (figures
   named ``..._loadN``); ``loadavg`` is the machine's 1-minute load when the
   figure started (other people's jobs on a shared machine).
3. The same 20-servo cycle on the other servo buses, each driven by its own
   client (emulator CPU per cycle, cycles/s unpaced, cycle time paced against
   the wire model):
   - a Protocol 1.0 bus of MX-28 behind a USB2AX, driven by pypot's DxlIO as
     Poppy's sync loop does (USB2AX SYNC_READ of Present Position/Speed/Load,
     SYNC_WRITE of Goal Position/Speed/Torque Limit), paced at 1 Mbaud (pypot's
     rate) and 3 Mbaud (the MX's fastest code); the wire model counts the
     request, the adapter's READ and reply for each servo on the Dynamixel bus,
     its combined reply and the write;
   - a Feetech bus of STS3215 driven by Feetech's SDK as LeRobot does
     (GroupSyncRead of Present Position, one status per servo; GroupSyncWrite
     of Goal Position), paced at 1 Mbaud (the STS's fastest) and 500 kbaud.
   Skipped with a note when pypot or scservo_sdk is not installed.

With ``--under-run`` the official SDK's cycles run in a child process started with ``hilbench run
--manifest M --`` against the bench (the preload shim on the SDK's pty, as a user's client would have it;
``HILBENCH_SERVE`` and the other variables of the environment reach it), figures named ``..._run``.
``--baud`` measures the paced SDK cycle at one rate only. ``--serve-ab`` measures the paced SDK cycle under
``hilbench run`` on the kernel path and on the serving path (``HILBENCH_SERVE=1``, hilbench/bench/serve_ring.py)
in alternating runs, with each round's ratio of the two.

Usage: tools/bench_dynamixel.py [--capture PATH] [--seconds S] [--load N] [--runs N] [--baud B]
                                [--under-run | --serve-ab] [--only decoder|unpaced|paced|protocol1|feetech]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dynamixel_sdk as sdk
from benchlib import CYCLE_BYTES, sdk_cycle

from hilbench.bench.control import ControlClient
from hilbench.bench.manifest import read_manifest
from hilbench.protocols.dynamixel import Decoder

REPO = Path(__file__).resolve().parents[1]
LINE_RATE_4M5 = 450_000  # bytes/s at 4.5 Mbaud, 8N1
BAUD = 2_000_000
IDS = list(range(1, 21))


def emit(name: str, value: float, unit: str, reference: float, ratio: float, **extra) -> None:
    print(json.dumps({"name": name, "value": round(value, 3), "unit": unit, "reference": round(reference, 3),
                      "ratio": round(ratio, 3), **extra}), flush=True)


def bench_decoder(capture: Path, repeats: int = 9) -> None:
    """``ratio``: median wall time; ``best_ratio``: best run; ``cpu_ratio``: median of this process's CPU time
    (``time.process_time``), which a machine shared with other jobs disturbs less."""
    data = capture.read_bytes()
    for label, chunk in (("whole", len(data)), ("4k_chunks", 4096)):
        times, cpu = [], []
        for _ in range(repeats):
            dec = Decoder()
            t0, c0 = time.perf_counter(), time.process_time()
            for i in range(0, len(data), chunk):
                dec.feed(data[i : i + chunk])
            dec.flush()
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        rate = len(data) / statistics.median(times)
        emit(f"dxl_decoder_{label}", rate, "bytes/s", LINE_RATE_4M5, rate / LINE_RATE_4M5, target_ratio=30,
             best_ratio=round(len(data) / min(times) / LINE_RATE_4M5, 3),
             cpu_ratio=round(len(data) / statistics.median(cpu) / LINE_RATE_4M5, 3), packets=dec.packets)


#: What the machine is doing besides the benchmark: {"load": N neighbours started, "loadavg": 1-min load};
#: "under_run": the SDK's cycles run in a child under ``hilbench run`` (``--under-run``).
CONDITION: dict = {"load": 0, "under_run": False}


@contextlib.contextmanager
def neighbours(n: int):
    """``n`` CPU-bound neighbour processes (pure-Python spinning), as an IDE, a browser or a test run would be."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    CONDITION["load"] = n
    try:
        yield
    finally:
        CONDITION["load"] = 0
        for p in procs:
            p.kill()
        for p in procs:
            p.wait()


def loadavg() -> float:
    return round(os.getloadavg()[0], 2)


def start_emulator(paced: bool, profile: str = "wolfgang") -> tuple[subprocess.Popen, str,
                                                                   tempfile.TemporaryDirectory]:
    tmp = tempfile.TemporaryDirectory(prefix="hilbench-bench-")
    manifest = Path(tmp.name) / "manifest.json"
    if "\n" in profile:  # a profile's text
        (Path(tmp.name) / "bench.toml").write_text(profile)
        profile = str(Path(tmp.name) / "bench.toml")
    cmd = [sys.executable, "-m", "hilbench.cli", "emulate", profile, "--manifest", str(manifest),
           "--paced" if paced else "--unpaced"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=REPO)
    deadline = time.monotonic() + 20
    while not manifest.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise SystemExit(f"emulator did not start: {proc.stderr.read().decode()}")
        time.sleep(0.01)
    endpoint = read_manifest(manifest)["endpoints"][0]
    CONDITION["scheduling"] = endpoint.get("scheduling")
    CONDITION["cpu_latency"] = endpoint.get("cpu_latency")
    return proc, endpoint["path"], tmp


def wolfgang_at(baud: int) -> str:
    """The bundled wolfgang profile's text with its bus at ``baud`` (the servos' Baud Rate follows)."""
    text = (REPO / "profiles" / "wolfgang.toml").read_text()
    return re.sub(r"(?m)^baud = 2_000_000", f"baud = {baud}", text, count=1)


class CustomBaudPortHandler(sdk.PortHandler):
    """The SDK's PortHandler with its list of rates lifted (spec §7.1: it refuses 4.5 Mbaud although
    pyserial opens any rate on Linux, BOTHER/termios2). Everything else is the SDK's own code."""

    def getCFlagBaud(self, baudrate: int) -> int:  # noqa: N802 (the SDK's name)
        return baudrate


def line_lateness(manifest: Path) -> tuple[int, float, float]:
    """(deliveries, seconds late in all, the latest single delivery) of the bench's serial line since it
    started, against its own wire model: what the emulator added to a paced cycle (the control channel's
    ``media``). The first two are differenced over the measured cycles; the latest is since the start,
    warm-up included."""
    stats = next(iter(ControlClient.from_manifest(manifest).media().values()))["stats"]
    return stats.get("late_count", 0), stats.get("late_total", 0.0), stats.get("late_max", 0.0)


def lateness_figures(before: tuple[int, float, float], after: tuple[int, float, float]) -> dict:
    """``line_late_us``: how late the line handed the measured cycles' transmissions over on average;
    ``line_late_max_us``: the latest delivery since the bench started (warm-up included)."""
    n = after[0] - before[0]
    return {"line_late_us": round((after[1] - before[1]) / n * 1e6, 1) if n else None,
            "line_late_max_us": round(after[2] * 1e6, 1)}


def process_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_cycles(path: str, seconds: float, emulator_pid: int, baud: int = BAUD,
               manifest: Path | None = None) -> tuple[int, float, float, float]:
    """(cycles, seconds, emulator CPU seconds, this process's CPU seconds) of the measured cycles, after a
    warm-up; with the bench's ``manifest``, the line's lateness over them goes to CONDITION."""
    port = CustomBaudPortHandler(path) if baud == 4_500_000 else sdk.PortHandler(path)
    port.openPort()
    if not port.setBaudRate(baud):
        raise SystemExit(f"the SDK did not open {path} at {baud}")
    ph, reader, writer = sdk_cycle(port, IDS)

    failed = [0]

    def cycle() -> None:
        # a reply the SDK gave up on (34 ms): counted, as a loaded machine can stall either process that long
        failed[0] += reader.txRxPacket() != sdk.COMM_SUCCESS
        writer.txPacket()

    warm_end = time.perf_counter() + min(0.5, seconds / 4)
    while time.perf_counter() < warm_end:
        cycle()
    n = failed[0] = 0
    late0 = line_lateness(manifest) if manifest is not None else None
    cpu0, own0 = process_cpu_s(emulator_pid), time.process_time()
    t0 = time.perf_counter()
    end = t0 + seconds
    while time.perf_counter() < end:
        cycle()
        n += 1
    dt = time.perf_counter() - t0
    cpu, own = process_cpu_s(emulator_pid) - cpu0, time.process_time() - own0
    if late0 is not None:
        CONDITION["lateness"] = lateness_figures(late0, line_lateness(manifest))
    port.closePort()
    CONDITION["failed_reads"] = failed[0]
    return n, dt, cpu, own


def suffix() -> str:
    return (f"_load{CONDITION['load']}" if CONDITION["load"] else "") + ("_run" if CONDITION["under_run"] else "")


def run_cycles_under_run(path: str, seconds: float, emulator_pid: int, baud: int,
                         manifest: Path | None) -> tuple[int, float, float, float]:
    """:func:`run_cycles` in a child process under ``hilbench run --manifest`` (``--client-cycle``)."""
    bench_manifest = manifest or MANIFESTS[emulator_pid]
    cmd = [sys.executable, "-m", "hilbench.cli", "run", "--manifest", str(bench_manifest), "--",
           sys.executable, str(Path(__file__).resolve()), "--client-cycle", path, str(baud), str(seconds),
           str(emulator_pid), str(manifest) if manifest is not None else "-"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, timeout=seconds * 3 + 60)
    if out.returncode != 0:
        raise SystemExit(f"the client under hilbench run failed ({out.returncode}): {out.stderr.strip()}")
    result = json.loads(out.stdout.strip().splitlines()[-1])
    CONDITION["failed_reads"] = result["failed_reads"]
    if result.get("lateness"):
        CONDITION["lateness"] = result["lateness"]
    if result.get("served"):
        CONDITION["served"] = result["served"]
    return result["n"], result["dt"], result["cpu"], result["own"]


#: The manifest of each running emulator, by pid (the unpaced cycle measures no lateness but needs one).
MANIFESTS: dict[int, Path] = {}


def client_cycle(argv: list[str]) -> None:
    """The child of :func:`run_cycles_under_run`: the cycles in this process, one JSON line of results."""
    path, baud, seconds, pid, manifest = argv
    n, dt, cpu, own = run_cycles(path, float(seconds), int(pid), int(baud),
                                 None if manifest == "-" else Path(manifest))
    print(json.dumps({"n": n, "dt": dt, "cpu": cpu, "own": own, "failed_reads": CONDITION["failed_reads"],
                      "lateness": CONDITION.get("lateness"), "served": serve_mode(path, manifest)}), flush=True)


def serve_mode(path: str, manifest: str) -> str | None:
    """The serving path's mode of the pty (HILBENCH_SERVE=1; hilbench/bench/serve_ring.py), else None."""
    from hilbench.bench import serve_ring

    if os.environ.get("HILBENCH_SERVE") != "1" or manifest == "-":
        return None
    ring = Path(read_manifest(Path(manifest))["port_state"]["socket"]).parent / serve_ring.FILE_NAME
    mode = serve_ring.mode_in(str(ring), os.stat(path).st_rdev)
    return None if mode is None else ("kernel", "served", "fallback")[mode]


def one_cycle_run(paced: bool, seconds: float, baud: int, serve: str | None = None) -> tuple:
    """One measurement of the SDK's cycles against a fresh emulator: (seconds per cycle, cycles, seconds,
    emulator CPU seconds, conditions, lateness). ``serve``: HILBENCH_SERVE for the client under run."""
    avg = loadavg()
    proc, path, tmp = start_emulator(paced, "wolfgang" if baud == BAUD else wolfgang_at(baud))
    manifest = Path(tmp.name) / "manifest.json"
    MANIFESTS[proc.pid] = manifest
    runner = run_cycles_under_run if CONDITION["under_run"] else run_cycles
    saved = os.environ.get("HILBENCH_SERVE")
    if serve is not None:
        os.environ["HILBENCH_SERVE"] = serve
    try:
        n, dt, emulator_cpu, own_cpu = runner(path, seconds, proc.pid, baud, manifest if paced else None)
    finally:
        if serve is not None:
            if saved is None:
                os.environ.pop("HILBENCH_SERVE", None)
            else:
                os.environ["HILBENCH_SERVE"] = saved
        proc.terminate()
        proc.wait(timeout=5)
        tmp.cleanup()
    cond = {"load": CONDITION["load"], "loadavg": avg,
            **({"served": CONDITION.pop("served")} if "served" in CONDITION else {}),
            "sdk_cpu_us": round(own_cpu / n * 1e6, 1), "emulator_cpu_us": round(emulator_cpu / n * 1e6, 1),
            "failed_reads": CONDITION["failed_reads"]}
    return dt / n, n, dt, emulator_cpu, cond, CONDITION.pop("lateness", {})


def bench_serve_ab(seconds: float, baud: int, runs: int) -> None:
    """The paced SDK cycle under ``hilbench run`` on the kernel path and on the serving path
    (HILBENCH_SERVE=0/1), one run of each per round in alternating order (a shared machine's load moves
    between rounds): the median of each, and each round's served/kernel ratio (``paired``)."""
    wire_cycle = CYCLE_BYTES * 10 / baud
    kernel, served, paired = [], [], []
    for i in range(max(1, runs)):
        order = ("0", "1") if i % 2 == 0 else ("1", "0")
        got = {mode: one_cycle_run(True, seconds, baud, mode) for mode in order}
        kernel.append(got["0"])
        served.append(got["1"])
        paired.append(round(got["1"][0] / got["0"][0], 3))
    label = f"{baud / 1e6:g}M".replace(".5M", "M5")
    for name, measured in (("", kernel), ("_served", served)):
        measured.sort(key=lambda run: run[0])
        per_cycle, n, _, _, cond, lateness = measured[len(measured) // 2]
        emit(f"dxl_sdk_cycle_paced_{label}{suffix()}{name}", per_cycle * 1e3, "ms/cycle", wire_cycle * 1e3,
             per_cycle / wire_cycle, target="ratio within 0.9..1.1", cycles=n, scheduling=CONDITION.get("scheduling"),
             **cond, **lateness,
             runs_ratio=[round(run[0] / wire_cycle, 3) for run in measured],
             runs_loadavg=[run[4]["loadavg"] for run in measured],
             **({"paired_served_over_kernel": paired} if name else {}))


def bench_cycle(paced: bool, seconds: float, baud: int = BAUD, runs: int = 1) -> None:
    """The official SDK's cycle against ``hilbench emulate`` in another process. Paced, ``runs`` > 1
    measures it that many times (a fresh emulator each) and reports the median run, with every run's
    ratio (``runs_ratio``): on a VM one run's figure moves by a few per cent from one run to the next."""
    wire_cycle = CYCLE_BYTES * 10 / baud  # seconds per cycle on the wire, Return Delay Time 0
    measured = [one_cycle_run(paced, seconds, baud) for _ in range(max(1, runs) if paced else 1)]
    measured.sort(key=lambda run: run[0])
    per_cycle, n, dt, emulator_cpu, cond, lateness = measured[len(measured) // 2]  # the median run
    if paced:
        spread = {"runs_ratio": [round(run[0] / wire_cycle, 3) for run in measured]} if len(measured) > 1 else {}
        label = f"{baud / 1e6:g}M".replace(".5M", "M5")
        emit(f"dxl_sdk_cycle_paced_{label}{suffix()}", per_cycle * 1e3, "ms/cycle", wire_cycle * 1e3,
             per_cycle / wire_cycle, target="ratio within 0.9..1.1", cycles=n, scheduling=CONDITION.get("scheduling"),
             cpu_latency=CONDITION.get("cpu_latency"), **cond, **lateness, **spread)
    else:
        rate = n / dt
        emit(f"dxl_sdk_cycle_unpaced{suffix()}", rate, "cycles/s", 1 / wire_cycle, rate * wire_cycle,
             target_value=2000, cycles=n, cpus=os.cpu_count(), **cond)
        # The emulator's CPU per cycle varies far less with the machine's load than the cycle rate,
        # which also includes the SDK's own (busy-polling) side and both processes' wake-ups.
        cpu_per_cycle = emulator_cpu / n
        emit(f"dxl_emulator_cpu_per_cycle{suffix()}", cpu_per_cycle * 1e6, "us", wire_cycle * 1e6,
             cpu_per_cycle / wire_cycle, target_value=150, load=CONDITION["load"], loadavg=cond["loadavg"],
             note="emulator process CPU per 20-servo cycle, against the cycle's wire time")


def bench_rough(capture: Path) -> None:
    """Both decoders on 1 MB of noise and on damaged input (the Wolfgang capture with 1 % of its bytes
    damaged; Protocol 1.0 traffic of its own), against the 4.5 Mbaud line (tools/rough.py)."""
    from rough import measure

    from hilbench.protocols.dynamixel_targets import DYNAMIXEL, DYNAMIXEL1

    measure(DYNAMIXEL, seed=capture.read_bytes(), seed_name="the Wolfgang capture", prefix="dxl_rough_")
    measure(DYNAMIXEL1, prefix="dxl_rough_")


SERVOS20 = list(range(1, 21))


def _profile(protocol: str, baud: int) -> str:
    if protocol == "protocol1":
        head = f'[endpoints.bus]\nprotocol = "dynamixel"\nprotocol_version = 1\nbaud = {baud}\n'
        dev = '[[devices]]\nmodel = "MX-28"\nids = {ids}\ninit = {{ return_delay_time = 0 }}\n'
    else:
        head = f'[defaults]\nsupply_voltage = 7.4\n[endpoints.bus]\nprotocol = "feetech"\nbaud = {baud}\n'
        dev = '[[devices]]\nmodel = "STS3215"\nids = {ids}\n'
    return "schema = 1\n" + head + dev.format(ids=SERVOS20)


def _cycle_pypot(path: str, baud: int):
    from pypot.dynamixel.io import DxlIO

    io = DxlIO(path, baudrate=baud, use_sync_read=True)
    goals = {i: (0.0, 0.0, 100.0) for i in SERVOS20}

    def cycle() -> bool:
        ok = len(io.get_present_position_speed_load(SERVOS20)) == len(SERVOS20)
        io.set_goal_position_speed_load(goals)
        return ok

    return cycle, io.close


def _cycle_feetech(path: str, baud: int):
    import scservo_sdk as scs

    port = scs.PortHandler(path)
    port.openPort()
    port.setBaudRate(baud)
    ph = scs.PacketHandler(0)
    reader = scs.GroupSyncRead(port, ph, 56, 2)
    writer = scs.GroupSyncWrite(port, ph, 42, 2)
    for i in SERVOS20:
        reader.addParam(i)
        writer.addParam(i, [0x00, 0x08])

    def cycle() -> bool:
        ok = reader.txRxPacket() == scs.COMM_SUCCESS
        writer.txPacket()
        return ok

    return cycle, port.closePort


#: Bytes on the servo bus per 20-servo cycle (see the module docstring).
WIRE_BYTES = {
    # USB2AX SYNC_READ (8 + N) + the adapter's READ (8) and each reply (6 + 6) + its reply (6 + 6N)
    # + SYNC_WRITE (8 + 7N)
    "protocol1": (8 + 20) + 20 * (8 + 12) + (6 + 6 * 20) + (8 + 7 * 20),
    # SYNC_READ (8 + N) + 20 statuses (6 + 2) + SYNC_WRITE (8 + 3N)
    "feetech": (8 + 20) + 20 * 8 + (8 + 3 * 20),
}


def bench_bus(kind: str, seconds: float, paced_bauds: tuple[int, ...]) -> None:
    """The 20-servo cycle of pypot (Protocol 1.0, USB2AX) or Feetech's SDK (LeRobot's loop)."""
    module = "pypot" if kind == "protocol1" else "scservo_sdk"
    try:
        __import__(module)
    except ImportError:
        print(json.dumps({"name": f"{kind}_cycle", "skipped": f"{module} is not installed (make install-robots)"}))
        return
    make = _cycle_pypot if kind == "protocol1" else _cycle_feetech
    client = "pypot" if kind == "protocol1" else "feetech_sdk"
    for paced, baud in ((False, 1_000_000), *((True, b) for b in paced_bauds)):
        avg = loadavg()
        proc, path, tmp = start_emulator(paced, _profile(kind, baud))
        try:
            cycle, close = make(path, baud)
            warm_end = time.perf_counter() + min(0.5, seconds / 4)
            while time.perf_counter() < warm_end:
                cycle()
            late0 = line_lateness(Path(tmp.name) / "manifest.json") if paced else None
            n, failed, cpu0, t0 = 0, 0, process_cpu_s(proc.pid), time.perf_counter()
            while time.perf_counter() < t0 + seconds:
                failed += not cycle()  # a reply timeout (the client's own) on a loaded machine
                n += 1
            dt = time.perf_counter() - t0
            cpu = process_cpu_s(proc.pid) - cpu0
            lateness = lateness_figures(late0, line_lateness(Path(tmp.name) / "manifest.json")) if paced else {}
            close()
        finally:
            proc.terminate()
            proc.wait(timeout=5)
            tmp.cleanup()
        wire = WIRE_BYTES[kind] * 10 / baud
        cond = {"load": CONDITION["load"], "loadavg": avg}
        if paced:
            emit(f"{kind}_{client}_cycle_paced_{baud // 1000}k{suffix()}", dt / n * 1e3, "ms/cycle", wire * 1e3,
                 dt / n / wire, target="ratio within 0.9..1.1", cycles=n, failed_reads=failed,
                 scheduling=CONDITION.get("scheduling"), cpu_latency=CONDITION.get("cpu_latency"),
                 emulator_cpu_us=round(cpu / n * 1e6, 1), **lateness, **cond)
        else:
            emit(f"{kind}_{client}_cycle_unpaced{suffix()}", n / dt, "cycles/s", 1 / wire, n / dt * wire, cycles=n,
                 failed_reads=failed, **cond)
            emit(f"{kind}_emulator_cpu_per_cycle{suffix()}", cpu / n * 1e6, "us", wire * 1e6, cpu / n / wire,
                 note="emulator process CPU per 20-servo cycle, against the cycle's wire time at 1 Mbaud", **cond)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", type=Path, default=REPO / "tests/data/dynamixel/wolfgang_trace.bin")
    ap.add_argument("--seconds", type=float, default=3.0, help="measuring time per cycle benchmark")
    ap.add_argument("--only", choices=("decoder", "rough", "unpaced", "paced", "protocol1", "feetech"))
    ap.add_argument("--load", type=int, default=1, metavar="N",
                    help="measure every cycle figure again with N CPU-bound neighbour processes (0: only as is)")
    ap.add_argument("--runs", type=int, default=1, metavar="N",
                    help="measure each paced SDK cycle N times and report the median run (runs_ratio: all)")
    ap.add_argument("--baud", type=int, choices=(BAUD, 4_500_000),
                    help="measure the paced SDK cycle at this rate only (default: both)")
    ap.add_argument("--under-run", action="store_true",
                    help="run the SDK's cycles in a child under `hilbench run --manifest` (figures ..._run)")
    ap.add_argument("--serve-ab", action="store_true",
                    help="paced SDK cycle only, under hilbench run: the kernel path and the serving path "
                         "(HILBENCH_SERVE=0/1) in alternating runs (figures ..._run and ..._run_served)")
    ap.add_argument("--client-cycle", nargs=5, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client_cycle:
        client_cycle(args.client_cycle)
        return
    CONDITION["under_run"] = args.under_run or args.serve_ab
    if args.serve_ab:
        for load in (0, args.load) if args.load else (0,):
            with neighbours(load):
                for baud in (BAUD, 4_500_000):
                    if args.baud in (None, baud):
                        bench_serve_ab(args.seconds, baud, args.runs)
        return
    if args.only in (None, "decoder"):
        bench_decoder(args.capture)
    if args.only in (None, "rough"):
        bench_rough(args.capture)
    for load in (0, args.load) if args.load else (0,):
        with neighbours(load):
            if args.only in (None, "unpaced"):
                bench_cycle(False, args.seconds)
            if args.only in (None, "paced"):
                for baud in (BAUD, 4_500_000):
                    if args.baud in (None, baud):
                        bench_cycle(True, args.seconds, baud, runs=args.runs)
            if args.only in (None, "protocol1"):
                bench_bus("protocol1", args.seconds, (1_000_000, 3_000_000))
            if args.only in (None, "feetech"):
                bench_bus("feetech", args.seconds, (1_000_000, 500_000))


if __name__ == "__main__":
    main()
