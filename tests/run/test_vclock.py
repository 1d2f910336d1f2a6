"""The virtual-time shim (``vclock.c``, in the preload library with ``shim.c``) against a fake lockstep
controller: a C and a Python client's sleeps, clocks and timeouts take exact virtual durations and little wall
time; a polling client advances in quanta; a thread that never waits stalls the clock (counted, named); without a
clock page the library passes every call through."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench.run import vclock_page as vp
from hilbench.run.build import SOURCES, find_compiler
from tests.run.conftest import build_c_client
from tests.run.vt_controller import VtController

CLIENTS = Path(__file__).parent / "clients"
RUN_DIR = Path(__file__).parents[2] / "hilbench" / "run"
S = 10**9


@pytest.fixture
def clock(tmp_path, library):
    made: list[VtController] = []

    def make(**kw) -> VtController:
        directory = tmp_path / f"clock{len(made)}"
        directory.mkdir()
        made.append(VtController(directory, library, **kw))
        return made[-1]

    yield make
    for ctl in made:
        ctl.close()


def run(ctl: VtController, library: Path, argv: list[str], tmp_path: Path, timeout: float = 20.0):
    """Runs argv under the clock; (stdout, stderr, wall seconds)."""
    env = {**os.environ, "LD_PRELOAD": str(library), **ctl.env}
    out, err = tmp_path / "stdout", tmp_path / "stderr"
    with out.open("w") as fo, err.open("w") as fe:
        t0 = time.monotonic()
        proc = subprocess.Popen(argv, env=env, stdout=fo, stderr=fe)
        try:
            ctl.serve(proc, timeout=timeout)
        finally:
            proc.wait()
        wall = time.monotonic() - t0
    assert proc.returncode == 0, err.read_text()
    return out.read_text(), err.read_text(), wall


def test_page_layout_is_the_same_in_c_and_python(library):
    code = "import ctypes, sys; f = ctypes.CDLL(sys.argv[1]).hb_vclock_layout; f.restype = ctypes.c_char_p; " \
           "print(f().decode())"
    text = subprocess.run([sys.executable, "-c", code, str(library)], capture_output=True, text=True,
                          check=True).stdout
    c = {k: int(v) for k, v in (line.split("=") for line in text.split())}
    assert c == vp.layout()
    assert vp.page_size(256, 2) == 512 + 256 * 64 + 2 * 64


def test_the_library_compiles_without_warnings(tmp_path):
    cc = find_compiler()
    if cc is None:
        pytest.skip("no C compiler (cc, gcc or clang)")
    proc = subprocess.run([*cc, "-shared", "-fPIC", "-O2", "-Wall", "-Wextra", "-Werror", "-o",
                           str(tmp_path / "lib.so"), *(str(RUN_DIR / s) for s in SOURCES), "-ldl", "-pthread"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def c_client(tmp_path_factory) -> str:
    return build_c_client(tmp_path_factory, "vtime_client")


def test_c_client_waits_in_virtual_time(clock, library, c_client, tmp_path):
    ctl = clock()
    stdout, _err, wall = run(ctl, library, [c_client], tmp_path)
    got = {name: (int(v), int(r)) for name, v, r in (line.split() for line in stdout.splitlines())}
    wall_ns = got.pop("wall")[0]
    assert got == {
        "nanosleep": (1 * S, 0), "usleep": (S // 4, 0), "sleep": (2 * S, 0),
        "realtime": (2 * S, 0),  # CLOCK_REALTIME moves with the virtual clock
        "time": (3, 0), "gettimeofday": (3 * S, 0),
        "clock_nanosleep_abs": (S * 3 // 2, 0), "clock_nanosleep_abs_realtime": (S // 2, 0),
        "clock_nanosleep_rel": (S // 8, 0),
        "select": (S * 7 // 10, 0), "select_left": (0, 0), "poll": (S * 3 // 10, 0), "epoll_wait": (S * 6 // 5, 0),
        "epoll_wait_ready": (S // 4, 1),  # a byte from another thread ends a 5 s wait
        "pthread_cond_timedwait": (S * 2 // 5, 1), "pthread_cond_clockwait": (S * 3 // 5, 1),
        "pthread_cond_signalled": (S // 2, 1),  # signalled by a thread after its 0.5 s sleep
        "sem_timedwait": (S * 3 // 10, 1), "pthread_join": (S * 3 // 4, 0),
        "fork_exec_sleep": (2 * S, 0),  # fork, exec /bin/sleep 2, waitpid: the child's sleep is virtual too
        "posix_spawn_sleep": (1 * S, 0),
    }
    virtual = ctl.vnow - vp.ORIGIN_NS
    assert virtual >= 16 * S
    assert wall_ns < virtual // 10, f"{wall_ns / 1e9:.3f} s wall for {virtual / 1e9:.1f} s virtual"
    assert ctl.stalls == 0


def test_python_client_waits_in_virtual_time(clock, library, tmp_path):
    ctl = clock()
    stdout, _err, wall = run(ctl, library, [sys.executable, str(CLIENTS / "vtime_client.py")], tmp_path)
    got = json.loads(stdout)
    client_wall = got.pop("wall_ms") / 1000
    rest = got.pop("rest")
    assert got == {
        "time.sleep": S, "time.time": S, "select.select": S // 2, "select.poll": S // 4, "select.epoll": S * 3 // 2,
        "selectors": S // 4, "Event.wait": S * 3 // 2, "Lock.acquire": S * 3 // 4, "Condition.wait": S // 2,
        "queue.get": 2 * S, "socket.recv": S * 3 // 4, "Thread.join": S, "Event.set_by_thread": S // 4, "queue.put_by_thread": S // 8,
        "selectors_ready": S // 2, "total": 60 * S,
    }
    assert rest > 40 * S
    assert client_wall < 30.0, f"60 virtual s took {client_wall:.2f} s wall"  # (virtual, not the wall clock's)
    assert ctl.stalls == 0


def test_subprocesses_and_shells_follow_the_clock(clock, library, tmp_path):
    """subprocess (vfork + exec), a shell waiting for its child (wait3), os.fork + waitpid."""
    code = """if True:
        import json, os, subprocess, time
        out = {}
        t0 = time.monotonic_ns(); subprocess.run(["/bin/sleep", "2"], check=True)
        out["run"] = time.monotonic_ns() - t0
        t0 = time.monotonic_ns()
        text = subprocess.run(["/bin/sh", "-c", "sleep 1; echo hi"], check=True, capture_output=True).stdout
        out["sh"] = time.monotonic_ns() - t0
        t0 = time.monotonic_ns()
        pid = os.fork()
        if pid == 0:
            time.sleep(0.5)
            os._exit(3)
        out["status"] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
        out["fork"] = time.monotonic_ns() - t0
        out["text"] = text.decode()
        print(json.dumps(out))
    """
    ctl = clock()
    stdout, _err, _wall = run(ctl, library, [sys.executable, "-c", code], tmp_path)
    assert json.loads(stdout) == {"run": 2 * S, "sh": S, "fork": S // 2, "status": 3, "text": "hi\n"}
    assert ctl.stalls == 0


def test_a_polling_client_advances_in_quanta(clock, library, tmp_path):
    ctl = clock(quantum_ns=1_000_000, poll_k=32)
    stdout, _err, _wall = run(ctl, library, [sys.executable, str(CLIENTS / "vtime_poll.py")], tmp_path)
    got = json.loads(stdout)
    assert got["virtual"] == S  # 1000 quanta of 1 ms, nothing else moved the clock
    assert 1000 <= ctl.advances <= 1005
    assert ctl.stalls == 0


def test_a_thread_that_never_waits_stalls_the_clock(clock, library, tmp_path):
    ctl = clock(stall=0.3)
    stdout, stderr, wall = run(ctl, library, [sys.executable, str(CLIENTS / "vtime_stall.py")], tmp_path)
    got = json.loads(stdout)
    assert ctl.stalls >= 1
    assert got["virtual"] >= 3.0
    assert got["wall"] >= 2.5  # time followed the wall clock: the sleeps took real seconds
    named = [w for w in ctl.warnings if f"/{got['spinner']} " in w]
    assert named and "lockstep stall" in named[0] and f"thread {os.getpid()}" not in named[0]
    assert not [w for w in ctl.warnings if f"/{got['main']} " in w]  # the sleeping main thread is not blamed


def test_without_stalls_a_spinning_thread_holds_the_clock(clock, library, tmp_path):
    ctl = clock(stall=float("inf"))
    with pytest.raises(TimeoutError):
        run(ctl, library, [sys.executable, str(CLIENTS / "vtime_stall.py")], tmp_path, timeout=1.5)
    assert ctl.vnow == vp.ORIGIN_NS  # nothing moved it: the stall is what moves time


@pytest.mark.parametrize("clock_env", [None, "/nonexistent/clock.page"])
def test_without_a_clock_page_the_library_passes_through(library, clock_env):
    env = {**os.environ, "LD_PRELOAD": str(library)}
    env.pop(vp.ENV, None)
    if clock_env:
        env[vp.ENV] = clock_env
    code = "import time, json; a = time.monotonic(); time.sleep(0.05); b = time.monotonic(); " \
           "print(json.dumps([a, b, time.time()]))"
    before = time.monotonic()
    a, b, wall = json.loads(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                           check=True).stdout)
    after = time.monotonic()
    assert before <= a <= b <= after  # the machine's own monotonic clock
    assert b - a >= 0.05
    assert abs(wall - time.time()) < 5


def test_bench_pty_reads_and_waits_in_virtual_time(clock, library, tmp_path):
    """Blocking reads with VMIN/VTIME, select, poll and epoll on a bench pty, with bytes delivered at virtual instants;
    the port's counters (read, written, discarded) on the page."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc or gcc): the C test client cannot be built")
    exe = tmp_path / "vtime_pty"
    subprocess.run([cc, "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe), str(CLIENTS / "vtime_pty.c")],
                   check=True, capture_output=True)
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        ctl = clock(ports=[(os.stat(path).st_rdev, slave)])
        at = vp.ORIGIN_NS
        for t, data in ((1.0, b"abc"), (2.0, b"ab"), (2.1, b"c"), (3.0, b"x"), (3.5, b"e"), (4.0, b"zz")):
            ctl.deliver_at(at + round(t * S), 0, master, data)
        stdout, _err, _wall = run(ctl, library, [str(exe), path], tmp_path)
        got = {name: ((int(v) - at) / S, int(r)) for name, v, r in (line.split() for line in stdout.splitlines())}
        assert got == {
            "read_vtime": (0.5, 0), "read_vmin1": (1.0, 3), "read_vmin5_vtime2": (2.3, 3), "select": (3.0, 1),
            "read_one": (3.0, 1), "poll": (3.25, 0), "epoll_wait": (3.5, 1), "read_e": (3.5, 1), "write": (3.5, 5),
            "tcflush": (4.5, 0),
        }
        assert (ctl.port(0, vp.P_DELIVERED), ctl.port(0, vp.P_READ), ctl.port(0, vp.P_DISCARDED),
                ctl.port(0, vp.P_WRITTEN)) == (10, 8, 2, 5)
        assert os.read(master, 64) == b"hello"
        assert ctl.stalls == 0
    finally:
        os.close(master)
        os.close(slave)
