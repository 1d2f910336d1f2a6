"""Between hilbench's :class:`~hilbench.protocols.can_frame.CanFrame` and python-can's ``can.Message``."""

from __future__ import annotations

from typing import Any

from hilbench.protocols.can_frame import CAN_ERR_MASK, CanFrame


def to_frame(msg: Any) -> CanFrame | None:
    """A python-can message as a frame (None for CAN FD frames, which a classic bus cannot carry)."""
    if getattr(msg, "is_fd", False) and (msg.dlc > 8 or len(msg.data) > 8):
        return None
    if msg.is_error_frame:
        return CanFrame(msg.arbitration_id & CAN_ERR_MASK, bytes(msg.data[:8]).ljust(8, b"\0"), False, False,
                        True, 8)
    if msg.is_remote_frame:
        return CanFrame(msg.arbitration_id, b"", msg.is_extended_id, True, False, min(msg.dlc, 8))
    data = bytes(msg.data[: msg.dlc]) if msg.dlc <= len(msg.data) else bytes(msg.data)
    return CanFrame(msg.arbitration_id, data[:8], msg.is_extended_id, False, False, len(data[:8]))


def to_message(frame: CanFrame, *, timestamp: float = 0.0, channel: Any = None, is_rx: bool = True) -> Any:
    """A frame as a python-can message."""
    import can

    if frame.error:
        return can.Message(timestamp=timestamp, arbitration_id=frame.can_id, is_error_frame=True,
                           is_extended_id=False, data=frame.data, dlc=len(frame.data), channel=channel, is_rx=is_rx)
    return can.Message(timestamp=timestamp, arbitration_id=frame.can_id, is_extended_id=frame.extended,
                       is_remote_frame=frame.remote, data=None if frame.remote else frame.data, dlc=frame.length,
                       channel=channel, is_rx=is_rx)


__all__ = ["to_frame", "to_message"]
