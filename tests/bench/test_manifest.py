"""Manifests: never replace a file hilbench did not write, remove only our own, report a bench that is gone."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from hilbench.bench.control import ControlClient, ControlError
from hilbench.bench.manifest import (
    MARKER,
    BenchNotRunning,
    ManifestBusy,
    ManifestError,
    devices_on,
    endpoint_of,
    read_manifest,
    remove_manifest,
    write_manifest,
)
from hilbench.errors import UsageError
from hilbench.pytest_plugin import wait_until
from hilbench.transports.sources import SourceError, open_source
from tests.conftest import interrupt


def hb(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hilbench.cli", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The pid of a process that has ended."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def doc(pid: int, **extra) -> dict:
    return {"pid": pid, "endpoints": [{"name": "arm", "tap": "tcp://127.0.0.1:1"}], "devices": [], **extra}


def test_a_manifest_is_marked_and_removed_only_while_it_is_ours(tmp_path):
    path = tmp_path / "bench.json"
    claim = write_manifest(path, doc(os.getpid()))
    data = json.loads(path.read_text())
    assert data[MARKER] == 1 and data["pid"] == os.getpid() and data["token"] == claim.token
    assert not [p for p in tmp_path.iterdir() if p != path]  # no temporary file left behind
    assert read_manifest(path)["endpoints"][0]["name"] == "arm"
    # rewriting our own manifest is fine
    again = write_manifest(path, doc(os.getpid(), note="later"), token=claim.token)
    assert json.loads(path.read_text())["note"] == "later"
    # the user put their own file there meanwhile: it stays
    path.write_text("schema = 1\n")
    assert not remove_manifest(again) and path.read_text() == "schema = 1\n"
    # another bench's manifest (other token) stays too
    path.unlink()
    other = write_manifest(path, doc(os.getpid()))
    assert not remove_manifest(again) and json.loads(path.read_text())["token"] == other.token
    assert remove_manifest(other) and not path.exists()


@pytest.mark.parametrize("content", ["schema = 1\n[endpoints.arm]\n", '{"a": 1}', "", "\xff\xfe garbage"])
def test_a_file_hilbench_did_not_write_is_never_replaced(tmp_path, content):
    path = tmp_path / "myarm.toml"
    path.write_bytes(content.encode("latin-1"))
    with pytest.raises(ManifestError, match="exists and is not a hilbench manifest; refusing to replace it"):
        write_manifest(path, doc(os.getpid()))
    assert path.read_bytes() == content.encode("latin-1")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["myarm.toml"]


def test_symlinks_and_directories_are_not_replaced(tmp_path):
    target = tmp_path / "profile.toml"
    target.write_text("schema = 1\n")
    link = tmp_path / "link.json"
    link.symlink_to(target)
    with pytest.raises(ManifestError, match="not a regular file"):
        write_manifest(link, doc(os.getpid()))
    assert link.is_symlink() and target.read_text() == "schema = 1\n"
    with pytest.raises(ManifestError, match="not a regular file"):
        write_manifest(tmp_path, doc(os.getpid()))
    with pytest.raises(ManifestError, match="no directory"):
        write_manifest(tmp_path / "missing" / "m.json", doc(os.getpid()))


def test_a_running_benchs_manifest_is_refused_and_a_stale_one_taken_over(tmp_path, dead_pid):
    path = tmp_path / "bench.json"
    live = write_manifest(path, doc(os.getpid()))  # this process is alive: a running bench
    with pytest.raises(ManifestBusy, match=f"the manifest of a running bench \\(pid {os.getpid()}\\)"):
        write_manifest(path, doc(os.getpid()))
    assert json.loads(path.read_text())["token"] == live.token
    path.write_text(json.dumps({MARKER: 1, **doc(dead_pid), "token": "gone"}))
    claim = write_manifest(path, doc(os.getpid()))
    assert claim.took_over == dead_pid and json.loads(path.read_text())["token"] == claim.token


def test_a_recycled_pid_is_not_taken_for_the_bench(tmp_path):
    path = tmp_path / "bench.json"
    # our own pid, but a start time that is not this process's: the number was reused
    path.write_text(json.dumps({MARKER: 1, **doc(os.getpid()), "pid_start": 1, "token": "old"}))
    with pytest.raises(BenchNotRunning, match=f"bench not running \\(stale manifest, pid {os.getpid()} gone\\)"):
        read_manifest(path)
    assert write_manifest(path, doc(os.getpid())).took_over == os.getpid()


def test_every_reader_reports_a_stale_manifest_in_one_line(tmp_path, dead_pid):
    path = tmp_path / "bench.json"
    path.write_text(json.dumps({MARKER: 1, **doc(dead_pid, control="127.0.0.1:1"), "token": "x"}))
    message = f"{path}: bench not running (stale manifest, pid {dead_pid} gone)"
    with pytest.raises(BenchNotRunning) as exc:
        read_manifest(path)
    assert str(exc.value) == message
    with pytest.raises(BenchNotRunning, match="stale manifest"):
        open_source(str(path))
    with pytest.raises(BenchNotRunning, match="stale manifest"):
        ControlClient.from_manifest(path)
    for args in (["monitor", str(path), "--summary"], ["trace", str(path)], ["record", str(path), "-"],
                 ["board", "--manifest", str(path), "status"]):
        proc = hb(*args)
        assert proc.returncode == 1, (args, proc.stderr)
        assert proc.stderr.splitlines() == [f"hilbench: error: {message}"], args


def test_readers_refuse_what_is_not_a_manifest(tmp_path):
    path = tmp_path / "x.json"
    path.write_text("[1, 2]")
    with pytest.raises(SourceError, match="not a bench manifest"):
        open_source(str(path))
    with pytest.raises(ControlError, match="not a bench manifest"):
        ControlClient.from_manifest(path)
    with pytest.raises(BenchNotRunning, match="no such manifest"):  # a bench removes it when it stops: exit 1
        read_manifest(tmp_path / "missing.json")


#: The verbs that find a bench through its manifest: the manifest is read where MANIFEST stands.
MANIFEST_VERBS = {
    "can": ["can", "send", "MANIFEST", "123#00"],
    "lidar": ["lidar", "MANIFEST"],
    "labgrid": ["labgrid", "exporter-config", "MANIFEST"],
    "run": ["run", "--manifest", "MANIFEST", "--", "true"],
}


@pytest.mark.parametrize("verb", sorted(MANIFEST_VERBS))
@pytest.mark.parametrize("given", ["other JSON", "directory", "10 MB file", "missing", "stale"])
def test_every_verb_reads_manifests_the_same_way(verb, given, tmp_path, dead_pid, capsys):
    """Not a manifest: one line, exit status 2 (what was asked cannot work); no bench there: 1 (errors.py)."""
    from hilbench.cli import main

    path = tmp_path / "bench.json"
    if given == "other JSON":  # e.g. a `hilbench trace --json` document
        path.write_text('{"tasks": {}}')
        want, code = "not a bench manifest (no endpoints)", 2
    elif given == "directory":
        path.mkdir()
        want, code = "not a bench manifest (not a regular file)", 2
    elif given == "10 MB file":
        with open(path, "wb") as fh:
            fh.truncate(10 << 20)  # sparse: no 10 MB written
        want, code = f"not a bench manifest ({10 << 20} bytes)", 2
    elif given == "missing":
        want, code = "no such manifest (is the bench running? start it with hilbench emulate --manifest)", 1
    else:
        path.write_text(json.dumps({MARKER: 1, **doc(dead_pid), "name": "arm", "token": "x"}))
        want, code = f"bench not running (stale manifest, pid {dead_pid} gone)", 1
    argv = [str(path) if a == "MANIFEST" else a for a in MANIFEST_VERBS[verb]]
    assert main(argv) == code
    out, err = capsys.readouterr()
    assert err.splitlines() == [f"hilbench: error: {path}: {want}"] and out == ""


def test_endpoint_of_is_the_one_name_rule():
    data = {"endpoints": [{"name": "lidar", "protocol": "rplidar"}, {"name": "lms", "protocol": "sick-lms200"},
                          {"name": "arm", "protocol": "dynamixel"}],
            "devices": [{"name": "a1", "endpoint": "lidar"}, {"name": "s1", "endpoint": "arm"},
                        {"name": "s2", "endpoint": "arm"}]}
    scanner = lambda e: e["protocol"] != "dynamixel"  # noqa: E731
    assert endpoint_of(data, "lms", "b.json", scanner, "scanners")["name"] == "lms"
    assert endpoint_of(data, "", "b.json", lambda e: e["name"] == "arm", "servo buses")["name"] == "arm"
    for fragment, predicate, message in (
        ("nope", scanner, "b.json: no endpoint named 'nope' (endpoints: lidar, lms, arm)"),
        ("arm", scanner, "b.json: endpoint 'arm' is not among the scanners"),
        ("", scanner, "b.json: several scanners (lidar, lms); add #NAME"),
        ("", lambda e: False, "b.json: no scanners (endpoints: lidar, lms, arm)"),
    ):
        with pytest.raises(UsageError) as exc:
            endpoint_of(data, fragment, "b.json", predicate, "scanners")
        assert str(exc.value) == message and exc.value.exit_code == 2
    assert [d["name"] for d in devices_on(data, "arm")] == ["s1", "s2"]
    assert devices_on(data, {"name": "lms"}) == [] and devices_on({}, "arm") == []


def emulate(manifest, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "hilbench.cli", "emulate", "arm", "--unpaced", "--manifest",
                             str(manifest), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_emulate_keeps_the_users_profile_and_survives_a_kill(tmp_path):
    profile = tmp_path / "myarm.toml"
    profile.write_text("schema = 1\n")
    refused = hb("emulate", "arm", "--manifest", str(profile))
    assert refused.returncode == 2 and profile.read_text() == "schema = 1\n"
    assert refused.stderr.splitlines() == [f"hilbench: error: {profile}: exists and is not a hilbench manifest; "
                                           "refusing to replace it (choose another --manifest path)"]

    manifest = tmp_path / "bench.json"
    first = emulate(manifest)
    try:
        wait_until(lambda: manifest.exists() or first.poll() is not None, timeout=30)
        pid = read_manifest(manifest)["pid"]
        assert pid == first.pid
        busy = hb("emulate", "arm", "--manifest", str(manifest))
        assert busy.returncode == 1 and f"the manifest of a running bench (pid {pid})" in busy.stderr
    finally:
        first.kill()  # SIGKILL: no clean-up, the manifest stays behind
        first.communicate(timeout=10)
    assert manifest.exists()
    stale = hb("monitor", str(manifest), "--summary")
    assert stale.returncode == 1
    assert stale.stderr.splitlines() == [f"hilbench: error: {manifest}: bench not running (stale manifest, pid "
                                         f"{pid} gone)"]

    second = emulate(manifest)
    try:
        wait_until(lambda: (manifest.exists() and json.loads(manifest.read_text())["pid"] == second.pid)
                   or second.poll() is not None, timeout=30)
        assert read_manifest(manifest)["pid"] == second.pid
    finally:
        out, err = interrupt(second, timeout=10)  # (a hang fails with every thread's stack)
    assert second.returncode == 0, err
    assert f"took over a stale manifest (pid {pid} gone)" in err
    assert not manifest.exists()  # its own manifest is removed at the end
