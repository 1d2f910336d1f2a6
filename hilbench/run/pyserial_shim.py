"""``hilbench run``'s Python fallback: a serial adapter's semantics for pyserial on a bench's ptys.

Where no C compiler builds the preload shim (or with ``HILBENCH_RUN_SHIM=python``),
Python clients still get modem lines, BREAK and flushes that reach the bench:
``serial.serialposix`` does every such call through its module globals
``fcntl`` and ``termios``, so those two are replaced by proxies that take the
same calls the C shim takes (ioctl TIOCMGET/TIOCMSET/TIOCMBIS/TIOCMBIC,
TIOCSBRK/TIOCCBRK, TCSBRK/TCSBRKP, TCFLSH, TCSETS*, TCGETS*; tcflush, tcdrain,
tcsendbreak, tcsetattr, tcgetattr), on descriptors whose device number is one of the
bench's ptys, and pass everything else to the real modules. Patching the two
module globals rather than Serial's methods keeps it working on pyserial forks
that keep serialposix's structure (labgrid's ``pyserial-labgrid``); a
``serial.serialposix`` without them is left alone.

A drain (``ser.flush()``, and the drain before a settings change) or an output
flush (``reset_output_buffer()``) with nothing pending costs no request: the
module's ``os`` is proxied too, so pyserial's writes to bench ports are
stamped on the bench's delivery ledger (:mod:`hilbench.bench.delivery_ledger`),
and when the bench has delivered everything written before the last stamp,
a drain returns at once, as on an adapter with an empty queue; so does an
output flush when this process wrote nothing since its last drain or flush
(otherwise it asks, and the devices hear ``OutputFlushed``). Requests to a
bench in another process reuse connections from a small pool.

Standard library only, and no hilbench import: the ``sitecustomize`` that loads
it may run in any Python 3 on the machine (a ROS node's system interpreter), not
only in hilbench's own. The request protocol is the port-state server's
(:mod:`hilbench.bench.port_state_server`). If the bench does not answer, the real call
runs (fail open), as in the C shim.
"""

from __future__ import annotations

import errno
import importlib.abc
import mmap
import os
import socket
import stat
import struct
import sys
import termios as _termios
import threading
import time
from collections.abc import Callable
from typing import Any

#: rdev -> the bench's port-state socket path, or (in-process) a callable answering one request line.
PORTS: dict[int, str | Callable[[str], str]] = {}
#: rdev -> the bench's delivery ledger file (None: the bench has none; every drain asks).
LEDGERS: dict[int, str | None] = {}
_lock = threading.Lock()
TIMEOUT = 30.0

# The delivery ledger's layout (hilbench/bench/delivery_ledger.py has the same numbers; a test compares).
LEDGER_MAGIC = b"HBLEDGR1"
LEDGER_VERSION = 1
LEDGER_HEADER = 64
LEDGER_SLOT = 64
LEDGER_RDEV, LEDGER_IDLE_NS, LEDGER_DIRTY_NS, LEDGER_DIRTY_PY_NS, LEDGER_WRITING, LEDGER_WRITING_PY, LEDGER_DRAIN_NS = range(7)
LEDGER_FILE = "port_state.ledger"

_T = _termios
TIOCMGET = getattr(_T, "TIOCMGET", 0x5415)
TIOCMBIS = getattr(_T, "TIOCMBIS", 0x5416)
TIOCMBIC = getattr(_T, "TIOCMBIC", 0x5417)
TIOCMSET = getattr(_T, "TIOCMSET", 0x5418)
TIOCSBRK = getattr(_T, "TIOCSBRK", 0x5427)
TIOCCBRK = getattr(_T, "TIOCCBRK", 0x5428)
TCSBRK = getattr(_T, "TCSBRK", 0x5409)
TCSBRKP = getattr(_T, "TCSBRKP", 0x5425)
TCFLSH = getattr(_T, "TCFLSH", 0x540B)
# TCSETS2 and friends (Linux, asm-generic numbering, as pyserial uses them for custom rates).
TCSETS_ALL = {getattr(_T, "TCSETS", 0x5402), getattr(_T, "TCSETSW", 0x5403), getattr(_T, "TCSETSF", 0x5404),
              0x402C542B, 0x402C542C, 0x402C542D}
TCGETS_ALL = {getattr(_T, "TCGETS", 0x5401), 0x802C542A}
_MODEM = {TIOCMSET: "mset", TIOCMBIS: "mbis", TIOCMBIC: "mbic"}
_FRAMING = _T.CSIZE | _T.PARENB | _T.PARODD | getattr(_T, "CMSPAR", 0o10000000000) | _T.CSTOPB


def load_env(value: str | None = None) -> int:
    """Register the ports of ``HILBENCH_RUN_PORTS`` (``RDEV=SOCKET;...``); returns how many."""
    value = os.environ.get("HILBENCH_RUN_PORTS", "") if value is None else value
    n = 0
    for item in value.split(";"):
        rdev, sep, path = item.partition("=")
        if sep and rdev.isdigit() and path:
            register(int(rdev), path)
            n += 1
    return n


def register(rdev: int, target: str | Callable[[str], str], ledger: str | None = None) -> None:
    """Treat the pty with device number ``rdev`` as a bench port reached through ``target``.

    ``ledger``: the bench's delivery ledger; by default the one beside a socket ``target``.
    """
    if ledger is None and isinstance(target, str):
        ledger = os.path.join(os.path.dirname(target), LEDGER_FILE)
    with _lock, _state_lock:
        PORTS[rdev] = target
        LEDGERS[rdev] = ledger
        _slots.pop(rdev, None)


def unregister(rdev: int) -> None:
    """Forget a port (and unmap its bench's ledger once no registered port uses it)."""
    with _lock, _state_lock:
        PORTS.pop(rdev, None)
        ledger = LEDGERS.pop(rdev, None)
        _slots.pop(rdev, None)
        _locals.pop(rdev, None)
        words = _maps.pop(ledger, None) if ledger and ledger not in LEDGERS.values() else None
        if words is not None:
            mapped = words.obj
            words.release()
            mapped.close()


# ---------------------------------------------------------------------- asking the bench

def _port(fd: Any) -> tuple[int, str | Callable[[str], str]] | None:
    if not PORTS:
        return None
    try:
        fd = fd if isinstance(fd, int) else fd.fileno()
        st = os.fstat(fd)
    except (OSError, AttributeError, TypeError, ValueError):
        return None
    if not stat.S_ISCHR(st.st_mode):
        return None
    target = PORTS.get(st.st_rdev)
    return None if target is None else (st.st_rdev, target)


def ask(port: tuple[int, str | Callable[[str], str]], request: str, timeout: float = TIMEOUT) -> int | None:
    """One request to the bench; the ``ok`` value, or None if it refused or did not answer."""
    rdev, target = port
    line = f"{rdev} {request}"
    if callable(target):
        try:
            reply = target(line)
        except (OSError, ValueError):
            return None
    else:
        reply = _request(target, line, timeout)
        if reply is None:
            return None
    words = reply.split()
    if len(words) >= 2 and words[0] == "ok":
        try:
            return int(words[1])
        except ValueError:
            return None
    return None


# Connections to port-state servers, kept for the next request (a connect and a server thread per request
# cost more than the request): a few per socket, one request at a time on each.
POOL_SIZE = 4
_pool: dict[str, list[socket.socket]] = {}
_pool_lock = threading.Lock()


def _request(path: str, line: str, timeout: float) -> str | None:
    """Send one request line on a pooled (or new) connection; the answer line, or None."""
    for _attempt in range(2):
        with _pool_lock:
            idle = _pool.get(path)
            conn = idle.pop() if idle else None
        reused = conn is not None
        data = b""
        stale = False  # a kept connection the server closed before it read the request
        try:
            if conn is None:
                conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                conn.settimeout(timeout)
                conn.connect(path)
            else:
                conn.settimeout(timeout)
            conn.sendall(line.encode("ascii") + b"\n")
            while not data.endswith(b"\n") and len(data) < 256:
                chunk = conn.recv(256)
                if not chunk:
                    stale = not data
                    break
                data += chunk
        except (BrokenPipeError, ConnectionResetError):
            stale = not data
        except (OSError, ValueError):
            pass  # a timeout is no reason to send it again
        if data.endswith(b"\n"):
            with _pool_lock:
                idle = _pool.setdefault(path, [])
                if len(idle) < POOL_SIZE:
                    idle.append(conn)
                    conn = None
            if conn is not None:
                conn.close()
            return data.decode("ascii", "replace")
        if conn is not None:
            conn.close()
        if not (reused and stale):
            return None  # a new connection failed, or the answer broke off: the bench is not answering
        # The server had closed the kept connection (it stopped, or restarted): once more, on a new one.
    return None


def _forget_pool_after_fork() -> None:
    """In a forked child: the parent's connections and locks are not ours to use."""
    global _pool_lock, _state_lock, _lock
    for conns in _pool.values():
        for conn in conns:
            conn.close()  # the child's copy only; the parent keeps its connection
    _pool.clear()
    _pool_lock, _state_lock, _lock = threading.Lock(), threading.Lock(), threading.Lock()


# ---------------------------------------------------------------------- what needs no request

class _Local:
    """This process's writes to one bench port."""

    __slots__ = ("dirty_ns", "in_flight", "wrote")

    def __init__(self) -> None:
        self.dirty_ns = 0  # CLOCK_MONOTONIC after the last write() returned
        self.in_flight = 0  # write() calls not returned yet
        self.wrote = False  # written since the last drain or output flush


class _Slot:
    """A port's slot on a bench's delivery ledger (words read and stored whole: 8 aligned bytes).

    Python has no atomic read-modify-write: the Python words are stored under ``_state_lock``, so one
    process's own stores only grow; two Python processes writing to one pty at the same moment could
    undo each other's, which each one's :class:`_Local` covers for its own bytes.
    """

    def __init__(self, words: memoryview, index: int) -> None:
        self._words = words
        self._i = index

    def idle_ns(self) -> int:
        self._words[self._i + LEDGER_DRAIN_NS] = time.monotonic_ns()  # someone drains: keep it fresh
        return self._words[self._i + LEDGER_IDLE_NS]

    def dirty_ns(self) -> int:
        return max(self._words[self._i + LEDGER_DIRTY_NS], self._words[self._i + LEDGER_DIRTY_PY_NS])

    def begin(self, ns: int) -> None:
        """A write begins (counted, then stamped: see hilbench/bench/delivery_ledger.py)."""
        self._words[self._i + LEDGER_WRITING_PY] = 1
        i = self._i + LEDGER_DIRTY_PY_NS
        if ns > self._words[i]:
            self._words[i] = ns

    def end(self) -> None:
        self._words[self._i + LEDGER_WRITING_PY] = 0


_locals: dict[int, _Local] = {}
_slots: dict[int, _Slot | None] = {}
_maps: dict[str, memoryview | None] = {}
_state_lock = threading.Lock()
#: Whether this process's pyserial writes are seen (its ``serial.serialposix`` has an ``os`` to proxy).
_writes_seen = False


def _ledger_words(path: str) -> memoryview | None:
    if path not in _maps:
        words = None
        try:
            fd = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
            try:
                size = os.fstat(fd).st_size
                if size >= LEDGER_HEADER:
                    words = memoryview(mmap.mmap(fd, size)).cast("Q")
            finally:
                os.close(fd)
        except (OSError, ValueError):
            words = None
        if words is not None and (words.obj[:8] != LEDGER_MAGIC or words[1] != LEDGER_VERSION  # type: ignore[index]
                                  or words[3] != LEDGER_SLOT or LEDGER_HEADER + LEDGER_SLOT * words[2] > len(words) * 8):
            words = None
        _maps[path] = words
    return _maps[path]


def _slot(rdev: int) -> _Slot | None:
    """The port's slot on its bench's ledger (mapped on first use), or None."""
    if rdev not in _slots:
        path = LEDGERS.get(rdev)
        words = _ledger_words(path) if path else None
        slot = None
        if words is not None:
            for n in range(words[2]):
                i = (LEDGER_HEADER + LEDGER_SLOT * n) // 8
                if words[i + LEDGER_RDEV] == rdev:
                    slot = _Slot(words, i)
                    break
        _slots[rdev] = slot
    return _slots[rdev]


def _local(rdev: int) -> _Local:
    local = _locals.get(rdev)
    if local is None:
        local = _locals[rdev] = _Local()
    return local


def _delivered(rdev: int) -> bool:
    """Whether everything this process (and, as far as the ledger knows, any other) wrote to the port
    is delivered: then a drain has nothing to wait for. Call with ``_state_lock`` held."""
    if not _writes_seen:
        return False
    slot = _slot(rdev)
    local = _local(rdev)
    if slot is None or local.in_flight:
        return False
    return slot.idle_ns() > max(local.dirty_ns, slot.dirty_ns())


def _drain(port: tuple[int, Any]) -> None:
    """tcdrain on a bench port: nothing to ask when everything written is delivered."""
    with _state_lock:
        _local(port[0]).wrote = False
        if _delivered(port[0]):
            return
    ask(port, "drain")


def _write(real: Callable[[int, Any], int], fd: Any, data: Any) -> int:
    port = _port(fd)
    if port is None:
        return real(fd, data)
    with _state_lock:
        local = _local(port[0])
        local.in_flight += 1
        local.wrote = True
        slot = _slot(port[0])
        if slot is not None:
            slot.begin(time.monotonic_ns())
    try:
        return real(fd, data)
    finally:
        now = time.monotonic_ns()  # after write() returned: what this process's own drains go by
        with _state_lock:
            local.in_flight -= 1
            local.dirty_ns = max(local.dirty_ns, now)
            if slot is not None and not local.in_flight:
                slot.end()


def _break(port: tuple[int, Any], seconds: float) -> bool:
    return ask(port, f"break {seconds:.3f}", TIMEOUT + seconds) is not None


def _flush(port: tuple[int, Any], fd: Any, queue: int, real_tcflush: Callable[[Any, int], None]) -> bool:
    """TCOFLUSH / TCIOFLUSH through the bench; False: not handled (do the real call). Nothing written
    since the last drain or flush and everything delivered: nothing to flush, nothing to ask."""
    if queue not in (_termios.TCOFLUSH, _termios.TCIOFLUSH):
        return False
    with _state_lock:
        local = _local(port[0])
        wrote, local.wrote = local.wrote, False
        idle = not wrote and _delivered(port[0])
    if not idle and ask(port, "flush") is None:
        return False
    if queue == _termios.TCIOFLUSH:
        real_tcflush(fd, _termios.TCIFLUSH)
    return True


# ---------------------------------------------------------------------- the proxies

class _Proxy:
    """A module stand-in: the overridden functions, everything else from the real module."""

    def __init__(self, real: Any) -> None:
        self._real = real

    def __getattr__(self, name: str) -> Any:
        value = getattr(self._real, name)
        if callable(value):  # kept: serialposix calls os.read, select... in its read loop
            setattr(self, name, value)
        return value

    def __repr__(self) -> str:
        return f"<hilbench run proxy of {self._real!r}>"


def _buffer_int(arg: Any) -> int | None:
    try:
        return struct.unpack_from("I", arg)[0]
    except (TypeError, struct.error):
        return None


class FcntlProxy(_Proxy):
    """``fcntl`` with ``ioctl`` taking the modem, break, flush and settings requests of bench ports."""

    def ioctl(self, fd: Any, request: int, arg: Any = 0, mutate_flag: bool = True) -> Any:
        real = self._real.ioctl
        port = _port(fd) if request in _HANDLED else None
        if port is None:
            return real(fd, request, arg, mutate_flag)
        if request == TIOCMGET and not isinstance(arg, int):
            mask = ask(port, "mget")
            if mask is not None:
                return _ioctl_result(arg, struct.pack("I", mask), mutate_flag)
        elif request in _MODEM and not isinstance(arg, int):
            value = _buffer_int(arg)
            if value is not None and ask(port, f"{_MODEM[request]} {value}") is not None:
                return _ioctl_result(arg, None, mutate_flag)
        elif request in (TIOCSBRK, TIOCCBRK):
            if ask(port, "break on" if request == TIOCSBRK else "break off") is not None:
                return _ioctl_result(arg, None, mutate_flag)
        elif request == TCSBRK and isinstance(arg, int):
            if arg == 0:
                if _break(port, 0.25):
                    return 0
            else:
                _drain(port)
        elif request == TCSBRKP and isinstance(arg, int):
            if _break(port, arg / 10.0 if arg > 0 else 0.25):
                return 0
        elif request == TCFLSH and isinstance(arg, int):
            if _flush(port, fd, arg, _termios.tcflush):
                return 0
        elif request in TCGETS_ALL and not isinstance(arg, int):
            result = real(fd, request, arg, mutate_flag)
            framing = ask(port, "framing")  # a pty forgets data bits and parity; the bench knows
            if framing is None or framing < 0:
                return result
            if isinstance(result, bytes):  # an immutable argument: the answer is a copy
                cflag = (_cflag(result) or 0) & ~_FRAMING | framing
                return result[:8] + struct.pack("I", cflag) + result[12:]
            view = memoryview(arg).cast("B")  # a mutable buffer, filled in place
            view[8:12] = struct.pack("I", (_cflag(view) or 0) & ~_FRAMING | framing)
            return result
        elif request in TCSETS_ALL and not isinstance(arg, int):
            _drain(port)
            result = real(fd, request, arg, mutate_flag)
            cflag = _cflag(arg)
            if cflag is not None:
                ask(port, f"sync {cflag}")
            return result
        return real(fd, request, arg, mutate_flag)


_HANDLED = {TIOCMGET, TIOCMSET, TIOCMBIS, TIOCMBIC, TIOCSBRK, TIOCCBRK, TCSBRK, TCSBRKP, TCFLSH, *TCSETS_ALL,
            *TCGETS_ALL}


def _cflag(arg: Any) -> int | None:
    try:
        return struct.unpack_from("I", arg, 8)[0]  # c_cflag: the third tcflag_t of struct termios(2)
    except (TypeError, struct.error):
        return None


def _ioctl_result(arg: Any, data: bytes | None, mutate_flag: bool) -> Any:
    """What fcntl.ioctl returns: a copy for immutable buffers, 0 after writing into a mutable one."""
    if isinstance(arg, (bytes, str)):  # noqa: UP038 (this module also runs on older interpreters)
        raw = arg.encode() if isinstance(arg, str) else arg
        return raw if data is None else data + raw[len(data):]
    if not mutate_flag:
        raw = bytes(memoryview(arg).cast("B"))
        return raw if data is None else data + raw[len(data):]
    if data is not None:
        memoryview(arg).cast("B")[:len(data)] = data
    return 0


class TermiosProxy(_Proxy):
    """``termios`` with tcflush, tcdrain, tcsendbreak, tcsetattr and tcgetattr going to the bench for its ports."""

    def tcflush(self, fd: Any, queue: int) -> None:
        port = _port(fd)
        if port is None or not _flush(port, fd, queue, self._real.tcflush):
            self._real.tcflush(fd, queue)

    def tcdrain(self, fd: Any) -> None:
        port = _port(fd)
        if port is not None:
            _drain(port)
        self._real.tcdrain(fd)

    def tcsendbreak(self, fd: Any, duration: int) -> None:
        port = _port(fd)
        # glibc's meaning: 0 is 0.25 s, a positive duration is milliseconds rounded up to tenths.
        seconds = 0.25 if duration <= 0 else ((duration + 99) // 100) / 10.0
        if port is None or not _break(port, seconds):
            self._real.tcsendbreak(fd, duration)

    def tcgetattr(self, fd: Any) -> list:
        attributes = self._real.tcgetattr(fd)
        port = _port(fd)
        if port is not None:
            framing = ask(port, "framing")
            if framing is not None and framing >= 0:  # a pty forgets data bits and parity; the bench knows
                attributes[2] = attributes[2] & ~_FRAMING | framing
        return attributes

    def tcsetattr(self, fd: Any, when: int, attributes: list) -> None:
        port = _port(fd)
        if port is None:
            self._real.tcsetattr(fd, when, attributes)
            return
        _drain(port)
        try:
            self._real.tcsetattr(fd, when, attributes)
        except self._real.error as exc:
            # Debian's and Fedora's glibc fail with EINVAL when the kernel changed PARENB or CSIZE,
            # which a pty always does; an adapter takes them (the C shim has the same rule).
            if exc.args[0] != errno.EINVAL or not _pty_took_the_rest(fd, attributes):
                raise
        ask(port, f"sync {int(attributes[2])}")


class OsProxy(_Proxy):
    """``os`` with ``write`` stamping writes to bench ports on the delivery ledger."""

    def write(self, fd: Any, data: Any) -> int:
        return _write(self._real.write, fd, data)


def _pty_took_the_rest(fd: Any, wanted: list) -> bool:
    forced = _termios.CSIZE | _termios.PARENB | _termios.CREAD | getattr(_termios, "CBAUD", 0o10017)
    try:
        got = _termios.tcgetattr(fd)
    except _termios.error:
        return False
    return (got[2] & ~forced) == (int(wanted[2]) & ~forced) and got[5] == wanted[5]


# ---------------------------------------------------------------------- patching serialposix

def patch(module: Any) -> bool:
    """Give a loaded ``serial.serialposix`` the proxies; False if it does not look like one."""
    global _writes_seen
    fc, te, os_ = getattr(module, "fcntl", None), getattr(module, "termios", None), getattr(module, "os", None)
    if fc is None or te is None:
        return False
    if not isinstance(fc, FcntlProxy):
        module.fcntl = FcntlProxy(fc)
    if not isinstance(te, TermiosProxy):
        module.termios = TermiosProxy(te)
    if os_ is not None and hasattr(os_, "write"):
        if not isinstance(os_, OsProxy):
            module.os = OsProxy(os_)
        _writes_seen = True  # else writes go unseen, and every drain asks
    return True


def unpatch(module: Any) -> None:
    """Put the real modules back."""
    for name in ("fcntl", "termios", "os"):
        value = getattr(module, name, None)
        if isinstance(value, _Proxy):
            setattr(module, name, value._real)


class _PatchingLoader(importlib.abc.Loader):
    def __init__(self, loader: Any) -> None:
        self._loader = loader

    def create_module(self, spec: Any) -> Any:
        return self._loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._loader.exec_module(module)
        patch(module)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loader, name)


class _PatchOnImport(importlib.abc.MetaPathFinder):
    """Patches ``serial.serialposix`` when something imports it (nothing is imported before)."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> Any:
        if name != "serial.serialposix":
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None:
                    spec.loader = _PatchingLoader(spec.loader)
                return spec
        return None


_hook = _PatchOnImport()


def install() -> None:
    """Patch ``serial.serialposix`` now if it is loaded, else when it is imported."""
    module = sys.modules.get("serial.serialposix")
    if module is not None:
        patch(module)
    elif _hook not in sys.meta_path:
        sys.meta_path.insert(0, _hook)


def uninstall() -> None:
    """Undo :func:`install`."""
    if _hook in sys.meta_path:
        sys.meta_path.remove(_hook)
    module = sys.modules.get("serial.serialposix")
    if module is not None:
        unpatch(module)


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_after_fork)


__all__ = ["LEDGERS", "PORTS", "FcntlProxy", "OsProxy", "TermiosProxy", "ask", "install", "load_env", "patch", "register",
           "uninstall", "unpatch"]
