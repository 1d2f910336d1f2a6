"""A Python client of the virtual-time shim (tests/run/test_vclock.py): each wait's virtual duration in ns
(``time.monotonic_ns``), as JSON on stdout, then 60 virtual seconds in all. Durations are dyadic fractions of
a second, so float deadlines (queue, threading) land on whole nanoseconds."""

import json
import os
import queue
import select
import selectors
import socket
import threading
import time

out: dict[str, int] = {}


def measure(name, fn):
    t0 = time.monotonic_ns()
    fn()
    out[name] = time.monotonic_ns() - t0


start, wall0 = time.monotonic_ns(), os.times().elapsed
t_real = time.time_ns()
measure("time.sleep", lambda: time.sleep(1))
out["time.time"] = time.time_ns() - t_real
r, w = os.pipe()
measure("select.select", lambda: select.select([r], [], [], 0.5))
p = select.poll()
p.register(r, select.POLLIN)
measure("select.poll", lambda: p.poll(250))
ep = select.epoll()
ep.register(r, select.EPOLLIN)
measure("select.epoll", lambda: ep.poll(1.5))
sel = selectors.DefaultSelector()
sel.register(r, selectors.EVENT_READ)
measure("selectors", lambda: sel.select(timeout=0.25))
measure("Event.wait", lambda: threading.Event().wait(1.5))
lock = threading.Lock()
lock.acquire()
measure("Lock.acquire", lambda: lock.acquire(timeout=0.75))
cond = threading.Condition()


def cond_wait():
    with cond:
        cond.wait(0.5)


measure("Condition.wait", cond_wait)


def queue_get():
    try:
        queue.Queue().get(timeout=2)
    except queue.Empty:
        pass


measure("queue.get", queue_get)
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.1", 0))
sock.settimeout(0.75)


def recv_timeout():
    try:
        sock.recv(10)
    except TimeoutError:
        pass


measure("socket.recv", recv_timeout)
later = threading.Thread(target=time.sleep, args=(1,))
measure("Thread.join", lambda: (later.start(), later.join()))
ev = threading.Event()
threading.Thread(target=lambda: (time.sleep(0.25), ev.set())).start()
measure("Event.set_by_thread", lambda: ev.wait(30))
q: queue.Queue[int] = queue.Queue()
threading.Thread(target=lambda: (time.sleep(0.125), q.put(1))).start()
measure("queue.put_by_thread", lambda: q.get(timeout=30))
threading.Timer(0.5, lambda: os.write(w, b"x")).start()
measure("selectors_ready", lambda: sel.select(timeout=10))
os.read(r, 1)


def the_rest():
    while (left := 60 * 10**9 - (time.monotonic_ns() - start)) > 0:
        time.sleep(min(1.0, left / 1e9))


measure("rest", the_rest)
out["total"] = time.monotonic_ns() - start
out["wall_ms"] = int((os.times().elapsed - wall0) * 1000)
print(json.dumps(out))
