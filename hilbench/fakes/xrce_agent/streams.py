"""XRCE streams as the Micro XRCE-DDS agent keeps them per session (spec sheet §1.2, §1.7).

Sequence numbers are u16 with serial arithmetic. A best-effort input accepts
only newer messages; a reliable input buffers up to :data:`RELIABLE_DEPTH`
messages ahead of the last one delivered, reassembles FRAGMENTs and fills
ACKNACKs; a reliable output keeps what it sent until acknowledged, answers
NACKs from that history and says what it has outstanding in HEARTBEATs. When a
reliable output's window is full, further messages wait in a bounded backlog
(the real agent blocks its reader thread instead); beyond it they are dropped
and counted.
"""

from __future__ import annotations

from collections import deque

from hilbench.protocols.xrce_dds import seq_newer

#: The agent's reliable and best-effort stream depths (UAGENT_CONFIG_*_STREAM_DEPTH).
RELIABLE_DEPTH = 16
#: Messages waiting for room in a reliable output's window.
BACKLOG = 1024
#: Largest reassembled fragmented message.
MAX_FRAGMENTED = 64 * 1024


def _add(a: int, n: int) -> int:
    return (a + n) & 0xFFFF


class BestEffortInput:
    """Delivers a message only if it is newer than the last one delivered."""

    def __init__(self) -> None:
        self.last = 0xFFFF
        self.dropped = 0

    def accept(self, seq: int) -> bool:
        if seq_newer(seq, self.last):
            self.last = seq
            return True
        self.dropped += 1
        return False


class ReliableInput:
    """In-order delivery with a window of :data:`RELIABLE_DEPTH`; FRAGMENT reassembly."""

    def __init__(self) -> None:
        self.last_handled = 0xFFFF
        self.last_announced = 0xFFFF
        self.pending: dict[int, bytes] = {}
        self.fragments = bytearray()
        self.duplicates = 0

    def push(self, seq: int, message: bytes) -> bool:
        """Keep ``message``; False for a duplicate or one beyond the window."""
        ahead = (seq - self.last_handled) & 0xFFFF
        if not 0 < ahead <= RELIABLE_DEPTH:
            self.duplicates += 1
            return False
        if seq in self.pending:
            self.duplicates += 1
            return False
        if seq_newer(seq, self.last_announced):
            self.last_announced = seq
        self.pending[seq] = message
        return True

    def pop(self) -> bytes | None:
        """The next message in order, if it is here."""
        nxt = _add(self.last_handled, 1)
        msg = self.pending.pop(nxt, None)
        if msg is not None:
            self.last_handled = nxt
        return msg

    def heartbeat(self, first_unacked: int, last_unacked: int) -> None:
        """A HEARTBEAT: what the sender no longer has is skipped; what it sent is announced."""
        if seq_newer(first_unacked, _add(self.last_handled, 1)):
            for s in list(self.pending):
                if not seq_newer(s, _add(first_unacked, -1 & 0xFFFF)):
                    del self.pending[s]
            self.last_handled = _add(first_unacked, 0xFFFF)
        if seq_newer(last_unacked, self.last_announced):
            self.last_announced = last_unacked

    def acknack(self) -> tuple[int, int]:
        """``(first_unacked, nack_bitmap)`` as the agent fills them."""
        first = _add(self.last_handled, 1)
        bitmap = 0
        for i in range(16):
            s = _add(first, i)
            if seq_newer(s, self.last_announced):
                break
            if s not in self.pending:
                bitmap |= 1 << i
        return first, bitmap

    def fragment(self, header: bytes, payload: bytes, last: bool) -> bytes | None:
        """Append a FRAGMENT's payload; the whole message (``header`` + payloads) once the last arrived."""
        if not self.fragments:
            self.fragments += header
        if len(self.fragments) + len(payload) > MAX_FRAGMENTED:
            self.fragments.clear()
            return None
        self.fragments += payload
        if last:
            whole = bytes(self.fragments)
            self.fragments.clear()
            return whole
        return None

    def reset(self) -> None:
        self.__init__()


class ReliableOutput:
    """Sent-but-unacknowledged history, HEARTBEAT contents, NACK answers, a bounded backlog."""

    def __init__(self) -> None:
        self.first_unacked = 0
        self.last_unacked = 0xFFFF  # nothing sent yet
        self.history: dict[int, bytes] = {}
        self.backlog: deque[tuple[int, bytes]] = deque()  # (submessage id, payload) waiting for room
        self.dropped = 0
        self.retransmissions = 0

    def room(self) -> bool:
        return ((self.last_unacked - self.first_unacked + 1) & 0xFFFF) < RELIABLE_DEPTH - 1 or not self.history

    def next_seq(self) -> int:
        self.last_unacked = _add(self.last_unacked, 1)
        return self.last_unacked

    def keep(self, seq: int, message: bytes) -> None:
        self.history[seq] = message

    def queue(self, item: tuple[int, bytes]) -> None:
        if len(self.backlog) >= BACKLOG:
            self.dropped += 1
            return
        self.backlog.append(item)

    def acknowledge(self, first_unacked: int) -> None:
        """Everything before ``first_unacked`` arrived (ignored if it names what was never sent)."""
        if seq_newer(first_unacked, _add(self.last_unacked, 1)):
            return
        while seq_newer(first_unacked, self.first_unacked):
            self.history.pop(self.first_unacked, None)
            self.first_unacked = _add(self.first_unacked, 1)

    def nacked(self, first_unacked: int, bitmap: int) -> list[bytes]:
        out = []
        for i in range(16):
            if bitmap >> i & 1:
                msg = self.history.get(_add(first_unacked, i))
                if msg is not None:
                    out.append(msg)
        self.retransmissions += len(out)
        return out

    def heartbeat(self) -> tuple[int, int] | None:
        """``(first_unacked, last_unacked)`` while anything is unacknowledged."""
        return (self.first_unacked, self.last_unacked) if self.history else None

    def reset(self) -> None:
        self.__init__()


__all__ = ["BACKLOG", "RELIABLE_DEPTH", "BestEffortInput", "ReliableInput", "ReliableOutput"]
