"""The board's trace output path: record buffers, the 2048-byte output ring, UART DMA and the wire.

All text (logs, stamp lines, reports) and binary words go through one ring
(spec §3.4). ``tsink`` drains it by UART DMA: each transfer takes the bytes
from the read position to the write position or the ring's end, whichever
comes first, and occupies the wire for 10 bits per byte at the baud rate.
Text writers wait in 1 ms steps while a line does not fit (nothing is lost,
the writer's timing shifts); binary stamps are claimed without waiting, and
a stamp that does not fit is dropped and counted, then reported by DROPS
words once space returns (docs/formats/tracestamp-binary.md).

Everything here is bookkeeping on arrays: the stamps a run produces arrive in
bulk, and only the stamps the ring accepts are ever encoded or formatted.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from hilbench.protocols import tracestamp_binary as tb

RING_SIZE = 2048


@dataclass
class Truth:
    """What the emulated board knows happened; tests compare instruments against it."""

    stamps_recorded: int = 0  # hook and scope stamps taken while sampling (the kernel's view)
    stamps_sent: int = 0  # stamps that entered the ring (as lines or words)
    stamps_dropped: int = 0  # binary: stamps that found the ring full
    records_lost: int = 0  # text paths: records overwritten in a record buffer before printing
    drops_reported: int = 0  # binary: sum of DROPS words written
    bytes_to_wire: int = 0
    bytes_dropped_fault: int = 0
    bytes_corrupted_fault: int = 0
    lines_written: int = 0
    dma_transfers: int = 0
    frames_ok: int = 0
    frames_crc_error: int = 0
    frames_length_error: int = 0
    setpoints_dropped: int = 0  # vel_sp_queue full
    frames_lost: int = 0  # received while recv_vel had RX_PENDING frames still to take
    rx_bytes_ignored: int = 0  # host bytes on a board without a UART receiver (micro-ROS build)
    rx_overruns: int = 0  # host writes (datagrams) that found the receive FIFO full, dropped
    rx_overrun_bytes: int = 0


@dataclass
class OutputFaults:
    """Fault knobs on the board's outgoing bytes and on the sink."""

    drop_rate: float = 0.0
    corrupt_rate: float = 0.0
    drop_next: int = 0
    corrupt_next: int = 0
    stall_until_us: float = 0.0  # the DMA does not start before this virtual time
    seed: int = 0
    rng: np.random.Generator = field(default=None, repr=False)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)

    @property
    def active(self) -> bool:
        return bool(self.drop_rate or self.corrupt_rate or self.drop_next or self.corrupt_next)


class Ring:
    """The byte ring: a FIFO with the physical read position, so DMA chunks stop at the ring's end."""

    def __init__(self, size: int = RING_SIZE) -> None:
        self.size = size
        self.buf = bytearray()
        self.read_pos = 0  # physical index of buf[0]
        self.in_flight = 0  # bytes at the front currently being sent by DMA

    @property
    def used(self) -> int:
        return len(self.buf)

    @property
    def free(self) -> int:
        return self.size - len(self.buf)

    def write(self, data: bytes) -> bool:
        if len(data) > self.free:
            return False
        self.buf += data
        return True

    def dma_chunk(self) -> int:
        """Bytes a DMA started now would send (contiguous from the read position); 0 if empty or busy."""
        if self.in_flight or not self.buf:
            return 0
        return min(len(self.buf), self.size - self.read_pos)

    def start(self, n: int) -> bytes:
        self.in_flight = n
        return bytes(self.buf[:n])

    def complete(self) -> None:
        n = self.in_flight
        del self.buf[:n]
        self.read_pos = (self.read_pos + n) % self.size
        self.in_flight = 0

    def clear(self) -> None:
        self.buf.clear()
        self.read_pos = 0
        self.in_flight = 0


class Wire:
    """Bytes on the board's TX line in virtual time: segments ``(t_start_us, bytes)`` at ``baud``."""

    def __init__(self, baud: int) -> None:
        self.byte_us = 10e6 / baud
        self.segments: deque[list] = deque()  # [t_start, data, sent]
        self.busy_until = 0.0
        self.total = 0

    def send(self, t_us: float, data: bytes) -> float:
        start = max(t_us, self.busy_until)
        self.segments.append([start, data, 0])
        self.busy_until = start + len(data) * self.byte_us
        self.total += len(data)
        return self.busy_until

    def take(self, until_us: float) -> tuple[bytes, float]:
        """Bytes whose last bit is out by ``until_us``, and the end time of the last one."""
        out = []
        t_last = 0.0
        bu = self.byte_us
        segs = self.segments
        while segs:
            seg = segs[0]
            start, data, sent = seg
            n = min(len(data), int((until_us - start) / bu + 1e-9))
            if n <= sent:
                break
            out.append(data[sent:n])
            t_last = start + n * bu
            if n == len(data):
                segs.popleft()
            else:
                seg[2] = n
                break
        return b"".join(out), t_last

    def take_all(self) -> bytes:
        out = [seg[1][seg[2]:] for seg in self.segments]
        self.segments.clear()
        return b"".join(out)

    def pending(self) -> int:
        return sum(len(s[1]) - s[2] for s in self.segments)


class RecordBuffer:
    """A hook-record buffer: ``ring`` (V1, V2: oldest unprinted records overwritten) or ``array`` (V3:
    the index wraps, and the dump prints only the records written after the last wrap).

    The ring keeps pushed chunks as they come and cuts them to the newest ``capacity`` records only
    when they are read (or pile up), so a push costs no copying."""

    def __init__(self, capacity: int, mode: str) -> None:
        self.capacity = capacity
        self.mode = mode
        self.written = 0  # records written since clear()
        self.lost = 0
        self.clear()

    def clear(self) -> None:
        self.t = np.zeros(0)
        self.ids = np.zeros(0, np.int16)
        self.begin = np.zeros(0, bool)
        self.written = 0
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._held = 0  # unprinted records that survive (<= capacity)
        self._raw = 0  # records in _chunks

    def push(self, t: np.ndarray, ids: np.ndarray, begin: np.ndarray) -> int:
        """Add records; returns how many unprinted records were lost to overwriting."""
        n = len(t)
        if n == 0:
            return 0
        self.written += n
        if self.mode == "array":
            # The index wraps: only the records written since the last wrap survive (spec §3.5).
            keep = self.written if self.written <= self.capacity else self.written % self.capacity
            before = len(self.t) + n
            t = np.concatenate((self.t, t))[before - keep :]
            ids = np.concatenate((self.ids, ids))[before - keep :]
            begin = np.concatenate((self.begin, begin))[before - keep :]
            self.t, self.ids, self.begin = t, ids, begin
            self.lost += before - keep
            return before - keep
        self._chunks.append((t, ids, begin))
        self._raw += n
        held = self._held + n
        lost = max(0, held - self.capacity)
        self._held = held - lost
        self.lost += lost
        if self._raw > 8 * self.capacity:
            self._compact()
        return lost

    def _compact(self) -> None:
        chunks = self._chunks
        if len(chunks) == 1:
            t, ids, begin = chunks[0]
        else:
            t = np.concatenate([c[0] for c in chunks])
            ids = np.concatenate([c[1] for c in chunks])
            begin = np.concatenate([c[2] for c in chunks])
        h = self._held
        self._chunks = [(t[len(t) - h :], ids[len(t) - h :], begin[len(t) - h :])]
        self._raw = h

    def take(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All unprinted records (the reader's snapshot); the buffer is empty afterwards."""
        if self.mode == "array":
            out = (self.t, self.ids, self.begin)
            self.t = np.zeros(0)
            self.ids = np.zeros(0, np.int16)
            self.begin = np.zeros(0, bool)
            return out
        if not self._chunks:
            return np.zeros(0), np.zeros(0, np.int16), np.zeros(0, bool)
        self._compact()
        out = self._chunks[0]
        self._chunks, self._held, self._raw = [], 0, 0
        return out

    def __len__(self) -> int:
        return len(self.t) if self.mode == "array" else self._held


class BinaryWriter:
    """Binary stamp words into the ring: TIME words at each new t >> 15, CHECK every 64 words, exact drops."""

    def __init__(self, ring: Ring, truth: Truth) -> None:
        self.ring = ring
        self.truth = truth
        self.checks = tb.CheckInserter()
        self.pending_drops = 0
        self.last_hi = -1
        self.need_time = True
        self.window = 0

    def start(self, window: int) -> bytes:
        """Words that open a window (WINDOW_START, TIME 0); written by a blocking writer."""
        self.window = window
        self.checks.restart()
        self.pending_drops = 0
        self.last_hi = 0
        self.need_time = False
        p = np.array([tb.control_payload(tb.Op.WINDOW_START, window % 8192), tb.time_payload(0)], np.uint32)
        return tb.encode_payloads(self.checks.add(p))

    def stop(self, t_us: int) -> bytes:
        """Words that close a window: outstanding DROPS (and TIME), the last CHECK, WINDOW_STOP."""
        words = self._drops_words(t_us)
        p = self.checks.add(np.array(words, np.uint32)) if words else np.zeros(0, np.uint32)
        tail = np.array(self.checks.close() + [tb.control_payload(tb.Op.WINDOW_STOP, self.window % 8192)],
                        np.uint32)
        return tb.encode_payloads(np.concatenate((p, tail)))

    def _drops_words(self, t_us: int) -> list[int]:
        if not self.pending_drops:
            return []
        words = tb.drops_payloads(self.pending_drops) + [tb.time_payload(t_us)]
        self.truth.drops_reported += self.pending_drops
        self.pending_drops = 0
        self.last_hi = t_us >> tb.HI_SHIFT
        return words

    def write(self, t_us: np.ndarray, ids: np.ndarray, begin: np.ndarray) -> int:
        """Claim words for stamps (time-ordered µs, wire ids, edges); returns how many were accepted."""
        n = len(t_us)
        if n == 0:
            return 0
        if n <= 32:
            return self._write_few(t_us.tolist(), ids.tolist(), begin.tolist())
        free = self.ring.free
        hi = t_us >> tb.HI_SHIFT
        need_time = np.empty(n, dtype=bool)
        need_time[0] = hi[0] != self.last_hi
        need_time[1:] = hi[1:] != hi[:-1]
        words = 1 + need_time.astype(np.int64)
        extra0 = 0
        if self.pending_drops:
            extra0 = len(tb.drops_payloads(self.pending_drops)) + 1 - int(need_time[0])  # DROPS + TIME
        words[0] += extra0
        cum_words = np.cumsum(words)
        checks = (self.checks.count + cum_words) // self.checks.block
        cum_bytes = 4 * (cum_words + checks)
        m = int(np.searchsorted(cum_bytes, free, side="right"))
        if m:
            payload = []
            if extra0:
                payload += self._drops_words(int(t_us[0]))
                need_first = False
            else:
                need_first = bool(need_time[0])
            acc_t, acc_ids, acc_b, acc_need = t_us[:m], ids[:m], begin[:m], need_time[:m].copy()
            acc_need[0] = need_first
            stamps = tb.stamp_payloads(acc_ids, acc_b, acc_t)
            if acc_need.any():
                times = np.array([tb.time_payload(int(x)) for x in acc_t[acc_need]], np.uint32)
                pos = np.flatnonzero(acc_need)
                stamps = np.insert(stamps, pos, times)
            allp = np.concatenate((np.array(payload, np.uint32), stamps)) if payload else stamps
            data = tb.encode_payloads(self.checks.add(allp))
            ok = self.ring.write(data)
            assert ok, "binary acceptance overflowed the ring"
            self.last_hi = int(hi[m - 1])
        dropped = n - m
        if dropped:
            self.pending_drops += dropped
        self.truth.stamps_sent += m
        self.truth.stamps_dropped += dropped
        return m

    def _write_few(self, t_us: list[int], ids: list[int], begin: list[bool]) -> int:
        """:meth:`BinaryWriter.write` for a few stamps in plain Python (same rules, no numpy overhead)."""
        free = self.ring.free
        block = self.checks.block
        count = self.checks.count
        words: list[int] = []
        m = 0
        for t, sid, b in zip(t_us, ids, begin, strict=True):
            hi = t >> tb.HI_SHIFT
            pre: list[int] = []
            if self.pending_drops:
                pre = tb.drops_payloads(self.pending_drops) + [tb.time_payload(t)]
            elif hi != self.last_hi:
                pre = [tb.time_payload(t)]
            add = len(pre) + 1
            total = len(words) + add
            checks = (count + total) // block
            if 4 * (total + checks) > free:
                break
            if self.pending_drops:
                self.truth.drops_reported += self.pending_drops
                self.pending_drops = 0
            words += pre
            words.append(sid << 18 | (1 << 17 if b else 0) | (t & tb.TIME_MASK))
            self.last_hi = hi
            m += 1
        if words:
            data = b"".join(map(tb.word_bytes, self.checks.add_list(words)))
            ok = self.ring.write(data)
            assert ok, "binary acceptance overflowed the ring"
        dropped = len(t_us) - m
        if dropped:
            self.pending_drops += dropped
        self.truth.stamps_sent += m
        self.truth.stamps_dropped += dropped
        return m
