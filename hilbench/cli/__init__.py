"""The ``hilbench`` command line: thin verbs over the library.

Verbs are plug-ins (:mod:`hilbench.registry`): each entry point of the
``hilbench.verbs`` group is named after a verb and names the module that adds
it (``monitor``, ``record`` and ``tap`` all name :mod:`hilbench.cli.monitor`).
The module has a ``register(subparsers)`` function adding its verbs, an
optional ``ORDER`` number for where ``--help`` lists them, or a dict of one
per verb (built-ins use 10-90; a lab's package adds its own verbs the same
way), and an optional
``VERBS`` dict, each verb ``register`` adds and its one-line help. An entry
point named ``VERB.NAME`` is an extension of VERB: a module whose
``extend(subparsers)`` adds sub-commands to VERB's once VERB is registered
(a family adding its own commands to a generic verb: ``can.canopen`` names
:mod:`hilbench.cli.canopen_board`), and whose optional ``SYNOPSIS`` lines join
the list of commands that opens VERB's ``--help`` (its description's first
block of indented lines).

``hilbench VERB ...`` imports the module of VERB (and VERB's extensions)
alone, so no command pays for every other verb's imports, options and help
texts (``monitor``'s load every source kind and instrument). ``hilbench
--help``, no verb at all and a typo import every verb module and list the
verbs of those with ``VERBS`` from it alone.

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
from types import ModuleType

from hilbench import __version__, registry
from hilbench.cli.common import CliError, OneLineParser
from hilbench.errors import HilbenchError


def _extend(sub: argparse._SubParsersAction, verb: str) -> None:
    """Let the extensions of ``verb`` (entry points ``VERB.NAME``) add their sub-commands to it."""
    parser = sub.choices.get(verb)
    if parser is None:
        return
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for name in sorted(registry.verbs.names()):
        if name.startswith(verb + ".") and subs:
            extension = registry.verbs.get(name)
            extension.extend(subs[0])
            synopsis = getattr(extension, "SYNOPSIS", "")
            if synopsis and parser.description:
                parser.description = _add_synopsis(parser.description, synopsis)


def _add_synopsis(description: str, lines: str) -> str:
    """``description`` with ``lines`` after its first block of indented lines (a verb's list of commands), or
    at its end."""
    text = description.split("\n")
    start = next((i for i, line in enumerate(text) if line.startswith("  ")), None)
    if start is None:
        return f"{description}\n\n{lines}"
    end = next((i for i in range(start, len(text)) if not text[i].startswith("  ")), len(text))
    return "\n".join([*text[:end], *lines.split("\n"), *text[end:]])


def _register(sub: argparse._SubParsersAction, module: ModuleType) -> None:
    """Register ``module``'s verbs and their extensions."""
    module.register(sub)
    for verb in getattr(module, "VERBS", ()):
        _extend(sub, verb)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: with ``argv`` naming a verb, that verb's module (and extensions) alone; else every
    verb, those of modules with ``VERBS`` by name and help line only (enough for ``--help``, a typo's list of
    choices, and no verb at all)."""
    p = OneLineParser(
        prog="hilbench",
        description="Hardware-in-the-loop benches for robots: emulated devices on real ptys, CAN and UDP, and "
                    "tools to talk to them.",
    )
    p.add_argument("--version", action="version", version=f"hilbench {__version__}")
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    verb = next((a for a in argv if not a.startswith("-")), None) if argv else None
    if verb is not None and "." not in verb and verb in registry.verbs:
        module = registry.verbs.get(verb)  # (a plug-in that fails to load: UsageError, one line)
        if verb in getattr(module, "VERBS", (verb,)):
            _register(sub, module)
            return p
    modules: dict[int, tuple[str, ModuleType]] = {}  # one entry per module: its first verb's name, the module
    for name, module in registry.verbs.items():
        if "." not in name:
            modules.setdefault(id(module), (name, module))
    if any(verb in getattr(module, "VERBS", ()) for _, module in modules.values()):  # a verb no entry point names
        for _name, module in modules.values():
            if verb in getattr(module, "VERBS", (verb,)):  # (a module without VERBS may have it)
                _register(sub, module)
        return p
    # Each verb where its module's ORDER puts it; a module without VERBS registers all of its own at once.
    entries: list[tuple[int, str, int, str | None, ModuleType]] = []
    for first, module in modules.values():
        listed = getattr(module, "VERBS", None)
        if listed is None:
            entries.append((_order(module, first), first, 0, None, module))
        else:
            entries += [(_order(module, name), first, n, name, module) for n, name in enumerate(listed)]
    for *_, name, module in sorted(entries, key=lambda e: e[:3]):
        if name is None:
            _register(sub, module)
        else:
            sub.add_parser(name, help=module.VERBS[name])
    return p


def _order(module: ModuleType, verb: str) -> int:
    """Where ``hilbench --help`` lists ``verb``: the module's ``ORDER``, a number or one per verb (default 100)."""
    order = getattr(module, "ORDER", 100)
    return order.get(verb, 100) if isinstance(order, dict) else order

def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hilbench`` command."""
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        parser = build_parser(argv)
        args = parser.parse_args(argv)
    except KeyboardInterrupt:  # Ctrl-C while the verbs load: no traceback
        return 130
    except HilbenchError as exc:  # a verb's plug-in that cannot be loaded
        print(f"hilbench: error: {exc}", file=sys.stderr)
        return exc.exit_code
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
