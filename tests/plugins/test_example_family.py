"""A lab's own device family as a separate pip package: tests/example_family, installed for this test run.

It adds a bus kind, a device family (a profile key, a device, a typed lookup),
an instrument (tracker and summary) and a verb through entry points only. Everything below goes through
the same paths as the built-in families: profile checks, `hilbench emulate`,
the manifest, the control channel, `hilbench monitor` (which must tell the
blinker's line from a Dynamixel bus by its bytes) and the verb table.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from hilbench import registry
from hilbench.pytest_plugin import wait_until

PACKAGE = Path(__file__).resolve().parents[1] / "example_family"
ROOT = PACKAGE.parents[1]
# What the example calls its parts: package, family, model, bus protocol, classes.
EXAMPLE_WORDS = ("hilbench_example", "example_family", "acme-blinker", "blinker")
EXAMPLE_NAMES = {"blink", "blinker", "acme-blinker", "hilbench_example"}


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``pip install`` the example package into a directory of its own (as a lab would install it)."""
    target = tmp_path_factory.mktemp("site")
    build = tmp_path_factory.mktemp("build")
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                           "--target", str(target), str(PACKAGE)],
                          capture_output=True, text=True, timeout=300, cwd=build)
    assert proc.returncode == 0, proc.stderr
    assert (target / "hilbench_example" / "family.py").exists()
    assert any(p.name.startswith("hilbench_example_family") and p.suffix == ".dist-info" for p in target.iterdir())
    return target


@pytest.fixture
def in_process(installed):
    """The example package importable in this process, its entry points read; forgotten afterwards."""
    sys.path.insert(0, str(installed))
    registry.reload()
    try:
        yield installed
    finally:
        sys.path.remove(str(installed))
        for name in [m for m in sys.modules if m.startswith("hilbench_example")]:
            del sys.modules[name]
        registry.reload()


def hb(installed: Path, *args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def _code_names(source: str) -> set[str]:
    """Identifiers and string constants of a module, docstrings left out (an example in a docstring is prose)."""
    tree = ast.parse(source)
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant) and isinstance(node.body[0].value.value, str)}
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings:
            names.add(node.value)
        elif isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, (ast.alias, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
    return names


def test_the_example_needs_nothing_outside_its_package(installed):
    """The example family is its own files and its entry points: hilbench names none of it (no table, branch or
    import of the family, its bus protocol or its package), the installed package is its own directory and
    nothing else, and its fuzz target joins the rough-input benchmark by its entry point alone (the other tests
    here drive its bus kind, family, instrument, control command and verb the same way)."""
    tracked = subprocess.run(["git", "ls-files", "hilbench"], cwd=ROOT, capture_output=True, text=True, check=True)
    files = [ROOT / name for name in tracked.stdout.split()]
    assert len(files) > 100
    naming = []
    for path in files:
        try:
            text = path.read_text()
        except (UnicodeDecodeError, FileNotFoundError):
            continue
        if any(word in text.lower() for word in EXAMPLE_WORDS):
            naming.append(str(path.relative_to(ROOT)))
        elif path.suffix == ".py":
            names = _code_names(text)
            if names & EXAMPLE_NAMES or any("blink" in n.lower() for n in names if n.isidentifier()):
                naming.append(str(path.relative_to(ROOT)))
    assert naming == []
    assert _code_names('"""protocol = \'blink\'"""\nX = "blink"\n') == {"X", "blink"}  # the check sees code only

    assert sorted(p.name for p in installed.iterdir() if p.name != "__pycache__") == [
        "hilbench_example", "hilbench_example_family-0.1.0.dist-info"]
    entry_points = (installed / "hilbench_example_family-0.1.0.dist-info" / "entry_points.txt").read_text()
    for group in ("bus_kinds", "families", "instruments", "fuzz_targets", "verbs"):
        assert f"[hilbench.{group}]" in entry_points

    env = {**os.environ, "PYTHONPATH": str(installed)}
    rough = subprocess.run([sys.executable, str(ROOT / "tools" / "rough.py"), "--only", "blink", "--size", "20000",
                            "--repeats", "1"], capture_output=True, text=True, timeout=120, env=env)
    assert rough.returncode == 0, rough.stderr
    rows = {row["name"]: row for row in map(json.loads, rough.stdout.splitlines())}
    assert rows["blink_clean"]["good"] > 1000 and rows["blink_clean"]["dropped"] == 0
    assert rows["blink_noise"]["good"] == 0 and rows["blink_noise"]["dropped"] > 0
    assert rows["blink_mutated"]["ratio"] >= 10


def test_without_the_package_hilbench_knows_no_blinker():
    assert "blinker" not in registry.families and "blink" not in registry.verbs and "blink" not in registry.bus_kinds


def test_the_package_adds_a_verb_a_family_and_an_instrument(installed):
    help_text = hb(installed, "--help").stdout
    assert "blink" in help_text and "Acme blinker" in help_text
    monitor_help = hb(installed, "monitor", "--help").stdout
    assert "--blink-pong-limit" in monitor_help and "blink" in monitor_help  # its option and protocol choice


def test_its_profile_keys_are_checked_in_one_line(installed, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text((installed / "hilbench_example" / "blinker.toml").read_text().replace("period_ms = 20",
                                                                                        "period_ms = 0"))
    proc = hb(installed, "emulate", str(bad))
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"hilbench: error: {bad}: devices[0].period_ms: expected a number 1.0..10000.0, got 0"


def test_emulate_serves_the_board_and_the_tools_work_on_it(installed, tmp_path):
    profile = installed / "hilbench_example" / "blinker.toml"
    manifest = tmp_path / "bench.json"
    env = {**os.environ, "PYTHONPATH": str(installed)}
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", str(profile), "--manifest",
                             str(manifest)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        wait_until(lambda: manifest.exists() or proc.poll() is not None, timeout=30)
        assert proc.poll() is None, proc.stderr.read()
        data = json.loads(manifest.read_text())
        (ep,) = data["endpoints"]
        (dev,) = data["devices"]
        assert (ep["protocol"], dev["model"], dev["board_id"], dev["period_ms"]) == ("blink", "acme-blinker", 7, 20)
        assert "control" in data  # the family declared a control command, so the bench serves the channel

        answered = hb(installed, "blink", ep["path"])
        assert answered.returncode == 0 and answered.stdout.strip() == "blinker 7 answered"

        summary = hb(installed, "monitor", str(manifest), "--summary", "--json", "--seconds", "1")
        assert summary.returncode == 0, summary.stderr
        report = json.loads(summary.stdout)
        assert report["protocol"] == "blink" and report["blinks"] >= 10 and report["bad_lines"] == 0

        from hilbench.bench.control import ControlClient

        assert ControlClient(data["control"]).call("blinks")["blinks"] >= 10
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        for stream in (proc.stdout, proc.stderr):
            stream.close()


def test_in_process_bench_and_monitor_tell_the_line_by_its_bytes(in_process, tmp_path):
    from hilbench.bench import Bench
    from hilbench.monitor import Monitor
    from hilbench.transports.capture_file import CaptureWriter
    from hilbench.transports.chunk import Chunk
    from hilbench.transports.sources import FileSource, MediumSource

    with Bench(in_process / "hilbench_example" / "blinker.toml") as bench:
        board = bench.device("blinky")
        assert bench.family_of("blinky").name == "blinker"
        assert bench.family("blinker").blinker() is board  # the package's own typed lookup
        assert bench.endpoint().bus_kind is registry.bus_kinds.get("blink")  # and its bus kind
        raw = tmp_path / "blink.bin"
        src = MediumSource(bench.endpoint().medium)
        chunks = []
        for chunk in src.chunks(0.05):
            if chunk is not None:
                chunks.append(chunk.data)
            if board.blinks >= 5:
                break
        src.close()
        raw.write_bytes(b"".join(chunks))
    # A raw dump says nothing of its protocol: the monitor asks every instrument and the blinker's wins.
    with Monitor(FileSource(raw)) as mon:
        mon.wait(10)
        report = mon.summary()
    assert report["protocol"] == "blink" and report["blinks"] >= 4
    # Its capture written with the protocol named is read without guessing.
    cap = tmp_path / "blink.hbcap"
    with CaptureWriter(cap, protocol="blink") as w:
        w.chunk(Chunk(1.0, "blink-board", raw.read_bytes()))
    with Monitor(FileSource(cap)) as mon:
        mon.wait(10)
        assert mon.summary()["protocol"] == "blink"
