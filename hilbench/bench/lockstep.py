"""The lockstep controller: clients under ``hilbench run`` share a virtual-time bench's clock.

A virtual-time bench (:class:`~hilbench.transports.virtual_loop.VirtualLoop`) gets one :class:`Lockstep`
(PLAN26 §3, §5). It owns the *clock page* (:mod:`hilbench.bench.clock_page`) and the FIFOs beside it in a
private 0700 directory; the manifest's ``clock`` entry names them, and ``hilbench run`` hands the page to
the client's preload shim (``vclock.c``), which claims one slot per client thread and publishes there
whether the thread runs or waits, and until when. The loop uses the controller in its phases:

- **B, settle**: every byte the bench wrote to a pty is visible on the client's side (``FIONREAD`` on the
  slave the bench holds) before any client is woken;
- **C, wake**: threads whose deadline came, and threads waiting on a pty the bench just delivered to, are
  woken (FUTEX_WAKE on the slot's word, a byte on its wake FIFO for descriptor waits), *after* the bench's
  events at that instant ran: a client sees what the bench did at an instant before it acts at it;
- **D, quiescence**: time may move only when every live thread waits (or polls), every byte a client wrote
  to a pty was taken by the bench (``written == taken``), and no waiter has a hand-over to re-check;
- **F, next time**: the earliest of the bench's next event and the waiting threads' deadlines (a poller's
  deadline is ``vnow`` + the quantum).

A thread that computes without ever waiting does not freeze the world: after :attr:`Lockstep.stall` wall
seconds (default 1 s, None: never) the loop counts a *lockstep stall*, warns once per thread (or pty) on stderr,
and lets virtual time follow the wall clock until every thread waits again (§5.6). A run with no stall is
deterministic; :meth:`Lockstep.stats` has the counters. A process's first thread gets a start-up grace
(:data:`STARTUP_GRACE`): interpreter start-up and imports run under a held clock without counting.

Atomic compare-and-swap and futex wake-ups come from gcc's ``libatomic`` and libc through ctypes (the
bench side needs no compiled module of its own).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import fcntl
import mmap
import os
import platform
import shutil
import struct
import sys
import tempfile
import termios
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilbench.bench import clock_page as vp
from hilbench.errors import BenchError
from hilbench.transports.channel_book import packed_ipv4, unpacked_ipv4
from hilbench.transports.readiness import readable

#: Wall seconds a running thread may hold the clock before a lockstep stall starts (None: never).
STALL = 1.0
#: Calls in a row that find nothing at one instant (empty polls, unchanged clock reads) before a client thread
#: counts as polling, and waits (PLAN26 §5.4). 8 ran the official SDK's busy cycle 1.4 - 2.3 times faster, but
#: python-can's zero-timeout drains between 1 s sleeps then counted as polling and moved time by quanta
#: (60.023 virtual s for 60 sleeps of 1 s).
POLL_K = 32
#: Wall seconds a process's threads may run before any of them first waits (start-up, imports) without
#: counting toward a stall.
STARTUP_GRACE = 30.0
#: Real seconds quiescence must have been blocked by RUNNING threads before their /proc state is read
#: (a thread asleep in a call the shim does not wrap counts as waiting, PLAN26 §4.3).
BLOCKED_CHECK = 200e-6
#: Real seconds between the two /proc looks that must both find such a thread asleep.
BLOCKED_CONFIRM = 100e-6
#: Real seconds B waits at most for a pty's delivered bytes to show on the client's side.
SETTLE_LIMIT = 0.002
#: Real seconds quiescence waits at most for a pty's delivered bytes to show on the client's side (a loaded
#: machine's kernel took up to 31 ms here).
UNSEEN_LIMIT = 0.1
#: Bytes a pty's input queue shows at most (FIONREAD on the client's side; N_TTY's buffer less one).
TTY_INQ_MAX = 4095
#: Real seconds a quiescence wait looks again at most (no notification comes for a thread that fell
#: asleep in an unwrapped call).
LOOK_AGAIN = 0.005
#: Wall seconds time waits for an ending process (its threads left the clock with ``SF_ENDING``) to have ended
#: (its parent may be about to wait for it), before freeing its slots anyway.
EXIT_GRACE = 1.0

_FUTEX_WAKE = 1
_SYS_FUTEX = {"x86_64": 202, "aarch64": 98, "riscv64": 98, "ppc64le": 221, "s390x": 238}
_STATE_WORD = vp.HEADER_SIZE // 4  # u32 index of slot 0's state
_SLOT_WORDS = vp.SLOT_SIZE // 4


class _Atomics:
    """Compare-and-swap, atomic add and FUTEX_WAKE on the shared page."""

    def __init__(self) -> None:
        name = ctypes.util.find_library("atomic") or "libatomic.so.1"
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            raise BenchError("virtual time for clients needs libatomic (gcc's runtime library, e.g. the "
                             "libatomic1 package)") from None
        self._cas = getattr(lib, "__atomic_compare_exchange_4")
        self._cas.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_int]
        self._cas.restype = ctypes.c_bool
        self._add8 = getattr(lib, "__atomic_fetch_add_8")
        self._add8.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_int]
        self._add8.restype = ctypes.c_uint64
        self._add4 = getattr(lib, "__atomic_fetch_add_4")
        self._add4.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int]
        self._add4.restype = ctypes.c_uint32
        self._syscall = ctypes.CDLL(None, use_errno=True).syscall
        self._futex = _SYS_FUTEX.get(platform.machine())
        self._expected = ctypes.c_uint32()

    def cas32(self, address: int, expected: int, desired: int) -> bool:
        self._expected.value = expected
        return self._cas(address, ctypes.addressof(self._expected), desired, 5, 5)

    def add64(self, address: int, n: int) -> int:
        return self._add8(address, n, 5)

    def wake(self, address: int) -> None:
        """Bump the futex word at ``address`` and wake every thread waiting on it."""
        self._add4(address, 1, 5)
        if self._futex is not None:
            self._syscall(self._futex, ctypes.c_void_p(address), _FUTEX_WAKE, 0x7FFFFFFF, None, None, 0)


@dataclass
class Verdict:
    """What :meth:`Lockstep.look` found: whether time may move, and until when the waiters wait."""

    quiet: bool
    next_ns: int | None = None  # earliest deadline among the waiting threads (None: none)
    blockers: list[int] = field(default_factory=list)  # slots that keep time from moving
    counted: bool = False  # whether a blocker counts toward a stall (not in its start-up grace)
    recheck: list[int] = field(default_factory=list)  # waiters to wake: a hand-over since they began to wait
    flight: list[str] = field(default_factory=list)  # ptys with bytes written and not taken, or delivered
    # and not visible on the client's side yet
    held: bool = False  # a client's request is in the bench's hands outside the loop (a line request)
    again: bool = False  # a thread or process ended during the look: look again at once


@dataclass
class _Slot:
    pid: int
    tid: int
    since: float  # real time first seen
    asleep: tuple[tuple[int, int], float] | None = None  # ((progress, ns on a CPU), real time) when /proc last
    # showed it asleep


@dataclass
class _Pty:
    name: str
    port: Any  # a PtyPort: bytes_in, bytes_out, slave_fd, rdev
    base_in: int
    base_out: int
    delivered: int = 0
    unseen: tuple[int, float] | None = None  # (delivered, real time) since its bytes do not show (-1: given up)


class Lockstep:
    """The clock page and the lockstep rules of one virtual-time bench (see the module docstring).

    ``ptys``: (endpoint name, pty host port) of each bench pty; the port's ``bytes_out``/``bytes_in`` are
    the bench's side of the page's port counters. ``stall``: wall seconds before a lockstep stall (None:
    never). ``epoch_ns``: virtual Unix time at ``origin_ns``. ``holding()``: whether the bench has a
    client's request in hand outside the loop (the port-state server's), which keeps time still.
    ``refuses(port)``: whether the bench leaves a pty's bytes unread on purpose (its line holds the writer
    back until the wire has room): they are not in flight, and time moves to let the wire drain.
    """

    def __init__(self, ptys: Iterable[tuple[str, Any]] = (), *, vnow_ns: int = vp.ORIGIN_NS,
                 origin_ns: int = vp.ORIGIN_NS, epoch_ns: int | None = None, stall: float | None = STALL,
                 nslots: int = vp.DEFAULT_SLOTS, poll_k: int = POLL_K, quantum_ns: int = 100_000,
                 startup_grace: float = STARTUP_GRACE, holding: Callable[[], bool] | None = None,
                 refuses: Callable[[Any], bool] | None = None, channels: Any = None,
                 nchans: int = vp.DEFAULT_CHANS) -> None:
        self.atomics = _Atomics()
        self._holding = holding
        self._refuses = refuses
        self.stall = stall  #: wall seconds a non-waiting thread may hold the clock (None: no limit)
        self.startup_grace = startup_grace
        self.nslots = nslots
        self.ptys = [_Pty(name, port, port.bytes_in, port.bytes_out) for name, port in ptys]
        self.dir = Path(tempfile.mkdtemp(prefix="hilbench-clock-"))  # (0700)
        self.page = self.dir / vp.PAGE_FILE
        self.notify_path = self.dir / vp.NOTIFY_FILE
        self.book = channels  #: the bench's ChannelBook (socket doors' counts per client address), or None
        self.nchans = nchans if channels is not None else 0
        self.chan_off = vp.page_size(nslots, len(self.ptys))
        size = self.chan_off + vp.channels_size(self.nchans)
        self.page.write_bytes(bytes(size))
        os.mkfifo(self.notify_path, 0o600)
        for i in range(nslots):
            os.mkfifo(self.dir / vp.WAKE_FILE.format(slot=i), 0o600)
        fd = os.open(self.page, os.O_RDWR)
        try:
            self.map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self.notify = os.open(self.notify_path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
        self._buf = (ctypes.c_char * size).from_buffer(self.map)
        self.base = ctypes.addressof(self._buf)
        self.u32, self.u64 = memoryview(self.map).cast("I"), memoryview(self.map).cast("Q")
        m = self.map
        struct.pack_into("III", m, vp.H_VERSION, vp.VERSION, nslots, len(self.ptys))
        self.epoch_ns = time.time_ns() if epoch_ns is None else int(epoch_ns)
        self.origin_ns = origin_ns
        struct.pack_into("QQ", m, vp.H_VNOW, vnow_ns, self.epoch_ns)
        struct.pack_into("I", m, vp.H_POLL_K, poll_k)
        struct.pack_into("Q", m, vp.H_POLL_QUANTUM, quantum_ns)
        struct.pack_into("Q", m, vp.H_ORIGIN, origin_ns)
        if self.nchans:
            struct.pack_into("I", m, vp.H_NCHANS, self.nchans)
            struct.pack_into("Q", m, vp.H_CHAN_OFF, self.chan_off)
        for i, p in enumerate(self.ptys):
            struct.pack_into("Q", m, vp.port_offset(nslots, i) + vp.P_RDEV, p.port.rdev)
        m[0:8] = vp.MAGIC  # last: a client that maps the page early sees no magic until it is whole
        self._vnow_ns = vnow_ns
        self._hint: int | None = None  # the deadline time moved to (float seconds lose no ns, but be sure)
        self._slots: dict[int, _Slot] = {}
        self._waited: set[int] = set()  # pids one of whose threads has waited (their start-up is over)
        self._pidfds: dict[int, int] = {}  # pid -> pidfd
        self._exiting: dict[int, float] = {}  # pid -> wall time its last thread left the clock (it is ending)
        self._wake_fds: dict[int, int] = {}
        self._warned: set[tuple[int, int]] = set()
        self._blocked_since: float | None = None  # real time quiescence began to be blocked
        self._counted_since: float | None = None  # real time it began to be blocked by what counts for a stall
        self._stall_at: tuple[int, float] | None = None  # (vnow ns, real) when the stall began
        self.wakes = self.rechecks = self.asleep_elsewhere = self.settle_timeouts = 0
        self.participants_seen = 0
        self.frees = 0  # slots freed (exits seen)
        self._schedstat = True  # whether /proc has the threads' time on a CPU (schedstat)
        self._woke_at = -1  # the instant of the last wake_due
        self.last_stall: dict[str, Any] | None = None
        self.warnings: deque[str] = deque(maxlen=64)  #: the latest warnings (also on stderr)
        self._flight_warned: set[str] = set()  # ptys a stall on bytes in flight was reported for
        self._ndoors = 0  # doors published on the page
        self._chan_states: list[int] = []  # the records' states at the last look, the open ones, and
        self._open: list[int] = []         # the book's changes count their totals were stored at
        self._book_seen = -1
        self._chan_keys: dict[int, tuple[tuple[int, int, int], tuple[int, str, int]]] = {}
        if self.book is not None:
            self._channels()  # (the doors, before any client looks)

    # ------------------------------------------------------------------ page access

    def _h(self, off: int) -> int:
        return self.u64[off // 8]

    def _s32(self, i: int, off: int) -> int:
        return self.u32[(vp.slot_offset(i) + off) // 4]

    def _s64(self, i: int, off: int) -> int:
        return self.u64[(vp.slot_offset(i) + off) // 8]

    def _port(self, i: int, off: int) -> int:
        return self.u64[(vp.port_offset(self.nslots, i) + off) // 8]

    def _set_port(self, i: int, off: int, value: int) -> None:
        self.u64[(vp.port_offset(self.nslots, i) + off) // 8] = value

    @property
    def vnow_ns(self) -> int:
        return self._vnow_ns

    @property
    def stalled(self) -> bool:
        return self._stall_at is not None

    @property
    def env(self) -> dict[str, str]:
        """What a client's environment needs to join (``hilbench run`` adds it from the manifest)."""
        return {vp.ENV: str(self.page)}

    # ------------------------------------------------------------------ the loop's phases

    def publish(self, t: float) -> None:
        """The loop is at virtual time ``t`` (seconds) for a new round: clients read it from now on."""
        ns = round(t * 1e9)
        if self._hint is not None and abs(self._hint - ns) <= 2:
            ns = self._hint
        self._hint = None
        if ns > self._vnow_ns:
            self._vnow_ns = ns
            self.u64[vp.H_VNOW // 8] = ns
        self.u64[vp.H_ROUND // 8] += 1

    def settle(self) -> list[int]:
        """B: publish the bench's pty counters; wait (briefly, in real time) until what was delivered since
        the last round shows on the client's side. Returns the ports delivered to."""
        fresh = []
        for i, p in enumerate(self.ptys):
            port = p.port
            self._set_port(i, vp.P_TAKEN, port.bytes_in - p.base_in)
            delivered = port.bytes_out - p.base_out
            if delivered == p.delivered:
                continue
            p.delivered = delivered
            self._set_port(i, vp.P_DELIVERED, delivered)
            fresh.append(i)
            unread = delivered - self._port(i, vp.P_READ) - self._port(i, vp.P_DISCARDED)
            end = None
            while True:
                try:
                    inq = _client_inq(port)
                except OSError:
                    break
                # (a tty's input queue holds TTY_INQ_MAX bytes at most: the rest waits in the kernel until read)
                if inq >= min(unread, TTY_INQ_MAX):
                    break
                now = time.monotonic()  # wall-clock: the kernel's hand-over takes microseconds of real time
                if end is None:
                    end = now + SETTLE_LIMIT
                elif self._reading(i):
                    break  # a client thread woke on the bytes and reads them (its count follows the read)
                elif now > end:  # (time does not move until they show, or UNSEEN_LIMIT: see look)
                    break
                os.sched_yield()
                unread = delivered - self._port(i, vp.P_READ) - self._port(i, vp.P_DISCARDED)
        if self.book is not None and (mask := self._channels()):
            fresh += [b for b in range(63) if mask >> b & 1]  # (the channels' bits, after the ptys')
        return fresh

    def _visible(self, i: int, p: _Pty, real: float) -> bool:
        """Whether what the bench delivered to pty ``i`` and no client read or dropped shows on the client's
        side (FIONREAD on the slave the bench holds; asked only while some is unread). Not for longer than
        :data:`UNSEEN_LIMIT` real seconds per delivery: a reader the shim does not count (stdio's ``fread``,
        a program outside the lockstep) takes bytes for good; that is counted in ``settle_timeouts``."""
        unread = p.delivered - self._port(i, vp.P_READ) - self._port(i, vp.P_DISCARDED)
        if unread <= 0:
            p.unseen = None
            return True
        try:
            inq = _client_inq(p.port)
        except OSError:
            return True
        if inq >= min(unread, TTY_INQ_MAX):
            p.unseen = None
            return True
        if p.unseen is None or p.unseen[0] != p.delivered:
            p.unseen = (p.delivered, real)
        elif p.unseen[1] < 0:
            return True  # (given up on for this delivery)
        elif real - p.unseen[1] > UNSEEN_LIMIT:
            p.unseen = (p.delivered, -1.0)
            self.settle_timeouts += 1
            return True
        return False

    def _reading(self, port: int) -> bool:
        """Whether a client thread that waited on ``port`` runs now (it may be reading it)."""
        bit = 1 << port
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        return any(st in (vp.RUNNING, vp.RUNNABLE, vp.WOKEN) and self._s64(i, vp.S_PORTS) & bit
                   for i, st in enumerate(states))

    def wake_due(self, fresh_ports: Iterable[int] = ()) -> int:
        """C: wake the waiters whose deadline came and those waiting on a pty just delivered to, and every
        poller once time moved or a pty was delivered to.

        A poller (a thread whose clock reads kept returning the same instant) is POLLING only for the
        instant it polled at: it does not block, and it notices news only at its next look. Left POLLING
        after time moved to a bench event before its quantum's end, it would count as waiting until it
        looked, and time could move on past the event in that (real-time) gap: the official SDK then saw
        a reply a quantum late, one cycle in a hundred (a 2.265 ms cycle where the model says 2.24)."""
        mask = 0
        for i in fresh_ports:
            mask |= 1 << i
        vnow, n = self._vnow_ns, 0
        moved = vnow != self._woke_at
        self._woke_at = vnow
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        for i, st in enumerate(states):
            polled = st == vp.POLLING and (moved or mask)
            if polled or st == vp.WAITING and (self._s64(i, vp.S_DEADLINE) <= vnow
                                               or (mask and self._s64(i, vp.S_PORTS) & mask)):
                n += self._wake(i)
        return n

    def _wake(self, i: int) -> bool:
        state = self.base + vp.slot_offset(i) + vp.S_STATE
        cas = self.atomics.cas32
        if not (cas(state, vp.WAITING, vp.WOKEN) or cas(state, vp.POLLING, vp.WOKEN)):
            return False
        self.wakes += 1
        self.atomics.wake(self.base + vp.slot_offset(i) + vp.S_WAKE)
        if self._s32(i, vp.S_FLAGS) & vp.SF_FDWAIT:
            try:
                if i not in self._wake_fds:
                    self._wake_fds[i] = os.open(self.dir / vp.WAKE_FILE.format(slot=i),
                                                os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
                os.write(self._wake_fds[i], b"w")
            except OSError:  # no reader (yet, or any more), or full: the thread re-checks on its own
                fd = self._wake_fds.pop(i, None)
                if fd is not None:
                    os.close(fd)
        return True

    def wake(self, slots: Iterable[int]) -> None:
        """RECHECK: wake ``slots`` (waiters that must look again at what they wait on)."""
        for i in slots:
            self.rechecks += self._wake(i)

    def _free(self, i: int) -> None:
        """Free slot ``i`` (its thread or process is gone: nobody else writes it now). Its pid and tid go first:
        a client that claims the slot once it is FREE has a moment before it stores its own, and a look then must
        not judge the new claim by the old owner's (dead) pid."""
        self.u32[(vp.slot_offset(i) + vp.S_PID) // 4] = 0
        self.u32[(vp.slot_offset(i) + vp.S_TID) // 4] = 0
        self.u32[(vp.slot_offset(i) + vp.S_STATE) // 4] = vp.FREE
        self._slots.pop(i, None)
        self.frees += 1
        # A thread seen asleep in a call the shim does not wrap must be seen asleep anew: a parent waiting for
        # this child in sigsuspend (bash) is woken by its SIGCHLD only after the child's pidfd said it ended.
        for other in self._slots.values():
            other.asleep = None
        self.atomics.add64(self.base + vp.H_ACTIVITY, 1)  # an exit is a hand-over (a joiner re-checks)

    def _dead(self, pid: int) -> bool:
        """Whether ``pid`` is gone (a pidfd is opened on first sight; :meth:`_reap` watches them)."""
        if pid in self._pidfds:
            return False
        try:
            self._pidfds[pid] = os.pidfd_open(pid)
        except OSError:  # gone already
            return True
        return False

    def _ended(self, pid: int) -> bool:
        """Whether process ``pid`` has ended: a zombie its parent can reap (its pidfd is readable), or gone."""
        return self._dead(pid) or bool(readable([self._pidfds[pid]], 0))

    def _reap(self, ready: Iterable[int] | None = None) -> None:
        """Free the slots of processes whose pidfd says they ended (``ready``: already polled)."""
        if not self._pidfds:
            return
        if ready is None:
            ready = readable(self._pidfds.values(), 0)
        ready = set(ready)
        for pid in [pid for pid, fd in self._pidfds.items() if fd in ready]:
            os.close(self._pidfds.pop(pid))
            self._waited.discard(pid)
            self._exiting.pop(pid, None)
            self._warned = {w for w in self._warned if w[0] != pid}  # (a pid may come back)
            for i, info in list(self._slots.items()):
                if info.pid == pid and self._s32(i, vp.S_PID) == pid and self._s32(i, vp.S_STATE) != vp.FREE:
                    self._free(i)

    def look(self, real: float | None = None) -> Verdict:
        """D: may time move now? Frees the slots of exited threads and dead processes on the way."""
        real = time.monotonic() if real is None else real
        frees = self.frees
        self._reap()
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        v = Verdict(quiet=True)
        nxt = vp.NO_DEADLINE
        foreign: list[int] = []
        asleep: list[tuple[int, int]] = []  # (slot, progress) of threads asleep in calls the shim does not wrap
        for i, st in enumerate(states):
            if st == vp.FREE:
                continue
            if st == vp.EXITED:
                pid = self._s32(i, vp.S_PID)
                # A process is ending (the shim's destructor let go of its threads): time waits until it has
                # ended, so a parent that waits for it (subprocess's polls, waitpid with WNOHANG) sees it gone
                # at the instant it ended, not one poll later in some runs (the kernel's teardown takes wall
                # time after the shim let go).
                if pid and self._s32(i, vp.S_FLAGS) & vp.SF_ENDING and not self._ended(pid) and \
                        real - self._exiting.setdefault(pid, real) < EXIT_GRACE:
                    v.quiet = False
                    continue
                self._exiting.pop(pid, None)
                self._free(i)
                continue
            pid = self._s32(i, vp.S_PID)
            info = self._slots.get(i)
            if info is None or info.pid != pid or info.tid != self._s32(i, vp.S_TID):
                info = self._slots[i] = _Slot(pid, self._s32(i, vp.S_TID), real)
                self.participants_seen += 1
            if pid and self._dead(pid):
                self._free(i)
                continue
            if st == vp.WAITING or st == vp.POLLING:
                self._waited.add(pid)
                if self._s32(i, vp.S_FLAGS) & vp.SF_FOREIGN:
                    foreign.append(i)
                nxt = min(nxt, self._s64(i, vp.S_DEADLINE))
                continue
            if st == vp.RUNNING and self._asleep_elsewhere(i, info, real):
                asleep.append((i, self._s64(i, vp.S_PROGRESS)))
                continue  # waiting in a call the shim does not wrap: no deadline
            v.quiet = False
            v.blockers.append(i)
        # Hand-overs since a waiter began to wait, judged after every slot: freeing an exited slot above is one
        # (a parent in waitpid must look again), and its slot may come before the child's.
        activity = self._h(vp.H_ACTIVITY)
        for i in foreign:
            if self._s64(i, vp.S_ACT_SEEN) < activity:
                v.recheck.append(i)
                v.quiet = False
        if self.frees != frees or v.quiet and self._moved(states, asleep):
            # A thread or process ended during this look: what it ends (a parent's read of its pipe, a joiner's
            # wait) may have been judged before, from a state that is stale now. Or a slot changed while the
            # pass looked at the others (a fork claimed one; a thread /proc showed asleep made a call since):
            # the pass is no snapshot of one instant. Look again.
            v.quiet = False
            v.again = True
        # (after every slot: a process's start-up is over once any of its threads waited)
        v.counted = any(self._slots[i].pid in self._waited or real - self._slots[i].since > self.startup_grace
                        for i in v.blockers)
        if self.book is not None:
            flight: list[str] = []
            bits = self._channels(flight)
            if bits:  # the bench sent on a channel since the last look (a reply read in D): its waiters look again
                self._wake_mask(bits)
                v.quiet = False
                v.again = True
            if flight:  # bytes (datagrams) a client sent the bench has not taken yet
                v.quiet = False
                v.counted = True
                v.flight += flight
        for i, p in enumerate(self.ptys):
            if self._port(i, vp.P_WRITTEN) > p.port.bytes_in - p.base_in and not (
                    self._refuses is not None and self._refuses(p.port)):
                v.quiet = False
                v.counted = True
                v.flight.append(p.name)
            elif v.quiet and not self._visible(i, p, real):
                # delivered bytes the kernel has not handed to the client's side yet (B's settle gave up
                # on a loaded machine): time moving now would let a waiter see them late
                v.quiet = False
                v.counted = True
                v.flight.append(p.name)
        if v.quiet and self._holding is not None and self._holding():
            v.quiet = False
            v.held = True  # (bounded by the port-state server's own timeouts: not a stall)
        v.next_ns = None if nxt == vp.NO_DEADLINE else nxt
        if v.quiet or not (v.blockers or v.flight):
            self._blocked_since = None
        elif self._blocked_since is None:
            self._blocked_since = real
        if not v.counted:
            self._counted_since = None
        elif self._counted_since is None:
            self._counted_since = real
        return v

    def _moved(self, states: list[int], asleep: list[tuple[int, int]]) -> bool:
        """Whether a slot changed state since ``states`` was read, or a thread judged asleep made progress."""
        now = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        return now != states or any(self._s64(i, vp.S_PROGRESS) != progress for i, progress in asleep)

    def _asleep_elsewhere(self, i: int, info: _Slot, real: float) -> bool:
        """A RUNNING thread that /proc shows asleep twice, :data:`BLOCKED_CONFIRM` apart, with no wrapped
        call in between (PLAN26 §4.3): it waits in a call the shim does not see (a mutex, a blocking read).

        Between two looks the thread must not have run at all: its time on a CPU (``schedstat``) is compared
        too, not only its count of wrapped calls. A thread woken from one such sleep (bash's ``sigsuspend``
        by its child's SIGCHLD, reaping it with a WNOHANG waitpid the shim does not count) that computed and
        fell asleep again somewhere else between two looks would otherwise still count as the sleeper it was."""
        confirmed = info.asleep is not None and info.asleep[1] < 0  # (seen asleep before, time moved since)
        if not info.tid or (not confirmed and (self._blocked_since is None
                                               or real - self._blocked_since < BLOCKED_CHECK)):
            info.asleep = None
            return False
        task = f"/proc/{info.pid}/task/{info.tid}"
        ran = 0
        try:
            if self._schedstat:
                try:
                    with open(f"{task}/schedstat", "rb") as f:
                        ran = int(f.read().split()[0])  # ns on a CPU (read first: a run after it shows in the state)
                except FileNotFoundError:
                    self._schedstat = os.path.exists(task)  # (a kernel without CONFIG_SCHED_INFO: progress only)
            with open(f"{task}/stat", "rb") as f:
                stat = f.read()
            state = stat[stat.rindex(b")") + 2:stat.rindex(b")") + 3]
        except (OSError, ValueError, IndexError):
            return False
        key = (self._s64(i, vp.S_PROGRESS), ran)
        if state != b"S":
            info.asleep = None
            return False
        if info.asleep is None or info.asleep[0] != key:
            info.asleep = (key, real)
            return False
        if confirmed:
            return True
        if real - info.asleep[1] < BLOCKED_CONFIRM:
            return False
        info.asleep = (key, -1.0)  # confirmed: later looks need one /proc read while it stays asleep
        self.asleep_elsewhere += 1
        return True

    def active(self) -> bool:
        """Whether any client thread holds a slot (the bench then waits for its clients)."""
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS]
        return any(states.tolist())

    # ------------------------------------------------------------------ socket channels (PLAN26 §4.8, phase 2)

    def _channels(self, flight: list[str] | None = None) -> int:
        """Publish the bench's socket doors, and store the bench's totals (:attr:`book`) beside each client
        socket's channel record. Returns the ``ports`` bits of the channels the bench sent to since the last
        call; ``flight`` gets the channels a client sent on and the bench has not taken all of yet. Records of
        processes that ended are freed."""
        book = self.book
        if len(book.doors) != self._ndoors:
            for i, (proto, host, port) in enumerate(book.doors[:vp.MAX_DOORS]):
                struct.pack_into("III", self.map, vp.door_offset(self.chan_off, i), proto, packed_ipv4(host), port)
            self._ndoors = min(len(book.doors), vp.MAX_DOORS)
            self.atomics.add64(self.base + vp.H_NCHANS, 0)  # (a full barrier: the table before its count)
            struct.pack_into("I", self.map, vp.H_NDOORS, self._ndoors)
        if not self._ndoors:
            return 0
        rec0 = vp.chan_offset(self.chan_off, 0)
        words = vp.CHAN_SIZE // 4
        states = self.u32[rec0 // 4:rec0 // 4 + words * self.nchans:words].tolist()
        if states != self._chan_states:  # (a record claimed or freed: which are open, and their totals again)
            self._chan_states = states
            self._open = [c for c, st in enumerate(states) if st == vp.CH_OPEN]
            self._book_seen = -1
        if not self._open:
            return 0
        sync = book.changes != self._book_seen  # (the bench's totals moved: store them)
        self._book_seen = book.changes
        if not sync and flight is None:
            return 0
        u32, u64, mask, nports = self.u32, self.u64, 0, len(self.ptys)
        for c in self._open:
            off = rec0 + vp.CHAN_SIZE * c
            w, q = off // 4, off // 8
            ident = (u32[w + vp.C_PROTO // 4], u32[w + vp.C_ADDR // 4], u32[w + vp.C_PORT // 4])
            known = self._chan_keys.get(c)
            if known is None or known[0] != ident:
                host = unpacked_ipv4(ident[1])
                known = self._chan_keys[c] = (ident, (ident[0], host, ident[2]))
            pid = u32[w + vp.C_PID // 4]
            if pid and self._dead(pid):
                u32[w + vp.C_STATE // 4] = vp.CH_FREE
                continue
            taken = u64[q + vp.C_BENCH_TAKEN // 8]
            totals = book.totals.get(known[1]) if sync else None
            if totals is not None:
                sent, taken = totals
                if u64[q + vp.C_BENCH_SENT // 8] != sent:
                    # (an atomic add: a full barrier before the waiters' states are read)
                    self.atomics.add64(self.base + off + vp.C_BENCH_SENT,
                                       (sent - u64[q + vp.C_BENCH_SENT // 8]) % 2**64)
                    mask |= 1 << vp.chan_bit(nports, c)
                if u64[q + vp.C_BENCH_TAKEN // 8] != taken:
                    u64[q + vp.C_BENCH_TAKEN // 8] = taken
            if flight is not None and u64[q + vp.C_SENT // 8] > taken and not self._door_refuses(
                    u32[w + vp.C_FLAGS // 4] >> 8 & 0xFF):
                flight.append(f"{'tcp' if ident[0] == vp.TCP else 'udp'} {known[1][1]}:{ident[2]}")
        return mask

    def _door_refuses(self, door: int) -> bool:
        """Whether the host port behind door ``door`` (1 + its index; 0: unknown) is left unread on purpose (a
        serial line holding its writer back): its clients' datagrams wait for the wire, not in flight."""
        ports = self.book.door_ports
        return bool(door) and door <= len(ports) and ports[door - 1] is not None and self._refuses is not None \
            and self._refuses(ports[door - 1])

    def _wake_mask(self, mask: int) -> None:
        """Wake the threads waiting on a port or channel in ``mask`` (bits of the slots' ``ports``)."""
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        for i, st in enumerate(states):
            if st == vp.WAITING and self._s64(i, vp.S_PORTS) & mask:
                self._wake(i)

    def channels(self) -> list[dict[str, Any]]:
        """The open channel records: the client's address and the four counts (for reports and tests)."""
        out = []
        for c in range(self.nchans):
            off = vp.chan_offset(self.chan_off, c)
            st, pid, proto, addr, port, flags = struct.unpack_from("6I", self.map, off)
            if st != vp.CH_OPEN:
                continue
            sent, received, bench_sent, bench_taken, given_up = struct.unpack_from("5Q", self.map, off + vp.C_SENT)
            out.append({"proto": "tcp" if proto == vp.TCP else "udp",
                        "address": f"{unpacked_ipv4(addr)}:{port}", "pid": pid,
                        "sent": sent, "received": received, "bench_sent": bench_sent, "bench_taken": bench_taken,
                        "given_up": given_up})
        return out

    # ------------------------------------------------------------------ waiting for news (D)

    def fds(self) -> list[int]:
        """What D waits on besides the bench's host ports: the notify FIFO and the clients' pidfds."""
        return [self.notify, *self._pidfds.values()]

    def arm(self) -> list[int]:
        """Ask clients to write to the notify FIFO from now on; returns the slot states as they are, to
        compare before blocking (a change before the arming would otherwise go unnoticed)."""
        self.u32[vp.H_ARMED // 4] = 1
        return self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()

    def disarm(self, ready: Iterable[int] = ()) -> None:
        self.u32[vp.H_ARMED // 4] = 0
        if self.notify in ready:
            with contextlib.suppress(BlockingIOError):
                os.read(self.notify, 4096)
        self._reap([fd for fd in ready if fd != self.notify])

    def unchanged(self, states: list[int]) -> bool:
        return states == self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()

    def wait_hint(self, v: Verdict, real: float) -> float:
        """Real seconds D may block for news given ``v`` (a stall, or a /proc look, is due sooner)."""
        timeout = BLOCKED_CONFIRM if v.held else LOOK_AGAIN
        if v.blockers and self._blocked_since is not None:
            since = real - self._blocked_since
            if since < BLOCKED_CHECK + BLOCKED_CONFIRM * 2:
                timeout = BLOCKED_CONFIRM
            if self.stall is not None and self._stall_at is None and self._counted_since is not None:
                timeout = min(timeout, max(0.0, self.stall - (real - self._counted_since)))
        if self._stall_at is not None:
            timeout = min(timeout, 0.001)
        return timeout

    # ------------------------------------------------------------------ the stall watchdog

    def stall_target(self, v: Verdict, real: float) -> int | None:
        """While not quiet: the virtual ns the clock may follow the wall clock to (a stall), or None."""
        if self._stall_at is None:
            if (self.stall is None or not v.counted or self._counted_since is None
                    or real - self._counted_since < self.stall):
                return None
            self._start_stall(v, real)
        v0, r0 = self._stall_at  # type: ignore[misc]
        return v0 + int((real - r0) * 1e9)

    def _start_stall(self, v: Verdict, real: float) -> None:
        self._stall_at = (self._vnow_ns, real)
        self.u64[vp.H_STALLS // 8] += 1
        self.u32[vp.H_FLAGS // 4] |= vp.FLAG_STALL
        ran = real - (self._counted_since or real)
        for i in v.blockers:
            pid, tid, st = self._s32(i, vp.S_PID), self._s32(i, vp.S_TID), self._s32(i, vp.S_STATE)
            comm = _comm(pid, tid)
            self.last_stall = {"pid": pid, "tid": tid, "comm": comm, "state": vp.STATE_NAMES[st],
                               "since": self._vnow_ns / 1e9}
            if (pid, tid) in self._warned:
                continue
            self._warned.add((pid, tid))
            self._say(f"hilbench: lockstep stall: thread {pid}/{tid} ({comm}) ran {ran:.1f} s without waiting; "
                      "time follows the wall clock until it waits")
        if v.flight and not v.blockers:
            self.last_stall = {"pid": 0, "tid": 0, "comm": "", "state": "FLIGHT", "since": self._vnow_ns / 1e9,
                               "ptys": list(v.flight)}
            if self._flight_warned.issuperset(v.flight):
                return  # (once per pty, as once per thread above: the stall counter has every one)
            self._flight_warned.update(v.flight)
            self._say(f"hilbench: lockstep stall: bytes written to {', '.join(v.flight)} were not taken (or bytes "
                      f"delivered did not show on the client's side) for {ran:.1f} s; time follows the wall clock")

    def _say(self, msg: str) -> None:
        self.warnings.append(msg)
        print(msg, file=sys.stderr, flush=True)

    def end_stall(self) -> None:
        """Quiescence again: back to lockstep (the stall's virtual seconds are counted)."""
        if self._stall_at is None:
            return
        self.u64[vp.H_STALLED_NS // 8] += self._vnow_ns - self._stall_at[0]
        self.u32[vp.H_FLAGS // 4] &= ~vp.FLAG_STALL
        self._stall_at = None

    def moved_to(self, ns: int) -> float:
        """The loop is about to move time to ``ns`` (a client deadline): seconds, remembered exactly."""
        self._hint = ns
        return ns / 1e9

    # ------------------------------------------------------------------ reporting

    def stats(self) -> dict[str, Any]:
        """The counters: stalls, the virtual seconds they lasted, the last one; clients, wakes."""
        states = self.u32[_STATE_WORD:_STATE_WORD + _SLOT_WORDS * self.nslots:_SLOT_WORDS].tolist()
        return {"vnow": self._vnow_ns / 1e9, "round": self._h(vp.H_ROUND), "stalls": self._h(vp.H_STALLS),
                "stalled_s": self._h(vp.H_STALLED_NS) / 1e9, "stalling": self._stall_at is not None,
                "last_stall": self.last_stall, "threads": sum(1 for s in states if s not in (vp.FREE, vp.EXITED)),
                "threads_seen": self.participants_seen, "wakes": self.wakes, "rechecks": self.rechecks,
                "asleep_elsewhere": self.asleep_elsewhere, "settle_timeouts": self.settle_timeouts,
                "unvirtualised": self._h(vp.H_UNVIRTUALISED), "channel_timeouts": self._h(vp.H_CHAN_TIMEOUTS)}

    def describe(self) -> dict[str, Any]:
        """The manifest's ``clock`` entry (what ``hilbench run`` reads)."""
        return {"virtual": True, "page": str(self.page), "notify": str(self.notify_path),
                "epoch": self.epoch_ns / 1e9, "origin": self.origin_ns / 1e9,
                "stall": self.stall, "stats": self.stats()}

    status = stats

    def close(self) -> None:
        if self.map.closed:
            return
        for fd in [self.notify, *self._wake_fds.values(), *self._pidfds.values()]:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_fds.clear()
        self._pidfds.clear()
        del self.u32, self.u64, self._buf
        with contextlib.suppress(BufferError):
            self.map.close()
        shutil.rmtree(self.dir, ignore_errors=True)


def _client_inq(port: Any) -> int:
    """The bytes a client of the pty ``port`` can read now: its input queue (FIONREAD on the slave the bench
    holds) and, while the port is served (``hilbench run``'s serving path), its ring."""
    inq = struct.unpack("i", fcntl.ioctl(port.slave_fd, termios.FIONREAD, b"\0" * 4))[0]
    pending = getattr(port, "serve_pending", None)
    return inq + pending() if pending is not None else inq


def _comm(pid: int, tid: int) -> str:
    try:
        return Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
    except OSError:
        return "?"


__all__ = ["BLOCKED_CHECK", "STALL", "STARTUP_GRACE", "Lockstep", "Verdict"]
