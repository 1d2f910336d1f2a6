"""Start-up: a verb imports the plug-ins it needs and no other family's code (issue 24).

Not timed (a loaded CI machine says nothing about start-up); what each command imported is what would make
it slow: ``tools/bench_startup.py`` measures the times. The modules are read from ``sys.modules`` when the
command ends, not from ``python -X importtime``, which does not report modules imported through
``importlib.import_module`` (every entry point, and the packages above it).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CAPTURE = ROOT / "tests/data/dynamixel/wolfgang_trace.bin"

#: Runs the command line in this process and writes the names of the modules imported when it ends (also
#: when it is interrupted).
RUN = r"""
import atexit, json, runpy, sys
out = sys.argv[1]
atexit.register(lambda: open(out, "w").write(json.dumps(sorted(sys.modules))))
sys.argv = ["hilbench", *sys.argv[2:]]
try:
    runpy.run_module("hilbench.cli", run_name="__main__", alter_sys=True)
except KeyboardInterrupt:
    pass
"""


def imported(tmp_path: Path, *args: str, first_line: bool = False) -> set[str]:
    """The modules ``hilbench ARGS`` imported; with ``first_line``, until it printed its first line."""
    out = tmp_path / "modules.json"
    argv = [sys.executable, "-c", RUN, str(out), *args]
    if first_line:
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
        try:
            assert proc.stdout.readline(), proc.stderr.read().decode()
        finally:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)
    else:
        proc = subprocess.run(argv, capture_output=True, timeout=120, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr.decode()
    return set(json.loads(out.read_text()))


def under(modules: set[str], *packages: str) -> set[str]:
    return {m for m in modules if any(m == p or m.startswith(p + ".") for p in packages)}


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("startup") / "dynamixel_small.bin"
    path.write_bytes(CAPTURE.read_bytes()[:2000])  # a raw dump: the monitor tells its protocol from the bytes
    return path


def test_monitor_of_a_dynamixel_capture_loads_no_other_instrument_code(tmp_path, small_capture):
    modules = imported(tmp_path, "monitor", str(small_capture), "--summary")
    assert "hilbench.monitor.dynamixel.tracker" in modules  # (the check sees what the command imports)
    # Every instrument is asked whether the bytes are its protocol, so each plug-in module is loaded (light:
    # the instrument class alone); none of their trackers, decoders, dialects or summaries.
    light = {"hilbench.monitor.can", "hilbench.monitor.udp", "hilbench.monitor.scanners", "hilbench.monitor.dynamixel1",
             "hilbench.monitor.feetech", "hilbench.profiler", "hilbench.profiler.instrument", "hilbench.profiler.stm32_rover",
             # each scanner family's instrument module (its tracker is *_tracker.py, imported when one is made)
             "hilbench.monitor.scanners.rplidar", "hilbench.monitor.scanners.scip2",
             "hilbench.monitor.scanners.sick_lms200"}
    heavy = under(modules, "hilbench.monitor.can", "hilbench.monitor.udp", "hilbench.monitor.scanners",
                  "hilbench.monitor.dynamixel1", "hilbench.monitor.feetech", "hilbench.profiler") - light
    assert not heavy, f"another instrument's code: {sorted(heavy)}"
    assert not under(modules, "hilbench.fakes", "hilbench.families", "hilbench.dashboard", "hilbench.clients",
                     "hilbench.bench.control", "hilbench.bench.server", "hilbench.servers", "dpkt", "cantools",
                     "canopen", "can")
    # the bench package's profile loader and the monitor's frame come with the names, not with the packages;
    # numpy comes with the first large buffer or damaged stretch, not with reading a capture's first bytes
    assert not modules & {"hilbench.bench.bench", "hilbench.bench.profile", "hilbench.bench.world", "numpy"}
    # asking every instrument about the bytes runs their decoders, not their construct layouts
    assert "construct" not in modules


@pytest.mark.parametrize("package", ["hilbench.bench", "hilbench.monitor"])
def test_a_package_s_names_come_from_their_modules_when_used(package):
    """``hilbench.bench`` and ``hilbench.monitor`` export their classes lazily (:mod:`hilbench.exports`):
    every name listed resolves, to the object its module defines, and each one listed is exported."""
    code = (f"import sys, {package} as p; before = set(sys.modules); "
            "names = {n: getattr(p, n) for n in p.__all__}; "
            "print(sorted(p._HOMES) == sorted(p.__all__), all(v.__module__.startswith(p.__name__ + '.') "
            "for v in names.values() if hasattr(v, '__module__')), len(set(sys.modules) - before) > 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert out.stdout.split() == ["True", "True", "True"], out.stderr


def test_help_loads_no_verb_s_dependencies(tmp_path):
    modules = imported(tmp_path, "--help")
    assert "hilbench.cli.monitor" in modules and "hilbench.cli.emulate" in modules  # every verb module, light
    assert not under(modules, "construct", "numpy", "rich", "dpkt", "hilbench.bench", "hilbench.monitor",
                     "hilbench.families", "hilbench.fakes", "hilbench.dashboard", "hilbench.profiler")


def test_a_verb_loads_its_own_module_alone(tmp_path):
    modules = imported(tmp_path, "dxl", "--help")
    assert not under(modules, "hilbench.cli.monitor", "hilbench.cli.emulate", "hilbench.cli.demo", "hilbench.cli.can",
                     "hilbench.cli.lidar", "hilbench.bench", "hilbench.monitor", "numpy", "dpkt")


def test_emulate_arm_loads_no_other_family_s_fakes(tmp_path):
    modules = imported(tmp_path, "emulate", "arm", first_line=True)
    assert "hilbench.fakes.dynamixel.servo" in modules  # the arm's servos are running
    others = {m for m in under(modules, "hilbench.fakes") if not m.startswith("hilbench.fakes.dynamixel")}
    kits = {"hilbench.fakes", "hilbench.fakes.control_table_servo", "hilbench.fakes.table_servo",
            "hilbench.fakes.servo_bus", "hilbench.fakes.motion", "hilbench.fakes.protocol1_bus",  # servo kits
            # every bench's world and its geometry
            "hilbench.fakes.world", "hilbench.fakes.scene"}
    assert not others - kits, f"other families' fakes: {sorted(others - kits)}"
    assert not under(modules, "hilbench.monitor", "hilbench.dashboard", "hilbench.profiler", "dpkt")
    assert "numpy" not in modules  # a world without walls or bodies has no arrays
    assert "construct" not in modules  # the servos and the tap run on the protocols' fast paths


def test_record_help_loads_the_instrument_plug_ins_not_their_trackers(tmp_path):
    modules = imported(tmp_path, "record", "--help")
    assert "hilbench.monitor.can" in modules  # its options are listed: the plug-in is loaded
    trackers = {m for m in under(modules, "hilbench.monitor", "hilbench.profiler")
                if m.rsplit(".", 1)[-1] in ("tracker", "summary", "decoders", "dialect", "analysis", "ingest")}
    assert not trackers, sorted(trackers)
    assert not under(modules, "dpkt", "cantools", "canopen", "hilbench.dashboard", "hilbench.fakes")
