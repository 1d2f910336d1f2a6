"""The bench clock (DESIGN §12): one time base for media, ports and devices, and nobody reads another."""

from __future__ import annotations

import io
import time
import tokenize
from pathlib import Path

import pytest

import hilbench
from hilbench.transports.can_medium import CanMedium
from hilbench.transports.clock import WALL, VirtualClock, WallClock
from hilbench.transports.datagram_medium import DatagramMedium
from hilbench.transports.serial_medium import SerialMedium

PACKAGE = Path(hilbench.__file__).parent
#: Where world time is read: media, ports, fakes, the bench and the families.
SCANNED = ("transports", "fakes", "bench", "families")
#: Modules that read the real clock by nature, and why. Anything else marks each such line with a comment
#: saying ``wall-clock`` (a service timer: a client's idle timeout, an EMFILE pause, a flush retry).
ALLOWED = {
    "transports/clock.py": "the clock itself, and the real waits of a wall-clock medium's thread",
    "transports/readiness.py": "real waits (ppoll timeouts)",
    "transports/listener.py": "the EMFILE pause of a listening socket",
    "transports/heap.py": "how often memory is given back to the system",
    "transports/recording_file.py": "how often a recording is flushed to disk",
    "transports/capture_file.py": "a capture header's mapping of its clock to Unix time",
    "transports/can_log.py": "the Unix time of live sources stamped with the monotonic clock",
    "transports/pcap.py": "the Unix time of live sources stamped with the monotonic clock",
    "transports/serial_tap.py": "a tap between real ports (real hardware, real time)",
    "transports/sources/": "sources read programs and devices outside the bench, in real time",
    "transports/tap_server.py": "its clients' stall and eviction timers",
    "transports/udp_relay.py": "its clients' idle timeouts",
    "bench/lockstep.py": "the lockstep's real-time settle waits and stall watchdog, and the clock page's epoch",
    "bench/control.py": "the control channel's connection timeouts and command waits",
    "bench/capture_replay.py": "--verify replays a capture through the bench's ptys and sockets as a client "
                               "does, in real time",
    "families/scip2_targets.py": "a fuzz target's harness, not a bench",
}
CLOCK_NAMES = {"monotonic", "monotonic_ns", "time", "time_ns"}


def clock_reads(source: str) -> list[tuple[int, str]]:
    """(line number, line) of every ``time.monotonic``/``time.time`` (and ``_ns``) in code, not in strings or
    comments, whose line does not say ``wall-clock`` in its comment."""
    toks = list(tokenize.generate_tokens(io.StringIO(source).readline))
    lines = source.splitlines()
    found = []
    for a, b, c in zip(toks, toks[1:], toks[2:], strict=False):
        if a.type == tokenize.NAME and a.string == "time" and b.string == "." and c.string in CLOCK_NAMES:
            line = lines[a.start[0] - 1]
            comment = line.partition("#")[2]
            if "wall-clock" not in comment:
                found.append((a.start[0], line.strip()))
        if a.type == tokenize.NAME and a.string == "from" and b.string == "time" and c.string == "import":
            found.append((a.start[0], lines[a.start[0] - 1].strip()))
    return found


def test_the_lint_finds_what_it_must():
    src = "import time\nt = time.monotonic()\nu = time.time_ns()  # wall-clock: a timer\ns = 'time.time()'\n"
    assert clock_reads(src) == [(2, "t = time.monotonic()")]


def test_media_fakes_and_bench_read_only_their_clock():
    offenders = []
    for part in SCANNED:
        for path in sorted((PACKAGE / part).rglob("*.py")):
            rel = path.relative_to(PACKAGE).as_posix()
            if any(rel == key or (key.endswith("/") and rel.startswith(key)) for key in ALLOWED):
                continue
            offenders += [f"hilbench/{rel}:{n}: {line}" for n, line in clock_reads(path.read_text())]
    assert not offenders, ("read the bench clock (medium.clock.now(), port.now()) or mark a service timer "
                           "'# wall-clock: why':\n" + "\n".join(offenders))


def test_the_allow_list_names_existing_modules():
    for key in ALLOWED:
        assert (PACKAGE / key).exists(), key


def test_wall_clock_now_is_the_monotonic_builtin():
    # The paced line's hot path reads clock.now: on the wall clock that is time.monotonic itself, no wrapper.
    assert WallClock.now is time.monotonic
    assert WALL.now is time.monotonic
    assert abs(WALL.wall(WALL.now()) - time.time()) < 0.05
    assert not WALL.virtual


@pytest.mark.parametrize("cls", [SerialMedium, CanMedium, DatagramMedium])
def test_media_take_the_clock_and_hand_it_to_devices(cls):
    clock = VirtualClock(epoch=1_700_000_000.0)
    medium = cls("m", 115200, clock=clock)
    try:
        assert medium.clock is clock

        class Dev:
            name = "dev"

        port = medium.add_device(Dev())
        assert port.clock is clock
        assert port.now() == clock.now() == VirtualClock.ORIGIN
        assert cls("w", 115200).clock is WALL  # the default: the wall clock
    finally:
        medium.close()


def test_virtual_clock_maps_to_unix_time_from_its_epoch():
    clock = VirtualClock(epoch=1_700_000_000.0)
    assert clock.virtual
    assert clock.now() == 1000.0  # "booted 1000 s ago": clients that take 0 for never still work
    assert clock.wall(clock.now()) == 1_700_000_000.0
    assert clock.wall(1012.5) == 1_700_000_012.5
    assert CanMedium("bus", clock=clock).wall(1001.0) == 1_700_000_001.0
    with pytest.raises(RuntimeError, match="no VirtualLoop"):
        clock.run_for(1.0)
