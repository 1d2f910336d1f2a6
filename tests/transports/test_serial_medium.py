"""Pty endpoints and the multi-drop serial line, with real pseudo-terminals."""

from __future__ import annotations

import os
import termios
import time

import serial

from hilbench.pytest_plugin import wait_until
from hilbench.transports.pty import PtyPort
from hilbench.transports.serial_medium import SerialMedium


class Recorder:
    """An in-process device that records what it receives and can answer."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.got: list[tuple[bytes, float, int | None]] = []
        self.port = None
        self.answer: bytes | None = None
        self.gap = 0.0

    def on_bytes(self, data: bytes, t: float, baud: int | None) -> None:
        self.got.append((data, t, baud))
        if self.answer and self.port:
            self.port.transmit(self.answer, t=t, gap=self.gap)

    def received(self) -> bytes:
        return b"".join(d for d, _, _ in self.got)


def read_exactly(ser: serial.Serial, n: int, timeout: float = 2.0) -> bytes:
    out = b""
    deadline = time.monotonic() + timeout
    while len(out) < n and time.monotonic() < deadline:
        out += ser.read(n - len(out))
    return out


def test_pty_is_raw_and_survives_reopen(tmp_path):
    with PtyPort("host", link=tmp_path / "dev" / "bus") as ep:
        assert os.path.islink(tmp_path / "dev" / "bus")
        assert ep.client_path == str(tmp_path / "dev" / "bus")
        for _ in range(3):
            with serial.Serial(ep.client_path, 115200, timeout=1) as ser:
                ser.write(b"\x19\x0d\x03\x00")  # bytes a cooked tty would rewrite or treat as signals
                got = wait_until(ep.read)
                assert got == b"\x19\x0d\x03\x00"
                ep.write(b"\x19\x0d\x0a\xff")
                assert read_exactly(ser, 4) == b"\x19\x0d\x0a\xff"
                assert ep.client_baud() == 115200
    assert not os.path.lexists(tmp_path / "dev" / "bus")


def test_client_baud_is_read_from_termios():
    with PtyPort("host") as ep, serial.Serial(ep.path, 1_000_000) as ser:
        assert ep.client_baud() == 1_000_000
        ser.baudrate = 57600
        assert ep.client_baud() == 57600
        assert termios.tcgetattr(ep.slave_fd)[5] == termios.B57600


def test_a_full_client_buffer_drops_and_counts_instead_of_blocking():
    with PtyPort("host") as ep:
        sent = ep.write(bytes(1 << 20))  # nobody reads: the pty buffer fills up
        assert sent < 1 << 20
        assert ep.dropped == (1 << 20) - sent


def test_every_party_hears_every_other_and_taps_see_everything():
    a, b = PtyPort("a"), PtyPort("b")
    dev1, dev2 = Recorder("dev1"), Recorder("dev2")
    line = SerialMedium("line", 115200)
    tapped: list[tuple[float, str, bytes]] = []
    line.add_tap(lambda t, src, data: tapped.append((t, src, data)))
    line.add_host(a)
    line.add_host(b)
    dev1.port = line.add_device(dev1)
    line.add_device(dev2)
    dev1.answer = b"pong"
    line.start()
    try:
        with serial.Serial(a.path, 115200, timeout=0) as sa, serial.Serial(b.path, 115200, timeout=0) as sb:
            sa.write(b"ping")
            # host b hears host a and device 1; host a hears only device 1 (not its own echo)
            assert read_exactly(sb, 8) == b"pingpong"
            assert read_exactly(sa, 4) == b"pong"
            assert wait_until(lambda: dev2.received() == b"pingpong")
            assert dev1.received() == b"ping"  # a device does not hear itself
            assert dev1.got[0][2] == 115200  # with the sender's line rate
        assert [(src, data) for _, src, data in tapped] == [("a", b"ping"), ("dev1", b"pong")]
        assert tapped[0][0] <= tapped[1][0]
        assert line.stats.by_source == {"a": 4, "dev1": 4}
    finally:
        line.close()
        a.close()
        b.close()


def test_listen_only_host_hears_but_is_not_heard():
    host, sniffer = PtyPort("host"), PtyPort("sniffer")
    dev = Recorder("dev")
    line = SerialMedium("line", 115200)
    line.add_host(host)
    line.add_host(sniffer, listen_only=True)
    line.add_device(dev)
    line.start()
    try:
        with serial.Serial(host.path, timeout=0) as sh, serial.Serial(sniffer.path, timeout=0) as ss:
            ss.write(b"ignored")
            sh.write(b"hello")
            assert read_exactly(ss, 5) == b"hello"
            wait_until(lambda: dev.received() == b"hello")
            assert read_exactly(sh, 1, timeout=0.05) == b""
    finally:
        line.close()
        host.close()
        sniffer.close()


def test_paced_line_models_wire_time_and_reply_gap():
    """10 bytes at 9600 baud take 10.4 ms each way; the reply waits its gap after the request."""
    host = PtyPort("host")
    dev = Recorder("dev")
    line = SerialMedium("line", 9600, paced=True)
    line.add_host(host)
    dev.port = line.add_device(dev)
    dev.answer = bytes(10)
    dev.gap = 0.005
    tapped = []
    line.add_tap(lambda t, src, data: tapped.append((t, src)))
    line.start()
    try:
        byte_time = 10 / 9600
        expected = 10 * byte_time + 0.005 + 10 * byte_time  # request, gap, reply
        times = []
        # a blocking read: a thread busy-polling the port would hold the GIL the line's thread needs, and a
        # loaded machine preempts it while it holds it
        with serial.Serial(host.path, 9600, timeout=1) as ser:
            for _ in range(5):  # the fastest of five: a loaded machine only adds delay
                t0 = time.monotonic()
                ser.write(bytes(10))
                assert read_exactly(ser, 10) == bytes(10)
                times.append(time.monotonic() - t0)
        assert expected * 0.98 < min(times) < expected + 0.010
        assert len(tapped) == 10
        for (t_req, src_req), (t_rep, src_rep) in zip(tapped[::2], tapped[1::2], strict=True):
            assert (src_req, src_rep) == ("host", "dev")
            assert abs((t_rep - t_req) - (0.005 + 10 * byte_time)) < 1e-6  # the model itself is exact
    finally:
        line.close()
        host.close()


def test_paced_transmissions_queue_behind_each_other():
    line = SerialMedium("line", 100_000, paced=True)  # 100 us per byte
    t = time.monotonic() + 1.0
    end1 = line.transmit("x", bytes(10), t=t)
    end2 = line.transmit("y", bytes(5), t=t)  # the line is busy until end1
    assert abs(end1 - (t + 0.001)) < 1e-9
    assert abs(end2 - (end1 + 0.0005)) < 1e-9
    line.close()


def test_a_burst_reaches_the_host_in_granules_never_early():
    """Deliveries due within the granule share a wake-up and a host write; none arrives before its wire time,
    and taps and devices still see each transmission at its own model time."""
    import hilbench.transports.serial_medium as sm

    host = PtyPort("host")
    line = SerialMedium("line", 1_000_000, paced=True)  # 10 us per byte: ten 5-byte replies, 50 us apart
    line.add_host(host)
    tapped = []
    line.add_tap(lambda t, src, data: tapped.append((t, data)))
    line.start()
    try:
        with serial.Serial(host.path, 1_000_000, timeout=0) as ser:
            arrivals = []
            for _ in range(5):  # the best of five: a loaded machine only makes deliveries later
                tapped.clear()
                t0 = time.monotonic() + 0.002
                ends = [line.transmit("dev", bytes([i]) * 5, t=t0) for i in range(10)]
                got, seen = b"", []
                while len(got) < 50 and time.monotonic() < t0 + 1:
                    chunk = ser.read(50)
                    if chunk:
                        seen.append((time.monotonic(), len(got) + len(chunk)))
                        got += chunk
                assert got == b"".join(bytes([i]) * 5 for i in range(10))
                for now, total in seen:  # every byte read had been on the wire by then
                    assert now >= ends[(total - 1) // 5]
                assert [t for t, _ in tapped] == ends  # taps: exact model times, one record per transmission
                arrivals.append((len(seen), seen[-1][0] - ends[-1]))
        chunks, late = min(arrivals, key=lambda a: a[1])
        assert late < 0.005  # the last byte came when the wire model says, give or take a wake-up
        assert min(n for n, _ in arrivals) < 10  # a 450 us burst came in fewer writes than transmissions
        assert sm.DELIVERY_GRANULE > 0
    finally:
        line.close()
        host.close()


def test_a_bursts_tail_is_handed_over_in_one_wake_up_and_the_rest_in_granules():
    """A Sync Read's twenty statuses 33 us apart (4.5 Mbaud): wake-ups cover a granule each, never early; the
    deliveries within TAIL_JOIN of the burst's last one share its wake-up (the line could not leave the CPU
    between them), which is the burst's last; a pending timer is never kept waiting by a group."""
    import hilbench.transports.serial_medium as sm

    line = SerialMedium("line", 4_500_000, paced=True)
    t0 = time.monotonic() + 10.0
    ends = [line.transmit("dev", bytes(15), t=t0) for _ in range(20)]
    assert abs((ends[1] - ends[0]) - 33.3e-6) < 1e-7
    wakes = []
    while line._events:
        wake, last = line._next_wake()
        group = [e for e in line._events if e[0] <= wake]
        assert group and max(e[0] for e in group) == wake  # never early: woken for a delivery's own time
        assert wake - min(e[0] for e in group) <= sm.DELIVERY_GRANULE + 1e-9
        wakes.append((len(group), last))
        line._events[:] = [e for e in line._events if e[0] > wake]
    assert [n for n, _ in wakes] == [4, 4, 4, 4, 2, 2]  # the tail: statuses 19 and 20, 33 us apart
    assert [last for _, last in wakes] == [False] * 5 + [True]
    assert sm.TAIL_JOIN < 50e-6  # replies 50 us apart or more (3 Mbaud and slower) each keep their own

    line._events.clear()
    ends = [line.transmit("dev", bytes(15), t=t0 + 1) for _ in range(3)]
    line.call_at(ends[0] + 10e-6, lambda: None)  # a timer between the first two deliveries
    assert line._next_wake() == (ends[0], False)
    line.close()


def test_paced_line_reports_its_scheduling_and_can_stay_normal(monkeypatch):
    line = SerialMedium("line", 9600, paced=True, realtime=False)
    line.start()
    try:
        assert line.scheduling == "SCHED_OTHER"
    finally:
        line.close()
    assert SerialMedium("x", 9600).cpu_latency is None  # unpaced lines never ask
    monkeypatch.setenv("HILBENCH_REALTIME", "0")
    assert SerialMedium("x", 9600, paced=True).realtime is False
    monkeypatch.delenv("HILBENCH_REALTIME")
    assert SerialMedium("x", 9600, paced=True).realtime is True
    assert SerialMedium("x", 9600, paced=False).realtime is False  # unpaced lines gain nothing from it
    line = SerialMedium("line", 9600, paced=True)
    line.start()
    try:  # root or CAP_SYS_NICE: SCHED_FIFO; otherwise the normal scheduler and why
        assert line.scheduling == "SCHED_FIFO 10" or line.scheduling.startswith("SCHED_OTHER (SCHED_FIFO refused")
        # and idle CPUs kept awake while it runs (root: the PM QoS request), or why not
        assert line.cpu_latency == "0 us" or line.cpu_latency.startswith("not ")
    finally:
        line.close()


def test_realtime_falls_back_with_the_reason():
    import threading

    from hilbench.transports.clock import try_realtime

    out = []
    t = threading.Thread(target=lambda: out.append(try_realtime(priority=1000)))  # no such priority
    t.start()
    t.join()
    assert out[0].startswith("SCHED_OTHER (SCHED_FIFO refused: ")
