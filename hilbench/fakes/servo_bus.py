"""What the emulated servo buses share: joining the line, who hears a packet, and putting statuses on it.

The Dynamixel Protocol 2.0 bus (:class:`~hilbench.fakes.dynamixel.bus.DynamixelBus`)
and the Protocol 1.0-framed ones (:class:`~hilbench.fakes.dynamixel.bus1.Protocol1Bus`,
Feetech's bus) decode and execute instructions their own way; the replies then
go out the same way: in the order given, each after its Return Delay Time when
the line is paced, through the servo's fault knobs (drop, corrupt, delay), and,
on an unpaced line, replies without a delay as one transmission.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

from hilbench.transports.serial_medium import DevicePort, SerialMedium


@dataclass
class ServoBusStats:
    """What the emulated devices received and sent."""

    requests: Counter = field(default_factory=Counter)
    replies: int = 0
    dropped_replies: int = 0
    corrupted_replies: int = 0
    crc_errors_received: int = 0
    invalid_received: int = 0


class ServoBusBase:
    """Emulated servos sharing one serial line; a subclass decodes and executes what the host sends."""

    #: The status packet builder of the bus's protocol: ``(id, err, data) -> bytes``.
    status_frame: ClassVar[Callable[[int, int, bytes], bytes]]
    #: Bytes of the checksum that ends a status (a corrupted reply has the first of them flipped).
    checksum_size: ClassVar[int] = 1
    #: What happens to a chain of replies after one that is dropped: "continue", or "stall" (the rest stay
    #: unsent, as a daisy chain waiting for the silent device does).
    chain_policy = "continue"
    #: The protocol number the line carries, for servos whose Protocol Type register chooses the one they
    #: speak (a subclass sets it); None: no servo chooses.
    protocol_type: ClassVar[int | None] = None

    def __init__(self, servos: list, *, name: str) -> None:
        self.name = name
        self.servos = list(servos)
        self.stats = ServoBusStats()
        self.port: DevicePort | None = None
        self._packets: dict[int, tuple[bytes, int, bytes]] = {}  # reply id -> (data, err, its last status)

    def attach(self, medium: SerialMedium) -> None:
        """Join a serial line."""
        self.port = medium.add_device(self)

    def add(self, servo: Any) -> None:
        """Put one more device on the bus (a servo, or a board answering at its own ID)."""
        self.servos.append(servo)

    def servo(self, servo_id: int) -> Any:
        """The device that currently has ``servo_id``."""
        for s in self.servos:
            if s.id == servo_id:
                return s
        raise KeyError(servo_id)

    def _hearing(self, t: float, baud: int | None) -> list:
        """Devices that receive this transmission: awake, at the sender's baud, and (where a servo's Protocol
        Type register chooses) speaking this line's protocol: a servo switched to the other one goes quiet."""
        v = self.protocol_type
        if v is None:
            return [s for s in self.servos if s.listens(t, baud)]
        # (the register read inline: this runs for every packet, a property call per servo showed in the cycle)
        return [s for s in self.servos if s.listens(t, baud)
                and ((a := s.protocol_type_address) is None or s.mem[a] == v)]

    def _send(self, replies: list[tuple[Any, int, bytes, int]], t: float) -> None:
        """Put status packets on the line in order: ``(device, err, data, reply id)``.

        On an unpaced line, replies without a delay all arrive at once anyway; they go out as one
        transmission (one pty write instead of twenty for a Sync Read), which changes nothing a
        host or tap can observe but the chunking.
        """
        port = self.port
        if port is None:
            return
        paced = port.paced
        end = t
        batch = bytearray()
        batch_baud: int | None = None
        status_frame = self.status_frame
        stats = self.stats
        packets = self._packets
        try:
            for s, err, data, reply_id in replies:
                faults = s.faults
                # (the knobs are read first: drawing from the generator only when a rate is set)
                if (faults.drop_next or faults.drop_rate) and faults.take_drop():
                    stats.dropped_replies += 1
                    if self.chain_policy == "stall":
                        return
                    continue
                cached = packets.get(reply_id)
                if cached is not None and cached[0] == data and cached[1] == err:
                    raw = cached[2]  # the same status as last time (a joint holding still): no new checksum
                else:
                    raw = status_frame(reply_id, err, data)
                    packets[reply_id] = (data, err, raw)
                if (faults.corrupt_next or faults.corrupt_rate) and faults.take_corrupt():
                    k = len(raw) - self.checksum_size
                    raw = raw[:k] + bytes((raw[k] ^ 0xFF,)) + raw[k + 1 :]
                    stats.corrupted_replies += 1
                gap = (s.return_delay if paced else 0.0) + faults.delay
                baud = s.baud
                stats.replies += 1
                joins = not paced and gap == 0.0
                if batch and not (joins and baud == batch_baud):
                    end = port.transmit(bytes(batch), t=end, baud=batch_baud)
                    batch.clear()
                if joins:
                    batch += raw
                    batch_baud = baud
                else:
                    end = port.transmit(raw, t=end, gap=gap, baud=baud)
        finally:
            if batch:
                port.transmit(bytes(batch), t=end, baud=batch_baud)


__all__ = ["ServoBusStats", "ServoBusBase"]
