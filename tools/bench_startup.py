#!/usr/bin/env python3
"""Start-up of ``hilbench``'s verbs: the wall time until each has done its job, and what it imports.

Each case runs ``python -m hilbench.cli ARGS`` in a fresh process, ``--runs`` times; its figure is the
least wall time (``startup_<case>``, s), until the process exits or, for ``emulate_arm``, until its first
line of output (the bench is running), and for ``plugins_first_row`` until its first plug-in's row (the
listing shows as the plug-ins load; ``plugins`` is the whole listing). The reference is ``python -c pass`` timed the same way in the same
run, so the ratio survives a loaded machine. Cases: ``help`` (``hilbench --help``), ``monitor_dynamixel``
(``monitor CAPTURE --summary`` on the first 2 000 bytes of ``tests/data/dynamixel/wolfgang_trace.bin``),
``profiles``, ``plugins``, the ``--help`` of ``emulate``, ``record``, the trace profiler's verb, ``lidar``,
``can``, ``dxl`` and ``demo``, and ``emulate_arm``.

Each figure also gives ``cpu``, the least CPU time (user + system) of the runs, and ``reference_cpu``, the
same of ``python -c pass``: on a machine other sessions load, the wall time is mostly waiting for a core, the
CPU time is what the command costs. ``emulate_arm``'s is its CPU time until its first line: every thread's
time on a core so far (``/proc/PID/task/*/schedstat``; Linux only, else none).

Each figure also says what the verb imported (``python -X importtime``): ``modules`` (all), ``hilbench``
(hilbench's), ``heavy`` (the large third-party packages among them) and ``unexpected``: heavy packages
and hilbench modules of the instruments, fakes, families, dashboard, bench and clients that the case does
not need (another family's tracker for a Dynamixel capture, the bench for a ``--help``), grouped by
package. ``--explain CASE`` prints, for each unexpected import, the chain of imports that brought it in
(innermost first: ``module:line``).

The commands run as an installed package does, from its compiled bytecode (``__pycache__``): each case runs
once untimed first, which writes the bytecode into a temporary ``PYTHONPYCACHEPREFIX`` (the repository and
the environment are left alone), whatever ``PYTHONDONTWRITEBYTECODE`` says in the caller's environment.
``--no-bytecode`` times every run compiling every module from its source instead (tens of ms more), the
condition of a checkout whose environment sets ``PYTHONDONTWRITEBYTECODE``.

The wall time is taken when the child is reaped (a blocking wait): ``subprocess.run(timeout=...)`` polls
with sleeps of up to 50 ms, which rounded the figures up to steps of about 50 ms.

Usage: tools/bench_startup.py [--runs N] [--only CASE,...] [--explain CASE] [--no-bytecode]
"""

from __future__ import annotations

import argparse
import contextlib
import fnmatch
import json
import os
import re
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import benchlib

REPO = benchlib.REPO
PY = sys.executable
#: The children's environment (:func:`set_bytecode`).
ENV: dict[str, str] | None = None
CAPTURE = REPO / "tests/data/dynamixel/wolfgang_trace.bin"
CAPTURE_BYTES = 2000

#: Third-party packages worth a look when they are imported (tens of ms each, or a deep tree).
HEAVY = ("numpy", "dpkt", "rich", "construct", "can", "canopen", "cantools", "serial", "dynamixel_sdk",
         "scservo_sdk", "matplotlib", "pexpect")
#: hilbench packages whose modules a verb imports only if it needs them (the layers above the codecs and
#: transports, which every verb may use).
WATCHED = ("hilbench.bench", "hilbench.families", "hilbench.fakes", "hilbench.monitor", "hilbench.profiler",
           "hilbench.dashboard", "hilbench.clients", "hilbench.labgrid", "hilbench.run", "hilbench.servers")


@dataclass(frozen=True)
class Case:
    name: str
    args: tuple[str, ...]
    #: Globs of the heavy packages and watched hilbench modules the case needs (the rest are unexpected).
    needs: tuple[str, ...] = ()
    #: Timed until this many lines of output (a command that runs until stopped, or a listing that shows
    #: while it loads), not until it exits (0).
    lines: int = 0


#: What listing the plug-ins needs: the plug-ins themselves (light objects), not what they use when they run.
PLUGINS = ("rich", "construct", "hilbench.bench*", "hilbench.families*", "hilbench.servers*", "hilbench.monitor*",
           "hilbench.profiler", "hilbench.profiler.instrument", "hilbench.profiler.stm32_rover")


def cases(capture: Path) -> list[Case]:
    dynamixel_monitor = ("numpy", "rich", "hilbench.monitor", "hilbench.monitor.instrument",
                         "hilbench.monitor.detect", "hilbench.monitor.errorlog", "hilbench.monitor.live",
                         "hilbench.monitor.dynamixel", "hilbench.monitor.dynamixel.*",
                         "hilbench.monitor.servo_bus*",  # the servo-bus kit the Dynamixel tracker builds on
                         "hilbench.profiler.instrument")  # every instrument plug-in is asked (light)
    return [
        Case("help", ("--help",)),
        Case("monitor_dynamixel", ("monitor", str(capture), "--summary"), dynamixel_monitor),
        Case("profiles", ("profiles",), ("rich", "construct", "hilbench.bench*", "hilbench.families*")),
        # the plug-ins themselves (light objects), not what they use when they run
        Case("plugins", ("plugins",), PLUGINS),
        Case("plugins_first_row", ("plugins",), PLUGINS, lines=2),  # (the listing shows as plug-ins load)
        *(Case(f"{verb}_help", (verb, "--help")) for verb in ("emulate", "record", "trace", "lidar", "can",
                                                             "dxl", "demo")),
        Case("emulate_arm", ("emulate", "arm"),
             ("rich", "serial", "hilbench.bench*", "hilbench.families", "hilbench.fakes",
              "hilbench.families.dynamixel", "hilbench.families.servo_bus", "hilbench.fakes.dynamixel*",
              "hilbench.fakes.control_table_servo", "hilbench.fakes.table_servo", "hilbench.fakes.servo_bus",
              "hilbench.fakes.protocol1_bus", "hilbench.fakes.motion",
              "hilbench.fakes.world", "hilbench.fakes.scene"),  # every bench has a world
             lines=1),
    ]


def cpu_once(argv: list[str]) -> float:
    """CPU time (user + system) of one run to its end: what the run costs whatever else the machine runs."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO, check=False, timeout=120,
                   env=ENV)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def cpu_so_far(pid: int) -> float | None:
    """CPU time (s) of every thread of process ``pid`` so far (the first field of each thread's schedstat: ns
    on a core), or None where /proc does not say."""
    total = 0
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            with contextlib.suppress(FileNotFoundError):  # (a thread that just ended)
                total += int((task / "schedstat").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return total / 1e9


@contextlib.contextmanager
def until_lines(argv: list[str], lines: int, stderr: int | None = subprocess.DEVNULL) -> Iterator[subprocess.Popen]:
    """``argv`` started; the block runs once it printed ``lines`` lines, then the process is interrupted."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=stderr, cwd=REPO, env=ENV)
    try:
        if not all(proc.stdout.readline() for _ in range(lines)):
            raise SystemExit(f"{' '.join(argv)}: no output")
        yield proc
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def first_lines_cpu(argv: list[str], lines: int) -> float | None:
    """CPU time of one run until ``lines`` lines of output (then it is interrupted)."""
    with until_lines(argv, lines) as proc:
        return cpu_so_far(proc.pid)


def run_once(argv: list[str], lines: int, stderr: int | None = subprocess.DEVNULL) -> float:
    """Wall time of one run: until it exits (``lines`` 0), or until that many lines of output (then it is
    interrupted)."""
    t0 = time.perf_counter()
    if not lines:
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=stderr, cwd=REPO, env=ENV)
        # A blocking wait reaps the child when it ends (wait(timeout=...) polls in steps of up to 50 ms).
        watchdog = threading.Timer(120, proc.kill)
        watchdog.start()
        try:
            proc.wait()
        finally:
            watchdog.cancel()
        return time.perf_counter() - t0
    with until_lines(argv, lines, stderr):
        return time.perf_counter() - t0


def least(argv: list[str], runs: int, lines: int = 0) -> float:
    run_once(argv, lines)  # untimed: writes the bytecode (and warms the page cache)
    return min(run_once(argv, lines) for _ in range(runs))


def set_bytecode(cache: Path | None) -> None:
    """Let the children write and use their bytecode under ``cache``, or (None) compile every module each run."""
    global ENV
    ENV = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPYCACHEPREFIX")}
    if cache is None:
        ENV["PYTHONDONTWRITEBYTECODE"] = "1"
    else:
        ENV["PYTHONPYCACHEPREFIX"] = str(cache)


def imported(case: Case) -> list[str]:
    """The modules the case imports, in order (``python -X importtime``)."""
    with tempfile.TemporaryFile() as err:
        run_once([PY, "-X", "importtime", "-m", "hilbench.cli", *case.args], case.lines, stderr=err.fileno())
        err.seek(0)
        text = err.read().decode(errors="replace")
    return re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)", text, re.M)


def heavy(module: str) -> str | None:
    top = module.partition(".")[0]
    return top if top in HEAVY else None


def watched(module: str) -> bool:
    return heavy(module) is not None or any(module == p or module.startswith(p + ".") for p in WATCHED)


def group(module: str) -> str:
    """What an unexpected module is reported as: its heavy package, or its hilbench package (3 levels)."""
    return heavy(module) or ".".join(module.split(".")[:3])


def unexpected(case: Case, modules: list[str]) -> list[str]:
    """The groups (:func:`group`) of the watched modules the case imports but does not need."""
    seen: dict[str, None] = {}
    for module in modules:
        if watched(module) and not any(fnmatch.fnmatchcase(heavy(module) or module, g) for g in case.needs):
            seen[group(module)] = None
    return list(seen)


#: Run in the child for --explain: a finder that records, for each module the first time it is looked up,
#: the frames that asked for it (module:line, innermost first, the import machinery left out).
WHO = r"""
import atexit, json, runpy, sys
first = {}
class Who:
    @staticmethod
    def find_spec(name, path=None, target=None):
        if name not in first:
            chain, f = [], sys._getframe(1)
            while f is not None:
                where, file = f.f_globals.get("__name__", "?"), f.f_code.co_filename
                if where == "__main__" and file.endswith("__main__.py"):
                    where = "hilbench.cli.__main__"
                if not file.startswith(("<frozen", "<string>")) and not where.startswith(("runpy", "importlib")):
                    link = f"{where}:{f.f_lineno}"
                    if not chain or not chain[-1].startswith(where + ":"):
                        chain.append(link)
                f = f.f_back
            first[name] = chain
        return None
def save():
    with open(OUT, "w") as fh:
        json.dump(first, fh)
OUT = sys.argv[1]
atexit.register(save)
sys.meta_path.insert(0, Who)
sys.argv = ["hilbench", *sys.argv[2:]]
runpy.run_module("hilbench.cli", run_name="__main__", alter_sys=True)
"""


def explain(case: Case) -> None:
    """Print who imported each unexpected group of ``case`` (its first module looked up)."""
    with tempfile.TemporaryDirectory(prefix="hilbench-startup-") as tmp:
        out = Path(tmp) / "who.json"
        run_once([PY, "-c", WHO, str(out), *case.args], case.lines)
        who = json.loads(out.read_text()) if out.exists() else {}
    modules = imported(case)
    order = {m: i for i, m in enumerate(who)}
    found = sorted(unexpected(case, modules), key=lambda g: order.get(g, len(order)))
    print(f"{case.name} (hilbench {' '.join(case.args)}): {len(modules)} modules, {len(found)} unexpected groups")
    for name in found:
        module = name if name in who else next((m for m in who if group(m) == name), name)
        print(f"  {module} <- {' <- '.join(who.get(module) or ['?'])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, metavar="N", help="runs per case; the least time counts "
                    "(default 5)")
    ap.add_argument("--only", metavar="CASE,...", help="these cases only")
    ap.add_argument("--explain", metavar="CASE", help="print who imported each unexpected module of CASE")
    ap.add_argument("--capture", type=Path, default=CAPTURE, help="the Dynamixel capture whose first 2 000 "
                    "bytes the monitor reads")
    ap.add_argument("--no-bytecode", action="store_true", help="compile every module from its source in every "
                    "run (no __pycache__), as in an environment that sets PYTHONDONTWRITEBYTECODE")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="hilbench-startup-") as tmp:
        set_bytecode(None if args.no_bytecode else Path(tmp) / "pycache")
        small = Path(tmp) / "dynamixel_small.bin"
        small.write_bytes(args.capture.read_bytes()[:CAPTURE_BYTES])
        todo = cases(small)
        known = [c.name for c in todo]
        if args.explain:
            if args.explain not in known:
                ap.error(f"--explain: no case {args.explain!r} (known: {', '.join(known)})")
            explain(next(c for c in todo if c.name == args.explain))
            return
        if args.only:
            wanted = args.only.split(",")
            if bad := [w for w in wanted if w not in known]:
                ap.error(f"--only: no case {', '.join(bad)} (known: {', '.join(known)})")
            todo = [c for c in todo if c.name in wanted]
        reference = least([PY, "-c", "pass"], args.runs)
        reference_cpu = min(cpu_once([PY, "-c", "pass"]) for _ in range(args.runs))
        for case in todo:
            argv = [PY, "-m", "hilbench.cli", *case.args]
            took = least(argv, args.runs, case.lines)
            # (a bench runs until stopped: its CPU time to the first line is not the process's)
            if case.lines:
                cpus = [first_lines_cpu(argv, case.lines) for _ in range(args.runs)]
                cpu = None if None in cpus else min(cpus)
            else:
                cpu = min(cpu_once(argv) for _ in range(args.runs))
            modules = imported(case)
            benchlib.emit(f"startup_{case.name}", took, "s", reference, took / reference, ratio_digits=1,
                          cpu=round(cpu, 3) if cpu is not None else None, reference_cpu=round(reference_cpu, 3),
                          bytecode=not args.no_bytecode,
                          modules=len(modules), hilbench=sum(m.startswith("hilbench") for m in modules),
                          heavy=sorted({h for m in modules if (h := heavy(m))}),
                          unexpected=sorted(unexpected(case, modules)))


if __name__ == "__main__":
    with contextlib.suppress(BrokenPipeError):
        main()
