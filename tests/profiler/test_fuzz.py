"""The profiler never raises, whatever arrives: random stamps (out of order, wrapping, unmatched, huge),
binary words, report fragments and garbage, in any chunking; its JSON and trace export stay valid."""

from __future__ import annotations

import itertools
import json

from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.profiler.export_perfetto import trace_events
from hilbench.profiler.ingest import Profiler
from hilbench.profiler.settings import ProfilerSettings
from hilbench.protocols import tracestamp_binary as tsb

WRAP = 19_884_107  # µs: the board's 32-bit cycle counter at 216 MHz

stamp = st.builds(lambda n, t, e: f"{n} {t} {e}\n".encode(), st.sampled_from(["IDLE", "wheel_ctrl", "pid", "Tmr Svc"]),
                  st.one_of(st.integers(0, 5000), st.integers(WRAP - 100, WRAP + 100), st.integers(0, 10**19)),
                  st.sampled_from(["in", "out", "0", "1"]))
other = st.sampled_from([
    b"=============================================\n", b"free heap:\t\t195696\n", b"ctx switches:\t\t7\n",
    b"Task\t\tTime\t\t%%\n", b"IDLE           \t201086\t\t95%\r\n", b"output took 18779120 us\n",
    b"12:00:01 [INFO]: [recv vel] [1.000000 0.000000 0.000000]\n", b"@tsb 1\n", b"@id 3 wheel_ctrl\n",
])
words = st.builds(lambda p: tsb.encode_payloads([p]), st.integers(0, (1 << 24) - 1))
piece = st.one_of(stamp, stamp, stamp, other, words, st.binary(max_size=12))


@settings(max_examples=150, deadline=None)
@given(st.lists(piece, max_size=120), st.integers(1, 97), st.booleans())
def test_anything_in_gives_an_analysis_never_an_exception(pieces, chunk, periods):
    data = b"".join(pieces)
    settings_ = ProfilerSettings(periods={"wheel_ctrl": 1000.0, "pid": 500.0} if periods else {},
                                deadlines={"wheel_ctrl": 25.0} if periods else {})
    p = Profiler(settings_)
    for i in range(0, len(data), chunk):
        p.feed(data[i : i + chunk])
    p.finish()
    a = p.analyse()
    doc = json.loads(json.dumps(a.to_json(), allow_nan=False))
    assert doc["quality"]["bytes"] == len(data)
    events = trace_events(a)
    json.dumps(events, allow_nan=False)
    assert all(e["ph"] in "XMiCBE" for e in events)


def test_a_huge_duration_alone_still_gets_linear_bins():
    """Found by the test above: one task instance 2**48 us long (a counter read as garbage) left a range numpy
    could not split into 20 finite bins, and the whole analysis raised."""
    data = b"IDLE 0 in\n" * 6 + b"IDLE 281474996594764 out\n"
    p = Profiler(ProfilerSettings())
    p.feed(data)
    p.finish()
    hist = p.analyse().tasks["IDLE"]["histograms"]["duration_linear"]
    assert sum(hist["counts"]) == 1 and len(hist["edges"]) == 21
    assert all(a < b for a, b in itertools.pairwise(hist["edges"]))


def test_a_fixed_bin_width_never_allocates_without_bound():
    from hilbench.profiler.histogram import MAX_BINS, linear_histogram

    hist = linear_histogram([0.0, 1e18, float("nan")], width=1.0)
    assert len(hist["counts"]) == MAX_BINS and sum(hist["counts"]) == 2
