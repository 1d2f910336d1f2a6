"""Writing files: a whole new file or the old one, never a fragment; recordings never replace one silently."""

from __future__ import annotations

import fcntl
import os
import stat
import subprocess
import sys

import pytest

from hilbench.transports.atomic_file import WriteError, atomic_write, write_atomically
from hilbench.transports.capture_file import CaptureReader, CaptureWriter
from hilbench.transports.chunk import CaptureError, Chunk
from hilbench.transports.pcap import PcapWriter
from hilbench.transports.recording_file import Recording, RecordingFile, RecordingRefused, partial_path


def listing(directory) -> list[str]:
    return sorted(os.listdir(directory))


# --------------------------------------------------------------------------- one-step replacement


def test_a_written_file_replaces_the_old_one_and_keeps_its_mode(tmp_path):
    path = tmp_path / "old.dbc"
    path.write_text("old")
    os.chmod(path, 0o640)
    write_atomically(path, "new contents")
    assert path.read_text() == "new contents"
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert listing(tmp_path) == ["old.dbc"]  # no temporary file left


def test_a_new_file_gets_the_mode_open_would_give_it(tmp_path):
    old = os.umask(0o027)
    try:
        write_atomically(tmp_path / "new.json", "{}")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "new.json").stat().st_mode) == 0o640


def test_an_error_while_writing_leaves_the_old_file_whole(tmp_path):
    path = tmp_path / "old.dbc"
    path.write_bytes(b"the user's file")
    with pytest.raises(RuntimeError), atomic_write(path) as f:
        f.write(b"x" * 100_000)
        raise RuntimeError("killed half way")
    assert path.read_bytes() == b"the user's file"
    assert listing(tmp_path) == ["old.dbc"]


def test_a_file_too_large_leaves_the_old_file_whole(tmp_path):
    # RLIMIT_FSIZE makes the write fail with EFBIG, as a full disk fails with ENOSPC, without root
    path = tmp_path / "old.dbc"
    path.write_bytes(b"the user's file")
    code = ("import resource, sys\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))\n"
            "from hilbench.transports.atomic_file import WriteError, write_atomically\n"
            "try:\n"
            f"    write_atomically({str(path)!r}, b'y' * 100_000)\n"
            "except WriteError as exc:\n"
            "    print(exc)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == f"{path}: cannot write: File too large (the old {path} is unchanged)", proc.stderr
    assert path.read_bytes() == b"the user's file"
    assert listing(tmp_path) == ["old.dbc"]


def test_a_symlink_is_written_through(tmp_path):
    (tmp_path / "real.json").write_text("old")
    (tmp_path / "link.json").symlink_to("real.json")
    write_atomically(tmp_path / "link.json", "new")
    assert os.readlink(tmp_path / "link.json") == "real.json"
    assert (tmp_path / "real.json").read_text() == "new"


def test_a_device_is_written_in_place_and_a_full_one_says_so():
    write_atomically("/dev/null", "nothing")  # cannot be replaced: written as it is
    with pytest.raises(WriteError, match=r"^/dev/full: cannot write: No space left on device$"):
        write_atomically("/dev/full", "x" * 10_000)


# --------------------------------------------------------------------------- recordings


@pytest.mark.parametrize(("name", "partial"), [
    ("rec.hbcap", "rec.partial.hbcap"), ("run.log.gz", "run.partial.log.gz"), ("my.run.asc", "my.run.partial.asc"),
    ("capture", "capture.partial"), (".hidden", ".hidden.partial"), ("x.pcapng", "x.partial.pcapng"),
])
def test_a_recording_runs_under_a_name_that_keeps_its_format_suffix(name, partial):
    assert partial_path(f"/d/{name}").name == partial


def capture_recording(path, **kw) -> Recording:
    return Recording(path, lambda p: CaptureWriter(p, protocol="dynamixel"), **kw)


def test_a_recording_is_renamed_into_place_when_it_ends(tmp_path):
    rec = capture_recording(tmp_path / "r.hbcap")
    rec.chunk(Chunk(0.0, "bus", b"\xff\xff\xfd\x00"))
    assert listing(tmp_path) == ["r.partial.hbcap"]
    rec.close()
    assert listing(tmp_path) == ["r.hbcap"]
    with CaptureReader(tmp_path / "r.hbcap") as reader:
        assert b"".join(c.data for c in reader) == b"\xff\xff\xfd\x00"


def test_a_recording_refuses_an_existing_file_unless_forced_and_keeps_its_mode(tmp_path):
    old = tmp_path / "r.hbcap"
    old.write_bytes(b"a recording of real hardware")
    os.chmod(old, 0o600)
    with pytest.raises(RecordingRefused, match=r"r.hbcap: exists \(28 bytes\); a recording does not replace"):
        capture_recording(old)
    assert old.read_bytes() == b"a recording of real hardware" and listing(tmp_path) == ["r.hbcap"]
    rec = capture_recording(old, force=True)
    rec.chunk(Chunk(0.0, "bus", b"new"))
    assert old.read_bytes() == b"a recording of real hardware"  # whole until the new one ends
    rec.close()
    assert old.read_bytes() != b"a recording of real hardware" and stat.S_IMODE(old.stat().st_mode) == 0o600


def test_an_empty_file_may_be_recorded_over(tmp_path):
    (tmp_path / "r.hbcap").touch()
    capture_recording(tmp_path / "r.hbcap").close()
    assert (tmp_path / "r.hbcap").stat().st_size > 0


def test_a_killed_recordings_data_is_not_replaced_unless_forced(tmp_path):
    (tmp_path / "r.partial.hbcap").write_bytes(b"what a killed recorder wrote")
    with pytest.raises(RecordingRefused, match="r.partial.hbcap holds 28 bytes of an earlier recording"):
        capture_recording(tmp_path / "r.hbcap")
    assert (tmp_path / "r.partial.hbcap").read_bytes() == b"what a killed recorder wrote"
    capture_recording(tmp_path / "r.hbcap", force=True).close()
    assert listing(tmp_path) == ["r.hbcap"]


def test_one_recorder_at_a_time_writes_a_file(tmp_path):
    first = capture_recording(tmp_path / "r.hbcap")
    with pytest.raises(RecordingRefused, match="another recording is writing"):
        capture_recording(tmp_path / "r.hbcap", force=True)
    first.close()
    # a lock another process holds counts too
    fd = os.open(tmp_path / "x.partial.hbcap", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        with pytest.raises(RecordingRefused, match="another recording is writing"):
            RecordingFile(tmp_path / "x.hbcap").claim()
    finally:
        os.close(fd)


def test_a_failed_write_stops_the_recording_and_keeps_what_was_written(tmp_path):
    class Full(CaptureWriter):
        def chunk(self, chunk):
            if chunk.data == b"too much":
                raise OSError(28, "No space left on device")
            super().chunk(chunk)

    old = tmp_path / "r.hbcap"
    old.write_bytes(b"old")
    rec = Recording(old, lambda p: Full(p), force=True)
    rec.chunk(Chunk(0.0, "bus", b"kept"))
    with pytest.raises(WriteError, match=r"recording stopped: No space left on device; what was written before is "
                                         r"in .*r.partial.hbcap; the old .*r.hbcap is unchanged"):
        rec.chunk(Chunk(0.1, "bus", b"too much"))
    rec.close()
    assert old.read_bytes() == b"old"
    with CaptureReader(tmp_path / "r.partial.hbcap") as reader:
        assert b"".join(c.data for c in reader) == b"kept"


def test_a_recording_refused_at_its_first_chunk_leaves_no_file(tmp_path):
    rec = Recording(tmp_path / "out.pcap", lambda p: PcapWriter(p))
    with pytest.raises(CaptureError, match=r"out.pcap: bus is not UDP traffic") as exc:
        rec.chunk(Chunk(0.0, "bus", b"serial bytes"))
    assert "partial" not in str(exc.value)  # named as the user named it: the .partial file goes away
    rec.close()
    assert listing(tmp_path) == []


def test_a_recording_to_a_full_device_says_so():
    rec = Recording("/dev/full", lambda p: CaptureWriter(p))
    rec.chunk(Chunk(0.0, "bus", b"x"))
    with pytest.raises(WriteError, match="^/dev/full: cannot write: No space left on device$"):
        rec.flush()
    rec.close()
