"""What every verb of the ``hilbench`` command shares: the one-line error and argument types."""

from __future__ import annotations

import argparse


class CliError(Exception):
    """An error to report on one line with exit status 2."""


def int_arg(text: str) -> int:
    """Integers in decimal or 0x hex."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
