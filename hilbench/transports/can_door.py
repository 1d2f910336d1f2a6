"""What a door of the CAN host port is: one way for host programs onto an emulated CAN bus.

:class:`~hilbench.transports.can_port.CanPort` opens the doors a profile
asks for (socketcand, SLCAN, python-can ``virtual``, SocketCAN) and fans the
bus's frames out to each; every door derives from :class:`CanDoor`. It lives
apart from the port so that the doors import this base, not the port that
imports them.
"""

from __future__ import annotations

from typing import Any

from hilbench.protocols.can_frame import CanFrame


class CanDoor:
    """Base class of the doors of a CAN host port; the :class:`~hilbench.transports.can_medium.CanMedium` drives
    them from its own thread, through :class:`~hilbench.transports.can_port.CanPort` (which fans out to
    every door).

    A door implements :meth:`filenos`, :meth:`read_frames`, :meth:`write_frame` and :meth:`close`; the others
    default to a door that sends at once and has no timed work.
    """

    kind: str = ""

    def attach(self, medium: Any) -> None:
        """The bus it serves (its bitrate, its clock's Unix time offset)."""

    def filenos(self) -> list[int]:
        """Descriptors the bus thread waits on for this door."""
        raise NotImplementedError

    def read_frames(self, now: float) -> list[tuple[str, CanFrame]]:
        """Frames the door's clients sent, each with its sender's name (called when a descriptor is ready)."""
        raise NotImplementedError

    def write_frame(self, t: float, source: str, frame: CanFrame) -> None:
        """A frame (or error frame) on the bus at ``t``: queue it for every client but ``source``."""
        raise NotImplementedError

    def flush(self) -> None:
        """Send what :meth:`write_frame` queued (once per round of the bus thread)."""

    def deadline(self) -> float | None:
        """When the door next needs :meth:`poll` (a handshake delay, a cyclic job), or None."""
        return None

    def wall_deadline(self) -> float | None:
        """When the door's service timers (a flush retry, a stalled client's timeout) next need :meth:`poll`,
        on the wall clock (``time.monotonic()``) whatever the bus's clock, or None."""
        return None

    def poll(self, now: float) -> list[tuple[str, CanFrame]]:
        """Timed work; returns frames it sends (cyclic jobs)."""
        return []

    def close(self) -> None:
        """Release the door's sockets or pty."""
        raise NotImplementedError


__all__ = ["CanDoor"]
