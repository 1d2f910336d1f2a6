"""The emulated rover board in virtual time: frames, kinematics, schedule, trace output paths, drops, faults."""

from __future__ import annotations

import struct
from collections import defaultdict

import numpy as np
import pytest

from hilbench.fakes.stm32_board import Board, BoardConfig, make_preset
from hilbench.fakes.stm32_board.robot import forward_kinematics
from hilbench.protocols import vel2d
from hilbench.protocols.tracestamp import RuntimeReport, Stamp
from hilbench.protocols.tracestamp_stream import StreamDecoder, stamps_of
from tests.stm32_vectors import crc32_mpeg2_bitwise

BYTE_US = 10e6 / 115_200
A = vel2d.build(0.0, 0.0, 0.0)
C = vel2d.build(0.1, -0.2, 0.3)



def board(preset="freertos-100-50", output="v1", baud=115_200, **kw) -> Board:
    p = kw.pop("preset_obj", None) or make_preset(preset, kw.pop("caches", True))
    return Board(BoardConfig(p, output=output, baud=baud, **kw))


def decode(b: Board):
    dec = StreamDecoder()
    items = dec.feed(b.take_output()) + dec.flush()
    return items, dec


def logs(b: Board) -> list[str]:
    return [f"[{x.level}]: {x.message}" for x in b.log]


# ------------------------------------------------------------------ velocity frames


def test_frames_from_hilbench_and_from_an_independent_crc_are_accepted_and_logged():
    b = board()
    b.run_for(0.01)
    b.receive(C)
    payload = struct.pack("<3d", 0.5, 0.0, 0.0)
    b.receive(payload + struct.pack("<I", crc32_mpeg2_bitwise(payload)), b.now_us + 10_000)
    b.run_for(0.05)
    assert logs(b)[-2:] == ["[INFO]: [recv vel] [100.000000 -200.000000 0.300000]",
                            "[INFO]: [recv vel] [500.000000 0.000000 0.000000]"]
    items, dec = decode(b)
    texts = [f"[{i.level}]: {i.message}" for i in items if type(i).__name__ == "LogMessage"]
    assert texts[-2:] == logs(b)[-2:]  # the same lines went out on the UART
    assert b.truth.frames_ok == 2 and b.fw.crc_err == 0


def test_corrupted_and_short_frames_are_rejected_with_the_firmware_messages():
    b = board()
    b.run_for(0.01)
    bad = bytearray(vel2d.build(0.5, 0.0, 0.0))
    bad[7] ^= 0x80  # the spec's B'
    b.receive(bytes(bad))
    b.receive(C[:27], b.now_us + 10_000)  # C', then the line goes idle
    b.run_for(0.05)
    assert logs(b)[-2:] == ["[ERROR]: crc mismatch!",
                            "[ERROR]: parsing velocity failed: insufficient bytes received"]
    assert b.fw.crc_err == 1 and b.truth.frames_length_error == 1 and b.truth.frames_ok == 0


def test_idle_line_framing_cases_of_the_spec():
    b = board()
    b.run_for(0.01)
    b.receive(A + C)  # back to back: two valid frames
    b.receive(b"\x00" + A, b.now_us + 20_000)  # 28 bytes fail the CRC, then 1 byte is a length error
    t = b.now_us + 40_000
    b.receive(C[:27], t)
    b.receive(A, t + 27 * BYTE_US + 3 * BYTE_US)  # C', an idle gap, then A
    b.run_for(0.1)
    got = [m.split(": ", 1)[1] for m in logs(b)[1:]]
    assert got == ["[recv vel] [0.000000 0.000000 0.000000]", "[recv vel] [100.000000 -200.000000 0.300000]",
                   "crc mismatch!", "parsing velocity failed: insufficient bytes received",
                   "parsing velocity failed: insufficient bytes received", "[recv vel] [0.000000 0.000000 0.000000]"]


def test_a_micro_ros_board_ignores_uart_frames():
    b = board("micro-ros-100-50", output="v2", baud=2_000_000)
    b.run_for(0.01)
    b.receive(C)  # the micro-ROS build takes setpoints over XRCE-DDS; UART3 only transmits
    b.run_for(0.05)
    assert b.truth.rx_bytes_ignored == 28 and b.truth.frames_ok == b.truth.frames_length_error == 0
    assert not any("recv vel" in line for line in logs(b))


@pytest.mark.parametrize(
    "frame,wheels,duty",
    [
        ((0.1, -0.2, 0.3), (-0.125, 4.125, -3.875, 7.875), (-1.1368, 37.5151, -35.2415, 71.6197)),
        ((0.5, 0.0, 0.0), (10, 10, 10, 10), (90.9457,) * 4),
        ((0.0, 0.0, 1.0), (6.25, -6.25, -6.25, 6.25), (56.8411, -56.8411, -56.8411, 56.8411)),
    ],
)
def test_kinematics_after_the_ramp_converges(frame, wheels, duty):
    b = board()
    b.receive(vel2d.build(*frame))
    b.run_for(1.0)  # 50 pose cycles: the 3 % ramp needs at most 34
    st = b.robot_state()
    assert st.wheels == pytest.approx(wheels, abs=1e-9)
    assert st.duty == pytest.approx(duty, abs=1e-4)
    mm = (frame[0] * 1000, frame[1] * 1000, frame[2])
    assert st.setpoint == pytest.approx(mm) and forward_kinematics(*st.wheels) == pytest.approx(mm)
    assert st.pose != (0.0, 0.0, 0.0)


def test_the_ramp_limits_the_change_per_pose_cycle():
    b = board()
    b.receive(vel2d.build(0.5, 0.0, 0.0))
    b.run_until(0.021e6)  # frame in at ~2.4 ms, then the first pose cycle at 20 ms
    assert b.robot_state().command[0] == pytest.approx(16.4934, abs=1e-3)


def test_a_full_setpoint_queue_drops_new_setpoints():
    b = board()
    b.receive(C * 14)  # 14 frames within 34 ms; pose_control takes one per 20 ms cycle
    b.run_for(0.4)
    assert b.truth.frames_ok == 14 and b.truth.setpoints_dropped >= 1
    assert b.robot_state().queued == 0


# ------------------------------------------------------------------ schedule and stamps


def run_window(b: Board, seconds: float, after: float = 0.5) -> tuple[list, StreamDecoder]:
    b.run_for(0.05)
    b.press_button()
    b.run_for(seconds)
    if b.config.window_ms is None and b.config.output != "v3":
        b.press_button()
    b.run_for(after)
    return decode(b)


def slices(stamps: list[Stamp]) -> tuple[dict, dict]:
    """Per name: durations of closed intervals and begin times (stamps sorted by time)."""
    open_, dur, starts = {}, defaultdict(list), defaultdict(list)
    for s in sorted(stamps, key=lambda s: s.t_us):
        if s.begin:
            open_[s.name] = s.t_us
            starts[s.name].append(s.t_us)
        elif s.name in open_:
            dur[s.name].append(s.t_us - open_.pop(s.name))
    return dur, starts


def test_stamps_periods_match_the_rates_and_durations_follow_the_distributions():
    p = make_preset("freertos-1000").with_task_timing("wheel_ctrl", mean_us=60.0, sd_us=6.0, min_us=40.0,
                                                        max_us=80.0)
    # V3 records during the window and prints afterwards, so no flusher competes with the control tasks.
    b = board(preset_obj=p, output="v3", baud=12_500_000, window_ms=500)
    items, dec = run_window(b, 0.5)
    stamps = stamps_of(items)
    assert b.truth.records_lost == 0
    assert dec.text.parse_errors == 0 and len(stamps) == b.truth.stamps_recorded == b.truth.stamps_sent
    dur, starts = slices(stamps)
    for name, period_us in (("hal_fetch", 1000), ("wheel_ctrl", 1000), ("odometry", 2000), ("pose_control", 2000),
                            ("tsink", 1000)):
        s = np.array(starts[name])
        assert (s[-1] - s[0]) / (len(s) - 1) == pytest.approx(period_us, abs=1.0), name  # mean period
        # Tasks sharing a tick run in delayed-list order, so single periods alternate around the mean.
        assert np.abs(np.diff(s) - period_us).max() < 60, name
    w = np.array(dur["wheel_ctrl"])
    assert len(w) >= 490
    assert w.mean() == pytest.approx(60.0, abs=1.0) and w.std() == pytest.approx(6.0, rel=0.2)
    assert w.min() >= 39 and w.max() <= 81
    h = np.array(dur["hal_fetch"])  # Table 9's cached mean, whole-µs stamps
    assert h.mean() == pytest.approx(6.61, abs=0.7)
    (rep,) = [i for i in items if isinstance(i, RuntimeReport)]
    assert rep.complete and rep.ctx_switches == b.truth.stamps_recorded
    assert rep.recomputed_percent() == {r.name: r.percent for r in rep.runtime}


@pytest.mark.parametrize(("preset", "caches", "output", "baud"), [
    ("freertos-10000-5000", True, "v2", 2_000_000),
    ("freertos-10000-5000", True, "v1", 1_152_000),  # the profile task's batches run in the background
    ("freertos-5000-2000", False, "v1", 2_000_000),  # overloaded ticks: bursts end just before the next tick
])
def test_fast_path_and_exact_simulation_give_identical_output(preset, caches, output, baud):
    outputs = []
    for fast in (True, False):
        b = board(preset, output=output, baud=baud, window_ms=150, caches=caches)
        b.fw.kernel.fast_enabled = fast
        b.run_for(0.01)
        b.press_button()
        b.run_for(0.4)
        outputs.append((b.take_output(), b.fw.kernel.fast_ticks, b.truth))
    (fast_out, fast_ticks, fast_truth), (exact_out, exact_ticks, exact_truth) = outputs
    assert fast_ticks > 1000 and exact_ticks == 0
    assert fast_out == exact_out and len(fast_out) > 20_000
    assert fast_truth == exact_truth


@pytest.mark.parametrize(("preset", "caches"), [("freertos-100-50", True), ("freertos-1000", False),
                                               ("micro-ros-100-50", True)])
def test_v1_slices_never_end_before_they_begin(preset, caches):
    """Per name, V1 lines alternate begin/end in non-decreasing time, from the window's first line on (the
    profile task, woken by the button, blocks without computing: its slice is shorter than a switch)."""
    b = board(preset, output="v1", baud=2_000_000, caches=caches)
    items, dec = run_window(b, 0.2)
    stamps = stamps_of(items)
    assert b.truth.records_lost == 0 and len(stamps) == b.truth.stamps_sent > 500
    per_name = defaultdict(list)
    for s in stamps:  # arrival order: each name's lines come from one writer, in record order
        per_name[s.name].append((s.t_us, s.begin))
    for name, seq in per_name.items():
        assert all(a[1] != c[1] and a[0] <= c[0] for a, c in zip(seq, seq[1:], strict=False)), (name, seq[:6])
    first_profile = per_name["profile"][:2]
    assert first_profile[0][1] and first_profile[0][0] <= first_profile[1][0]


def test_v1_micro_ros_writes_scope_stamps_directly_so_lines_are_out_of_order():
    b = board("micro-ros-100-50", output="v1", baud=2_000_000)
    items, dec = run_window(b, 0.3)
    stamps = stamps_of(items)
    names = {s.name for s in stamps}
    assert {"uros", "w_ctrl", "p_ctrl", "odom", "EthIf", "tcpip_thread", "tsink", "profile"} <= names
    times = [s.t_us for s in stamps]
    late = sum(1 for a, b_ in zip(times, times[1:], strict=False) if b_ < a)
    assert late > 10  # buffered hook stamps arrive after the directly written scope stamps
    assert dec.text.dialects["thesis"] == len(stamps)
    (rep,) = [i for i in items if isinstance(i, RuntimeReport)]
    assert rep.closing == "profiled for" and rep.percent_header == "%"
    dur, starts = slices(stamps)
    assert 25 <= len(starts["w_ctrl"]) <= 31 and 12 <= len(starts["p_ctrl"]) <= 16  # 100 | 50 Hz


def test_v3_fixed_window_dump_and_report():
    b = board("freertos-50-30", output="v3", baud=115_200)
    items, dec = run_window(b, 1.0, after=9.0)  # the dump of ~4,400 lines takes ~6.5 s at 115200 baud
    stamps = stamps_of(items)
    (rep,) = [i for i in items if isinstance(i, RuntimeReport)]
    assert rep.complete and rep.closing == "output took" and rep.closing_us > 1_000_000
    assert stamps[0].t_us == 0 and len(stamps) == rep.ctx_switches == b.truth.stamps_recorded
    assert [t.name for t in rep.tasks if t.state == "X"] == ["rt_stats"]
    assert {t.name: t.number for t in rep.tasks}["Tmr Svc"] == 10
    assert dec.text.dialects["branch"] == len(stamps)


def test_v3_overrun_prints_only_the_records_after_the_wrap():
    b = board("freertos-10000-5000", output="v3", baud=2_000_000)
    items, dec = run_window(b, 1.0, after=12.0)
    stamps = stamps_of(items)
    assert b.truth.stamps_recorded > 32_768
    assert len(stamps) == b.truth.stamps_recorded % 32_768 == b.truth.stamps_sent
    assert stamps[0].t_us > 500_000  # the first printed stamp is far from 0: the array wrapped
    assert b.truth.records_lost == b.truth.stamps_recorded - len(stamps)


def test_overflow_binary_drop_counter_equals_the_true_number_dropped():
    b = board("freertos-10000-5000", output="binary", baud=1_152_000)
    items, dec = run_window(b, 0.5)
    stamps = stamps_of(items)
    w = dec.words
    assert b.truth.stamps_dropped > 10_000  # 80,000 stamps/s into a 115 kB/s link
    assert w.drops == b.truth.stamps_dropped == b.truth.drops_reported
    assert len(stamps) == b.truth.stamps_sent and len(stamps) + w.drops == b.truth.stamps_recorded
    assert (w.checks_failed, w.broken_words, w.unnamed_stamps, w.unsynced_stamps) == (0, 0, 0, 0)
    assert w.windows_started == w.windows_stopped == 1
    assert [i.kind for i in items if type(i).__name__ == "Marker"].count("drops") > 3
    (rep,) = [i for i in items if isinstance(i, RuntimeReport)]
    assert rep.ctx_switches == b.truth.stamps_recorded  # the cross-check the spec recommends


def test_overflow_v1_loses_records_silently():
    b = board("freertos-10000-5000", output="v1", baud=1_152_000)
    items, dec = run_window(b, 0.3)
    stamps = stamps_of(items)
    assert b.truth.records_lost > 10_000 and len(stamps) == b.truth.stamps_sent
    (rep,) = [i for i in items if isinstance(i, RuntimeReport)]
    assert rep.ctx_switches - len(stamps) == b.truth.records_lost  # estimated drops = ctx switches - lines


# ------------------------------------------------------------------ faults, button, reset


def test_corrupted_and_dropped_bytes_are_detected_in_binary():
    b = board("freertos-1000", output="binary", baud=1_152_000)
    b.set_faults(corrupt_rate=0.001, drop_rate=0.001)
    items, dec = run_window(b, 0.5)
    assert b.truth.bytes_corrupted_fault > 0 and b.truth.bytes_dropped_fault > 0
    assert dec.words.broken_words + dec.words.checks_failed > 0
    assert len(stamps_of(items)) > 0.9 * b.truth.stamps_sent


def test_stalled_sink_drops_stamps_and_reports_them():
    b = board("freertos-1000", output="binary", baud=1_152_000)
    b.run_for(0.05)
    b.press_button()
    b.run_for(0.1)
    b.set_faults(stall=0.2)
    b.run_for(0.4)
    b.press_button()
    b.run_for(0.5)
    items, dec = decode(b)
    assert b.truth.stamps_dropped > 1000 and dec.words.drops == b.truth.stamps_dropped


def test_button_is_debounced_and_reset_reboots():
    b = board(output="v2", baud=2_000_000)
    b.run_for(0.05)
    b.press_button()
    b.press_button(b.now_us + 10_000)  # bounce: ignored
    b.run_for(0.2)
    assert b.sampling
    b.reset()
    assert b.boots == 2 and not b.sampling
    b.run_for(0.05)
    assert "boot 2" in b.log[0].message and b.truth.stamps_recorded == 0
    with pytest.raises(KeyError):
        b.set_faults(warp=1)


def test_stamp_times_are_whole_us_of_dwt_cycles_whatever_the_float_summation():
    from hilbench.fakes.stm32_board.firmware import elapsed_us, stamp_us

    # Tick + ISR + switch summed in another order lands a hair below the whole µs it is.
    t = (35 + 1.8 - 0.1) + (1.2 + 0.1)
    assert t < 38.0 and stamp_us(np.array([t, 38.0, 38.99]), 0.0).tolist() == [38, 38, 38]
    assert elapsed_us(t, 0.0) == 38 and elapsed_us(1000.99, 0.0) == 1000
    # On the 216 MHz grid: one cycle short of a whole µs still truncates.
    assert stamp_us(np.array([50.0 + 215 / 216, 50.0 + 216 / 216]), 50.0).tolist() == [0, 1]
