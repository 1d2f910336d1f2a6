"""Benches in virtual time (``Bench(virtual_time=...)``): faster than real time when little happens, and the
same every run."""

from __future__ import annotations

import time
from pathlib import Path

import can
import pytest
import serial

from hilbench.bench import Bench
from hilbench.bench.profile import load_profile
from hilbench.errors import UsageError
from hilbench.protocols import dynamixel as dxl
from hilbench.transports.clock import VirtualClock

PROFILES = Path(__file__).resolve().parents[2] / "profiles"
EPOCH = 1_700_000_000.0
T0 = VirtualClock.ORIGIN


def heartbeat_run(channel: str) -> tuple[list[tuple[float, str, bytes]], list[can.Message], float]:
    """60.5 virtual seconds of mecarover-can (node 2, heartbeat 1 s): the bench's tap records, what an
    in-process python-can virtual bus received, and the wall time it took."""
    profile = load_profile(PROFILES / "mecarover-can.toml", {"can.virtual": channel})
    tapped: list[tuple[float, str, bytes]] = []
    bench = Bench(profile, virtual_time=True, virtual_epoch=EPOCH, seed=7)
    listener = can.Bus(interface="virtual", channel=channel)
    try:
        bench.start(on_endpoint=lambda ep: ep.medium.add_tap(lambda t, src, data: tapped.append((t, src, data))))
        start = time.monotonic()
        assert bench.clock.run_for(60.5, timeout=30) == T0 + 60.5
        wall = time.monotonic() - start
        received = []
        while (msg := listener.recv(0)) is not None:
            received.append(msg)
    finally:
        listener.shutdown()
        bench.stop()
    return tapped, received, wall


def test_a_minute_of_heartbeats_takes_no_time_and_comes_out_the_same_twice():
    tapped, received, wall = heartbeat_run("vt-heartbeats-1")
    assert wall < 6.0  # 60 virtual seconds: a tenth of that at most (in practice milliseconds)
    node2 = [(t, data) for t, src, data in tapped if data[:4] == bytes([0x02, 0x07, 0, 0])]  # id 0x702
    boot, beats = node2[0], node2[1:]
    assert boot[1][8] == 0x00  # the boot-up message, then 60 heartbeats (pre-operational: 0x7f)
    assert len(beats) == 60 and all(data[8] == 0x7F for _, data in beats)
    assert [round(t - boot[0], 9) for t, _ in beats] == [float(k) for k in range(1, 61)]  # exactly 1 s apart
    # The in-process python-can bus saw the same frames, stamped with the virtual clock's Unix time.
    heard = [m for m in received if m.arbitration_id == 0x702]
    assert len(heard) == 61
    assert [round(m.timestamp - EPOCH, 6) for m in heard] == [round(t - T0, 6) for t, _ in node2]
    # A second run of the same profile and seed: the same capture, to the bit and the nanosecond.
    again, _, _ = heartbeat_run("vt-heartbeats-2")
    assert again == tapped


def test_a_virtual_bench_is_paced_and_refuses_unpaced():
    with pytest.raises(UsageError, match="virtual time is paced"):
        Bench(PROFILES / "mecarover-can.toml", paced=False, virtual_time=True)
    with pytest.raises(UsageError, match="hold, free"):
        Bench(PROFILES / "mecarover-can.toml", virtual_time="fast")


def test_a_pyserial_client_gets_replies_at_wire_times_from_a_free_running_bench():
    # A program outside the lockstep (here a pyserial client in this process) against a free-running
    # virtual bench: its request is stamped with the instant the loop reads it, the reply follows the
    # wire model exactly (2 Mbaud, each servo's Return Delay Time).
    with Bench(PROFILES / "wolfgang.toml", virtual_time="free") as bench:
        ep = bench.endpoint()
        seen: list[tuple[float, str, bytes]] = []
        ep.medium.add_tap(lambda t, src, data: seen.append((t, src, data)))
        with serial.Serial(ep.path, 2_000_000, timeout=2) as ser:
            ping = dxl.instruction_packet(1, dxl.Instruction.PING)
            ser.write(ping)
            reply = ser.read(14)
        assert reply[:5] == b"\xff\xff\xfd\x00\x01" and reply[7] == 0x55  # a status packet from ID 1
        (t_req, _, req), (t_rep, _, rep) = seen[:2]
        assert req == ping and rep == reply
        byte = 10 / 2_000_000
        delay = bench.device(1).return_delay  # (the servo's Return Delay Time)
        assert t_rep == pytest.approx(t_req + delay + len(reply) * byte, abs=1e-12)


def board_run() -> tuple[list[tuple[float, str, bytes]], dict]:
    """The rover board (mecarover) sampling for 1.5 virtual seconds: its trace stream on the line's tap."""
    tapped: list[tuple[float, str, bytes]] = []
    with Bench(PROFILES / "mecarover.toml", virtual_time=True, virtual_epoch=EPOCH) as bench:
        bench.endpoint("rover").medium.add_tap(lambda t, src, data: tapped.append((t, src, data)))
        board = bench.family("stm32-rover").board()
        bench.clock.run_for(0.1, timeout=30)
        board.press_button()
        bench.clock.run_for(1.5, timeout=60)
        status = board.status()
    return tapped, status


def test_the_rover_boards_trace_stream_runs_in_virtual_time_the_same_every_run():
    tapped, status = board_run()
    assert status["window"] == 1 and status["truth"]["stamps_sent"] > 100  # the button's 1 s trace window
    assert status["lag_us"] == 0.0  # the loop's timers keep the firmware ahead of the line, always
    assert 1.6e6 <= status["now_us"] <= 1.6e6 + 2500  # the firmware's clock is the bench's (plus its lookahead)
    sent = sum(len(data) for _, src, data in tapped if src == "rover-board")
    assert sent >= status["truth"]["bytes_to_wire"] - 1000  # (what the UART has sent by now, less the tail)
    assert all(T0 <= t <= T0 + 1.6 for t, _, _ in tapped)
    again, _ = board_run()
    assert again == tapped  # the same bytes at the same virtual instants


def test_a_socketcand_clients_cyclic_job_runs_on_the_virtual_clock():
    # A client outside the process adds a BCM job (every 100 ms): the bench runs it in virtual time, at
    # exact instants, however slowly or quickly the wall clock goes.
    import socket

    from hilbench.pytest_plugin import wait_until

    with Bench(PROFILES / "mecarover-can.toml", virtual_time=True, virtual_epoch=EPOCH) as bench:
        ep = bench.endpoint("can")
        seen: list[tuple[float, bytes]] = []
        ep.medium.add_tap(lambda t, src, data: seen.append((t, data)))
        server = ep.port.socketcand
        with socket.create_connection(server.address, timeout=5) as sock:
            sock.sendall(b"< open can0 >< add 0 100000 321 1 aa >")
            wait_until(lambda: any(c.jobs for c in server.clients), timeout=10)  # (read at the held instant)
            start = bench.clock.now()
            bench.clock.run_for(1.0, timeout=30)
        job = [t for t, data in seen if data[:4] == bytes([0x21, 0x03, 0, 0])]  # id 0x321
        assert len(job) == 10  # at the instant it was added, then every 100 ms (the 11th is its bits past 1 s)
        assert job[0] >= start
        bit_time = job[0] - start  # (the frame's bits at 500 kbit/s: it is delivered when sent)
        assert 0 < bit_time < 200e-6
        assert [round(t - start - bit_time, 9) for t in job] == [round(0.1 * k, 9) for k in range(10)]


def world_run(channel: str) -> dict:
    """mecarover-can on a held virtual clock: one RPDO1 setpoint (0.2 m/s ahead, no setpoint timeout) from
    an in-process python-can bus, then the rover's world body at virtual instants."""
    from hilbench.protocols import board_can as bc
    from hilbench.pytest_plugin import wait_until

    profile = load_profile(PROFILES / "mecarover-can.toml", {
        "can.virtual": channel, "devices.rover.autostart": True, "devices.rover.setpoint_timeout_ms": 0})
    sender = can.Bus(interface="virtual", channel=channel)
    bench = Bench(profile, virtual_time=True, virtual_epoch=EPOCH)
    try:
        bench.start()
        world, node = bench.world, bench.family("canopen").node()
        out: dict = {"start": world.snapshot()}
        bench.clock.run_for(0.1, timeout=30)  # (the node is operational by now: autostart)
        sender.send(can.Message(arbitration_id=bc.SETPOINT.cob_id(2), data=bc.build_setpoint(0.2, 0.0, 0.0, 1),
                                is_extended_id=False))
        door = next(d for d in bench.endpoint("can").port.doors if d.kind == "virtual")
        wait_until(lambda: door.received, timeout=10)  # (the loop reads it at the held instant, the next round)
        out["t_sent"] = bench.clock.now()
        for at in (1.0, 2.0, 3.0):  # virtual seconds after the bench started
            bench.clock.run_until(T0 + at, timeout=30)
            out[at] = (bench.clock.now(), world.world.t, world.world.steps, world.body("rover").pose,
                       world.snapshot())
        out["setpoint"] = node.setpoint
    finally:
        sender.shutdown()
        bench.stop()
    return out


def test_a_virtual_benchs_world_steps_in_virtual_time_and_a_setpoint_moves_the_body_by_v_times_t():
    run = world_run("vt-world-1")
    start = run["start"]
    assert start["time"] == T0 and start["unix_time"] == EPOCH  # the world's clock is the bench's
    step = 1 / 200  # (the profile's world steps at 200 Hz)
    for at in (1.0, 2.0, 3.0):
        now, world_t, steps, _, snap = run[at]
        assert now == T0 + at
        assert world_t == pytest.approx(now, abs=1e-9)  # stepped as the loop's timers, right up to now
        assert steps == round(at / step)  # every step, none twice, none late
        assert snap["time"] == now and snap["unix_time"] == pytest.approx(EPOCH + at, abs=1e-9)
    assert run["t_sent"] == T0 + 0.1 and run["setpoint"] == (0.2, 0.0, 0.0)
    # Once the firmware's ramp has reached the setpoint (13 pose cycles of 10 ms), the body moves at exactly
    # 0.2 m/s of virtual time, straight ahead (no wall clock, no load, no lateness in it).
    (x1, y1, th1), (x2, _, _), (x3, y3, th3) = (run[at][3] for at in (1.0, 2.0, 3.0))
    assert x2 - x1 == pytest.approx(0.2, abs=1e-9) and x3 - x2 == pytest.approx(0.2, abs=1e-9)
    assert y1 == y3 == 0.0 and th1 == th3 == 0.0
    again = world_run("vt-world-2")
    assert [again[at][3] for at in (1.0, 2.0, 3.0)] == [run[at][3] for at in (1.0, 2.0, 3.0)]  # the same, twice
