"""What every verb of the ``hilbench`` command shares: one-line errors, argument types, byte sources."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator

from hilbench.errors import UsageError


class CliError(UsageError):
    """A usage mistake found by a verb: one line, exit status 2."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (exit 2), like every other hilbench error.

    Sub-parsers inherit the class, so every verb behaves the same; ``--help`` still shows the usage.
    """

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def int_arg(text: str) -> int:
    """Integers in decimal or 0x hex."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def warn_beyond_machine(host: str, what: str, why: str) -> bool:
    """Warn on stderr when ``what`` listens on ``host`` and that is not loopback: reachable from other
    machines (``why`` says what that means or how to avoid it). Returns whether it warned. Every verb that
    opens a listening socket says it the same way."""
    from hilbench.transports.host_port import is_loopback

    if is_loopback(host):
        return False
    print(f"hilbench: warning: {what} listens on {host}, beyond this machine ({why})", file=sys.stderr)
    return True


def terminate_on_sigterm() -> None:
    """SIGTERM ends a verb like Ctrl-C does (summary printed, files closed)."""

    def handler(*_):
        raise KeyboardInterrupt

    with contextlib.suppress(ValueError):  # not the main thread
        signal.signal(signal.SIGTERM, handler)


@contextlib.contextmanager
def open_cli_source(spec: str, *, baud: int | None, speed: float | None = None,
                    default_baud: int = 57_600, endpoint: str | None = None) -> Iterator:
    """A byte source for a verb (:func:`hilbench.transports.sources.open_source`), or ``bench:PROFILE``,
    which starts that bench in this process and taps ``endpoint`` (default: the first). Errors become
    one-line :class:`CliError` s; the source (and bench) close when the block ends."""
    from hilbench.transports.capture_file import CaptureError
    from hilbench.transports.sources import MediumSource, SourceError, open_source

    bench = None
    try:
        if spec.startswith("bench:"):
            from hilbench.bench import Bench
            from hilbench.bench.profile import DEFAULT_PROFILE

            bench = Bench(spec[len("bench:"):] or DEFAULT_PROFILE).start()
            ep = bench.endpoint(endpoint or next(iter(bench.endpoints)))
            source = MediumSource(ep.medium, name=f"bench {bench.profile.name}: {ep.path}",
                                  protocol=ep.spec.protocol)
        else:
            source = open_source(spec, baud=baud, speed=speed, default_baud=default_baud)
    except (SourceError, CaptureError) as exc:
        if bench is not None:
            bench.stop()
        raise CliError(str(exc)) from None
    try:
        yield source
    finally:
        source.close()
        if bench is not None:
            bench.stop()
