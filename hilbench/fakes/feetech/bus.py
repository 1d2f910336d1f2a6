"""The emulated servos of one Feetech bus: Dynamixel Protocol 1.0 framing with Feetech's instruction set.

Differences from :class:`~hilbench.fakes.protocol1_bus.Protocol1Bus`
(spec sheet ``servo_buses.md`` §4):

- SYNC_READ is 0x82, and every listed servo answers with its own status, in
  request order (Feetech's SDK reads them one by one, in the order it listed
  them); a servo that is missing simply stays silent;
- a broadcast PING is answered by every servo, in ID order;
- no BULK_READ and no USB2AX;
- the ERR byte carries only the servo's condition (input voltage, overheat);
  a refused write is not flagged, as Feetech's servos have no instruction,
  range or checksum bits (a packet that fails its checksum goes unanswered);
- Response Status Level 0 answers only PING and READ (and SYNC_READ).
"""

from __future__ import annotations

from hilbench.fakes.protocol1_bus import Protocol1Bus
from hilbench.protocols import feetech as ft
from hilbench.protocols.dynamixel_protocol1 import Instruction1 as I1  # noqa: N814
from hilbench.protocols.feetech import BROADCAST_ID, Packet1
from hilbench.protocols.feetech import Instruction as I  # noqa: N814


class FeetechBus(Protocol1Bus):
    """Emulated Feetech servos sharing one line (see the module docstring)."""

    broadcast_ping = True
    protocol_type = None  # Feetech servos have no Protocol Type register
    reply_checksum_errors = False
    read_level = 0
    write_level = 1
    reset_mode = 0x01  # back to factory values; the servo keeps its ID

    def __init__(self, servos: list, *, name: str = "feetech", inter_byte_timeout: float | None = 0.0015) -> None:
        super().__init__(servos, name=name, usb2ax=False, inter_byte_timeout=inter_byte_timeout)

    def handlers(self):
        """Protocol 1.0's, with Feetech's SYNC_READ for the BULK_READ and the USB2AX's SYNC_READ it lacks."""
        out = super().handlers()
        del out[I1.BULK_READ], out[I1.SYNC_READ]
        out[I.SYNC_READ] = self._sync_read
        return out

    @staticmethod
    def instruction_name(code: int) -> str:
        return ft.INSTRUCTION_NAMES.get(code, f"0x{code:02x}")

    def error_bits(self, s, number: int = 0) -> int:
        return s.condition_bits()

    def _sync_read(self, pkt: Packet1, t: float, hearing: list) -> None:
        p = pkt.params
        address, length, ids = p[0], p[1], p[2:]
        if pkt.id != BROADCAST_ID or not length:
            return
        by_id = {s.id: s for s in hearing}
        replies = []
        for sid in ids:
            s = by_id.get(sid)
            if s is None:
                continue
            err, data = s.read(address, length, t)
            replies.append((s, self.error_bits(s), data, s.id))
        self._send(replies, t)


__all__ = ["FeetechBus"]
