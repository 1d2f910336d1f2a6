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

Standard library only, and no hilbench import: the ``sitecustomize`` that loads
it may run in any Python 3 on the machine (a ROS node's system interpreter), not
only in hilbench's own. The request protocol is the line server's
(:mod:`hilbench.bench.line_server`). If the bench does not answer, the real call
runs (fail open), as in the C shim.
"""

from __future__ import annotations

import errno
import importlib.abc
import os
import socket
import stat
import struct
import sys
import termios as _termios
import threading
from collections.abc import Callable
from typing import Any

#: rdev -> the bench's line socket path, or (in-process) a callable answering one request line.
PORTS: dict[int, str | Callable[[str], str]] = {}
_lock = threading.Lock()
TIMEOUT = 30.0

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


def register(rdev: int, target: str | Callable[[str], str]) -> None:
    """Treat the pty with device number ``rdev`` as a bench port reached through ``target``."""
    with _lock:
        PORTS[rdev] = target


def unregister(rdev: int) -> None:
    with _lock:
        PORTS.pop(rdev, None)


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
    try:
        if callable(target):
            reply = target(line)
        else:
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                s.settimeout(timeout)
                s.connect(target)
                s.sendall(line.encode("ascii") + b"\n")
                data = b""
                while not data.endswith(b"\n") and len(data) < 256:
                    chunk = s.recv(256)
                    if not chunk:
                        break
                    data += chunk
            reply = data.decode("ascii", "replace")
    except (OSError, ValueError):
        return None
    words = reply.split()
    if len(words) >= 2 and words[0] == "ok":
        try:
            return int(words[1])
        except ValueError:
            return None
    return None


def _break(port: tuple[int, Any], seconds: float) -> bool:
    return ask(port, f"break {seconds:.3f}", TIMEOUT + seconds) is not None


def _flush(port: tuple[int, Any], fd: Any, queue: int, real_tcflush: Callable[[Any, int], None]) -> bool:
    """TCOFLUSH / TCIOFLUSH through the bench; False: not handled (do the real call)."""
    if queue not in (_termios.TCOFLUSH, _termios.TCIOFLUSH) or ask(port, "flush") is None:
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
        return getattr(self._real, name)

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
                ask(port, "drain")
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
            ask(port, "drain")
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
            ask(port, "drain")
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
        ask(port, "drain")
        try:
            self._real.tcsetattr(fd, when, attributes)
        except self._real.error as exc:
            # Debian's and Fedora's glibc fail with EINVAL when the kernel changed PARENB or CSIZE,
            # which a pty always does; an adapter takes them (the C shim has the same rule).
            if exc.args[0] != errno.EINVAL or not _pty_took_the_rest(fd, attributes):
                raise
        ask(port, f"sync {int(attributes[2])}")


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
    fc, te = getattr(module, "fcntl", None), getattr(module, "termios", None)
    if fc is None or te is None:
        return False
    if not isinstance(fc, FcntlProxy):
        module.fcntl = FcntlProxy(fc)
    if not isinstance(te, TermiosProxy):
        module.termios = TermiosProxy(te)
    return True


def unpatch(module: Any) -> None:
    """Put the real modules back."""
    for name in ("fcntl", "termios"):
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


__all__ = ["PORTS", "FcntlProxy", "TermiosProxy", "ask", "install", "load_env", "patch", "register",
           "uninstall", "unpatch"]
