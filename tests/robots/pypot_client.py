"""pypot's own Poppy creature on a bench, in a process of its own (run by tests/robots/test_pypot.py).

    python pypot_client.py humanoid|ergo_jr MANIFEST SECONDS

The creature's published configuration (poppy-humanoid's or poppy-ergo-jr's JSON) is used as it
is but for the port names, which point at the bench's endpoints; the creature starts as its own
software does (``PoppyHumanoid(config=...)``) without a camera (``camera="dummy"``, as on a robot
that has none) and without its web services. Its synchronisation loops then run for SECONDS
while a few joints are sent somewhere; one JSON line on stdout tells what happened, with every
warning pypot logged.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import tempfile
import time


class _Warnings(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(f"{record.name}: {record.getMessage()}")


def main() -> None:
    creature, manifest, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    warnings = _Warnings()
    logging.getLogger().addHandler(warnings)
    with open(manifest) as fh:
        ports = {e["name"]: e["path"] for e in json.load(fh)["endpoints"]}
    if creature == "humanoid":
        import poppy_humanoid
        from poppy_humanoid import PoppyHumanoid as Creature

        package, name = poppy_humanoid, "poppy_humanoid.json"
        moves = {"head_z": 30.0, "l_elbow_y": -40.0, "r_hip_x": 10.0}
    else:
        import poppy_ergo_jr
        from poppy_ergo_jr import PoppyErgoJr as Creature

        package, name = poppy_ergo_jr, "poppy_ergo_jr.json"
        moves = {"m1": 30.0, "m2": -20.0, "m6": 15.0}
    with open(os.path.join(os.path.dirname(package.__file__), "configuration", name)) as fh:
        config = json.load(fh)
    controllers = config["controllers"]
    if creature == "humanoid":
        controllers["upper_body_controller"]["port"] = ports["upper"]
        controllers["lower_body_controller"]["port"] = ports["lower"]
    else:
        controllers["my_dxl_controller"]["port"] = ports["bus"]
    path = os.path.join(tempfile.mkdtemp(), name)
    with open(path, "w") as fh:
        json.dump(config, fh)
    t0 = time.monotonic()
    robot = Creature(config=path, camera="dummy", start_background_services=False)
    out = {"start_s": round(time.monotonic() - t0, 3),
           "motors": {m.name: {"id": m.id, "model": m.model} for m in robot.motors}}
    time.sleep(0.5)
    out["before"] = {m.name: m.present_position for m in robot.motors}
    for joint, angle in moves.items():
        motor = getattr(robot, joint)
        motor.compliant = False
        motor.goal_position = angle
    time.sleep(max(1.0, seconds))
    out["goals"] = moves
    out["after"] = {joint: getattr(robot, joint).present_position for joint in moves}
    out["temperatures"] = {m.name: m.present_temperature for m in robot.motors}
    robot.close()
    out["warnings"] = warnings.lines
    print(json.dumps(out))


if __name__ == "__main__":
    main()
