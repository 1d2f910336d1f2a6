"""Keyboard teleoperation like ROS's ``teleop_twist_keyboard``, sending Vel2d frames instead of Twists.

The key bindings, speed factors and defaults (speed 0.5 m/s, turn 1.0 rad/s)
are those of teleop_twist_keyboard; each key press sends one frame, as the
ROS node publishes one Twist per key and ``vel2d_bridge`` turns each into a
frame. ``t``/``b`` (linear.z) have no field in a Vel2d frame and only count as
a key press. :class:`Teleop` is the logic (testable without a terminal);
:func:`run` drives it from a terminal.
"""

from __future__ import annotations

import contextlib
import os
import sys
import termios
import time
import tty
from dataclasses import dataclass

from hilbench.protocols import vel2d
from hilbench.protocols.tracestamp_stream import StreamDecoder
from hilbench.transports.host_connection import HostConnection
from hilbench.transports.readiness import readable

HELP = """\
Reading from the keyboard and sending Vel2d frames!
---------------------------
Moving around:
   u    i    o
   j    k    l
   m    ,    .

For Holonomic mode (strafing), hold down the shift key:
---------------------------
   U    I    O
   J    K    L
   M    <    >

anything else : stop

q/z : increase/decrease max speeds by 10%
w/x : increase/decrease only linear speed by 10%
e/c : increase/decrease only angular speed by 10%

CTRL-C to quit
"""

#: key: (x, y, z, th) directions, as teleop_twist_keyboard's moveBindings.
MOVE_BINDINGS: dict[str, tuple[int, int, int, int]] = {
    "i": (1, 0, 0, 0), "o": (1, 0, 0, -1), "j": (0, 0, 0, 1), "l": (0, 0, 0, -1), "u": (1, 0, 0, 1),
    ",": (-1, 0, 0, 0), ".": (-1, 0, 0, 1), "m": (-1, 0, 0, -1), "O": (1, -1, 0, 0), "I": (1, 0, 0, 0),
    "J": (0, 1, 0, 0), "L": (0, -1, 0, 0), "U": (1, 1, 0, 0), "<": (-1, 0, 0, 0), ">": (-1, -1, 0, 0),
    "M": (-1, 1, 0, 0), "t": (0, 0, 1, 0), "b": (0, 0, -1, 0),
}
#: key: (linear factor, angular factor), as speedBindings.
SPEED_BINDINGS: dict[str, tuple[float, float]] = {
    "q": (1.1, 1.1), "z": (0.9, 0.9), "w": (1.1, 1.0), "x": (0.9, 1.0), "e": (1.0, 1.1), "c": (1.0, 0.9),
}


@dataclass
class Teleop:
    """The state machine: feed keys, get the Twist (x, y, angular z) to send."""

    speed: float = 0.5
    turn: float = 1.0
    x: int = 0
    y: int = 0
    th: int = 0

    def key(self, k: str) -> tuple[float, float, float]:
        """Apply one key; returns (linear.x, linear.y, angular.z) to send."""
        if k in MOVE_BINDINGS:
            self.x, self.y, _, self.th = MOVE_BINDINGS[k]
        elif k in SPEED_BINDINGS:
            fs, ft = SPEED_BINDINGS[k]
            self.speed *= fs
            self.turn *= ft
        else:
            self.x = self.y = self.th = 0
        return self.twist()

    def twist(self) -> tuple[float, float, float]:
        return self.x * self.speed, self.y * self.speed, self.th * self.turn

    def status(self) -> str:
        return f"currently:\tspeed {self.speed:.6g}\tturn {self.turn:.6g}"


def run(port: str, baud: int = 115_200, speed: float = 0.5, turn: float = 1.0, repeat_rate: float = 0.0,
        out=None) -> int:
    """Drive a board from this terminal until Ctrl-C; returns the number of frames sent."""
    out = out or sys.stdout
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        raise OSError("teleop needs a terminal: stdin is not a tty")
    connection = HostConnection.open(port, baud)
    state = Teleop(speed, turn)
    decoder = StreamDecoder()
    sent = 0
    last_log = ""
    saved = termios.tcgetattr(fd)

    def send(reason: str) -> None:
        nonlocal sent
        x, y, z = state.twist()
        connection.send(vel2d.build(x, y, z))
        sent += 1
        line = f"\r\x1b[Ksent x={x:+.3f} y={y:+.3f} z={z:+.3f} ({reason}, {sent} frames)"
        if last_log:
            line += f"  board: {last_log[:60]}"
        out.write(line)
        out.flush()

    try:
        tty.setraw(fd)
        out.write(HELP.replace("\n", "\r\n") + "\r\n" + state.status().replace("\t", "  ") + "\r\n")
        out.flush()
        connection.register()
        next_repeat = time.monotonic() + (1 / repeat_rate if repeat_rate > 0 else 1e9)
        while True:
            timeout = max(0.0, min(0.05, next_repeat - time.monotonic()))
            ready = readable([fd, connection.fileno()], timeout)
            if connection.fileno() in ready:
                for item in decoder.feed(connection.read()):
                    if type(item).__name__ == "LogMessage":
                        last_log = f"[{item.level}] {item.message}"
            if fd in ready:
                keys = os.read(fd, 64).decode("latin-1")
                for k in keys:
                    if k == "\x03":
                        raise KeyboardInterrupt
                    before = (state.speed, state.turn)
                    state.key(k)
                    if (state.speed, state.turn) != before:
                        out.write("\r\x1b[K" + state.status().replace("\t", "  ") + "\r\n")
                    send(f"key {k!r}")
            if repeat_rate > 0 and time.monotonic() >= next_repeat:
                send("repeat")
                next_repeat += 1 / repeat_rate
    except KeyboardInterrupt:
        pass
    finally:
        with contextlib.suppress(Exception):
            state.x = state.y = state.th = 0
            connection.send(vel2d.build(0.0, 0.0, 0.0))  # stop the robot on exit, as the ROS node does
            sent += 1
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)
        connection.close()
        out.write(f"\nteleop: {sent} frames sent\n")
        out.flush()
    return sent
