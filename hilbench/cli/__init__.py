"""The ``hilbench`` command line: thin verbs over the library.

Verbs are plug-ins: every module named in the ``hilbench.verbs`` entry-point
group (:mod:`hilbench.registry`) has a ``register(subparsers)`` function, an
optional ``ORDER`` number for where ``--help`` lists it (built-ins use
10-90; a lab's package adds its own verbs the same way), and an optional
``VERBS`` dict, each verb ``register`` adds and its one-line help. With it,
``hilbench VERB ...`` registers only the module that has VERB (and those
without ``VERBS``), and ``hilbench --help`` lists its verbs from ``VERBS``
alone, so no command pays for every other verb's options and help texts
(``monitor``'s load every source kind and instrument: a third of a second).

Every error is a :class:`~hilbench.errors.HilbenchError`: one line on stderr
and its exit status (2 for usage mistakes, 1 for devices or benches that fail).
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import os
import select
import signal
import sys
from collections.abc import Callable, Sequence

from hilbench import __version__, registry
from hilbench.cli.common import CliError, OneLineParser
from hilbench.errors import HilbenchError


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: with ``argv`` naming a verb some module's ``VERBS`` has, that module's verbs
    (and those of modules without ``VERBS``); else every verb, those of modules with ``VERBS`` by name and
    help line only (enough for ``--help``, a typo's list of choices, and no verb at all)."""
    p = OneLineParser(
        prog="hilbench",
        description="Hardware-in-the-loop benches for robots: emulated devices on real ptys, CAN and UDP, and "
                    "tools to talk to them.",
    )
    p.add_argument("--version", action="version", version=f"hilbench {__version__}")
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    modules = sorted(registry.verbs.items(), key=lambda item: (getattr(item[1], "ORDER", 100), item[0]))
    verb = next((a for a in argv if not a.startswith("-")), None) if argv else None
    if any(verb in getattr(module, "VERBS", ()) for _, module in modules):
        modules = [(name, module) for name, module in modules
                   if verb in getattr(module, "VERBS", (verb,))]  # (a module without VERBS may have it)
        for _name, module in modules:
            module.register(sub)
        return p
    for _name, module in modules:
        listed = getattr(module, "VERBS", None)
        if listed is None:
            module.register(sub)
        else:
            for name, help_line in listed.items():
                sub.add_parser(name, help=help_line)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hilbench`` command."""
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(argv)
        args = parser.parse_args(argv)
    except KeyboardInterrupt:  # Ctrl-C while the verbs load: no traceback
        return 130
    func: Callable[[argparse.Namespace], int] = args.func
    if hasattr(signal, "SIGUSR1"):  # `kill -USR1 PID`: every thread's stack on stderr (a command that hangs)
        with contextlib.suppress(AttributeError, OSError, ValueError):  # stderr without a descriptor (embedded)
            faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        return func(args)
    except HilbenchError as exc:
        print(f"hilbench: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError as exc:
        if not _reader_gone(sys.stdout):
            print(f"hilbench: error: {exc}", file=sys.stderr)  # some other pipe or socket broke
            return 1
        # The reader of our output went away (`| head -1`): it has what it wanted, so this is no
        # error. Stop quietly with status 0, and keep Python's exit-time flush from complaining again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        print(f"hilbench: error: {exc}", file=sys.stderr)
        return 1


def _reader_gone(stream) -> bool:
    """Whether the pipe behind ``stream`` lost its reader (poll reports an error on the write end)."""
    try:
        poller = select.poll()
        poller.register(stream.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return True  # no descriptor to ask: assume the usual cause


__all__ = ["CliError", "build_parser", "main"]
