"""``hilbench run``: run an unmodified client with a serial adapter's semantics on the bench's ptys."""

from __future__ import annotations

import argparse
import os
import sys

from hilbench.cli.common import CliError

DESCRIPTION = """\
Run COMMAND so that, on the ptys of the given benches only, what a USB serial
adapter does besides bytes reaches the emulated devices: DTR/RTS changes
(TIOCMSET/TIOCMBIS/TIOCMBIC, pyserial's .dtr/.rts) become modem-line events,
TIOCMGET (pyserial's .cts/.dsr/.ri/.cd) reads what the devices drive, BREAK
(TIOCSBRK/TIOCCBRK, tcsendbreak) arrives as an event, tcflush(TCOFLUSH)
delivers the bytes already written instead of discarding them, tcdrain
returns once they are delivered (at once, asking the bench nothing, when they
already are), and baud rate and framing changes are reported. Every other
file and call is untouched.

Compiled and Python programs alike get this from a small LD_PRELOAD library,
built with the system's C compiler on first use and cached in
$XDG_CACHE_HOME/hilbench. Without a compiler (or with --shim python), a
pyserial patch loaded through PYTHONPATH covers Python clients using pyserial
only. hilbench run replaces itself with COMMAND (exec): signals reach the
program directly and its exit status is hilbench run's.

Against a bench started with --virtual-time (its manifest has a `clock`
entry), COMMAND also runs on the bench's virtual clock: its clocks, sleeps and
timeouts are virtual, and time advances only when every thread of COMMAND (and
of its children) waits. This needs the preload library (no Python fallback),
and sets PYTHONHASHSEED=0 unless it is set. A thread that runs without ever
waiting holds the clock for at most the bench's --lockstep-stall (1 s wall by
default); after that time follows the wall clock until it waits, counted as a
lockstep stall and warned about once per thread.

Limits: statically linked and setuid programs ignore LD_PRELOAD; programs that
make raw system calls bypass libc; Linux with glibc only; the shim is built for
the machine's own word size (a 32-bit program on a 64-bit system sees a plain pty).
"""

EPILOG = """\
examples:
  hilbench emulate arm --manifest /tmp/arm.json &
  hilbench run --manifest /tmp/arm.json -- python3 my_driver.py /dev/pts/3
  HILBENCH_MANIFEST=/tmp/lidar.json hilbench run -- ./ultra_simple --channel --serial /dev/pts/4 115200
"""


def cmd_run(args: argparse.Namespace) -> int:
    from hilbench.run.environment import manifest_paths, read_bench, run_environment

    command = list(args.command)
    if command and command[0] == "--":
        command = command[1:]
    if not command:
        raise CliError("no command to run: hilbench run [--manifest FILE] -- COMMAND [ARGS...]")
    benches = [read_bench(path) for path in manifest_paths(args.manifest)]
    shim = args.shim or os.environ.get("HILBENCH_RUN_SHIM") or "auto"
    env, notes = run_environment(benches, shim)
    for note in notes:
        print(f"hilbench run: note: {note}", file=sys.stderr)
    if not any(b.ports or b.clock for b in benches):
        print("hilbench run: note: the bench has no pty endpoints; COMMAND runs unchanged", file=sys.stderr)
    if args.verbose:
        for b in benches:
            for name, port in b.ports.items():
                print(f"hilbench run: {name}: {port.get('path')} (rdev {port.get('rdev')}) via {b.socket}",
                      file=sys.stderr)
        print(f"hilbench run: shim: {env['HILBENCH_RUN']}", file=sys.stderr)
        for b in benches:
            if b.clock:
                print(f"hilbench run: clock: virtual, {b.clock.get('page')} ({b.manifest})", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        # exec, not a child: nothing to do while it runs (the bench answers), and the program keeps
        # our pid, gets its signals directly (Ctrl-C, SIGTERM from a launcher) and exits with its status.
        os.execvpe(command[0], command, env)
    except FileNotFoundError:
        print(f"hilbench: error: {command[0]}: command not found", file=sys.stderr)
        return 127
    except PermissionError:
        print(f"hilbench: error: {command[0]}: permission denied", file=sys.stderr)
        return 126
    return 0  # not reached


ORDER = 15
VERBS = {  # each verb register() adds and its line in `hilbench --help` (see hilbench.cli)
    "run": "run a client with a real serial adapter's modem lines, BREAK and flushes",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help=VERBS["run"],
                       description=DESCRIPTION, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--manifest", metavar="FILE", action="append",
                   help="a running bench's manifest (`hilbench emulate --manifest FILE`); repeatable; "
                        "default: $HILBENCH_MANIFEST (several joined with ':')")
    p.add_argument("--shim", choices=("auto", "c", "python"),
                   help="how: c (LD_PRELOAD library), python (pyserial only), auto (c, else python; "
                        "default, or $HILBENCH_RUN_SHIM)")
    p.add_argument("-v", "--verbose", action="store_true", help="say which ptys are served and how")
    p.add_argument("command", nargs=argparse.REMAINDER, metavar="-- COMMAND [ARGS...]",
                   help="the program to run and its arguments")
    p.set_defaults(func=cmd_run)
