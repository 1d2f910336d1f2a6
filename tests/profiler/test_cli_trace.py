"""``hilbench trace`` as a user runs it (real subprocesses): files, stdin, JSON keys, export, Gantt, compare,
windows, strict mode and one-line errors."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys

import pytest

JSON_TASK_KEYS = {"count", "mean_us", "min_us", "max_us", "total_us", "share", "freq_hz", "period_mean_us",
                  "jitter_us"}


def run(*args: str, stdin: bytes | None = None, check_rc: int | None = 0) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "trace", *args], input=stdin,
                          capture_output=True, timeout=60)
    if check_rc is not None:
        assert proc.returncode == check_rc, proc.stderr.decode()
    return proc


@pytest.fixture
def trace64(spec, tmp_path):
    path = tmp_path / "t64.txt"
    path.write_bytes(spec.lines(spec.TRACE_64))
    return path


SPEC_ARGS = ("--tasks", "IDLE,wheel_ctrl,tsink", "--period", "wheel_ctrl=1kHz", "--merge-gap", "wheel_ctrl=500",
             "--deadline", "wheel_ctrl=25us")


def test_help():
    out = run("--help").stdout.decode()
    for opt in ("--json", "--export", "--gantt", "--window", "--period", "--compare", "--live", "--tasks", "udp://"):
        assert opt in out


def test_json_document_has_the_issue_keys_and_the_spec_figures(trace64, tmp_path):
    doc = json.loads(run(str(trace64), "--json", *SPEC_ARGS).stdout)
    assert set(doc) >= {"tasks", "quality", "runtime_stats", "window"}
    for name in ("IDLE", "wheel_ctrl", "tsink", "pid"):
        assert set(doc["tasks"][name]) >= JSON_TASK_KEYS, name
    wc = doc["tasks"]["wheel_ctrl"]
    assert (wc["count"], wc["total_us"], wc["jitter_us"], wc["deadline_misses"]) == (7, 72, 22, 1)
    assert wc["share"] == pytest.approx(1.4368, abs=1e-4) and wc["freq_hz"] == pytest.approx(999.80, abs=0.01)
    assert doc["quality"]["out_of_order"] == 2 and doc["quality"]["untrustworthy"] is False
    assert doc["runtime_stats"] is None and doc["window"]["W_us"] == 5011


def test_table_export_and_gantt_from_stdin(spec, tmp_path):
    export, gantt = tmp_path / "trace.json", tmp_path / "g.png"
    proc = run("-", *SPEC_ARGS, "--export", str(export), "--gantt", str(gantt), "--gantt-window", "2.9ms:3.1ms",
               "--hist", "latency", stdin=spec.lines(spec.TRACE_64))
    out = proc.stdout.decode()
    assert "Trace profile of stdin" in out and "wheel_ctrl" in out and "fn pid" in out and "98.364" in out
    assert "latency histogram" in out and "Periodicity against nominal periods" in out
    doc = json.loads(export.read_text())
    assert {e["name"] for e in doc["traceEvents"] if e["ph"] == "X"} == {"wheel_ctrl", "IDLE", "tsink", "pid"}
    assert gantt.stat().st_size > 5000 and b"4 rows" in proc.stderr


def test_report_beside_the_runtime_statistics(spec, tmp_path):
    path = tmp_path / "l38.txt"
    path.write_bytes(spec.lines(spec.LISTING_38) + spec.REPORT_65)
    proc = run(str(path), "--strict", check_rc=3)  # the excerpt lacks 76,129 hook stamps: untrustworthy
    out = proc.stdout.decode()
    assert "Run-time statistics of the board beside the profiler" in out and "UNTRUSTWORTHY" in out
    assert "estimated_drops=76129" in proc.stderr.decode()
    doc = json.loads(run(str(path), "--json").stdout)
    assert doc["runtime_stats"]["tasks"]["IDLE"]["pct_printed"] == 95


def test_window_and_compare_with_a_saved_run(trace64, tmp_path):
    base = tmp_path / "base.json"
    run(str(trace64), *SPEC_ARGS, "--json-out", str(base))
    doc = json.loads(run(str(trace64), *SPEC_ARGS, "--window", "2ms:4.1ms", "--json", "--compare",
                         str(base)).stdout)
    assert doc["window"]["t_first_us"] == 2007 and doc["window"]["t_last_us"] == 4011  # stamps inside 2000..4100
    c = doc["compare"]["tasks"]["wheel_ctrl"]
    assert c["base_total"] == 72 and c["other_total"] == 31 and round(c["change_total_pct"], 2) == -56.94
    proc = run(str(trace64), *SPEC_ARGS, "--compare", str(trace64))  # a capture file works as the baseline too
    assert b"Comparison" in proc.stdout and b"+0.00" in proc.stdout


@pytest.mark.parametrize(("args", "message", "code"), [
    (("/nonexistent/trace.txt",), "no such file, port or source", 1),  # not there (hilbench.errors' rule)
    (("udp://127.0.0.1:99999",), "expected HOST:PORT", 2),
    (("x.txt", "--period", "wheel_ctrl"), "expected NAME=VALUE", 2),
    (("x.txt", "--window", "5:1"), "window end before its start", 2),
])
def test_errors_are_one_line(args, message, code, tmp_path):
    (tmp_path / "x.txt").write_bytes(b"a 1 in\n")
    proc = subprocess.run([sys.executable, "-m", "hilbench.cli", "trace", *args], capture_output=True,
                          timeout=60, cwd=tmp_path)
    assert proc.returncode == code
    err = proc.stderr.decode().strip().splitlines()
    assert message in err[-1] and not any("Traceback" in line for line in err)


def test_gantt_suffix_error(trace64, tmp_path):
    proc = run(str(trace64), "--gantt", str(tmp_path / "g.jpg"), check_rc=2)
    assert proc.stderr.decode().strip() == f"hilbench: error: --gantt {tmp_path / 'g.jpg'}: the Gantt chart is " \
                                           "drawn as .png or .svg"


def test_live_view_on_a_file_ends_with_the_full_report(trace64):
    proc = run(str(trace64), *SPEC_ARGS, "--live", "--live-gantt", "6ms")
    out = proc.stdout.decode()
    assert "rate Hz" in out and "last 6 ms" in out and "Trace profile of" in out


def test_linear_histograms_are_printed_and_in_the_json(trace64, tmp_path):
    out = tmp_path / "run.json"
    proc = run(str(trace64), *SPEC_ARGS, "--hist", "duration:linear,latency:linear", "--bins", "4", "--only",
               "wheel_ctrl", "--json-out", str(out))
    text = proc.stdout.decode()
    assert "duration histogram, linear bins" in text and "latency histogram, linear bins" in text
    hists = json.loads(out.read_text())["tasks"]["wheel_ctrl"]["histograms"]
    assert sum(hists["duration_linear"]["counts"]) == 7 and len(hists["duration_linear"]["edges"]) == 5
    assert sum(hists["latency_linear"]["counts"]) == 6  # one release latency per job (spec §6.4)
    assert sum(hists["response_linear"]["counts"]) == 6
    bad = run(str(trace64), "--hist", "durations", check_rc=2)
    assert b"unknown histogram 'durations'" in bad.stderr


def test_a_dynamixel_bench_is_refused_not_profiled(hilbench_emulator, tmp_path):
    """`profile MANIFEST` of a servo bus: one line pointing to `hilbench monitor`, exit 2, no empty profile."""
    manifest = hilbench_emulator("arm")
    mfile = tmp_path / "bench.json"
    mfile.write_text(json.dumps({k: v for k, v in manifest.items() if k != "process"}))
    tap = manifest["endpoints"][0]["tap"]
    for source, name in ((str(mfile), f"{mfile}#arm"), (f"{mfile}#arm", f"{mfile}#arm"), (tap, tap)):
        proc = run(source, "--duration", "1", "--json", check_rc=2)
        assert proc.stdout == b""
        assert proc.stderr.decode().splitlines() == [
            f"hilbench: error: {name} carries dynamixel, not vel2d (Dynamixel Protocol 2.0 bus: use `hilbench "
            "monitor`)"]


@pytest.mark.parametrize(("content", "message"), [
    (random.Random(23).randbytes(4096), "neither a `hilbench trace --json` document nor a board's trace"),
    (b'{"devices": {"1": {}}}', "not a `hilbench trace --json` document (no 'tasks' table of figures)"),
    (b'{"tasks": {"IDLE": 3}}', "not a `hilbench trace --json` document (no 'tasks' table of figures)"),
    (b"[1, 2]", "not a `hilbench trace --json` document"),
    (b"{\xff\xfe", "not JSON"),
])
def test_compare_refuses_what_is_not_a_run_in_one_line(trace64, tmp_path, content, message):
    other = tmp_path / "other.bin"
    other.write_bytes(content)
    proc = run(str(trace64), "--compare", str(other), "--json", check_rc=2)
    assert proc.stdout == b""
    (line,) = proc.stderr.decode().splitlines()
    assert line.startswith(f"hilbench: error: --compare {other}: ") and message in line


def test_a_duration_that_cuts_a_line_is_no_damage(spec, tmp_path):
    """A live source stopped by --duration mid-line: the cut line is dropped, not counted as unreadable."""
    fifo = tmp_path / "trace"
    os.mkfifo(fifo)
    data = spec.lines(spec.TRACE_64)
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "trace", str(fifo), "--duration", "1", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    fd = os.open(fifo, os.O_WRONLY)  # returns once the profiler has opened the FIFO
    try:
        os.write(fd, data[:-3])  # the last line, "tsink 3030 out", cut after "o"; the writer stays
        out, err = proc.communicate(timeout=30)
    finally:
        os.close(fd)
    assert proc.returncode == 0, err.decode()
    q = json.loads(out)["quality"]
    assert q["untrustworthy"] is False and q["parse_errors"] == 0 and q["reasons"] == []
    assert q["cut_bytes"] == len(b"tsink 3030 o") and q["stamps"] == 31
    # a file that ends mid-line is damaged: nobody chose to stop there
    cut = tmp_path / "cut.txt"
    cut.write_bytes(data[:-3])
    q = json.loads(run(str(cut), "--json").stdout)["quality"]
    assert q["untrustworthy"] is True and q["parse_errors"] == 1 and q["cut_bytes"] == 0



def test_a_live_stream_joined_mid_line_is_no_damage(spec, tmp_path):
    """Joining a running stream (a bench's tap, a port the board already writes to) starts inside a line: its
    unreadable tail is cut, not damage; the same bytes in a file are damage (nobody chose to start there)."""
    data = spec.lines(spec.TRACE_64)[5:]  # "IDLE 0 out" joined after "IDLE ": "0 out" is no line
    fifo = tmp_path / "trace"
    os.mkfifo(fifo)
    proc = subprocess.Popen([sys.executable, "-m", "hilbench.cli", "trace", str(fifo), "--duration", "1", "--json",
                             "--strict"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    fd = os.open(fifo, os.O_WRONLY)
    try:
        os.write(fd, data[:-3])  # and cut at the end by --duration, as the test above
        out, err = proc.communicate(timeout=30)
    finally:
        os.close(fd)
    assert proc.returncode == 0, err.decode()
    q = json.loads(out)["quality"]
    assert q["untrustworthy"] is False and q["parse_errors"] == 0 and q["unreadable_lines"] == []
    assert q["cut_bytes"] == len(b"0 out\n") + len(b"tsink 3030 o") and q["stamps"] == 30
    cut = tmp_path / "cut.txt"
    cut.write_bytes(data)
    q = json.loads(run(str(cut), "--json").stdout)["quality"]
    assert q["untrustworthy"] is True and q["parse_errors"] == 1 and q["cut_bytes"] == 0

def test_the_board_s_defaults_come_from_its_family_s_trace_instrument():
    """`hilbench trace` names no board: the serial rate, the board's side of a bench line and the exported
    process name are the trace instrument's the rover family registers (hilbench.profiler.stm32_rover)."""
    from types import SimpleNamespace

    from hilbench import registry
    from hilbench.cli import build_parser
    from hilbench.cli.trace import _device_name, board_sources
    from hilbench.profiler.instrument import default_baud, trace_instrument

    rover = registry.instruments.get("vel2d")
    assert type(rover).__module__ == "hilbench.profiler.stm32_rover"
    assert trace_instrument("vel2d") is rover and trace_instrument("tracestamp") is rover
    assert trace_instrument("dynamixel") is None and trace_instrument(None) is None
    assert default_baud() == rover.default_baud == 115_200
    verb = build_parser(["trace"])._subparsers._group_actions[0].choices["trace"]
    baud = next(a for a in verb._actions if a.dest == "baud")
    assert f"(default {rover.default_baud})" in baud.help  # the help says what default_baud() gives
    on_board_line = board_sources(SimpleNamespace(protocol="vel2d"), None)
    assert on_board_line("rover-board") and not on_board_line("rover")
    assert board_sources(SimpleNamespace(protocol=None), None)("rover")  # elsewhere: every source
    assert board_sources(SimpleNamespace(protocol="vel2d"), "rov*")("rover")  # --from wins
    assert _device_name("vel2d") == _device_name(None) == rover.device_name == "stm32f767-rover"
