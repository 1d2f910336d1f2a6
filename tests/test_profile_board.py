"""Board profiles: the bundled rover profiles load; bad board settings fail in one line naming file and key."""

from __future__ import annotations

import pytest

from hilbench.bench.profile import ProfileError, load_profile
from hilbench.families.stm32_rover import BoardSpec, board_config

GOOD = """
schema = 1
[endpoints.rover]
protocol = "vel2d"
baud = 115200
[[devices]]
model = "stm32f767-rover"
preset = "freertos-1000"
"""


def write(tmp_path, text: str):
    p = tmp_path / "rover.toml"
    p.write_text(text)
    return p


def test_bundled_rover_profiles():
    for name, (kind, output, baud) in {"mecarover": ("pty", "v3", 115_200),
                                       "mecarover-thesis": ("pty", "v1", 1_152_000),
                                       "mecarover-udp": ("udp", "binary", 1_152_000)}.items():
        prof = load_profile(name)
        (board,) = prof.devices_of("stm32-rover", BoardSpec)
        ep = prof.endpoints[board.endpoint]
        assert (ep.type, ep.protocol, board.output, ep.baud) == (kind, "vel2d", output, baud)
        assert prof.devices_of("dynamixel") == [] and board.model == "stm32f767-rover"


def test_board_defaults_and_task_overrides(tmp_path):
    prof = load_profile(write(tmp_path, GOOD + 'tasks = { wheel_ctrl = { mean_us = 12.5, sd_us = 1.0 } }\n'))
    (board,) = prof.devices
    assert isinstance(board, BoardSpec) and board.name == "rover" and board.output == "v1" and board.caches
    cfg = board_config(board, 115_200)
    t = cfg.preset.task("wheel_ctrl").timing
    assert (t.mean_us, t.sd_us) == (12.5, 1.0) and cfg.preset.tick_hz == 1000


@pytest.mark.parametrize(
    "edit,key,expected",
    [
        (GOOD.replace('"freertos-1000"', '"freertos-42"'), "devices[0].preset", "expected one of freertos-50-30"),
        (GOOD + 'output = "v9"\n', "devices[0].output", "expected one of v1, v2, v3, binary"),
        (GOOD + "tasks = { warp = { mean_us = 1.0 } }\n", "devices[0].tasks.warp", "no such task or function"),
        (GOOD + 'tasks = { IDLE = { mean = 1.0 } }\n', "devices[0].tasks.IDLE.mean", "unknown key"),
        (GOOD + "faults = { drop_rate = 3 }\n", "devices[0].faults.drop_rate", "expected a number 0..1"),
        (GOOD.replace("115200", "50"), "endpoints.rover.baud", "expected an integer 1200..12500000"),
        (GOOD.replace('protocol = "vel2d"', 'protocol = "vel2d"\nport = 9000'), "endpoints.rover.port",
         '"udp"'),
        (GOOD.replace('protocol = "vel2d"', 'protocol = "vel2d"\ntype = "udp"\npeer = "nowhere"'),
         "endpoints.rover.peer", 'expected "host:port"'),
        (GOOD + '[[devices]]\nmodel = "stm32f767-rover"\nname = "two"\n', "devices[1].endpoint",
         "already has a board"),
        (GOOD.replace('protocol = "vel2d"', 'protocol = "dynamixel"').replace("115200", "57600"),
         "devices[0].endpoint", 'needs an endpoint with protocol = "vel2d"'),
    ],
)
def test_bad_board_profiles(tmp_path, edit, key, expected):
    path = write(tmp_path, edit)
    with pytest.raises(ProfileError) as exc:
        load_profile(path)
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"{path}: {key}") and expected in msg
