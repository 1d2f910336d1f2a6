"""The virtual clock's shared page: the contract between the bench's lockstep loop and ``vclock.c``.

A client under ``hilbench run`` against a virtual-time bench finds the page through
``HILBENCH_CLOCK=<dir>/clock.page`` (PLAN26 §4.2). The bench creates the page and
the FIFOs beside it; every client thread of every client process claims one
*slot* and publishes there whether it runs or waits, and until when; the loop
advances ``vnow`` only when every live slot waits. All integers are native
(little-endian on every supported machine), naturally aligned, and accessed
atomically by both sides.

This module holds the numbers only: byte offsets, sizes, states and flags. The bench's lockstep
(:mod:`hilbench.bench.lockstep`) creates the page; :mod:`hilbench.run.vclock_page` is the same module
for the client side. ``hilbench/run/vclock.c`` defines the same numbers (a test compares them with
the library's own ``hb_vclock_layout()``).
"""

from __future__ import annotations

from hilbench.transports import channel_book

MAGIC = b"HBCLOCK1"
VERSION = 1

#: File names in the clock directory.
PAGE_FILE = "clock.page"
NOTIFY_FILE = "clock.notify"  # FIFO a client writes one byte to when the loop is armed
WAKE_FILE = "wake.{slot}"     # one FIFO per slot: the loop wakes a thread that waits on descriptors
ENV = "HILBENCH_CLOCK"        # the page's path, in the client's environment
ENV_SLOT = "HILBENCH_CLOCK_SLOT"  # set by the shim across exec: the slot the new image adopts

HEADER_SIZE = 512
SLOT_SIZE = 64
PORT_SIZE = 64
DEFAULT_SLOTS = 256

# Header fields: byte offsets.
H_MAGIC = 0              # 8 bytes
H_VERSION = 8            # u32
H_NSLOTS = 12            # u32
H_NPORTS = 16            # u32
H_VNOW = 24              # u64: virtual CLOCK_MONOTONIC, ns; written by the loop only, between rounds
H_EPOCH = 32             # u64: CLOCK_REALTIME (ns) at vnow == origin
H_ROUND = 40             # u64: rounds the loop ran
H_ACTIVITY = 48          # u64: clients bump it on hand-overs the loop cannot see (foreign writes, posts)
H_ARMED = 56             # u32: 1 while the loop waits for news (clients then write to clock.notify)
H_FLAGS = 60             # u32: FLAG_STALL, FLAG_HOLD
H_POLL_K = 64            # u32: unproductive calls before a thread counts as polling
H_POLL_QUANTUM = 72      # u64: ns a poller's wait lasts (its deadline is vnow + quantum)
H_STALLS = 80            # u64: lockstep stalls so far
H_ORIGIN = 88            # u64: vnow at the start (virtual realtime = epoch + vnow - origin)
H_STALLED_NS = 96        # u64: virtual ns that passed in stalls
H_UNVIRTUALISED = 104    # u64: calls of timers the shim does not virtualise (alarm, setitimer, timerfd, ...)
# Socket channels (PLAN26 §4.8, phase 2): the bench's socket doors and one record per client socket talking to one.
H_NCHANS = 112           # u32: channel records (0: the page has none)
H_NDOORS = 116           # u32: door entries in use (the bench adds them; clients read them at connect/sendto)
H_CHAN_OFF = 120         # u64: byte offset of the door table (DOOR_SIZE * MAX_DOORS), the channel records after it
H_CHAN_TIMEOUTS = 128    # u64: clients gave up waiting for bytes the bench sent on a channel to show (CHAN_LIMIT)

# Slot fields (one 64-byte slot per client thread): byte offsets within a slot.
S_STATE = 0          # u32: one of the states below
S_WAKE = 4           # u32: futex word the loop bumps (and FUTEX_WAKEs) to wake the thread
S_PID = 8            # u32
S_TID = 12           # u32
S_DEADLINE = 16      # u64: virtual ns the wait ends at (NO_DEADLINE: none)
S_PORTS = 24         # u64: bitmask of bench ports among the descriptors waited on
S_ACT_SEEN = 32      # u64: header activity when the wait began
S_SEEN_ROUND = 40    # u64: loop round the thread last woke in
S_UNPRODUCTIVE = 48  # u32: polling calls in a row (clock reads without news, empty 0-timeout polls)
S_FLAGS = 52         # u32: SF_* below
S_PROGRESS = 56      # u64: wrapped calls made (a "blocked elsewhere" check sees it move)

# Port records (after the slots): one per bench pty, byte offsets within a record.
P_RDEV = 0
P_KIND = 8
P_DELIVERED = 16     # bench: bytes written to the master
P_READ = 24          # clients: bytes read from the slave
P_DISCARDED = 32     # clients: bytes dropped by TCIFLUSH
P_WRITTEN = 40       # clients: bytes written to the slave
P_TAKEN = 48         # bench: bytes read from the master

# Doors (the bench's TCP listeners and UDP sockets whose traffic it counts): 16 bytes each.
D_PROTO = 0          # u32: 6 TCP, 17 UDP (0: unused)
D_ADDR = 4           # u32: IPv4 address as in sin_addr (network order; 0.0.0.0: any of this machine's)
D_PORT = 8           # u32: port (host order)

# Channel records (one per client socket connected or sending to a door): byte offsets within a record. Counts
# are bytes on TCP, datagrams on UDP. The client's fields are the shim's (atomic adds), the bench's the loop's
# (stores of the bench's totals for the client's address).
C_STATE = 0          # u32: CH_FREE, CH_CLAIMING, CH_OPEN
C_PID = 4            # u32: the process that claimed it (freed when it closes the socket or ends)
C_PROTO = 8          # u32: 6 TCP, 17 UDP
C_ADDR = 12          # u32: the client socket's IPv4 address (network order)
C_PORT = 16          # u32: the client socket's port (host order)
C_FLAGS = 20         # u32: CF_CONNECTED (a UDP socket connected to a door: all it receives is the bench's);
                     # bits 8-15: 1 + the index of the door it first sent to or connected to
C_SENT = 24          # u64: client: sent to the bench
C_RECEIVED = 32      # u64: client: received from the bench
C_BENCH_SENT = 40    # u64: bench: sent to the client
C_BENCH_TAKEN = 48   # u64: bench: taken from the client
C_GIVEN_UP = 56      # u64: client: the bench_sent it gave up waiting for (it did not show within CHAN_LIMIT)

DOOR_SIZE = 16
MAX_DOORS = 32
CHAN_SIZE = 64
DEFAULT_CHANS = 64   # at most 64: a slot's wait and an epoll set name channels in 64-bit masks
CH_FREE, CH_CLAIMING, CH_OPEN = range(3)
CF_CONNECTED = 1
TCP, UDP = channel_book.TCP, channel_book.UDP  # (a door's and a record's protocol)

# Slot states.
FREE, STARTING, RUNNING, RUNNABLE, WAITING, POLLING, REQUEST, WOKEN, EXITED = range(9)
STATE_NAMES = ("FREE", "STARTING", "RUNNING", "RUNNABLE", "WAITING", "POLLING", "REQUEST", "WOKEN", "EXITED")

# Slot flags.
SF_FDWAIT = 1    # waits on descriptors: wake it with a byte on its wake FIFO too
SF_FOREIGN = 2   # waits on something a client can hand over (a pipe, a semaphore): RECHECK it on activity
SF_INTERP = 4    # inside the interpreter's own lock (the GIL): real time
SF_TIMER = 8     # used a timer the shim does not virtualise
SF_ENDING = 16   # left the clock because its process ends (not one thread): time waits until it has ended

# Header flags.
FLAG_STALL = 1
FLAG_HOLD = 2

NO_DEADLINE = 2**64 - 1
ORIGIN_NS = 1000 * 10**9  # virtual CLOCK_MONOTONIC starts at 1000 s ("booted 1000 s ago")


def page_size(nslots: int = DEFAULT_SLOTS, nports: int = 0) -> int:
    """Bytes of a page with ``nslots`` slots and ``nports`` port records."""
    return HEADER_SIZE + SLOT_SIZE * nslots + PORT_SIZE * nports


def slot_offset(i: int) -> int:
    """Byte offset of slot ``i``."""
    return HEADER_SIZE + SLOT_SIZE * i


def port_offset(nslots: int, i: int) -> int:
    """Byte offset of port record ``i`` in a page of ``nslots`` slots."""
    return HEADER_SIZE + SLOT_SIZE * nslots + PORT_SIZE * i


def chan_bit(nports: int, c: int) -> int:
    """The bit of channel record ``c`` in a slot's ``ports`` mask (after the ptys'; the last ones share bit 62)."""
    return min(nports + c, 62)


def channels_size(nchans: int) -> int:
    """Bytes of the door table and ``nchans`` channel records (none without channels)."""
    return DOOR_SIZE * MAX_DOORS + CHAN_SIZE * nchans if nchans else 0


def door_offset(chan_off: int, i: int) -> int:
    """Byte offset of door ``i``, the table starting at ``chan_off`` (the header's ``H_CHAN_OFF``)."""
    return chan_off + DOOR_SIZE * i


def chan_offset(chan_off: int, c: int) -> int:
    """Byte offset of channel record ``c`` (after the door table at ``chan_off``)."""
    return chan_off + DOOR_SIZE * MAX_DOORS + CHAN_SIZE * c


def layout() -> dict[str, int]:
    """The numbers both sides must agree on, by name, as ``hb_vclock_layout()`` in the C library prints them."""
    names = [n for n in globals() if n[:2] in ("H_", "S_", "P_", "SF", "D_", "C_", "CH", "CF") or n in (
        "VERSION", "HEADER_SIZE", "SLOT_SIZE", "PORT_SIZE", "FLAG_STALL", "FLAG_HOLD", "DOOR_SIZE", "MAX_DOORS",
        "CHAN_SIZE", "TCP", "UDP")]
    out = {n: globals()[n] for n in names if isinstance(globals()[n], int)}
    out.update(zip(STATE_NAMES, range(len(STATE_NAMES)), strict=True))
    return out


__all__ = [n for n in list(globals()) if n.isupper()] + ["chan_bit", "chan_offset", "channels_size", "door_offset",
                                                          "layout", "page_size", "port_offset", "slot_offset"]
