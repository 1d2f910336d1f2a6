"""Sockets to a virtual-time bench are channels of its lockstep (PLAN26 §4.8, phase 2; §10 risk 1).

A client under ``hilbench run`` that *blocks* on a socket to the bench (python-can's socketcand interface in
``bus.recv(timeout=...)``, which selects on its TCP connection; a UDP client in ``select`` or a blocking
``recvfrom`` on a bench's UDP door) is woken by the bench's loop at the virtual instant the bench sent to it,
and time does not move while the bytes are on their way. Before channels it was woken by the kernel, and the
loop could move time to the client's own deadline first: python-can saw a heartbeat at its next ``recv``
timeout (60 ms late here), and the UDP client's datagram instants moved from run to run. Real benches, real
client processes with the preload shim; the third run of each has a CPU-bound neighbour.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hilbench.bench import Bench
from hilbench.bench.control import ControlClient
from tests.run.test_virtual_time import client
from tests.run.test_virtual_time_sdk import neighbour

pytestmark = pytest.mark.usefixtures("library")  # (tests/run/conftest.py: skipped without the shim)

EPOCH = 1_700_000_000


def run_client(bench: Bench, tmp_path: Path, code: str, *args: str) -> str:
    """Run ``code`` under ``hilbench run`` against ``bench``; its stdout. Each call gets a directory of its own
    (:func:`client` keeps one manifest per directory, and a test here runs several benches)."""
    run_dir = tmp_path / f"bench-{len(list(tmp_path.glob('bench-*')))}"
    run_dir.mkdir()
    return client(bench, run_dir, code, *args, timeout=120)[0].stdout


CAN_RECEIVER = """
    import json, sys, time
    import can
    host, port, seconds, epoch = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
    bus = can.Bus(interface="socketcand", host=host, port=port, channel="can0")
    t0, beats = time.monotonic(), []
    while time.monotonic() - t0 < seconds:
        msg = bus.recv(timeout=0.3)  # (select on the connection with a 0.3 s timeout, then recv)
        if msg is not None and msg.arbitration_id == 0x702:
            beats.append([time.monotonic_ns(), round(msg.timestamp - epoch, 6), bytes(msg.data).hex()])
    bus.shutdown()
    print(json.dumps(beats))
"""


def test_python_can_blocking_in_recv_sees_each_heartbeat_at_its_virtual_instant(tmp_path):
    """Node 2's heartbeat (1 s) over socketcand to a client that blocks in ``bus.recv(timeout=0.3)`` for 4
    virtual seconds: every heartbeat is received at the virtual instant the bench sent it (its frame's time
    stamp), the same in three runs, the third beside a CPU-bound neighbour."""
    pytest.importorskip("can")
    runs = []
    for busy in (False, False, True):
        with Bench("mecarover-can", virtual_time=True, virtual_epoch=EPOCH) as bench, neighbour(busy):
            bench.clock.run_for(0.5, timeout=10)  # past the node's boot-up (0.02 s), then NMT start
            bench.serve_control()
            ControlClient(bench.control.address_text).call("nmt", device="rover", state="operational")
            s = bench.manifest()["endpoints"][0]["socketcand"]
            beats = json.loads(run_client(bench, tmp_path, CAN_RECEIVER, s["host"], str(s["port"]), "4",
                                          str(EPOCH)))
            stats = bench.services["clock"].stats()
        assert stats["stalls"] == 0 and stats["channel_timeouts"] == 0
        # four heartbeats 1 s apart (the first at 1001.020368: the boot-up's instant plus the frame's time on the
        # bus), OPERATIONAL (0x05)
        first = beats[0][1]
        assert [stamp for _t, stamp, _d in beats] == pytest.approx([first + k for k in range(4)], abs=2e-6)
        assert [data for _t, _s, data in beats] == ["05"] * 4
        # received when sent: the client's clock reads the frame's instant (not its next recv timeout's, up to
        # 0.3 s later)
        late = [(t / 1e9 - 1000, stamp) for t, stamp, _d in beats if abs(t / 1e9 - 1000 - stamp) > 2e-6]
        assert late == [], beats
        runs.append(beats)
    assert runs[0] == runs[1] == runs[2]


UDP_RECEIVER = """
    import json, select, socket, sys, time
    host, port, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.sendto(b"", (host, port))  # (registers this socket for the board's output)
    banner, _ = s.recvfrom(65536)  # blocking, no timeout
    t0, got = time.monotonic_ns(), []
    while time.monotonic_ns() - t0 < seconds * 1e9:
        ready, _, _ = select.select([s], [], [], 0.05)
        if ready:
            data, _ = s.recvfrom(65536)
            got.append([time.monotonic_ns() - t0, len(data)])
    print(json.dumps({"t0": t0, "banner": len(banner), "got": got}))
"""


def test_a_udp_client_blocking_on_a_bench_door_gets_datagrams_at_the_same_instants(tmp_path):
    """The rover board behind UDP (``mecarover-udp``) dumps its trace window (the button pressed before the client
    joins) at the pace of its 1,152,000-baud UART, one datagram per delivery, to a client that waits in a
    blocking ``recvfrom`` and then in ``select`` with a 50 ms timeout: every run receives the same datagrams at
    the same virtual nanoseconds (the third beside a CPU-bound neighbour)."""
    from hilbench.clients.stm32_rover import BoardClient

    runs = []
    for busy in (False, False, True):
        with Bench("mecarover-udp", virtual_time=True, virtual_epoch=EPOCH) as bench, neighbour(busy):
            ep = bench.manifest()["endpoints"][0]
            bench.serve_control()
            # (the press lands at the board's own time: let the loop's first rounds run before it, or it lands
            # before or after the board's first step depending on how soon the loop thread ran)
            bench.clock.run_for(0.01, timeout=10)
            BoardClient(bench.control.address_text).button()  # (the window starts when time next moves)
            out = json.loads(run_client(bench, tmp_path, UDP_RECEIVER, ep["host"], str(ep["port"]), "0.5"))
            stats = bench.services["clock"].stats()
        assert stats["stalls"] == 0 and stats["channel_timeouts"] == 0
        # (the blocking recvfrom waited, in virtual time, for the board's first datagram)
        assert out["t0"] > 1000.01 * 10**9 and out["banner"] > 0
        assert len(out["got"]) > 400  # (a datagram about every millisecond)
        runs.append(out)
    assert runs[0] == runs[1] == runs[2]


RCVTIMEO = """
    import json, socket, struct, sys, time
    s = socket.create_connection((sys.argv[1], int(sys.argv[2])))
    hi = s.recv(64)  # (blocking: the server's greeting)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.pack("ll", 0, 200_000))
    t0 = time.monotonic_ns()
    try:
        s.recv(64)  # nothing comes before "< open >": SO_RCVTIMEO ends it
        err = None
    except BlockingIOError:
        err = "EAGAIN"
    print(json.dumps({"hi": hi.decode(), "waited": time.monotonic_ns() - t0, "err": err}))
"""


def test_a_blocking_recv_on_a_channel_times_out_at_its_virtual_so_rcvtimeo(tmp_path):
    """A blocking ``recv`` on a socketcand connection with ``SO_RCVTIMEO`` 0.2 s and nothing to come: it waits
    in virtual time and fails with EAGAIN after exactly 0.2 virtual seconds (the kernel's timeout would be
    0.2 s of wall time, and the bench's clock would not have moved). (The kernel keeps the timeout in jiffies
    and the shim uses what it reports: 0.25 s comes back as 0.252 s at HZ=250; 0.2 s is whole at 100, 250,
    300 and 1000.)"""
    with Bench("mecarover-can", virtual_time=True) as bench:
        s = bench.manifest()["endpoints"][0]["socketcand"]
        out = json.loads(run_client(bench, tmp_path, RCVTIMEO, s["host"], str(s["port"])))
        stats = bench.services["clock"].stats()
    assert out == {"hi": "< hi >", "waited": 200_000_000, "err": "EAGAIN"}
    assert stats["stalls"] == 0


ASYNCIO_RECEIVER = """
    import asyncio, json, sys, time
    host, port, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    got = []

    class Receiver(asyncio.DatagramProtocol):
        def datagram_received(self, data, addr):
            got.append([time.monotonic_ns(), len(data)])

    async def main():
        transport, _ = await asyncio.get_running_loop().create_datagram_endpoint(Receiver, remote_addr=(host, port))
        transport.sendto(b"x")  # (registers; asyncio sends no empty datagram)
        await asyncio.sleep(seconds)
        transport.close()

    asyncio.run(main())
    print(json.dumps(got))
"""


def test_an_asyncio_udp_client_in_epoll_gets_each_datagram_at_its_instant(tmp_path):
    """The same trace window to an asyncio client (``create_datagram_endpoint``: a connected UDP socket in an
    epoll set, ``epoll_wait`` with the timeout of its next timer): the same datagrams at the same virtual
    nanoseconds in three runs, the third beside a CPU-bound neighbour. (4def11e: the loop moved time to the
    client's 0.3 s sleep while the kernel woke it, and it read the first datagrams all at once at 18, 31 or
    40 ms.)"""
    from hilbench.clients.stm32_rover import BoardClient

    runs = []
    for busy in (False, False, True):
        with Bench("mecarover-udp", virtual_time=True, virtual_epoch=EPOCH) as bench, neighbour(busy):
            ep = bench.manifest()["endpoints"][0]
            bench.serve_control()
            bench.clock.run_for(0.01, timeout=10)  # (see the test above)
            BoardClient(bench.control.address_text).button()
            got = json.loads(run_client(bench, tmp_path, ASYNCIO_RECEIVER, ep["host"], str(ep["port"]), "0.3"))
            stats = bench.services["clock"].stats()
        assert stats["stalls"] == 0 and stats["channel_timeouts"] == 0
        assert len(got) > 250
        assert got[0][0] != got[1][0]  # (each received at its own instant, not in a batch)
        runs.append(got)
    assert runs[0] == runs[1] == runs[2]


SPINNER = """
    import json, socket, sys, time
    s = socket.create_connection((sys.argv[1], int(sys.argv[2])))
    s.recv(64)  # (the greeting)
    s.setblocking(False)
    t0 = time.monotonic_ns()
    for _ in range(20_000):  # a non-blocking recv in a loop, and nothing else: polling
        try:
            s.recv(64)
        except BlockingIOError:
            pass
    print(json.dumps({"v": time.monotonic_ns() - t0}))
"""


def test_a_client_spinning_on_a_non_blocking_recv_of_a_channel_polls(tmp_path):
    """Non-blocking ``recv`` calls that find nothing on a channel count as polling, as empty reads of a pty do:
    every 32nd (the poll K) waits one quantum (100 us) of virtual time, so the clock moves and the spinner
    holds it for no stall (4def11e: ``recv`` was not looked at, and 20 000 of them took no virtual time)."""
    with Bench("mecarover-can", virtual_time=True) as bench:
        s = bench.manifest()["endpoints"][0]["socketcand"]
        out = json.loads(run_client(bench, tmp_path, SPINNER, s["host"], str(s["port"])))
        stats = bench.services["clock"].stats()
    assert out["v"] == 20_000 // 32 * 100_000 and stats["stalls"] == 0
