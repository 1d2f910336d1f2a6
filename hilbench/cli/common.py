"""What every verb of the ``hilbench`` command shares: one-line errors, argument types, byte sources."""

from __future__ import annotations

import argparse
import contextlib
import functools
import signal
import sys
from collections.abc import Callable, Iterator
from typing import Any

from hilbench.errors import UsageError


class CliError(UsageError):
    """A usage mistake found by a verb: one line, exit status 2."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (exit 2), like every other hilbench error.

    Sub-parsers inherit the class, so every verb behaves the same; ``--help`` still shows the usage, and
    every option whose type is a :class:`~hilbench.rules.Rule` shows its range there (:func:`with_ranges`).
    """

    def __init__(self, *args, formatter_class: type[argparse.HelpFormatter] = argparse.HelpFormatter,
                 **kwargs) -> None:
        super().__init__(*args, formatter_class=with_ranges(formatter_class), **kwargs)

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@functools.cache
def with_ranges(formatter: type[argparse.HelpFormatter]) -> type[argparse.HelpFormatter]:
    """``formatter`` that ends each option's help with the range its rule checks (``[a number 0..1000]``),
    so the range shown is the one enforced, for every verb (plug-ins' too) without restating it by hand."""
    if getattr(formatter, "shows_ranges", False):
        return formatter

    class RangeHelp(formatter):  # type: ignore[valid-type, misc]
        shows_ranges = True

        def _get_help_string(self, action: argparse.Action) -> str | None:
            text = super()._get_help_string(action)
            expected = getattr(action.type, "expected", None)
            if text and isinstance(expected, str) and action.choices is None:
                text = f"{text} [{expected.replace('%', '%%')}]"
            return text

    RangeHelp.__name__ = f"RangeHelp{formatter.__name__}"
    return RangeHelp


def int_arg(text: str) -> int:
    """Integers in decimal or 0x hex."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


SET_HELP = ("change a key of the profile before the bench starts, checked as the file is: ENDPOINT.KEY[.SUBKEY] "
            "(ENDPOINT.baud=1000000, ENDPOINT.port=0 for any free port), devices.NAME.KEY or TABLE.KEY; the value "
            "is read as TOML; repeatable")


def add_set_option(parser: argparse.ArgumentParser, what: str = "") -> None:
    """``--set KEY=VALUE`` (repeatable) into ``args.overrides``: profile overrides
    (:func:`hilbench.bench.profile.apply_overrides`) for a verb that starts a bench from a profile."""
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help=f"{what}{SET_HELP}")


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


def _overflow_of(bench, ep) -> Callable[[], dict[str, Any]]:
    """An in-process bench endpoint's overflow counters, read when asked (:mod:`hilbench.bench.overflow`)."""
    from hilbench.bench.overflow import endpoint_overflow

    return lambda: {"endpoint": ep.name, **endpoint_overflow(bench, ep)}


@contextlib.contextmanager
def open_cli_source(spec: str, *, baud: int | None, speed: float | None = None,
                    default_baud: int = 57_600, endpoint: str | None = None,
                    overrides: list[str] | None = None) -> Iterator:
    """A byte source for a verb (:func:`hilbench.transports.sources.open_source`), or ``bench:PROFILE``,
    which starts that bench (its profile changed by ``overrides``, ``--set``) in this process and taps
    ``endpoint`` (default: the first). Errors are one line, a source's own keeping its exit status; the source
    (and bench) close when the block ends."""
    from hilbench.transports.chunk import CaptureError
    from hilbench.transports.sources import MediumSource, open_source

    bench = None
    if overrides and not spec.startswith("bench:"):
        raise CliError(f"--set changes the profile of a bench this command starts: give bench:PROFILE, not {spec}")
    try:
        if spec.startswith("bench:"):
            from hilbench.bench import Bench
            from hilbench.bench.profile import DEFAULT_PROFILE, load_profile

            bench = Bench(load_profile(spec[len("bench:"):] or DEFAULT_PROFILE, overrides)).start()
            ep = bench.endpoint(endpoint or next(iter(bench.endpoints)))
            source = MediumSource(ep.medium, name=f"bench {bench.profile.name}: {ep.path}",
                                  protocol=ep.spec.protocol)
            source.bench_overflow = _overflow_of(bench, ep)
        else:
            source = open_source(spec, baud=baud, speed=speed, default_baud=default_baud)
            if source.bench_control is not None:  # a bench's tap (its manifest): ask its control channel
                from hilbench.bench.control import control_overflow

                address, name = source.bench_control
                source.bench_overflow = lambda: control_overflow(address, name)
    except CaptureError as exc:  # a file that is not a readable capture
        if bench is not None:
            bench.stop()
        raise CliError(str(exc)) from None
    except BaseException:
        if bench is not None:
            bench.stop()
        raise
    try:
        yield source
    finally:
        source.close()
        if bench is not None:
            bench.stop()
