"""The profiler on streams of the emulated rover board (hilbench.fakes.stm32_board), whose settings are known:
it recovers the configured frequencies, execution times and CPU shares, agrees with the board's own run-time
statistics, and finds overflow drops exactly. Offline in virtual time (fast), then live over a pty and UDP."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import serial

from hilbench.fakes.stm32_board.board import Board
from hilbench.fakes.stm32_board.presets import BoardConfig, make_preset
from hilbench.profiler.ingest import Profiler
from hilbench.profiler.settings import ProfilerSettings
from hilbench.protocols import vel2d
from hilbench.pytest_plugin import wait_until

ROLES = ("hal_fetch", "wheel_ctrl", "odometry", "pose_control")


def emulate(output: str, preset: str = "freertos-100-50", *, baud: int = 2_000_000, caches: bool = True,
            window_ms: float = 1000) -> tuple[Board, bytes]:
    """One sampling window from boot: press the button at 1 ms, run until the report has left the UART."""
    board = Board(BoardConfig(make_preset(preset, caches), output=output, baud=baud,
                              window_ms=None if output == "v3" else window_ms))
    board.run_for(0.001)
    board.press_button()
    for _ in range(4000):
        board.run_for(0.05)
        if board.reports and not board.reporting:
            break
    board.run_for(0.2)  # the last report bytes drain from the UART
    return board, board.take_output()


def periods_of(preset) -> dict[str, float]:
    wheel, pose = 1e6 / preset.wheel_hz, 1e6 / preset.pose_hz
    tick = preset.tick_us
    return {"hal_fetch": round(wheel / tick) * tick, "wheel_ctrl": round(wheel / tick) * tick,
            "odometry": round(pose / tick) * tick, "pose_control": round(pose / tick) * tick}


def analyse(data: bytes, settings: ProfilerSettings | None = None, chunk: int = 4096):
    p = Profiler(settings)
    for i in range(0, len(data), chunk):
        p.feed(data[i : i + chunk])
    p.finish()
    return p.analyse()


@pytest.mark.parametrize(("output", "baud", "share_tol_pp"), [("v1", 2_000_000, 0.15), ("v2", 2_000_000, 0.15),
                                                              ("binary", 2_000_000, 0.15), ("v3", 115_200, 1.0)])
def test_recovers_configured_rates_times_and_shares(output, baud, share_tol_pp):
    board, data = emulate(output, baud=baud)
    preset = board.config.preset
    periods = periods_of(preset)
    a = analyse(data, ProfilerSettings(periods=periods))
    q = a.quality
    assert a.classification == "report" and q["reports"] == 1 and q["windows"] == 1
    assert (q["parse_errors"], q["orphan_ends"], q["orphan_begins"], q["double_begins"], q["drops"]) == (0,) * 5
    assert q["edge_orphan_ends"] == q["edge_orphan_begins"] == 1 and not q["untrustworthy"]
    for name in ROLES:
        s = a.tasks[name]
        assert s["kind"] == "task"
        assert s["freq_hz"] == pytest.approx(1e6 / periods[name], rel=1e-3), name  # configured rate
        assert s["missed_activations"] == 0 and s["deadline_misses"] == 0 and s["overruns"] == 0, name
        assert s["mean_us"] == pytest.approx(preset.task(name).timing.mean_us, rel=0.04), name  # configured time
        assert s["jitter_abs_us"] < 0.01 * periods[name], name
    assert a.window["W_us"] == pytest.approx(1e6, rel=0.003)  # the 1000 ms window
    # The board's own run-time statistics: every hook call arrived, and the shares agree.
    rs = a.runtime_stats
    assert rs["ctx_switches"] == rs["hook_stamps"] == board.truth.stamps_recorded and rs["estimated_drops"] == 0
    for name, row in rs["tasks"].items():
        if row.get("profiler_share") is not None:
            assert abs(row["diff_pp"]) < share_tol_pp, (name, row)
    assert abs(rs["tasks"]["IDLE"]["kernel_share"] - a.tasks["IDLE"]["share"]) < share_tol_pp


def test_thesis_output_v1_micro_ros_functions_arrive_late_and_nest_in_the_executor():
    board, data = emulate("v1", "micro-ros-100-50", baud=2_000_000, window_ms=500)
    preset = board.config.preset
    a = analyse(data, ProfilerSettings(periods={"w_ctrl": 1e4, "p_ctrl": 2e4, "odom": 1e4}))
    q = a.quality
    # V1 writes scope stamps at once and hook stamps at the next flush: many lines arrive out of order.
    assert q["out_of_order"] > 100 and q["late_beyond_reorder"] == 0
    assert (q["parse_errors"], q["orphan_ends"], q["orphan_begins"], q["double_begins"], q["drops"]) == (0,) * 5
    assert q["edge_orphan_ends"] == q["edge_orphan_begins"] == 1 and not q["untrustworthy"]
    assert a.runtime_stats["closing"] == "profiled for"
    for f in preset.functions:
        s = a.tasks[f.name]
        assert s["kind"] == "function" and s["owner"] == "uros" and s["net_preemption_not_removed"] == 0
        assert s["freq_hz"] == pytest.approx(1e6 / a.settings.periods[f.name], rel=2e-3), f.name
        # V1 formats the begin line inside the scope (spec §3.4): the line cost adds to the callback's time.
        expect = f.timing.mean_us + preset.line_cost.mean_us
        assert s["mean_us"] == pytest.approx(expect, rel=0.06), f.name
        assert s["net_mean_us"] <= s["mean_us"]
    assert a.tasks["uros"]["kind"] == "task" and a.tasks["uros"]["total_us"] > a.tasks["w_ctrl"]["total_us"]


@pytest.mark.parametrize("output", ["binary", "v2"])
def test_overflow_drops_are_found_exactly(output):
    # 10000|5000 Hz makes ~8 stamps per 100 µs: the binary sink and V2's 512-record ring overflow (spec §4.3).
    board, data = emulate(output, "freertos-10000-5000", baud=2_000_000, window_ms=300)
    a = analyse(data, ProfilerSettings(periods=periods_of(board.config.preset)))
    q, truth = a.quality, board.truth
    lost = truth.stamps_dropped if output == "binary" else truth.records_lost
    assert lost > 1000
    if output == "binary":
        assert q["drops"] == truth.drops_reported == lost  # exact DROPS words
        assert q["checks_failed"] == q["broken_words"] == 0
    assert q["estimated_drops"] == a.runtime_stats["ctx_switches"] - a.runtime_stats["hook_stamps"] == lost
    assert q["untrustworthy"] and any("drops" in r for r in q["reasons"])


def _profile_cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "hilbench.cli", "trace", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


@pytest.mark.hilbench_profile("mecarover-thesis")
def test_cli_on_the_emulated_board_over_a_pty(bench):
    """The thesis set-up (V1 at 1,152,000 baud): hilbench trace reads the pty while the button is pressed."""
    ep = bench.endpoint("rover")
    board = bench.family("stm32-rover").board()
    proc = _profile_cli(ep.path, "--baud", "1152000", "--reports", "1", "--json", "--period", "wheel_ctrl=10ms",
                        "--period", "hal_fetch=100Hz", "--duration", "20")
    try:
        # Once the profiler has opened the port (pyserial set its baud) and the debounce time has passed.
        wait_until(lambda: ep.port.client_baud() == 1_152_000 and board.now_us > 2e5, timeout=10)
        board.press_button()
        wait_until(lambda: board.truth.stamps_sent > 2000, timeout=10)
        board.press_button()
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    doc = json.loads(out)
    q = doc["quality"]
    assert doc["runtime_stats"]["closing"] == "profiled for" and q["parse_errors"] == 0, q["unreadable_lines"]
    assert (q["orphan_ends"], q["orphan_begins"], q["double_begins"]) == (0, 0, 0)
    for name in ("wheel_ctrl", "hal_fetch"):
        assert doc["tasks"][name]["freq_hz"] == pytest.approx(100, rel=2e-3)
        assert doc["tasks"][name]["missed_activations"] == 0
    assert doc["runtime_stats"]["estimated_drops"] == 0
    assert doc["runtime_stats"]["ctx_switches"] == board.truth.stamps_recorded


def test_cli_on_the_emulated_board_over_udp(hilbench_bench):
    """Binary words over UDP: the profiler binds 127.0.0.1 and registers with the board (?peer=)."""
    bench = hilbench_bench("mecarover-udp")
    ep = bench.endpoint("rover")
    board = bench.family("stm32-rover").board()
    board_addr = ep.path.removeprefix("udp://")
    proc = _profile_cli(f"udp://127.0.0.1:0?peer={board_addr}", "--reports", "1", "--json", "--duration", "20",
                        "--period", "hal_fetch=1ms", "--tasks", "IDLE,tsink,hal_fetch,wheel_ctrl,odometry,"
                        "pose_control,profile,recv_vel")
    try:
        wait_until(lambda: len(ep.port.peers) > 0, timeout=10)  # the profiler registered
        board.press_button()
        wait_until(lambda: board.truth.stamps_recorded > 3000, timeout=10)
        board.press_button()
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    doc = json.loads(out)
    q = doc["quality"]
    assert q["drops"] == board.truth.stamps_dropped and q["checks_failed"] == 0 and q["windows_started"] == 1
    assert doc["tasks"]["hal_fetch"]["freq_hz"] == pytest.approx(1000, rel=2e-3)
    assert doc["runtime_stats"]["ctx_switches"] == q["binary_stamps"] + q["drops"]
    assert doc["source"].startswith("udp://127.0.0.1:")


@pytest.mark.slow  # a long CLI session on a running bench: the slow set
def test_cli_follows_a_running_bench_through_its_tap(hilbench_emulator, tmp_path):
    """`hilbench emulate mecarover` in its own process; the profiler reads the board's side of its traffic
    tap (manifest.json#rover), while a host sends a frame on the same line (which it must skip)."""
    from hilbench.families.stm32_rover import BoardClient as ControlClient

    manifest = hilbench_emulator("mecarover")
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({k: v for k, v in manifest.items() if k != "process"}))
    proc = _profile_cli(f"{path}#rover", "--reports", "1", "--json", "--duration", "30")
    try:
        client = ControlClient.from_manifest(path)
        wait_until(lambda: client.taps()["rover"]["clients"] == 1, timeout=20)  # the profiler is listening
        with serial.Serial(manifest["endpoints"][0]["path"], 115_200) as host:
            host.write(vel2d.build(0.1, -0.2, 0.3))  # host -> board bytes pass the same tap
            host.flush()
        client.button()  # a 1000 ms window on this (V3) board, then the dump and the report
        out, err = proc.communicate(timeout=40)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    doc = json.loads(out)
    assert doc["source"] == f"{path}#rover"
    assert doc["quality"]["parse_errors"] == 0 and doc["quality"]["broken_words"] == 0  # no host frame bytes
    assert doc["tasks"]["wheel_ctrl"]["freq_hz"] == pytest.approx(50, rel=2e-3)
    assert doc["tasks"]["pose_control"]["freq_hz"] == pytest.approx(1e6 / 33_000, rel=2e-3)
    assert doc["runtime_stats"]["estimated_drops"] == 0


def test_every_preset_and_output_gives_clean_pairs_unless_stamps_were_lost():
    """Across every preset, cache setting and output path: no double begins or orphans except where the
    board really lost stamps (records overrun or binary drops), which the profiler then reports."""
    from hilbench.fakes.stm32_board.presets import preset_names

    dirty = []
    for name in preset_names():
        for caches in (True, False):
            for output in ("v1", "v2", "v3", "binary"):
                board = Board(BoardConfig(make_preset(name, caches), output=output, baud=2_000_000, window_ms=100))
                board.run_for(0.002)
                board.press_button()
                board.run_for(0.12)
                if output != "v3":
                    board.press_button()
                board.run_for(0.4 if output != "v3" else 1.5)
                q = analyse(board.take_output(), ProfilerSettings()).quality
                lost = board.truth.records_lost + board.truth.stamps_dropped
                anomalies = (q["double_begins"], q["orphan_ends"], q["orphan_begins"])
                if any(anomalies) and not lost:
                    dirty.append((name, caches, output, anomalies))
                if lost:
                    assert q["untrustworthy"], (name, caches, output)
    assert dirty == []
