"""The emulated CAN bus: delivery, arbitration, bit-time pacing, error frames, bus-off, bus load."""

from __future__ import annotations

import threading

import pytest

from hilbench.protocols import can_frame as cf
from hilbench.protocols.can_frame import data_frame
from hilbench.pytest_plugin import wait_until
from hilbench.transports.can_medium import BUS_OFF_RECOVERY_BITS, CanMedium


class Recorder:
    def __init__(self, name: str) -> None:
        self.name = name
        self.frames: list[tuple[float, cf.CanFrame]] = []
        self.states: list[str] = []
        self.lock = threading.Lock()

    def on_frame(self, frame, t):
        with self.lock:
            self.frames.append((t, frame))

    def on_bus_state(self, state, t):
        self.states.append(state)

    def data(self):
        with self.lock:
            return [f for _, f in self.frames if not f.error]

    def errors(self):
        with self.lock:
            return [f for _, f in self.frames if f.error]


@pytest.fixture
def bus():
    media = []

    def make(paced=False, bitrate=500_000, **faults):
        m = CanMedium("can", bitrate, paced=paced, seed=1)
        if faults:
            m.set_faults(**faults)
        media.append(m)
        return m

    yield make
    for m in media:
        m.close()


def sender_and_receiver(m: CanMedium) -> tuple[Recorder, Recorder, object]:
    """Devices ``a`` (with its port) and ``rx`` on bus ``m``, which is started."""
    a, rx = Recorder("a"), Recorder("rx")
    port = m.add_device(a)
    m.add_device(rx)
    m.start()
    return a, rx, port


def test_every_party_but_the_sender_gets_the_frame(bus):
    m = bus()
    a, b, c = Recorder("a"), Recorder("b"), Recorder("c")
    ports = {d.name: m.add_device(d) for d in (a, b, c)}
    tapped = []
    m.add_tap(lambda t, src, data: tapped.append((src, data)))
    m.start()
    frame = data_frame(0x123, b"\x01\x02")
    ports["a"].send(frame)
    wait_until(lambda: b.data() and c.data())
    assert a.data() == [] and b.data() == [frame] and c.data() == [frame]
    assert tapped == [("a", cf.pack(frame))]
    assert m.stats.frames == 1 and m.stats.by_source == {"a": 1}


def test_generic_transmit_takes_socketcan_records(bus):
    m = bus()
    a, b = Recorder("a"), Recorder("b")
    port = m.add_device(a)
    m.add_device(b)
    m.start()
    frames = [data_frame(0x100 + i, bytes([i])) for i in range(3)]
    port.transmit(b"".join(cf.pack(f) for f in frames))
    wait_until(lambda: len(b.data()) == 3)
    assert b.data() == frames


def test_paced_arbitration_and_bit_times(bus):
    m = bus(paced=True, bitrate=10_000)
    parties = {n: Recorder(n) for n in ("a", "b", "c", "d", "rx")}
    ports = {n: m.add_device(d) for n, d in parties.items()}
    m.start()
    first = data_frame(0x700, bytes(8))
    later = {"b": data_frame(0x300, b"\x01"), "c": data_frame(0x100, b"\x02"), "d": data_frame(0x200, b"\x03")}

    def rest():  # queued while the first frame occupies the bus (11 ms at 10 kbit/s)
        for name, frame in later.items():
            ports[name].send(frame)

    def burst():
        ports["a"].send(first)  # wins the idle bus at once
        m.call_at(None, rest)

    m.call_at(None, burst)
    rx = parties["rx"]
    wait_until(lambda: len(rx.data()) == 4)
    order = [f for _, f in rx.frames]
    assert order == [first, later["c"], later["d"], later["b"]]  # lowest identifier wins each arbitration
    times = [t for t, _ in rx.frames]
    for (t0, _), (t1, f1) in zip(rx.frames, rx.frames[1:], strict=False):
        assert t1 - t0 == pytest.approx(cf.frame_bits(f1) / 10_000, abs=1e-9)  # back to back, exact bit times
    assert times == sorted(times)


def test_one_sender_keeps_its_order(bus):
    m = bus(paced=True)
    a, rx, port = sender_and_receiver(m)
    frames = [data_frame(0x300 - i, bytes([i])) for i in range(5)]  # falling IDs from one FIFO
    m.call_at(None, lambda: [port.send(f) for f in frames])
    wait_until(lambda: len(rx.data()) == 5)
    assert rx.data() == frames


def test_bus_load_follows_the_traffic(bus):
    m = bus(paced=True, bitrate=125_000)
    a, rx, port = sender_and_receiver(m)
    frame = data_frame(0x555, bytes(8))
    n = 200
    m.call_at(None, lambda: [port.send(frame) for _ in range(n)])
    wait_until(lambda: len(rx.data()) == n, timeout=10)
    busy = n * cf.frame_bits(frame) / 125_000  # seconds the bus was occupied
    end = rx.frames[-1][0]
    assert m.load(window=busy, now=end) == pytest.approx(1.0, rel=0.02)  # saturated while it lasted
    assert m.stats.bits == n * cf.frame_bits(frame)


def test_an_unpaced_bus_faster_than_its_bitrate_reports_no_load(bus):
    """Unpaced, frames go at once: a second's worth of 10 kbit/s in a moment is no load of 2 000 %."""
    m = bus(paced=False, bitrate=10_000)
    _, rx, port = sender_and_receiver(m)
    frame = data_frame(0x555, bytes(8))
    n = 200  # about 22 000 bits
    m.call_at(None, lambda: [port.send(frame) for _ in range(n)])
    wait_until(lambda: len(rx.data()) == n, timeout=10)
    status = m.status()
    assert status["unpaced"] is True and status["load"] is None and status["paced"] is False


@pytest.mark.parametrize("paced", [False, True])
def test_error_frames_and_retransmission(bus, paced):
    m = bus(paced=paced, error_next=3)
    a, rx, port = sender_and_receiver(m)
    frame = data_frame(0x123, b"\x42")
    port.send(frame)
    wait_until(lambda: rx.data())
    assert rx.data() == [frame]  # delivered once, after three destroyed attempts
    errors = rx.errors()
    assert len(errors) == 3 and all(e.can_id & cf.CAN_ERR_PROT for e in errors)
    assert [e.data[6] for e in errors] == [8, 16, 24]  # the sender's TEC, as SocketCAN reports it
    assert m.tec["a"] == 23 and m.controller_state("a") == "active"


def test_bus_off_and_recovery(bus):
    m = bus(paced=True, bitrate=10_000, error_rate=1.0)  # slow: recovery takes 141 ms, time to look
    a, rx, port = sender_and_receiver(m)
    port.send(data_frame(0x123, b"\x01"))
    wait_until(lambda: "bus-off" in a.states)
    assert a.states[:2] == ["passive", "bus-off"]
    classes = [e.can_id for e in rx.errors()]
    assert sum(1 for c in classes if c & cf.CAN_ERR_PROT) == 32  # 32 x 8 = 256: bus-off
    assert cf.CAN_ERR_BUSOFF in classes and any(c & cf.CAN_ERR_CRTL for c in classes)
    assert rx.data() == []
    port.send(data_frame(0x124, b""))  # refused while bus-off
    m.set_faults(error_rate=0.0)
    wait_until(lambda: "recovered" in a.states, timeout=2)
    restarted = [t for t, e in rx.frames if e.error and e.can_id == cf.CAN_ERR_RESTARTED]
    off = [t for t, e in rx.frames if e.error and e.can_id == cf.CAN_ERR_BUSOFF]
    assert restarted[0] - off[0] == pytest.approx(BUS_OFF_RECOVERY_BITS / 10_000)
    assert m.stats.dropped_bus_off >= 1 and m.tec["a"] == 0
    port.send(data_frame(0x125, b""))
    wait_until(lambda: rx.data())
    assert rx.data()[0].can_id == 0x125


def test_forced_bus_off_without_recovery(bus):
    m = bus(auto_recover=False)
    a, rx, port = sender_and_receiver(m)
    m.force_bus_off("a")
    wait_until(lambda: a.states == ["bus-off"])
    port.send(data_frame(0x1, b""))
    wait_until(lambda: m.stats.dropped_bus_off == 1)
    assert m.status()["controllers"]["a"]["state"] == "bus-off"
    m.recover("a")
    wait_until(lambda: a.states[-1] == "recovered")
    port.send(data_frame(0x2, b""))
    wait_until(lambda: rx.data())


def test_fault_knobs_are_checked(bus):
    m = bus()
    with pytest.raises(ValueError):
        m.set_faults(error_rate=2)
    with pytest.raises(ValueError):
        m.set_faults(flood=True)
