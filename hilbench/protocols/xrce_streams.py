"""XRCE streams as the Micro XRCE-DDS agent and client keep them per session (spec sheet §1.2, §1.7).

Sequence numbers are u16 with serial arithmetic. A best-effort input accepts
only newer messages; a reliable input buffers up to :data:`RELIABLE_DEPTH`
messages ahead of the last one delivered, reassembles FRAGMENTs and fills
ACKNACKs; a reliable output keeps what it sent until acknowledged, answers
NACKs from that history and says what it has outstanding in HEARTBEATs. When a
reliable output's window is full, further messages wait in a bounded backlog
(the real agent blocks its reader thread instead); beyond it they are dropped
and counted. Each stream keeps the bytes it holds (:attr:`ReliableInput.bytes`,
:attr:`ReliableOutput.bytes`), so the agent can bound a session's memory.
"""

from __future__ import annotations

from collections import deque

from hilbench.protocols.xrce_dds import seq_newer

#: The agent's reliable and best-effort stream depths (UAGENT_CONFIG_*_STREAM_DEPTH).
RELIABLE_DEPTH = 16
#: Messages waiting for room in a reliable output's window, and their bytes at most.
BACKLOG = 1024
BACKLOG_BYTES = 256 * 1024
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
        self.pending_bytes = 0
        self.fragments_dropped = 0  #: fragmented messages dropped (too large)
        self._skipping = False  # the rest of a dropped fragmented message is ignored up to its last fragment

    @property
    def bytes(self) -> int:
        """What the stream holds: messages ahead of a gap and a message being reassembled."""
        return self.pending_bytes + len(self.fragments)

    def next_in_order(self, seq: int) -> bool:
        """Whether ``seq`` is the message delivered next (it never waits in the stream)."""
        return seq == _add(self.last_handled, 1)

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
        self.pending_bytes += len(message)
        return True

    def pop(self) -> bytes | None:
        """The next message in order, if it is here."""
        nxt = _add(self.last_handled, 1)
        msg = self.pending.pop(nxt, None)
        if msg is not None:
            self.last_handled = nxt
            self.pending_bytes -= len(msg)
        return msg

    def heartbeat(self, first_unacked: int, last_unacked: int) -> None:
        """A HEARTBEAT: what the sender no longer has is skipped; what it sent is announced."""
        if seq_newer(first_unacked, _add(self.last_handled, 1)):
            for s in list(self.pending):
                if not seq_newer(s, _add(first_unacked, -1 & 0xFFFF)):
                    self.pending_bytes -= len(self.pending.pop(s))
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

    def fragment(self, header: bytes, payload: bytes, last: bool, limit: int = MAX_FRAGMENTED) -> bytes | None:
        """Append a FRAGMENT's payload; the whole message (``header`` + payloads) once the last arrived.

        A message that would grow beyond ``limit`` bytes (at most :data:`MAX_FRAGMENTED`) is dropped, with
        its fragments up to the last one (counted in :attr:`fragments_dropped`)."""
        if self._skipping:
            self._skipping = not last
            return None
        if not self.fragments:
            self.fragments += header
        if len(self.fragments) + len(payload) > min(limit, MAX_FRAGMENTED):
            self.fragments.clear()
            self.fragments_dropped += 1
            self._skipping = not last
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
        self.dropped = 0  #: submessages the backlog refused
        self.retransmissions = 0
        self.history_bytes = 0
        self.backlog_bytes = 0

    @property
    def bytes(self) -> int:
        """What the stream holds: unacknowledged messages and the backlog."""
        return self.history_bytes + self.backlog_bytes

    def room(self) -> bool:
        return ((self.last_unacked - self.first_unacked + 1) & 0xFFFF) < RELIABLE_DEPTH - 1 or not self.history

    def next_seq(self) -> int:
        self.last_unacked = _add(self.last_unacked, 1)
        return self.last_unacked

    def keep(self, seq: int, message: bytes) -> None:
        old = self.history.get(seq)
        self.history_bytes += len(message) - (len(old) if old is not None else 0)
        self.history[seq] = message

    def queue(self, item: tuple[int, bytes], room: bool = True) -> bool:
        """Put a submessage in the backlog; False (counted in :attr:`dropped`) if it is full or not ``room``."""
        if not room or len(self.backlog) >= BACKLOG or self.backlog_bytes + len(item[1]) > BACKLOG_BYTES:
            self.dropped += 1
            return False
        self.backlog.append(item)
        self.backlog_bytes += len(item[1])
        return True

    def unqueue(self) -> tuple[int, bytes]:
        """The oldest backlog item (taken out)."""
        item = self.backlog.popleft()
        self.backlog_bytes -= len(item[1])
        return item

    def acknowledge(self, first_unacked: int) -> None:
        """Everything before ``first_unacked`` arrived (ignored if it names what was never sent)."""
        if seq_newer(first_unacked, _add(self.last_unacked, 1)):
            return
        while seq_newer(first_unacked, self.first_unacked):
            gone = self.history.pop(self.first_unacked, None)
            if gone is not None:
                self.history_bytes -= len(gone)
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


__all__ = ["BACKLOG", "BACKLOG_BYTES", "MAX_FRAGMENTED", "RELIABLE_DEPTH", "BestEffortInput", "ReliableInput",
           "ReliableOutput"]
