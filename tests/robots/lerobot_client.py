"""LeRobot's own robot classes on a bench, in a process of their own (run by tests/robots/test_lerobot.py).

    python lerobot_client.py KIND PORT CALIBRATION_DIR [CYCLES]

KIND is koch_follower, koch_leader, so101_follower or so101_leader. The arm is connected exactly as
``lerobot-teleoperate`` does (``connect()``: handshake, calibration check, ``configure()``), then
the control loop runs at 60 Hz for CYCLES cycles (a follower is sent a target away from where it is
for the first half, then back), then ``disconnect()``. One JSON line on stdout tells what happened.

LeRobot's servo code runs unmodified. Its package imports two modules of its machine-learning stack
that this code path does not use (``lerobot.processor``: the type aliases RobotAction and
RobotObservation; ``lerobot.utils.utils``: enter_pressed and move_cursor_up, used only while
recording ranges of motion in an interactive calibration); they would pull in torch, accelerate
and datasets (several GB), so they are replaced by stand-ins with those names before LeRobot is
imported. Anything else that asks the user (``input``) fails the run instead of waiting.
"""

from __future__ import annotations

import builtins
import json
import logging
import sys
import time
import types
from pathlib import Path


def _stand_ins() -> None:
    processor = types.ModuleType("lerobot.processor")
    processor.RobotAction = dict
    processor.RobotObservation = dict
    sys.modules["lerobot.processor"] = processor
    utils = types.ModuleType("lerobot.utils.utils")
    utils.enter_pressed = lambda: False
    utils.move_cursor_up = lambda lines: None
    sys.modules["lerobot.utils.utils"] = utils


def _no_input(prompt: str = "") -> str:
    raise RuntimeError(f"LeRobot asked the user: {prompt!r}")


class _Warnings(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


def main() -> None:
    kind, port, cal_dir = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    cycles = int(sys.argv[4]) if len(sys.argv) > 4 else 60
    _stand_ins()
    builtins.input = _no_input
    warnings = _Warnings()
    logging.getLogger().addHandler(warnings)
    logging.getLogger().setLevel(logging.INFO)
    infos: list[str] = []
    logging.getLogger().addHandler(type("H", (logging.Handler,), {"emit": lambda s, r: infos.append(r.getMessage())})())
    if kind == "koch_follower":
        from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig
        arm = KochFollower(KochFollowerConfig(port=port, id="hilbench", calibration_dir=cal_dir))
    elif kind == "so101_follower":
        from lerobot.robots.so_follower import SOFollower, SOFollowerRobotConfig
        arm = SOFollower(SOFollowerRobotConfig(port=port, id="hilbench", calibration_dir=cal_dir))
    elif kind == "koch_leader":
        from lerobot.teleoperators.koch_leader import KochLeader, KochLeaderConfig
        arm = KochLeader(KochLeaderConfig(port=port, id="hilbench", calibration_dir=cal_dir))
    elif kind == "so101_leader":
        from lerobot.teleoperators.so_leader import SOLeader, SOLeaderTeleopConfig
        arm = SOLeader(SOLeaderTeleopConfig(port=port, id="hilbench", calibration_dir=cal_dir))
    else:
        raise SystemExit(f"unknown arm {kind!r}")
    follower = kind.endswith("follower")
    out: dict = {"kind": kind}
    t0 = time.monotonic()
    arm.connect()
    out["connect_s"] = round(time.monotonic() - t0, 3)
    out["calibrated"] = bool(arm.is_calibrated)
    out["models"] = {name: m.model for name, m in arm.bus.motors.items()}
    read = arm.get_observation if follower else arm.get_action
    first = read()
    out["first"] = first
    period = 1 / 60
    target = None
    if follower:
        target = {k: (v + 10.0 if v < 50 else v - 10.0) for k, v in first.items()}
    loop_t0 = time.monotonic()
    last = first
    errors = 0
    for k in range(cycles):
        start = time.monotonic()
        try:
            last = read()
            if follower:
                if k == cycles // 2:
                    out["at_target"] = last  # where the first half's target took the arm
                arm.send_action(target if k < cycles // 2 else first)
        except Exception as exc:  # noqa: BLE001 - counted and reported
            errors += 1
            out.setdefault("error", repr(exc))
        time.sleep(max(0.0, period - (time.monotonic() - start)))
    out["loop_hz"] = round(cycles / (time.monotonic() - loop_t0), 1)
    out["loop_errors"] = errors
    if follower:
        time.sleep(0.3)
        out["back"] = read()
        out["target"] = target
    out["last"] = last
    arm.disconnect()
    out["warnings"] = warnings.lines
    out["asked_to_calibrate"] = any("calibrat" in line.lower() and "mismatch" in line.lower() for line in infos)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
