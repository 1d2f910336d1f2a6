"""Nothing a user recorded is lost: every verb that writes a file refuses to write over its input, a recording
never replaces one silently, a refusal creates nothing, a full disk or a kill leaves the old file whole, and a
recording killed with -9 keeps what it recorded up to the last half second."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hilbench import cli
from hilbench.pytest_plugin import wait_until
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from tests.conftest import WOLFGANG_TRACE

HB = [sys.executable, "-m", "hilbench.cli"]


@pytest.fixture
def hb(capsys):
    """``hb(*args)`` runs the command line in this process: ``(exit status, stdout, stderr)``."""
    saved = signal.getsignal(signal.SIGTERM)

    def run(*args: str) -> tuple[int, str, str]:
        capsys.readouterr()
        code = cli.main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out, err

    yield run
    signal.signal(signal.SIGTERM, saved)


def refused(result: tuple[int, str, str], *needles: str) -> None:
    code, _out, err = result
    assert code == 2, err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hilbench: error: ") and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A hilbench capture of the Wolfgang trace, made once."""
    path = tmp_path_factory.mktemp("recorded") / "rec.hbcap"
    with CaptureReader(WOLFGANG_TRACE, raw_baud=2_000_000) as reader, \
            CaptureWriter(path, baud=2_000_000, protocol="dynamixel", timestamps="synthetic") as writer:
        for chunk in reader:
            writer.chunk(chunk)
    return path


@pytest.fixture
def capture(recorded, tmp_path):
    """A user's recording (``rec.hbcap``, the Wolfgang trace) in the test's directory."""
    return Path(shutil.copy(recorded, tmp_path / "rec.hbcap"))


def snapshot(path) -> tuple[bytes, int]:
    return path.read_bytes(), path.stat().st_mtime_ns


# --------------------------------------------------------------------------- an output that is an input


def test_record_refuses_to_write_over_its_input_by_any_name(hb, capture, tmp_path):
    before = snapshot(capture)
    (tmp_path / "link.hbcap").symlink_to(capture.name)
    os.link(capture, tmp_path / "hard.hbcap")
    refused(hb("record", capture, capture), f"FILE {capture} is the input: writing it would destroy what is read")
    refused(hb("record", capture, tmp_path / "link.hbcap", "--force"), "is the input")
    refused(hb("record", tmp_path / "link.hbcap", tmp_path / "hard.hbcap", "--force"), "is the input")
    refused(hb("monitor", capture, "--record", capture, "--summary"), f"--record {capture} is the input")
    assert snapshot(capture) == before
    assert sorted(os.listdir(tmp_path)) == ["hard.hbcap", "link.hbcap", "rec.hbcap"]


def test_stdin_and_stdout_redirected_to_the_file_count_too(capture):
    before = snapshot(capture)
    with open(capture, "rb") as stdin:
        proc = subprocess.run([*HB, "record", "-", str(capture), "--force"], stdin=stdin, capture_output=True,
                              text=True, timeout=60)
    assert proc.returncode == 2 and "is the input (standard input)" in proc.stderr
    with open(capture, "ab") as stdout:
        proc = subprocess.run([*HB, "record", str(capture), "-"], stdout=stdout, stderr=subprocess.PIPE,
                              text=True, timeout=60)
    assert proc.returncode == 2 and "standard output is the input" in proc.stderr
    assert snapshot(capture) == before


def test_every_verb_with_an_input_and_an_output_refuses_the_same_file(hb, capture, tmp_path):
    trace = tmp_path / "trace.txt"
    trace.write_text("IDLE 0 out\nwheel_ctrl 0 in\nwheel_ctrl 10 out\nIDLE 10 in\n")
    profile = tmp_path / "rover.toml"
    profile.write_text('schema = 1\n[endpoints.can]\ntype = "can"\nprotocol = "can"\n'
                       '[[devices]]\nmodel = "stm32f767-rover-canopen"\nname = "rover"\n')
    manifest = tmp_path / "bench.json"
    manifest.write_text("{}")
    files = {p: snapshot(p) for p in (capture, trace, profile, manifest)}
    refused(hb("trace", trace, "--json-out", trace), f"--json-out {trace} is the input")
    refused(hb("trace", trace, "--export", trace), "--export")
    refused(hb("trace", trace, "--gantt", tmp_path / "trace.png", "--compare", tmp_path / "trace.png"),
            "--gantt")
    refused(hb("trace", trace, "--json-out", tmp_path / "a.json", "--export", f"{tmp_path}/./a.json"),
            "--json-out and --export name the same file")
    refused(hb("can", "dbc", profile, "-o", profile), f"-o {profile} is the input")
    refused(hb("can", "eds", profile, "-o", profile), "is the input")
    refused(hb("labgrid", "exporter-config", manifest, "-o", manifest), f"-o {manifest} is the input")
    refused(hb("labgrid", "env", manifest, "-o", manifest), "is the input")
    refused(hb("lidar", f"{manifest}#lms", "--png", manifest), "--png", "is the input")
    refused(hb("monitor", f"bench:{profile}", "--record", profile, "--summary"), "is the input")
    refused(hb("tap", "/dev/null", "--record", "/dev/null", "--summary"), "--record /dev/null is the input")
    # the files an instrument's options read: a DBC, an EDS (even with --force, which replaces recordings only)
    dbc, eds = tmp_path / "board.dbc", tmp_path / "board.eds"
    dbc.write_text('VERSION "the lab\'s own"\n')
    eds.write_text("[FileInfo]\n")
    files |= {p: snapshot(p) for p in (dbc, eds)}
    refused(hb("monitor", capture, "--dbc", dbc, "--record", dbc, "--summary", "--force"),
            f"--record {dbc} is the input")
    refused(hb("monitor", capture, "--eds", f"{eds}:2", "--record", eds, "--summary", "--force"),
            f"--record {eds} is the input")
    refused(hb("tap", "/dev/null", "--dbc", dbc, "--record", dbc, "--summary", "--force"), "is the input")
    assert {p: snapshot(p) for p in files} == files
    assert sorted(os.listdir(tmp_path)) == ["bench.json", "board.dbc", "board.eds", "rec.hbcap", "rover.toml",
                                            "trace.txt"]


def test_an_output_in_a_missing_directory_is_refused_before_anything_runs(hb, capture, tmp_path):
    refused(hb("record", capture, tmp_path / "no" / "r.hbcap"), "no directory")
    refused(hb("can", "dbc", "mecarover-can", "-o", tmp_path / "no" / "x.dbc"), "-o", "no directory")
    refused(hb("record", capture, tmp_path), "is a directory")
    assert sorted(os.listdir(tmp_path)) == ["rec.hbcap"]


# --------------------------------------------------------------------------- recordings


def test_a_recording_never_replaces_a_file_without_force(hb, capture, tmp_path):
    out = tmp_path / "new.hbcap"
    out.write_bytes(b"a capture of real hardware")
    refused(hb("record", capture, out), f"{out}: exists (26 bytes); a recording does not replace a file",
            "--force")
    refused(hb("monitor", capture, "--record", out, "--summary"), "exists (26 bytes)")
    assert out.read_bytes() == b"a capture of real hardware"
    code, _, err = hb("record", capture, out, "--force")
    assert code == 0, err
    with CaptureReader(out) as reader:
        assert sum(len(c.data) for c in reader) == WOLFGANG_TRACE.stat().st_size
    assert sorted(os.listdir(tmp_path)) == ["new.hbcap", "rec.hbcap"]


def test_monitor_record_renames_its_recording_into_place(hb, capture, tmp_path):
    out = tmp_path / "copy.hbcap"
    code, _, err = hb("monitor", capture, "--record", out, "--summary")
    assert code == 0, err
    with CaptureReader(out) as copy, CaptureReader(capture) as original:
        assert [(c.t, c.data) for c in copy] == [(c.t, c.data) for c in original]
    assert sorted(os.listdir(tmp_path)) == ["copy.hbcap", "rec.hbcap"]


def test_a_refused_recording_creates_nothing(hb, capture, tmp_path):
    code, _, err = hb("record", capture, tmp_path / "out.pcap")
    assert code == 2 and f"{tmp_path / 'out.pcap'}: bus is not UDP traffic" in err, err
    assert sorted(os.listdir(tmp_path)) == ["rec.hbcap"]


def test_a_recording_refused_inside_monitor_creates_nothing(hb, tmp_path):
    code, _, err = hb("monitor", WOLFGANG_TRACE, "--protocol", "dynamixel", "--record", tmp_path / "out.pcap",
                      "--summary")
    assert code == 2 and "out.pcap: bus is not UDP traffic" in err and "partial" not in err, err
    assert os.listdir(tmp_path) == []


def test_a_live_recording_stopped_by_a_signal_is_renamed_into_place(tmp_path):
    out = tmp_path / "live.hbcap"
    proc = subprocess.Popen([*HB, "record", "-", str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    data = WOLFGANG_TRACE.read_bytes()[:1000]
    proc.stdin.write(data)
    proc.stdin.flush()
    wait_until(lambda: os.path.exists(tmp_path / "live.partial.hbcap")
               and os.path.getsize(tmp_path / "live.partial.hbcap") > len(data), timeout=20)
    proc.send_signal(signal.SIGTERM)  # the input stays open: the signal ends the recording
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert os.listdir(tmp_path) == ["live.hbcap"]
    with CaptureReader(out) as reader:
        assert b"".join(c.data for c in reader) == data


def test_a_full_device_is_one_line_and_exit_1(hb, capture):
    code, _, err = hb("record", capture, "/dev/full")
    assert code == 1 and err == "hilbench: error: /dev/full: cannot write: No space left on device\n"


def _limited(size: int):
    def limit() -> None:  # writes beyond `size` bytes fail with EFBIG, as a full disk fails with ENOSPC
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))
    return limit


def test_a_full_disk_leaves_the_old_dbc_whole(tmp_path):
    old = tmp_path / "old.dbc"
    old.write_text("VERSION \"the user's own\"\n")
    proc = subprocess.run([*HB, "can", "dbc", "mecarover-can", "-o", str(old)], capture_output=True, text=True,
                          timeout=60, preexec_fn=_limited(2048), env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    assert proc.returncode == 1
    assert proc.stderr == f"hilbench: error: {old}: cannot write: File too large (the old {old} is unchanged)\n"
    assert old.read_text() == "VERSION \"the user's own\"\n"
    assert os.listdir(tmp_path) == ["old.dbc"]


def test_a_full_disk_stops_a_recording_and_keeps_the_old_file_and_what_was_recorded(capture, tmp_path):
    old = tmp_path / "old.hbcap"
    old.write_bytes(b"an earlier recording")
    proc = subprocess.run([*HB, "record", str(capture), str(old), "--force"], capture_output=True, text=True,
                          timeout=60, preexec_fn=_limited(100_000), env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    partial = tmp_path / "old.partial.hbcap"
    assert proc.returncode == 1
    assert proc.stderr == (f"hilbench: error: {old}: recording stopped: File too large; what was written before is "
                           f"in {partial}; the old {old} is unchanged\n")
    assert old.read_bytes() == b"an earlier recording"
    assert 0 < partial.stat().st_size <= 100_000
    with CaptureReader(partial) as reader:
        assert sum(len(c.data) for c in reader) > 0


def test_a_recording_killed_with_sigkill_keeps_what_it_recorded(hb, tmp_path):
    """A live recording is flushed every half second: kill -9 loses at most that, and the data is readable."""
    out = tmp_path / "live.hbcap"
    partial = tmp_path / "live.partial.hbcap"
    proc = subprocess.Popen([*HB, "record", "-", str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        head = WOLFGANG_TRACE.read_bytes()[:4000]  # a few Dynamixel packets, sent live on stdin
        proc.stdin.write(head)
        proc.stdin.flush()
        # the data is on disk while the recorder runs and its input stays open (a flush, not an exit)
        wait_until(lambda: partial.exists() and partial.stat().st_size > len(head), timeout=20)
        t = time.monotonic()
        proc.stdin.write(head)
        proc.stdin.flush()
        wait_until(lambda: partial.stat().st_size > 2 * len(head), timeout=20)
        flushed_within = time.monotonic() - t
        assert proc.poll() is None
    finally:
        proc.kill()
        proc.communicate(timeout=20)
    assert flushed_within < 5  # 0.5 s by design; generous for a loaded machine, but no exit-time flush
    assert sorted(os.listdir(tmp_path)) == ["live.partial.hbcap"]
    with CaptureReader(partial) as reader:
        assert b"".join(c.data for c in reader) == head + head
    code, out_text, err = hb("monitor", partial, "--protocol", "dynamixel", "--json")
    assert code == 0, err
    assert json.loads(out_text)["bytes"] == 2 * len(head)
    # the next recording to that name does not replace what the killed one left
    refused(hb("record", WOLFGANG_TRACE, out), "live.partial.hbcap holds", "--force")
    refused(hb("record", partial, out, "--force"), f"records into {partial}, the input")
    assert sorted(os.listdir(tmp_path)) == ["live.partial.hbcap"]


# --------------------------------------------------------------------------- hilbench world's files


def test_world_png_and_record_follow_the_output_rules(hb, hilbench_bench, tmp_path):
    """``world --png`` and ``--record``: never the manifest read, a recording never replaces a file without
    --force and is renamed into place when it ends, a picture replaces its file in one step."""
    from hilbench.fakes.world import read_record

    bench = hilbench_bench("arena")
    control = bench.serve_control().address_text
    manifest = tmp_path / "bench.json"
    bench.write_manifest(manifest)
    (tmp_path / "link.json").symlink_to(manifest.name)
    before = snapshot(manifest)
    refused(hb("world", manifest, "--png", manifest), f"--png {manifest} is the input")
    refused(hb("world", tmp_path / "link.json", "--record", manifest), "--record", "is the input")
    refused(hb("world", manifest, "--png", tmp_path / "w.jpeg"), "the world is drawn as .png (or .svg, .pdf)")
    old = tmp_path / "truth.jsonl"
    old.write_text("a record of yesterday's run\n")
    refused(hb("world", "--control", control, "--record", old, "--duration", "0.5"), "exists (28 bytes)",
            "--force")
    assert old.read_text() == "a record of yesterday's run\n" and snapshot(manifest) == before
    assert sorted(os.listdir(tmp_path)) == ["bench.json", "link.json", "truth.jsonl"]
    code, _, err = hb("world", "--control", control, "--record", old, "--duration", "0.6", "--force")
    assert code == 0, err
    rec = read_record(str(old))
    assert rec["header"]["bodies"].keys() == {"r1", "r2"} and rec["poses"]
    png = tmp_path / "w.png"
    png.write_bytes(b"an old picture")
    code, _, err = hb("world", "--control", control, "--png", png)
    assert code == 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", err
    assert sorted(os.listdir(tmp_path)) == ["bench.json", "link.json", "truth.jsonl", "w.png"]


def test_world_record_stopped_by_sigterm_is_renamed_into_place(hilbench_bench, tmp_path):
    bench = hilbench_bench("arena")
    control = bench.serve_control().address_text
    out = tmp_path / "truth.jsonl"
    partial = tmp_path / "truth.partial.jsonl"
    proc = subprocess.Popen([*HB, "world", "--control", control, "--record", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        # streamed (and flushed) while it runs: a kill -9 would leave this much
        wait_until(lambda: partial.exists() and partial.stat().st_size > 1000, timeout=30)
        assert not out.exists()
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert os.listdir(tmp_path) == ["truth.jsonl"]
    from hilbench.fakes.world import read_record

    assert len(read_record(str(out))["poses"]) > 10


@pytest.mark.parametrize("writer", ["trace --json-out", "trace --export", "profiles from-capture -o"])
def test_a_full_disk_leaves_every_writer_s_old_file_whole(writer, capture, tmp_path):
    """The neighbours of ``can dbc -o``: every other writer goes through the same atomic write."""
    trace = tmp_path / "trace.txt"
    trace.write_text("IDLE 0 out\nwheel_ctrl 0 in\nwheel_ctrl 10 out\nIDLE 10 in\n" * 20)
    old = tmp_path / "old.out"
    old.write_text("the user's own\n")
    argv = {"trace --json-out": ["trace", str(trace), "--json-out", str(old)],
            "trace --export": ["trace", str(trace), "--export", str(old)],
            "profiles from-capture -o": ["profiles", "from-capture", str(capture), "-o", str(old), "--force"]}[writer]
    proc = subprocess.run([*HB, *argv], capture_output=True, text=True, timeout=60, preexec_fn=_limited(400),
                          env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.endswith(f"hilbench: error: {old}: cannot write: File too large (the old {old} is "
                                "unchanged)\n"), proc.stderr
    assert old.read_text() == "the user's own\n"
    assert sorted(os.listdir(tmp_path)) == ["old.out", "rec.hbcap", "trace.txt"]


def test_monitor_record_killed_with_sigkill_keeps_what_it_recorded(tmp_path):
    """monitor --record flushes as record does (the same Recording): a kill -9 leaves the data readable."""
    out = tmp_path / "live.hbcap"
    partial = tmp_path / "live.partial.hbcap"
    proc = subprocess.Popen([*HB, "monitor", "-", "--protocol", "dynamixel", "--record", str(out), "--summary"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        head = WOLFGANG_TRACE.read_bytes()[:4000]
        proc.stdin.write(head)
        proc.stdin.flush()
        wait_until(lambda: partial.exists() and partial.stat().st_size > len(head), timeout=20)
        assert proc.poll() is None  # flushed while running, not at exit
    finally:
        proc.kill()
        proc.communicate(timeout=20)
    assert sorted(os.listdir(tmp_path)) == ["live.partial.hbcap"]
    with CaptureReader(partial) as reader:
        assert b"".join(c.data for c in reader) == head


def test_the_world_record_of_the_python_api_is_a_recording_too(tmp_path):
    """``bench.world.record(path)``: streamed into its .partial file (flushed while it runs), the old file whole
    until the record ends, renamed into place by stop_recording or when the bench stops."""
    from hilbench.bench import Bench
    from hilbench.fakes.world import read_record

    first, second = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    second.write_text("yesterday's truth\n")
    with Bench("arena") as bench:
        rec_a = bench.world.record(str(first))
        bench.world.record(str(second))
        wait_until(lambda: (tmp_path / "b.partial.jsonl").stat().st_size > 1000, timeout=20)
        assert second.read_text() == "yesterday's truth\n" and not first.exists()
        bench.world.stop_recording(rec_a)
        assert read_record(str(first))["poses"]
    assert sorted(os.listdir(tmp_path)) == ["a.jsonl", "b.jsonl"]
    assert read_record(str(second))["header"]["bench"] == "arena"


def test_a_picture_of_a_format_not_drawn_is_refused_before_anything_runs(hb, tmp_path):
    missing = tmp_path / "gone.json"  # (checked first: the refusal comes before the source is looked for)
    refused(hb("trace", missing, "--gantt", tmp_path / "g.pdf"), "--gantt", "the Gantt chart is drawn as .png or .svg")
    refused(hb("world", missing, "--png", tmp_path / "w.jpeg"), "--png", "the world is drawn as .png (or .svg, .pdf)")
    refused(hb("lidar", missing, "--png", tmp_path / "l.txt"), "--png", "the scan is drawn as .png (or .svg, .pdf)")
    assert os.listdir(tmp_path) == []
