"""The rough-input registry: every reader of outside bytes is registered, survives noise and damage, and the
fuzz script and the rough-input benchmark drive them all."""

from __future__ import annotations

import json
import random
import subprocess
import sys

import pytest

from hilbench.decoders import mutate, run, targets
from tests.conftest import REPO

BUILT_IN = {"dynamixel", "dynamixel1", "vel2d", "tracestamp-text", "tracestamp-binary", "tracestamp-stream",
            "capture", "monitor-dynamixel", "profiler", "rplidar", "sick-lms200", "scip2", "slcan",
            "socketcand-client", "socketcand-server", "monitor-udp"}


def test_every_built_in_reader_is_registered():
    found = {t.name: t for t in targets()}
    assert set(found) >= BUILT_IN
    assert {found[n].kind for n in ("monitor-dynamixel", "monitor-udp", "profiler")} == {"instrument"}
    assert all(t.line_rate > 0 and t.line for t in found.values())


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_clean_traffic_decodes_and_garbage_is_survived(name):
    target = next(t for t in targets() if t.name == name)
    rng = random.Random(3)
    clean = target.sample(rng, 20_000)
    whole = run(target.make(), clean)
    assert whole.good() > 0 and whole.dropped() == 0
    # any split of the same bytes decodes the same
    assert run(target.make(), clean, lambda: rng.randrange(1, 300)).good() == whole.good()
    for data in (target.noise(rng, 20_000), mutate(rng, clean, rate=0.02), clean[: len(clean) // 3], b"", b"\xff"):
        reader = run(target.make(), data, lambda: rng.randrange(1, 5000))
        assert reader.good() >= 0 and reader.dropped() >= 0


def test_the_fuzz_script_runs_every_target():
    proc = subprocess.run([sys.executable, str(REPO / "tools/fuzz.py"), "--engine", "random", "--inputs", "30",
                           "--measure", "3", "--size", "65536"], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout.strip().splitlines()[-1])
    assert doc["exceptions"] == 0 and set(doc["targets"]) >= BUILT_IN
    assert doc["inputs"] == 30 * len(doc["targets"])
    assert all(r["noise_ratio"] > 0 and "items_lost_per_damaged_byte" in r for r in doc["targets"].values())
