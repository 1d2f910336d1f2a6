"""From a robot's own software back to its bench (issue 27): record a bundled bench's bus while the robot's
software drives it, make a profile of the recording, and compare it with the bundled one.

pypot runs poppy-ergo-jr's own configuration against ``hilbench emulate`` (the recording reads the bench's tap,
as ``hilbench record MANIFEST#bus`` does); LeRobot's SO-101 follower runs against an in-process bench whose line
is recorded. The generated profile must name the same IDs, models and baud rate, hold the values of the
registers the software read, and replay the recording with >= 95 % of the replies matching.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.capture_profile import check_profile_text
from hilbench.bench.profile import load_profile
from hilbench.transports.capture_file import CaptureWriter
from hilbench.transports.sources import open_source
from tests.helpers.recording import infer_file, recording
from tests.robots.clients import need, run_client

pytestmark = [pytest.mark.robots, pytest.mark.slow]

PROFILES = Path(__file__).resolve().parents[2] / "profiles"


def _compare(gen_text: str, draft, original: str, endpoint: str, find_model) -> None:
    """IDs, models, baud, and every read-write item the software read: the generated value (or the model's
    default where the profile leaves it out) is the bundled profile's."""
    gen = check_profile_text(gen_text)
    orig = load_profile(original)
    (gen_ep,) = gen.endpoints.values()
    assert gen_ep.baud == orig.endpoints[endpoint].baud
    want = {s.id: s for s in orig.devices if s.endpoint == endpoint}
    got = {s.id: s for s in gen.devices}
    assert set(got) == set(want)
    compared = 0
    for i, spec in want.items():
        model = find_model(spec.model)
        assert find_model(got[i].model).name == model.name, i
        for key in draft.read.get(i, []):
            f = model.field_named(key)
            if f.access != "RW" or key == "id" or key == "baud_rate" or key.startswith("goal_") or \
                    key == "torque_enable":
                continue  # (set by the software itself, or by the endpoint)
            assert got[i].init.get(key, f.default) == spec.init.get(key, f.default), (i, key)
            compared += 1
    assert compared, "the software read no read-write item"


def _verify(text: str, draft) -> None:
    with Bench(check_profile_text(text)).start() as bench:
        report = draft.replay.run(bench, speed=None)
    assert report.ratio >= 0.95, report.lines()


def test_pypot_poppy_ergo_jr_round_trip(hilbench_emulator, hilbench_run, tmp_path):
    need("poppy_ergo_jr", "poppy-ergo-jr (with pypot)")
    from hilbench.protocols.dynamixel_models import find_model

    manifest = hilbench_emulator("poppy-ergo-jr")
    path = tmp_path / "ergo.hbcap"
    source = open_source(f"{manifest['manifest_path']}#bus")  # connected to the bench's tap when it returns
    writer = CaptureWriter(path, baud=source.baud, protocol=source.protocol or "dynamixel")

    def record() -> None:
        for chunk in source:
            writer.chunk(chunk)

    thread = threading.Thread(target=record, daemon=True)
    thread.start()
    try:
        run_client("pypot_client.py", "ergo_jr", manifest["manifest_path"], "2", run=hilbench_run, bench=manifest)
    finally:
        source.close()
        thread.join(timeout=5)
        writer.close()
    draft, _, text = infer_file(path)
    _compare(text, draft, "poppy-ergo-jr", "bus", find_model)
    assert any(line.startswith("sync_read ") or line.startswith("read ") for line in draft.pattern)
    _verify(text, draft)


def test_lerobot_so101_follower_round_trip(hilbench_bench, hilbench_run, tmp_path):
    need("lerobot", "LeRobot")
    need("draccus", "LeRobot's configuration library (draccus)")
    from hilbench.protocols.feetech_models import find_model

    bench = hilbench_bench("so101-follower")
    with recording(bench.endpoint(), tmp_path / "so101.hbcap") as path:
        out = run_client("lerobot_client.py", "so101_follower", bench.endpoint().path,
                         str(PROFILES / "lerobot" / "robots/so101_follower"), "60", run=hilbench_run, bench=bench)
    assert out["calibrated"] and out["loop_errors"] == 0
    draft, _, text = infer_file(path)
    _compare(text, draft, "so101-follower", "arm", find_model)
    assert "homing_offset" in draft.read[1]  # LeRobot checks the calibration in the EEPROM
    _verify(text, draft)
