"""The lockstep controller (:mod:`hilbench.bench.lockstep`) without the shim: this test plays the client by
writing its slots on the clock page the way ``vclock.c`` does, and checks the controller's verdicts (when time
may move, and to when), its wake-ups, the pty counters, the stall watchdog, and the loop's order at one
instant (the bench's events before the clients' wake-ups)."""

from __future__ import annotations

import fcntl
import os
import struct
import subprocess
import sys
import termios
import threading
import tty
from types import SimpleNamespace

import pytest

from hilbench.bench import clock_page as vp
from hilbench.bench.lockstep import Lockstep
from hilbench.pytest_plugin import wait_until
from hilbench.transports.channel_book import ChannelBook, packed_ipv4
from hilbench.transports.clock import VirtualClock
from hilbench.transports.virtual_loop import VirtualLoop

S = 10**9
V0 = vp.ORIGIN_NS


@pytest.fixture
def lockstep():
    made: list[Lockstep] = []

    def make(*args, **kw) -> Lockstep:
        kw.setdefault("nslots", 8)
        made.append(Lockstep(*args, **kw))
        return made[-1]

    yield make
    for ls in made:
        ls.close()


def put(ls: Lockstep, i: int, state: int, deadline: int = vp.NO_DEADLINE, *, pid: int | None = None,
        tid: int | None = None, flags: int = 0, ports: int = 0, act_seen: int = 0) -> None:
    """Write slot ``i`` as a client thread would (state last)."""
    base = vp.slot_offset(i)
    struct.pack_into("II", ls.map, base + vp.S_PID, os.getpid() if pid is None else pid,
                     threading.get_native_id() if tid is None else tid)
    struct.pack_into("QQQ", ls.map, base + vp.S_DEADLINE, deadline, ports, act_seen)
    struct.pack_into("I", ls.map, base + vp.S_FLAGS, flags)
    struct.pack_into("I", ls.map, base + vp.S_STATE, state)


def state(ls: Lockstep, i: int) -> int:
    return struct.unpack_from("I", ls.map, vp.slot_offset(i) + vp.S_STATE)[0]


def word(ls: Lockstep, i: int) -> int:
    return struct.unpack_from("I", ls.map, vp.slot_offset(i) + vp.S_WAKE)[0]


def test_the_page_is_laid_out_for_the_shim(lockstep):
    ls = lockstep(nslots=4, epoch_ns=1_700_000_000 * S, stall=2.0)
    m = ls.map
    assert m[0:8] == vp.MAGIC
    assert struct.unpack_from("III", m, vp.H_VERSION) == (vp.VERSION, 4, 0)
    assert struct.unpack_from("QQ", m, vp.H_VNOW) == (V0, 1_700_000_000 * S)
    assert struct.unpack_from("Q", m, vp.H_ORIGIN)[0] == V0
    assert len(m) == vp.page_size(4, 0)
    names = sorted(p.name for p in ls.dir.iterdir())
    assert names == sorted([vp.PAGE_FILE, vp.NOTIFY_FILE] + [vp.WAKE_FILE.format(slot=i) for i in range(4)])
    assert os.stat(ls.dir).st_mode & 0o777 == 0o700
    entry = ls.describe()
    assert entry["virtual"] and entry["page"] == str(ls.page) and entry["stall"] == 2.0
    assert entry["stats"]["stalls"] == 0 and entry["stats"]["threads"] == 0
    directory = ls.dir
    ls.close()
    assert not directory.exists()


def test_time_moves_to_the_earliest_deadline_when_every_thread_waits(lockstep):
    ls = lockstep()
    v = ls.look()
    assert v.quiet and v.next_ns is None and not ls.active()
    put(ls, 0, vp.WAITING, V0 + 3 * S)
    put(ls, 1, vp.POLLING, V0 + 100_000)  # a poller's quantum
    put(ls, 2, vp.WAITING)  # no deadline (a join, a blocking read)
    v = ls.look()
    assert ls.active() and v.quiet and v.next_ns == V0 + 100_000
    put(ls, 3, vp.RUNNING)
    v = ls.look()
    assert not v.quiet and v.blockers == [3]
    for st in (vp.STARTING, vp.RUNNABLE, vp.WOKEN):
        put(ls, 3, st)
        assert not ls.look().quiet, vp.STATE_NAMES[st]


def test_exited_threads_and_dead_processes_give_their_slots_back(lockstep):
    ls = lockstep()
    gone = subprocess.Popen(["true"])
    gone.wait()
    put(ls, 0, vp.EXITED)
    put(ls, 1, vp.RUNNING, pid=gone.pid, tid=gone.pid)  # killed while it ran
    activity = ls.u64[vp.H_ACTIVITY // 8]
    v = ls.look()
    assert not v.quiet and v.again  # (a look that freed a slot is made again before time moves)
    assert state(ls, 0) == state(ls, 1) == vp.FREE
    assert ls.u64[vp.H_ACTIVITY // 8] == activity + 2  # exits are hand-overs: joiners re-check
    assert struct.unpack_from("II", ls.map, vp.slot_offset(1) + vp.S_PID) == (0, 0)  # (no dead pid left in it)
    assert ls.look().quiet


def test_time_waits_for_an_ending_process_to_have_ended(lockstep):
    """A process whose shim let go at exit (SF_ENDING) holds time until it has ended, so a parent polling for
    it sees it gone at that instant in every run; a thread that left alone (no SF_ENDING) does not."""
    ls = lockstep()
    ending = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        put(ls, 0, vp.EXITED, pid=ending.pid, tid=ending.pid, flags=vp.SF_ENDING)
        put(ls, 1, vp.EXITED, pid=ending.pid, tid=ending.pid + 1)  # one of its threads, earlier
        v = ls.look()
        assert not v.quiet and state(ls, 0) == vp.EXITED and state(ls, 1) == vp.FREE
        ending.stdin.close()
        ending.wait(timeout=30)  # (reaped here; a zombie counts as ended too)
        v = ls.look()
        assert not v.quiet and v.again and state(ls, 0) == vp.FREE
        assert ls.look().quiet
    finally:
        ending.kill()
        ending.wait()


def test_a_parent_judged_before_its_childs_end_in_the_same_look_is_woken_to_look_again(lockstep):
    """A look goes over the slots in order: a parent waiting for its child (waitpid: a hand-over wait), in a
    slot before the child's, was judged before the child's slot was freed in the same look. Its end is a
    hand-over the parent must see: the parent is re-checked and time does not move (before, it moved to the
    bench's next event: shell start-ups took a different amount of virtual time each run)."""
    ls = lockstep()
    activity = ls.u64[vp.H_ACTIVITY // 8]
    put(ls, 0, vp.WAITING, flags=vp.SF_FOREIGN, act_seen=activity)  # the parent, in waitpid
    put(ls, 1, vp.EXITED, tid=threading.get_native_id() + 1)  # its child's (here: a thread's) end
    v = ls.look()
    assert not v.quiet and v.recheck == [0] and state(ls, 1) == vp.FREE


def test_a_look_is_made_again_when_a_slot_changed_during_it(lockstep, monkeypatch):
    """A slot claimed (a fork) while the look went over the others: the verdict is no snapshot of one instant."""
    ls = lockstep()
    put(ls, 0, vp.WAITING, V0 + S)
    judge = ls._asleep_elsewhere

    def claim_meanwhile(*args):
        put(ls, 2, vp.STARTING, pid=0, tid=0)
        return judge(*args)

    put(ls, 1, vp.RUNNING)
    monkeypatch.setattr(ls, "_asleep_elsewhere", lambda *args: claim_meanwhile(*args) or True)
    v = ls.look()
    assert not v.quiet and v.again
    assert not ls.look().quiet  # (the claim is a blocker now)


def test_a_waiter_on_a_hand_over_is_woken_to_look_again(lockstep):
    ls = lockstep()
    put(ls, 0, vp.WAITING, flags=vp.SF_FOREIGN, act_seen=0)
    assert ls.look().quiet
    ls.atomics.add64(ls.base + vp.H_ACTIVITY, 1)  # another client thread posted, wrote to a pipe, ...
    v = ls.look()
    assert not v.quiet and v.recheck == [0]
    before = word(ls, 0)
    ls.wake(v.recheck)
    assert state(ls, 0) == vp.WOKEN and word(ls, 0) == before + 1 and ls.rechecks == 1


def test_due_waiters_are_woken_and_the_others_left(lockstep):
    ls = lockstep()
    put(ls, 0, vp.WAITING, V0 + S)
    put(ls, 1, vp.WAITING, V0 + 2 * S)
    put(ls, 2, vp.POLLING, V0 + S)
    ls.publish(1001.0)
    assert ls.vnow_ns == V0 + S and ls.u64[vp.H_VNOW // 8] == V0 + S
    assert ls.wake_due() == 2
    assert [state(ls, i) for i in range(3)] == [vp.WOKEN, vp.WAITING, vp.WOKEN]
    assert word(ls, 0) == 1 and word(ls, 1) == 0
    ls.publish(1000.5)  # never backwards
    assert ls.vnow_ns == V0 + S



def test_a_poller_is_woken_whenever_time_moved_or_a_pty_was_delivered_to(lockstep):
    """A POLLING thread holds for the instant it polled at: time moving to a bench event before its quantum
    ends (or a delivery at that instant) wakes it to look, so time cannot pass the event before it did."""
    ls = lockstep()
    ls.publish(1000.0)
    ls.wake_due()  # (the round at 1000.0 began)
    put(ls, 0, vp.POLLING, V0 + 100_000)
    put(ls, 1, vp.WAITING, V0 + 100_000)  # (a plain waiter stays: its deadline has not come)
    assert ls.wake_due() == 0  # the instant it polled at, and no news: it stays POLLING
    assert state(ls, 0) == vp.POLLING
    ls.publish(1000.000075)  # a reply's delivery, before the poller's quantum ends
    assert ls.wake_due() == 1
    assert [state(ls, 0), state(ls, 1)] == [vp.WOKEN, vp.WAITING] and word(ls, 0) == 1
    put(ls, 0, vp.POLLING, V0 + 175_000)  # it looked, and polls again at this instant
    assert ls.wake_due() == 0 and state(ls, 0) == vp.POLLING
    assert ls.wake_due([0]) == 1 and state(ls, 0) == vp.WOKEN  # a delivery at the same instant

@pytest.fixture
def pty():
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    port = SimpleNamespace(bytes_in=0, bytes_out=0, rdev=os.fstat(slave).st_rdev, slave_fd=slave)
    yield master, port
    os.close(master)
    os.close(slave)


def test_bytes_in_flight_on_a_pty_keep_time_still(lockstep, pty):
    master, port = pty
    ls = lockstep([("lidar", port)])
    rec = vp.port_offset(ls.nslots, 0)
    assert struct.unpack_from("Q", ls.map, rec + vp.P_RDEV)[0] == port.rdev
    put(ls, 0, vp.WAITING, V0 + S)
    struct.pack_into("Q", ls.map, rec + vp.P_WRITTEN, 5)  # the client wrote 5 bytes the bench has not read
    v = ls.look()
    assert not v.quiet and v.flight == ["lidar"] and v.counted
    port.bytes_in = 5  # the bench took them
    ls.settle()
    assert struct.unpack_from("Q", ls.map, rec + vp.P_TAKEN)[0] == 5
    assert ls.look().quiet


def test_bytes_the_bench_leaves_unread_on_purpose_are_not_in_flight(lockstep, pty):
    """A line holding its writer back (the wire is behind) leaves bytes unread: time must move for the wire to
    drain, so they do not keep it still."""
    master, port = pty
    refused = {"lidar": True}
    ls = lockstep([("lidar", port)], refuses=lambda p: refused["lidar"] if p is port else False)
    rec = vp.port_offset(ls.nslots, 0)
    put(ls, 0, vp.WAITING, V0 + S)
    struct.pack_into("Q", ls.map, rec + vp.P_WRITTEN, 5)
    assert ls.look().quiet
    refused["lidar"] = False  # released: now they are in flight until read
    v = ls.look()
    assert not v.quiet and v.flight == ["lidar"]


def test_a_stall_on_bytes_in_flight_warns_once_per_pty(lockstep, pty, capfd):
    master, port = pty
    ls = lockstep([("lidar", port)], stall=0.5)
    rec = vp.port_offset(ls.nslots, 0)
    put(ls, 0, vp.WAITING, V0 + S)
    struct.pack_into("Q", ls.map, rec + vp.P_WRITTEN, 5)
    for start in (100.0, 200.0):  # two stalls on the same pty, time back in lockstep between them
        v = ls.look(real=start)
        assert v.flight == ["lidar"] and ls.stall_target(v, start + 1.0) is not None
        ls.end_stall()
    assert ls.stats()["stalls"] == 2
    (warning,) = ls.warnings
    assert "bytes written to lidar were not taken" in warning and capfd.readouterr().err.count(warning) == 1


def test_a_delivery_is_settled_and_wakes_its_waiter(lockstep, pty):
    master, port = pty
    ls = lockstep([("lidar", port)])
    reader = os.open(ls.dir / vp.WAKE_FILE.format(slot=0), os.O_RDONLY | os.O_NONBLOCK)
    try:
        put(ls, 0, vp.WAITING, flags=vp.SF_FDWAIT, ports=1)  # select() on the pty, no timeout
        put(ls, 1, vp.WAITING, flags=vp.SF_FDWAIT, ports=2)  # another port
        port.bytes_out += os.write(master, b"x" * 300)
        assert ls.settle() == [0]
        inq = struct.unpack("i", fcntl.ioctl(port.slave_fd, termios.FIONREAD, b"\0" * 4))[0]
        assert inq == 300  # visible on the client's side before anyone is woken
        assert struct.unpack_from("Q", ls.map, vp.port_offset(ls.nslots, 0) + vp.P_DELIVERED)[0] == 300
        assert ls.wake_due([0]) == 1
        assert state(ls, 0) == vp.WOKEN and state(ls, 1) == vp.WAITING
        assert os.read(reader, 16) == b"w"  # descriptor waits also get a byte on their wake FIFO
        assert ls.settle() == []  # nothing new: no settling, no waking
    finally:
        os.close(reader)


def test_time_waits_until_delivered_bytes_show_on_the_clients_side(lockstep, pty):
    """Quiescence needs every byte the bench delivered visible on the client's side (the kernel's hand-over
    took up to 31 ms on a loaded machine, far past B's settle): a waiter would see them late otherwise. A
    reader that takes them unseen (stdio, a program outside the lockstep) holds time for UNSEEN_LIMIT at most,
    counted."""
    from hilbench.bench import lockstep as lockstep_module

    master, port = pty
    ls = lockstep([("lidar", port)])
    put(ls, 0, vp.WAITING, flags=vp.SF_FDWAIT, ports=1)
    port.bytes_out += 300  # delivered, and still in the kernel's hands
    assert ls.settle() == [0]  # (B gives up after SETTLE_LIMIT)
    v = ls.look(real=10.0)
    assert not v.quiet and v.flight == ["lidar"] and ls.stats()["settle_timeouts"] == 0
    os.write(master, b"x" * 300)
    wait_until(lambda: ls.look(real=10.01).quiet, timeout=5)  # they show: time may move
    os.read(port.slave_fd, 300)  # taken by a reader the shim does not count
    port.bytes_out += os.write(master, b"y" * 10)
    ls.settle()
    assert not ls.look(real=20.0).quiet
    assert not ls.look(real=20.0 + lockstep_module.UNSEEN_LIMIT / 2).quiet
    assert ls.look(real=20.0 + lockstep_module.UNSEEN_LIMIT * 1.5).quiet  # given up on, and counted
    assert ls.stats()["settle_timeouts"] == 1

def test_the_stall_watchdog(lockstep, capfd):
    ls = lockstep(stall=0.5, startup_grace=10.0)
    put(ls, 0, vp.RUNNING)  # this thread: /proc shows it running
    v = ls.look(real=100.0)
    assert not v.quiet and not v.counted  # start-up grace: the process never waited yet
    assert ls.stall_target(v, 100.9) is None
    put(ls, 1, vp.WAITING, V0 + 5 * S)  # one of its threads waits: its start-up is over
    v = ls.look(real=101.0)
    assert v.counted and ls.stall_target(v, 101.2) is None
    assert ls.stall_target(v, 101.5) == V0  # the stall begins: time follows the wall clock from here
    assert ls.stalled and ls.u64[vp.H_STALLS // 8] == 1 and ls.u32[vp.H_FLAGS // 4] & vp.FLAG_STALL
    assert ls.stall_target(v, 102.0) == V0 + S // 2
    (warning,) = ls.warnings
    assert f"lockstep stall: thread {os.getpid()}/{threading.get_native_id()} (" in warning
    assert "ran 0.5 s without waiting; time follows the wall clock until it waits" in warning
    assert warning in capfd.readouterr().err
    ls.publish(1000.5)
    put(ls, 0, vp.WAITING)
    v = ls.look(real=102.1)
    assert v.quiet
    ls.end_stall()
    stats = ls.stats()
    assert stats["stalls"] == 1 and stats["stalled_s"] == 0.5 and not stats["stalling"]
    assert stats["last_stall"]["tid"] == threading.get_native_id() and stats["last_stall"]["state"] == "RUNNING"
    put(ls, 0, vp.RUNNING)  # the same thread again: counted, not warned again
    ls.look(real=200.0)
    v = ls.look(real=201.0)
    assert ls.stall_target(v, 201.0) is not None and ls.stats()["stalls"] == 2 and len(ls.warnings) == 1


def test_never_stalls_without_a_limit(lockstep):
    ls = lockstep(stall=None)
    put(ls, 0, vp.WAITING, V0 + S)
    put(ls, 1, vp.RUNNING)
    ls.look(real=0.0)
    v = ls.look(real=1e6)
    assert not v.quiet and ls.stall_target(v, 1e6) is None and ls.stats()["stalls"] == 0


def test_a_thread_asleep_in_an_unwrapped_call_counts_as_waiting(lockstep):
    ls = lockstep()
    ready = threading.Event()
    done = threading.Event()
    tid: list[int] = []

    def blocked() -> None:
        tid.append(threading.get_native_id())
        ready.set()
        done.wait()  # asleep in the kernel (a futex the shim would not see)

    t = threading.Thread(target=blocked)
    t.start()
    try:
        ready.wait(5)
        put(ls, 0, vp.RUNNING, tid=tid[0])
        put(ls, 1, vp.WAITING, V0 + S)
        real = iter(10.0 + k * 1e-4 for k in range(10**6))  # a look every 100 us
        assert not ls.look(real=next(real)).quiet
        assert not ls.look(real=next(real)).quiet  # blocked for less than BLOCKED_CHECK: no /proc look yet
        wait_until(lambda: ls.look(real=next(real)).quiet, timeout=5)  # asleep twice, 100 us apart
        assert ls.asleep_elsewhere == 1 and ls.look(real=next(real)).quiet  # (one /proc read while it sleeps)
        put(ls, 0, vp.RUNNING, tid=threading.get_native_id())  # this thread runs
        assert not ls.look(real=next(real)).quiet
    finally:
        done.set()
        t.join()


def test_a_thread_asleep_elsewhere_must_not_have_run_between_looks(lockstep):
    """A thread confirmed asleep in an unwrapped call that wakes, computes and falls asleep elsewhere between
    two looks, with no wrapped call (bash: woken from sigsuspend by SIGCHLD, a WNOHANG waitpid), is judged
    anew: its time on a CPU changed. And every such judgement is dropped when a slot is freed (a parent may
    be woken by its child's end only after the child's pidfd said it ended)."""
    ls = lockstep()
    first, second, done = threading.Event(), threading.Event(), threading.Event()
    tid: list[int] = []

    def sleeper() -> None:
        tid.append(threading.get_native_id())
        first.wait()
        sum(range(200_000))  # runs (no wrapped call: its progress count stays)
        second.set()
        done.wait()  # asleep elsewhere

    t = threading.Thread(target=sleeper)
    t.start()
    try:
        wait_until(lambda: tid, timeout=5)
        put(ls, 0, vp.RUNNING, tid=tid[0])
        real = iter(10.0 + k * 1e-4 for k in range(10**6))
        wait_until(lambda: ls.look(real=next(real)).quiet, timeout=5)
        first.set()
        second.wait(5)
        assert not ls.look(real=next(real)).quiet  # it ran since: seen asleep once (if at all), not confirmed
        wait_until(lambda: ls.look(real=next(real)).quiet, timeout=5)  # asleep twice again: confirmed
        put(ls, 1, vp.EXITED, tid=tid[0] + 1)
        assert not ls.look(real=next(real)).quiet  # (a freed slot: looked at again)
        assert not ls.look(real=next(real)).quiet  # confirmation dropped: seen asleep once so far
        wait_until(lambda: ls.look(real=next(real)).quiet, timeout=5)
    finally:
        first.set()
        done.set()
        t.join()


def test_the_loop_runs_the_bench_at_an_instant_before_waking_clients_there(lockstep):
    clock = VirtualClock(epoch=1_700_000_000.0)
    loop = VirtualLoop(clock, name="t")
    ls = loop.lockstep = lockstep(vnow_ns=V0, epoch_ns=1_700_000_000 * S)
    seen: list[tuple[float, int]] = []
    loop.call_at(1005.0, lambda: seen.append((clock.now(), state(ls, 0))))
    loop.call_at(1007.0, lambda: seen.append((clock.now(), state(ls, 0))))
    put(ls, 0, vp.WAITING, V0 + 5 * S)  # a client sleeping 5 virtual seconds, in a held bench
    loop.start()
    try:
        wait_until(lambda: state(ls, 0) == vp.WOKEN, timeout=5)
        # the bench's event at 1005 ran first (the client still waited), then the client was woken at 1005
        assert seen == [(1005.0, vp.WAITING)] and clock.now() == 1005.0 and ls.vnow_ns == V0 + 5 * S
        put(ls, 0, vp.RUNNING)  # it computes: time stays, the bench's event at 1007 waits
        assert ls.look().blockers == [0]
        assert clock.now() == 1005.0
        put(ls, 0, vp.WAITING)  # it waits without a deadline: time moves to the bench's next event
        wait_until(lambda: len(seen) == 2, timeout=5)
        assert seen[1] == (1007.0, vp.WAITING) and clock.now() == 1007.0
        put(ls, 0, vp.EXITED)  # the last client left: a held bench holds again
        wait_until(lambda: not ls.active(), timeout=5)
        loop.call_at(1010.0, lambda: seen.append((clock.now(), -1)))
        assert clock.now() == 1007.0 and len(seen) == 2
    finally:
        loop.close()


def test_what_clients_write_at_an_instant_is_one_transmission_sent_when_they_all_wait():
    """Two packets a client writes at one instant, read by the bench one at a time while the client runs,
    go on the line together once every client waits: how the loop's reads fall between the writes does not
    change the wire (the official SDK's Sync Write and Sync Read, back to back)."""
    from hilbench.bench import Bench
    from hilbench.protocols import dynamixel as dxl

    with Bench("wolfgang", virtual_time=True) as bench:
        ls = bench.services["clock"]
        ep = bench.endpoint("dxl")
        seen: list[tuple[float, str, bytes]] = []
        ep.medium.add_tap(lambda t, source, data, addr=None: seen.append((t, source, bytes(data))))
        fd = os.open(ep.port.client_path, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            attrs[4] = attrs[5] = termios.B2000000  # (the bus's rate: the servos hear it)
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            put(ls, 0, vp.RUNNING, tid=0)  # a client thread that computes (tid 0: no /proc look)
            pings = [dxl.instruction_packet(i, dxl.Instruction.PING) for i in (1, 2)]
            taken = ep.port.bytes_in
            for ping in pings:
                os.write(fd, ping)
                taken += len(ping)
                wait_until(lambda n=taken: ep.port.bytes_in == n, timeout=5)  # the bench read it
            assert bench.clock.now() == 1000.0
            put(ls, 0, vp.WAITING, tid=0)  # it waits: what it wrote goes on the line, then time moves
            wait_until(lambda: len([s for s in seen if s[1] != "dxl"]) == 2, timeout=5)  # both servos answered
        finally:
            put(ls, 0, vp.EXITED)
            os.close(fd)
    sent = [(t, data) for t, source, data in seen if source == "dxl"]
    wire = len(pings[0] + pings[1]) * 10 / ep.spec.baud
    assert sent == [(pytest.approx(1000.0 + wire, abs=1e-9), pings[0] + pings[1])]


def claim_channel(ls: Lockstep, c: int, proto: int, host: str, port: int, *, sent: int = 0,
                  received: int = 0) -> int:
    """Write channel record ``c`` as a client's shim does after its socket connected or sent to a door (state
    last); returns its byte offset."""
    off = vp.chan_offset(ls.chan_off, c)
    struct.pack_into("5I", ls.map, off + vp.C_PID, os.getpid(), proto, packed_ipv4(host), port, 0)
    struct.pack_into("QQ", ls.map, off + vp.C_SENT, sent, received)
    struct.pack_into("I", ls.map, off + vp.C_STATE, vp.CH_OPEN)
    return off


def test_socket_channels_hold_time_while_bytes_fly_and_wake_their_waiters(lockstep):
    """PLAN26 §4.8, phase 2: the bench's doors are on the page; bytes a client sent on a channel and the bench
    has not taken keep time still; a thread waiting on a channel is woken when the bench sent to it (in the
    look after a send in D, or in settle after the bench phase), and the bench's totals sit beside the client's
    counts (bytes on TCP, datagrams on UDP)."""
    book = ChannelBook()
    book.door(vp.TCP, ("127.0.0.1", 29536))
    ls = lockstep(channels=book)
    assert struct.unpack_from("I", ls.map, vp.H_NCHANS)[0] == vp.DEFAULT_CHANS
    assert struct.unpack_from("IQ", ls.map, vp.H_NDOORS)[0] == 1 and ls.chan_off == vp.page_size(8, 0)
    assert struct.unpack_from("3I", ls.map, vp.door_offset(ls.chan_off, 0)) == (vp.TCP, packed_ipv4("127.0.0.1"),
                                                                                  29536)
    book.door(vp.UDP, ("0.0.0.0", 8888))  # (a door added later, e.g. a device's socket, is published too)
    assert ls.look().quiet
    assert struct.unpack_from("I", ls.map, vp.H_NDOORS)[0] == 2
    off = claim_channel(ls, 3, vp.TCP, "127.0.0.1", 40000, sent=12)
    bit = 1 << vp.chan_bit(0, 3)
    put(ls, 0, vp.WAITING, V0 + S, ports=bit, flags=vp.SF_FDWAIT)  # (select on the socket, 1 s timeout)
    v = ls.look()
    assert not v.quiet and v.flight == ["tcp 127.0.0.1:40000"]  # 12 bytes sent, none taken
    book.took(vp.TCP, ("127.0.0.1", 40000), 12)
    book.sent(vp.TCP, ("127.0.0.1", 40000), 7)  # the reply, sent as the loop read the command (D)
    v = ls.look()
    assert not v.quiet and v.again and state(ls, 0) == vp.WOKEN
    assert struct.unpack_from("QQ", ls.map, off + vp.C_BENCH_SENT) == (7, 12)
    put(ls, 0, vp.WAITING, V0 + S, ports=bit, flags=vp.SF_FDWAIT)
    v = ls.look()
    assert v.quiet and v.next_ns == V0 + S and not v.flight  # nothing new: time may move to the deadline
    # a send in the bench phase (A): B's settle publishes it and C wakes the waiter at that instant
    book.sent(vp.TCP, ("127.0.0.1", 40000), 20)
    assert ls.wake_due(ls.settle()) == 1 and state(ls, 0) == vp.WOKEN
    assert struct.unpack_from("Q", ls.map, off + vp.C_BENCH_SENT)[0] == 27
    assert ls.channels() == [{"proto": "tcp", "address": "127.0.0.1:40000", "pid": os.getpid(), "sent": 12,
                              "received": 0, "bench_sent": 27, "bench_taken": 12, "given_up": 0}]
    # a waiter on another port or channel is not woken by it
    put(ls, 1, vp.WAITING, ports=1 << vp.chan_bit(0, 4), flags=vp.SF_FDWAIT)
    book.sent(vp.TCP, ("127.0.0.1", 40000), 1)
    ls.wake_due(ls.settle())
    assert state(ls, 1) == vp.WAITING
    # the record of a process that ended is freed
    gone = subprocess.Popen(["true"])
    gone.wait()
    struct.pack_into("I", ls.map, off + vp.C_PID, gone.pid)
    ls.look()
    assert struct.unpack_from("I", ls.map, off + vp.C_STATE)[0] == vp.CH_FREE and ls.channels() == []


def test_a_bench_without_a_channel_book_has_no_channel_region(lockstep):
    ls = lockstep()
    assert len(ls.map) == vp.page_size(8, 0) and struct.unpack_from("I", ls.map, vp.H_NCHANS)[0] == 0
    assert ls.channels() == []
