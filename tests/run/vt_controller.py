"""A fake lockstep controller for the virtual-time shim's tests (the bench's loop comes in PLAN26 step 3).

It owns a clock page (:mod:`hilbench.run.vclock_page`) and the FIFOs beside it, and
advances virtual time when every live client thread waits: to the earliest deadline
(a sleep's end, a timeout, a poller's quantum) or scheduled delivery (bytes written
to a pty master at a virtual instant, settled before the waiters on that port wake). A
waiter on something a client hands over (``SF_FOREIGN``) is woken to re-check when
``activity`` moved since it began to wait. A thread that runs without waiting for
``stall`` wall seconds starts a lockstep stall: time then follows the wall clock until
every thread waits again, counted in the header and warned about once per thread.
The page's atomics come from the shim library itself (``hb_vclock_cas32`` and friends).
"""

from __future__ import annotations

import ctypes
import fcntl
import heapq
import mmap
import os
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

from hilbench.run import vclock_page as vp


class VtController:
    def __init__(self, directory: Path, library: str | os.PathLike[str], *, nslots: int = 32, poll_k: int = 32,
                 quantum_ns: int = 100_000, stall: float = 1.0, epoch_ns: int | None = None,
                 ports: list[tuple[int, int]] = ()) -> None:
        """``ports``: (rdev, slave fd) of each bench pty; the controller reads FIONREAD on the slave to settle."""
        self.dir, self.nslots, self.stall = Path(directory), nslots, stall
        self.ports = list(ports)
        self.page = self.dir / vp.PAGE_FILE
        size = vp.page_size(nslots, len(self.ports))
        self.page.write_bytes(bytes(size))
        os.mkfifo(self.dir / vp.NOTIFY_FILE)
        for i in range(nslots):
            os.mkfifo(self.dir / vp.WAKE_FILE.format(slot=i))
        fd = os.open(self.page, os.O_RDWR)
        self.map = mmap.mmap(fd, size)
        os.close(fd)
        self.notify = os.open(self.dir / vp.NOTIFY_FILE, os.O_RDWR | os.O_NONBLOCK)
        self.lib = ctypes.CDLL(str(library))
        self.lib.hb_vclock_cas32.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
        self.lib.hb_vclock_wake.argtypes = [ctypes.c_void_p]
        self.lib.hb_vclock_add64.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        self._buf = (ctypes.c_char * size).from_buffer(self.map)
        self.base = ctypes.addressof(self._buf)
        self.u32, self.u64 = memoryview(self.map).cast("I"), memoryview(self.map).cast("Q")
        m = self.map
        m[0:8] = vp.MAGIC
        struct.pack_into("III", m, vp.H_VERSION, vp.VERSION, nslots, len(self.ports))
        for i, (rdev, _slave) in enumerate(self.ports):
            struct.pack_into("Q", m, vp.port_offset(nslots, i) + vp.P_RDEV, rdev)
        self._events: list[tuple[int, int, int, int, bytes]] = []  # (t, seq, port, master fd, data)
        struct.pack_into("QQ", m, vp.H_VNOW, vp.ORIGIN_NS, time.time_ns() if epoch_ns is None else epoch_ns)
        struct.pack_into("I", m, vp.H_POLL_K, poll_k)
        struct.pack_into("Q", m, vp.H_POLL_QUANTUM, quantum_ns)
        struct.pack_into("Q", m, vp.H_ORIGIN, vp.ORIGIN_NS)
        self.advances = self.rechecks = 0
        self.warnings: list[str] = []
        self._warned: set[tuple[int, int]] = set()
        self._wake_fds: dict[int, int] = {}
        self._pidfds: dict[int, int] = {}

    # page access
    def h(self, off: int) -> int:
        return self.u64[off // 8]

    def s32(self, i: int, off: int) -> int:
        return self.u32[(vp.slot_offset(i) + off) // 4]

    def s64(self, i: int, off: int) -> int:
        return self.u64[(vp.slot_offset(i) + off) // 8]

    @property
    def vnow(self) -> int:
        return self.h(vp.H_VNOW)

    @property
    def stalls(self) -> int:
        return self.h(vp.H_STALLS)

    @property
    def env(self) -> dict[str, str]:
        return {vp.ENV: str(self.page)}

    def port(self, i: int, off: int) -> int:
        return self.u64[(vp.port_offset(self.nslots, i) + off) // 8]

    def deliver_at(self, t: int, port: int, master: int, data: bytes) -> None:
        """Write ``data`` to ``master`` (port record ``port``) when virtual time reaches ``t`` ns."""
        heapq.heappush(self._events, (t, len(self._events), port, master, data))

    def _run_events(self, v: int) -> None:
        woken: set[int] = set()
        while self._events and self._events[0][0] <= v:
            _t, _seq, port, master, data = heapq.heappop(self._events)
            os.write(master, data)
            off = (vp.port_offset(self.nslots, port) + vp.P_DELIVERED) // 8
            self.u64[off] += len(data)
            woken.add(port)
        for port in woken:  # settle: the client sees every delivered byte before it is woken
            unread = self.port(port, vp.P_DELIVERED) - self.port(port, vp.P_READ) - self.port(port, vp.P_DISCARDED)
            end = time.monotonic() + 0.5
            while self._inq(self.ports[port][1]) < unread and time.monotonic() < end:
                pass
        for i, state, _d, flags, *_ in self._scan():
            ports = self.s64(i, vp.S_PORTS)
            if state == vp.WAITING and flags & vp.SF_FDWAIT and any(ports >> p & 1 for p in woken):
                self._wake(i)

    @staticmethod
    def _inq(fd: int) -> int:
        return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4))[0]

    def _set(self, off: int, value: int) -> None:
        self.u64[off // 8] = value

    def _wake(self, i: int) -> bool:
        state = self.base + vp.slot_offset(i) + vp.S_STATE
        if not (self.lib.hb_vclock_cas32(state, vp.WAITING, vp.WOKEN) or
                self.lib.hb_vclock_cas32(state, vp.POLLING, vp.WOKEN)):
            return False
        self.lib.hb_vclock_wake(self.base + vp.slot_offset(i) + vp.S_WAKE)
        if self.s32(i, vp.S_FLAGS) & vp.SF_FDWAIT:
            try:
                if i not in self._wake_fds:
                    self._wake_fds[i] = os.open(self.dir / vp.WAKE_FILE.format(slot=i), os.O_WRONLY | os.O_NONBLOCK)
                os.write(self._wake_fds[i], b"w")
            except OSError:  # no reader (yet, or any more), or full: it re-checks on its own
                os.close(self._wake_fds.pop(i, -1)) if i in self._wake_fds else None
        return True

    def _reap(self) -> None:
        """EXITED slots and the slots of dead processes become FREE (an exit is activity)."""
        for i in range(self.nslots):
            state, pid = self.s32(i, vp.S_STATE), self.s32(i, vp.S_PID)
            if state == vp.FREE:
                continue
            dead = state == vp.EXITED
            if not dead and pid:
                if pid not in self._pidfds:
                    try:
                        self._pidfds[pid] = os.pidfd_open(pid)
                    except ProcessLookupError:
                        dead = True
                if pid in self._pidfds and select.select([self._pidfds[pid]], [], [], 0)[0]:
                    dead = True
            if dead:
                self.u32[(vp.slot_offset(i) + vp.S_STATE) // 4] = vp.FREE
                self.lib.hb_vclock_add64(self.base + vp.H_ACTIVITY, 1)

    def _scan(self) -> list[tuple[int, int, int, int, int, int]]:
        return [(i, self.s32(i, vp.S_STATE), self.s64(i, vp.S_DEADLINE), self.s32(i, vp.S_FLAGS),
                 self.s64(i, vp.S_ACT_SEEN), self.s32(i, vp.S_WAKE))
                for i in range(self.nslots) if self.s32(i, vp.S_STATE) != vp.FREE]

    def _advance(self, v: int) -> None:
        self._set(vp.H_VNOW, v)
        self._set(vp.H_ROUND, self.h(vp.H_ROUND) + 1)
        self._run_events(v)
        for i, state, deadline, *_ in self._scan():
            if state in (vp.WAITING, vp.POLLING) and deadline <= v:
                self._wake(i)

    def _warn(self, live) -> None:
        for i, state, *_ in live:
            pid, tid = self.s32(i, vp.S_PID), self.s32(i, vp.S_TID)
            if state in (vp.RUNNING, vp.RUNNABLE) and (pid, tid) not in self._warned:
                self._warned.add((pid, tid))
                try:
                    comm = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
                except OSError:
                    comm = "?"
                msg = (f"hilbench: lockstep stall: thread {pid}/{tid} ({comm}) ran {self.stall:.1f} s without "
                       "waiting; time follows the wall clock until it waits")
                self.warnings.append(msg)
                print(msg, file=sys.stderr)

    def serve(self, proc: subprocess.Popen, timeout: float = 30.0) -> None:
        """Run the clock until ``proc`` exits (killing it after ``timeout`` wall seconds)."""
        end = time.monotonic() + timeout
        blocked_since = stall_at = None
        exited = os.pidfd_open(proc.pid)
        while proc.poll() is None:
            now = time.monotonic()
            if now > end:
                proc.kill()
                proc.wait()
                raise TimeoutError(f"client still running after {timeout} s wall (vnow {self.vnow})")
            self._reap()
            live, act = self._scan(), self.h(vp.H_ACTIVITY)
            stale = [i for i, st, _d, fl, seen, _w in live if st == vp.WAITING and fl & vp.SF_FOREIGN and seen < act]
            for i in stale:  # RECHECK: a hand-over since it began to wait
                self.rechecks += self._wake(i)
            if live and not stale and all(st in (vp.WAITING, vp.POLLING) for _i, st, *_ in live):
                blocked_since = None
                if stall_at is not None:
                    self._set(vp.H_STALLED_NS, self.h(vp.H_STALLED_NS) + self.vnow - stall_at[0])
                    self.u32[vp.H_FLAGS // 4] &= ~vp.FLAG_STALL
                    stall_at = None
                nxt = min([d for _i, _st, d, *_ in live] + [e[0] for e in self._events[:1]])
                if nxt != vp.NO_DEADLINE:
                    self.advances += 1
                    self._advance(max(self.vnow, nxt))
                    continue
            elif live and not stale:
                blocked_since = blocked_since or now
                if stall_at is None and now - blocked_since > self.stall:
                    stall_at = (self.vnow, now)
                    self._set(vp.H_STALLS, self.h(vp.H_STALLS) + 1)
                    self.u32[vp.H_FLAGS // 4] |= vp.FLAG_STALL
                    self._warn(live)
                if stall_at is not None:  # rate 1: virtual time follows the wall clock
                    self._advance(max(self.vnow, stall_at[0] + int((now - stall_at[1]) * 1e9)))
            self._wait_news(live, 0.01 if stall_at else 0.05, exited)
        os.close(exited)

    def _wait_news(self, seen, timeout: float, exited: int) -> None:
        self.u32[vp.H_ARMED // 4] = 1
        if self._scan() == seen:  # anything that changed before the arming is seen here
            select.select([self.notify, exited], [], [], timeout)
        self.u32[vp.H_ARMED // 4] = 0
        try:
            os.read(self.notify, 4096)
        except BlockingIOError:
            pass

    def close(self) -> None:
        for fd in [self.notify, *self._wake_fds.values(), *self._pidfds.values()]:
            os.close(fd)
        del self.u32, self.u64, self._buf
        self.map.close()
