"""The ``hilbench`` command line: thin verbs over the library.

Each verb group lives in its own module with a ``register(subparsers)``
function; :data:`VERB_MODULES` lists them in the order ``--help`` shows them.
Every error is one line on stderr and a non-zero exit status.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence

from hilbench import __version__
from hilbench.cli.common import CliError, OneLineParser
from hilbench.profile import ProfileError

#: Modules under ``hilbench.cli`` that register verbs.
VERB_MODULES = ("emulate", "monitor", "dxl", "rover", "board", "profile", "demo")


def build_parser() -> argparse.ArgumentParser:
    """The whole argument parser, every verb registered."""
    p = OneLineParser(
        prog="hilbench",
        description="Hardware-in-the-loop benches for robots: emulated devices on real ptys, and tools to talk to them.",
    )
    p.add_argument("--version", action="version", version=f"hilbench {__version__}")
    sub = p.add_subparsers(dest="verb", required=True, metavar="VERB")
    for name in VERB_MODULES:
        importlib.import_module(f"hilbench.cli.{name}").register(sub)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``hilbench`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (ProfileError, CliError) as exc:
        print(f"hilbench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # The reader went away (`| head`): stop quietly, as Unix tools do, and keep Python's
        # exit-time flush of stdout from complaining again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except Exception as exc:
        from hilbench.dxl_client import DxlError

        if isinstance(exc, DxlError | OSError):
            print(f"hilbench: error: {exc}", file=sys.stderr)
            return 1
        raise


__all__ = ["CliError", "build_parser", "main"]
