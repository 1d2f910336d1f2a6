"""The fuzz targets (:mod:`hilbench.fuzzing`): every reader of outside bytes and every server is registered and
survives noise and damage, and the fuzz script and the rough-input benchmark drive them all."""

from __future__ import annotations

import json
import random
import subprocess
import sys

import pytest

from hilbench import registry
from hilbench.bench.control_targets import ControlTarget, merge_profiles
from hilbench.fuzzing import mutate, run, targets
from tests.conftest import REPO

BUILT_IN = {"dynamixel", "dynamixel1", "vel2d", "tracestamp-text", "tracestamp-binary", "tracestamp-stream",
            "capture", "monitor-dynamixel", "profiler", "rplidar", "sick-lms200", "scip2", "slcan",
            "socketcand-client", "socketcand-server", "monitor-udp"}
#: Every built-in family that takes control commands brings its control target (``server-control-<family>``),
#: but FreeRTPS: its nodes bind their domain's fixed UDP ports, which a fuzz run must not depend on.
CONTROL_FAMILIES = {"canopen", "micro-ros-agent", "rplidar", "scip2", "sick-lms200", "stm32-rover"}
SERVERS = {"server-control", "server-scip", "server-socketcand", "server-rfc2217", "server-xrce", "server-rtps",
           *(f"server-control-{family}" for family in CONTROL_FAMILIES)}


def test_every_built_in_reader_is_registered():
    found = {t.name: t for t in targets()}
    assert set(found) >= BUILT_IN | SERVERS
    assert {found[n].kind for n in SERVERS} == {"server"} and all(found[n].max_input for n in SERVERS)
    assert {found[n].kind for n in ("monitor-dynamixel", "monitor-udp", "profiler")} == {"instrument"}
    assert all(t.line_rate > 0 and t.line for t in found.values())


def test_every_family_that_takes_commands_brings_its_control_target():
    takes = {n for n, f in registry.families.items() if f.control_commands and registry.families.origin(n) == "hilbench"}
    assert takes - CONTROL_FAMILIES == {"freertps"}
    parts = {t.name: t for t in targets() if isinstance(t, ControlTarget)}
    assert set(parts) == {f"server-control-{family}" for family in CONTROL_FAMILIES}
    for target in parts.values():  # a family's requests name its own devices (or none)
        names = {d["name"] for d in target.profile["devices"]}
        asked = {target.request(random.Random(seed)).get("device") for seed in range(50)} - {None}
        assert asked and asked <= names, target.name


def test_server_control_puts_every_family_on_one_bench():
    """The family-free control target: one bench with every family's devices, sent every family's requests."""
    parts = [t for t in targets() if isinstance(t, ControlTarget)]
    merged = merge_profiles([t.profile for t in parts], "all")
    assert {d["name"] for d in merged["devices"]} == {d["name"] for t in parts for d in t.profile["devices"]}
    assert len(merged["scene"]["walls"]) == 1  # two scanners' identical room, once
    session = next(t for t in targets() if t.name == "server-control").sample(random.Random(1), 20_000)
    asked = {json.loads(line).get("device") for line in session.splitlines()}
    assert asked >= {d["name"] for d in merged["devices"]}
    with pytest.raises(ValueError, match="endpoint 'x'"):
        merge_profiles([{"endpoints": {"x": {}}}, {"endpoints": {"x": {}}}], "clash")


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


def test_the_fuzz_script_runs_every_decoder():
    decoders = [t.name for t in targets() if t.kind != "server"]
    proc = subprocess.run([sys.executable, str(REPO / "tools/fuzz.py"), "--engine", "random", "--inputs", "30",
                           "--measure", "3", "--size", "65536", "--targets", ",".join(decoders)],
                          capture_output=True, text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout.strip().splitlines()[-1])
    assert doc["exceptions"] == 0 and set(doc["targets"]) >= BUILT_IN
    assert doc["inputs"] == 30 * len(doc["targets"])
    assert all(r["noise_ratio"] > 0 and "items_lost_per_damaged_byte" in r for r in doc["targets"].values())


@pytest.mark.parametrize("name", sorted(SERVERS))
def test_a_clean_session_is_served_and_a_damaged_one_survived(name):
    target = next(t for t in targets() if t.name == name)
    rng = random.Random(5)
    clean = target.sample(rng, 1500)
    assert run(target.make(), clean, lambda: rng.randrange(1, 300)).good() > 0
    run(target.make(), b"")
    run(target.make(), clean[: len(clean) // 3])


@pytest.fixture(scope="module")
def server_fuzz(tmp_path_factory):
    """tools/fuzz.py over every server target, 300 inputs each (about 4 s; the script's own runs go
    further): its figure lines by name."""
    out = tmp_path_factory.mktemp("fuzz") / "fuzz.json"
    proc = subprocess.run([sys.executable, str(REPO / "tools/fuzz.py"), "--engine", "random", "--inputs", "300",
                           "--targets", "servers", "--json", str(out)],
                          capture_output=True, text=True, timeout=600, cwd=REPO)
    figures = {}
    for line in proc.stdout.splitlines():
        if line.startswith('{"name"'):
            figure = json.loads(line)
            figures[figure["name"]] = figure
    return proc, figures, json.loads(out.read_text())


@pytest.mark.parametrize("name", sorted(SERVERS))
def test_the_fuzz_script_drives_each_server_without_a_traceback(server_fuzz, name):
    proc, figures, doc = server_fuzz
    assert set(doc["targets"]) == SERVERS, proc.stderr[-3000:]
    inputs, tracebacks = figures[f"fuzz_{name}_inputs"], figures[f"fuzz_{name}_tracebacks"]
    assert inputs["value"] == 300 and inputs["unit"] == "inputs" and set(inputs) >= {"reference", "ratio"}
    assert tracebacks["reference"] == 300
    assert tracebacks["value"] == 0, doc["targets"][name]["first_exception"]
