"""Profiles: the bundled ones load; bad ones fail with one line naming file, key and expectation."""

from __future__ import annotations

import subprocess
import sys

import pytest

from hilbench.bench.profile import DEFAULT_PROFILE, ProfileError, bundled_profiles, load_profile

GOOD = """
schema = 1
[endpoints.bus]
baud = 1_000_000
[[devices]]
model = "XM430-W350"
ids = [1, 2]
"""


def write(tmp_path, text: str):
    p = tmp_path / "bench.toml"
    p.write_text(text)
    return p


def test_bundled_profiles_load():
    names = bundled_profiles()
    assert {"wolfgang", "arm"} <= set(names)
    assert DEFAULT_PROFILE in names
    wolfgang = load_profile("wolfgang")
    servos = {d.id: (d.model, d.firmware) for d in wolfgang.devices if d.model.startswith("MX")}
    assert set(servos) == set(range(1, 21))
    assert {i for i, (m, _) in servos.items() if m == "MX-64(2.0)"} == {1, 2, 3, 4, 5, 6, 19, 20}
    assert {i for i, (_, fw) in servos.items() if fw == 42} == {11, 16, 18}
    assert wolfgang.endpoints["dxl"].baud == 2_000_000
    foot = next(d for d in wolfgang.devices if d.id == 101)
    assert foot.model == "Wolfgang Foot" and foot.faults == {"vanished": True}


def test_good_profile(tmp_path):
    prof = load_profile(write(tmp_path, GOOD))
    assert [d.id for d in prof.devices] == [1, 2]
    assert prof.devices[0].endpoint == "bus"  # the only endpoint is the default


@pytest.mark.parametrize(
    "edit,key,expected",
    [
        (GOOD.replace('"XM430-W350"', '"XM999"'), "devices[0].model", "unknown model 'XM999'"),
        (GOOD + '[[devices]]\nmodel = "MX-64"\nid = 2\n', "devices[1].id",
         "ID 2 is taken on endpoint 'bus' by devices[0] ('bus.2')"),
        (GOOD.replace("1_000_000", "1_500_000"), "endpoints.bus.baud", "expected a Dynamixel baud rate"),
        (GOOD.replace("schema = 1", "schema = 7"), "schema", "expected 1, got 7"),
        (GOOD.replace("ids = [1, 2]", "ids = [1, 300]"), "devices[0].id", "expected an integer 0..252, got 300"),
        (GOOD + "init = { led = 7 }\n", "devices[0].init.led", "expected 0..1, got 7"),
        (GOOD + "init = { warp_drive = 1 }\n", "devices[0].init.warp_drive", "no such control-table item"),
        (GOOD + "faults = { drop_rate = 2.0 }\n", "devices[0].faults.drop_rate", "expected a number 0..1"),
        (GOOD + "colour = 'red'\n", "devices[0].colour", "unknown key"),
        (GOOD.replace("[endpoints.bus]", "[endpoints.bus]\npaced = 'yes'"), "endpoints.bus.paced",
         "expected true or false"),
        ("schema = 1\n", "endpoints", "expected at least one"),
        ("schema = 1\n[endpoints", "", "not valid TOML"),
    ],
)
def test_bad_profiles_name_file_key_and_expectation(tmp_path, edit, key, expected):
    path = write(tmp_path, edit)
    with pytest.raises(ProfileError) as exc:
        load_profile(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}: {key}")
    assert expected in msg


def test_cli_reports_a_bad_profile_in_one_line_and_fails(tmp_path):
    path = write(tmp_path, GOOD.replace('"XM430-W350"', '"XM999"'))
    proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "emulate", str(path)],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"hilbench: error: {path}: devices[0].model: unknown model 'XM999'")


def test_unknown_profile_name():
    with pytest.raises(ProfileError, match="no such profile"):
        load_profile("no-such-bench")
