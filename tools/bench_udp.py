#!/usr/bin/env python3
"""UDP benchmarks (micro-ROS / RTPS); prints one JSON object per figure (see DESIGN.md §11).

1. ``udp_monitor_classify_decode``: datagrams per second the UDP monitor's
   tracker classifies and decodes (sessions, streams, entities, topics, RTPS
   writers, flags), fed in memory with addresses, as a ratio to a saturated
   100 Mbit/s Ethernet link of 100-byte datagrams (100 + 8 UDP + 20 IPv4 + 14
   Ethernet + 4 FCS + 8 preamble + 12 gap = 166 byte times: 75,301 datagrams/s).
   Target >= 1x. The mix: XRCE WRITE_DATA (best effort, 100 bytes), the
   agent's DATA to a reader, reliable WRITE_DATA with ACKNACKs and HEARTBEATs,
   and RTPS user DATA of 100 bytes from two writers. Median of ``--repeats``
   runs (``ratio``), best run (``best_ratio``) and the median over CPU time
   (``cpu_ratio``).
2. ``agent_reliable_round_trips``: round trips per second through the emulated
   agent on 127.0.0.1 for a reliable stream: a client writes one WRITE_DATA on
   stream 0x80 and waits for the agent's ACKNACK before the next. Reference: a
   plain UDP echo (a Python thread answering each datagram) measured in the
   same run, so the ratio is the agent's cost against Python's own UDP floor.

Usage: tools/bench_udp.py [--repeats N] [--datagrams N] [--seconds S]
"""

from __future__ import annotations

import argparse
import socket
import statistics
import threading
import time

from benchlib import emit

from hilbench.bench import Bench
from hilbench.bench.profile import parse_profile
from hilbench.monitor.udp.targets import datagrams
from hilbench.monitor.udp.tracker import UdpTracker
from hilbench.protocols import xrce_dds as x

#: 100-byte datagrams on a saturated 100 Mbit/s link: 166 byte times each (see the docstring).
LINK_DATAGRAMS = 100e6 / (8 * (100 + 8 + 20 + 14 + 4 + 8 + 12))


def bench_monitor(n: int, repeats: int) -> None:
    data = datagrams(n)
    sizes = {len(d) for _, d, _ in data}
    walls, cpus = [], []
    for _ in range(repeats):
        tr = UdpTracker()
        feed = tr.feed_datagram
        c0, w0 = time.process_time(), time.perf_counter()
        for t, d, addr in data:
            feed(t, "bench", d, addr)
        walls.append(n / (time.perf_counter() - w0))
        cpus.append(n / (time.process_time() - c0))
    assert tr.datagrams == n and not tr.flags, tr.flags
    med = statistics.median(walls)
    emit("udp_monitor_classify_decode", med, "datagrams/s", LINK_DATAGRAMS, med / LINK_DATAGRAMS,
         best_ratio=round(max(walls) / LINK_DATAGRAMS, 3),
         cpu_ratio=round(statistics.median(cpus) / LINK_DATAGRAMS, 3), datagram_bytes=sorted(sizes),
         datagrams=n, repeats=repeats)


def _echo_rate(seconds: float) -> float:
    srv = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    srv.bind(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        srv.settimeout(0.2)
        while not stop.is_set():
            try:
                d, a = srv.recvfrom(2048)
            except TimeoutError:
                continue
            srv.sendto(d, a)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    cli = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    cli.settimeout(2)
    n = 0
    end = time.perf_counter() + seconds
    t0 = time.perf_counter()
    while time.perf_counter() < end:
        cli.sendto(b"x" * 24, srv.getsockname())
        cli.recvfrom(2048)
        n += 1
    rate = n / (time.perf_counter() - t0)
    stop.set()
    th.join()
    srv.close()
    cli.close()
    return rate


def bench_agent(seconds: float) -> None:
    prof = {"schema": 1, "endpoints": {"agent": {"type": "udp", "protocol": "xrce-dds", "port": 0}}}
    bench = Bench(parse_profile(prof, "bench.toml")).start()
    try:
        agent = tuple(bench.endpoint().port.address)
        cli = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        cli.bind(("127.0.0.1", 0))
        cli.settimeout(2)
        key = bytes.fromhex("60C93570")
        cli.sendto(x.build_message(0x80, 0, 0, [(0, 1, x.client_representation(key, 0x81))]), agent)
        cli.recvfrom(2048)
        xml = {"participant": "<dds><participant><rtps><name>p</name></rtps></participant></dds>",
               "topic": "<dds><topic><name>rt/bench</name><dataType>std_msgs::msg::dds_::Int32_</dataType></topic></dds>",
               "writer": "<dds><data_writer><topic><kind>NO_KEY</kind><name>rt/bench</name><dataType>"
                         "std_msgs::msg::dds_::Int32_</dataType></topic></data_writer></dds>"}
        K = x.ObjectKind
        creates = [
            (x.object_id(1, K.PARTICIPANT), K.PARTICIPANT, {"representation": {"format": 2, "value": xml["participant"]},
                                                            "domain_id": 0}),
            (x.object_id(1, K.TOPIC), K.TOPIC, {"representation": {"format": 2, "value": xml["topic"]},
                                                "participant_id": x.object_id(1, K.PARTICIPANT)}),
            (x.object_id(1, K.PUBLISHER), K.PUBLISHER, {"representation": {"format": 2, "value": ""},
                                                        "participant_id": x.object_id(1, K.PARTICIPANT)}),
            (x.object_id(1, K.DATAWRITER), K.DATAWRITER, {"representation": {"format": 2, "value": xml["writer"]},
                                                          "publisher_id": x.object_id(1, K.PUBLISHER)}),
        ]
        seq = 0
        for i, (oid, kind, rep) in enumerate(creates):
            cli.sendto(x.build_message(0x81, 0x80, seq, [(1, 5, x.create((10 + i).to_bytes(2, "big"), oid, kind, rep))]),
                       agent)
            seq += 1
        deadline = time.monotonic() + 2
        while time.monotonic() < deadline and not bench.family("micro-ros-agent").agent().counters["replies"] >= 9:
            time.sleep(0.01)
        cli.sendto(x.build_message(0x81, 0, 0, [(10, 1, x.acknack(4, 0, 0x80))]), agent)  # its STATUSes
        time.sleep(0.05)
        while True:  # drain what came back so far
            cli.settimeout(0.05)
            try:
                cli.recvfrom(2048)
            except TimeoutError:
                break
        cli.settimeout(2)
        writer = x.object_id(1, K.DATAWRITER)
        n = 0
        t0 = time.perf_counter()
        end = t0 + seconds
        while time.perf_counter() < end:
            cli.sendto(x.build_message(0x81, 0x80, seq & 0xFFFF, [(7, 1, x.data(b"\x00\x0a", writer,
                                                                                 n.to_bytes(4, "little")))]), agent)
            while True:
                d = cli.recvfrom(2048)[0]
                if len(d) >= 9 and d[4] == 10:  # the ACKNACK for it
                    break
            seq += 1
            n += 1
        rate = n / (time.perf_counter() - t0)
        cli.close()
        s = next(iter(bench.family("micro-ros-agent").agent().sessions.values()))
        assert s.samples_in == n, (s.samples_in, n)
    finally:
        bench.stop()
    echo = _echo_rate(seconds)
    emit("agent_reliable_round_trips", rate, "round trips/s", echo, rate / echo, samples=n,
         reference_name="Python UDP echo on 127.0.0.1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--datagrams", type=int, default=100_000)
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    bench_monitor(args.datagrams, args.repeats)
    bench_agent(args.seconds)


if __name__ == "__main__":
    main()
