"""The Acme blinker board as a device on a hilbench serial medium."""

from __future__ import annotations

from hilbench_example.protocol import BLINK, OK, PING, PONG, RATE, LineDecoder, build


class Blinker:
    """Answers PING and RATE; sends BLINK every ``period_ms`` while started."""

    def __init__(self, name: str, board_id: int, period_ms: float) -> None:
        self.name = name
        self.board_id = board_id
        self.period_ms = period_ms
        self.blinks = 0
        self.decoder = LineDecoder()
        self.port = None
        self._running = False

    def attach(self, medium) -> None:
        self.port = medium.add_device(self)

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        for msg in self.decoder.feed(data):
            if msg.word == PING:
                self.port.transmit(build(PONG, self.board_id), t=t)
            elif msg.word == RATE and msg.value:
                self.period_ms = float(msg.value)
                self.port.transmit(build(OK), t=t)

    def start(self, t: float) -> None:
        self._running = True
        self.port.call_at(t + self.period_ms / 1000, lambda: self._blink(t + self.period_ms / 1000))

    def _blink(self, t: float) -> None:
        if not self._running:
            return
        self.blinks += 1
        self.port.transmit(build(BLINK, self.blinks), t=t)
        nxt = t + self.period_ms / 1000
        self.port.call_at(nxt, lambda: self._blink(nxt))

    def stop(self) -> None:
        self._running = False
