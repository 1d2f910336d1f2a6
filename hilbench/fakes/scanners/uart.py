"""A device's transmit line paced at its own baud rate, on a medium that delivers at once.

A scanner's UART is full duplex: what it sends does not wait for the host's
bytes, so its endpoint's medium runs unpaced and the device paces itself, as
the STM32 board does. :class:`UartTx` keeps the line's busy-until time, cuts
long writes into chunks of about a millisecond of wire time, and hands each
chunk to the medium stamped with the time its last bit leaves the device
(:meth:`DevicePort.transmit <hilbench.transports.medium.DevicePort.transmit>` with ``t``). Nothing sleeps: every chunk is one
event on the medium's clock.

Queued chunks can be cancelled (:meth:`~UartTx.cancel`: a STOP, a reset), so what a
device has not yet put on the wire never reaches the host; the chunk being
sent still completes, as on a real UART.

The queue is bounded like a firmware's transmit ring (:data:`TX_QUEUE`): a
write that finds it full is dropped whole and counted, so a host asking
faster than the answers can go out (a flood of 2-byte requests each worth a
27-byte reply) costs no memory and the unit answers again as soon as the
ring has room.
"""

from __future__ import annotations

from collections.abc import Callable

#: Longest piece of one write handed to the medium as a unit (seconds of wire time).
CHUNK_S = 0.001
#: Bytes the transmit queue holds: a write that would not fit behind what is queued is dropped (counted).
TX_QUEUE = 4096


class UartTx:
    """The TX line of a device: ``send(data, t_ready)`` paces ``data`` at :attr:`baud` (10 bits a byte)."""

    def __init__(self, port, baud: int | None, *, chunk_s: float = CHUNK_S,
                 counters: dict[str, int] | None = None) -> None:
        self.port = port
        self.baud = baud  #: the line rate (None: not paced)
        self.chunk_s = chunk_s
        self.busy_until = 0.0
        self.epoch = 0
        self.bytes_sent = 0
        self.bytes_cancelled = 0
        self.bytes_dropped = 0
        #: Where drops are also counted (the device's counters: ``tx_dropped``, ``tx_dropped_bytes``).
        self.counters = counters
        self._pending = 0  # chunks scheduled and not yet handed over
        self.on_idle: Callable[[float], None] | None = None

    def byte_time(self) -> float:
        return 10.0 / self.baud if self.baud else 0.0

    def send(self, data: bytes, t_ready: float | None = None, *, whole: bool = False) -> float:
        """Queue ``data`` ready to send at ``t_ready`` (default now); returns when its last byte is out.

        ``whole``: hand it over as one piece (a reply a device writes with one send on a fast link).
        """
        if not data:
            return max(self.busy_until, t_ready or 0.0)
        now = self.port.now() if t_ready is None else t_ready
        start = max(now, self.busy_until)
        bt = self.byte_time()
        if bt and start > now and (start - now) / bt + len(data) > TX_QUEUE:  # the ring is full: dropped
            self.bytes_dropped += len(data)
            if self.counters is not None:
                self.counters["tx_dropped"] += 1
                self.counters["tx_dropped_bytes"] += len(data)
            return start
        step = len(data) if whole or bt == 0 else max(1, int(self.chunk_s / bt))
        epoch = self.epoch
        t = start
        for k in range(0, len(data), step):
            piece = data[k:k + step]
            t += len(piece) * bt
            self._pending += 1
            self.port.call_at(t, lambda p=piece, te=t, ep=epoch: self._emit(p, te, ep))
        self.busy_until = t
        return t

    def _emit(self, piece: bytes, t_end: float, epoch: int) -> None:
        self._pending -= 1
        if epoch != self.epoch:
            self.bytes_cancelled += len(piece)
        else:
            self.bytes_sent += len(piece)
            self.port.transmit(piece, t=t_end)
        if self._pending == 0 and self.on_idle is not None:
            self.on_idle(t_end)

    @property
    def idle(self) -> bool:
        return self._pending == 0

    @property
    def waiting(self) -> int:
        """Pieces handed to :meth:`send` and not yet on the wire (a whole write is one)."""
        return self._pending

    def cancel(self, now: float | None = None) -> None:
        """Drop everything queued and not yet on the wire; the line is free from ``now``."""
        self.epoch += 1
        now = self.port.now() if now is None else now
        # The chunk in flight finishes (it was handed over whole); later ones are dropped.
        self.busy_until = min(self.busy_until, now + self.chunk_s)


__all__ = ["CHUNK_S", "UartTx"]
