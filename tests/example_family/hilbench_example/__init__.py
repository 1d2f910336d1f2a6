"""hilbench-example-family: the Acme blinker board, a toy device family added as a plug-in.

The board speaks lines of ASCII on a serial port: ``PING`` is answered with
``PONG <id>``, ``RATE <ms>`` sets the blink period (``OK``), and the board
sends ``BLINK <n>`` every period on its own.
"""

from hilbench_example.protocol import BLINK, PING, PONG, LineDecoder, build

__all__ = ["BLINK", "PING", "PONG", "LineDecoder", "build"]
